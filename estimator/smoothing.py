"""Smooth curves: the paper's 6th-degree polynomial, and weighted robust splines for profiles."""

from __future__ import annotations

import numpy as np

from estimator.spline_curve import evaluate, least_squares_spline


def chord_parameter(points: np.ndarray) -> np.ndarray:
    """Normalised cumulative chord length in [0, 1] along an ordered point set."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return arc / max(arc[-1], 1e-12)


def polynomial_smooth(points: np.ndarray, degree: int = 6) -> np.ndarray:
    """Fit each coordinate with a polynomial of the chord parameter and evaluate it in place.

    Args:
        points: (N, D) ordered points.
        degree: polynomial degree (paper: 6); lowered to N - 1 when there are few points.

    Returns:
        (N, D) smoothed points.
    """
    points = np.asarray(points, dtype=np.float64)
    t = chord_parameter(points)
    degree = min(degree, len(points) - 1)
    out = np.empty_like(points)
    for k in range(points.shape[1]):
        out[:, k] = np.polynomial.Polynomial.fit(t, points[:, k], degree)(t)
    return out


def robust_spline_profile(x: np.ndarray, y: np.ndarray, weights: np.ndarray, at: np.ndarray, *,
                          knots: int = 8, iterations: int = 3, huber: float = 1.5,
                          flat_start: bool = False) -> np.ndarray:
    """Weighted least-squares cubic spline y(x) with Huber reweighting, evaluated at ``at``.

    Used for the disparity along the arm: matches that rows pin down well carry large weights,
    and the spline carries the profile across stretches with none (curve along the rows,
    baseplates). Beyond the data the profile continues in a straight line.

    Args:
        x: (M,) positions (any order); y: (M,) values; weights: (M,) >= 0 (0 = ignore).
        knots: interior knots, spread over the weighted data by quantile.
        huber: residuals beyond this many robust standard deviations are down-weighted.
        flat_start: continue flat (zero slope) before the data instead of straight on.
    """
    use = (weights > 0) & np.isfinite(y)
    order = np.argsort(x[use], kind="stable")
    x, y, w = x[use][order], y[use][order], weights[use][order]
    if len(x) < 6:
        raise ValueError(f"too few weighted samples for a spline profile ({len(x)})")
    lo, hi = x.min(), x.max()
    inner = np.quantile(x, np.linspace(0, 1, knots + 2)[1:-1]) if knots > 0 else np.zeros(0)
    inner = np.unique(inner[(inner > lo + 1e-9) & (inner < hi - 1e-9)])
    t = np.concatenate([[lo] * 4, inner, [hi] * 4])
    robust = np.ones_like(w)
    values = np.ascontiguousarray(y, np.float64)[:, None]
    coefficients = None
    for _ in range(iterations):
        coefficients, solved = least_squares_spline(x, values, t, w * robust)
        if not solved:
            raise ValueError("the spline profile's normal equations are singular")
        r = y - evaluate(t, coefficients, x)[0][:, 0]
        scale = 1.4826 * np.median(np.abs(r)) + 1e-9
        z = np.abs(r) / (huber * scale)
        robust = np.where(z <= 1, 1.0, 1.0 / np.maximum(z, 1e-12))

    def spline(u):
        return evaluate(t, coefficients, np.atleast_1d(np.asarray(u, np.float64)))[0][:, 0]

    # Beyond the data, continue straight with the mean slope of the last tenth of the data:
    # cubic extrapolation runs away, and the end derivative alone is the noisiest part of a fit.
    at = np.asarray(at, dtype=np.float64)
    inside = np.clip(at, lo, hi)
    reach = 0.1 * (hi - lo)
    slope_lo = (spline(lo + reach) - spline(lo))[0] / reach
    slope_hi = (spline(hi) - spline(hi - reach))[0] / reach
    slope = np.where(at < lo, 0.0 if flat_start else slope_lo, slope_hi)
    return spline(inside) + slope * (at - inside)
