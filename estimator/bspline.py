"""Clamped uniform cubic B-splines: the smooth 3D curve the tube fit moves.

A curve C(u) = sum_k N_k(u) P_k on u in [0, 1] with ``count`` control points P_k; each u
touches four of them, so the fit's normal equations stay small and banded. Compiled, because
the fit evaluates basis functions for every edge observation at every iteration.
"""

from __future__ import annotations

import numba
import numpy as np

DEGREE = 3


def clamped_knots(count: int) -> np.ndarray:
    """Knot vector of a clamped uniform cubic B-spline with ``count`` (>= 4) control points."""
    if count < DEGREE + 1:
        raise ValueError(f"count: expected at least {DEGREE + 1} control points, got {count}")
    inner = np.linspace(0.0, 1.0, count - DEGREE + 1)
    return np.concatenate([[0.0] * DEGREE, inner, [1.0] * DEGREE])


@numba.njit(cache=True, nogil=True)
def basis(knots, count, u):
    """(first index, values (4,), first derivatives (4,)) of the cubic basis at u in [0, 1]."""
    return basis_at(knots, count, min(max(u, 0.0), 1.0))


@numba.njit(cache=True, nogil=True)
def basis_at(knots, count, u):
    """``basis`` on any knot vector (``count`` + 4 knots, the first and last four repeated) at any u:
    beyond the end knots, the end pieces' polynomials (extrapolation)."""
    work, values, deriv = basis_workspace()
    first = basis_into(knots, count, u, work, values, deriv)
    return first, values, deriv


@numba.njit(cache=True, nogil=True)
def basis_workspace():
    """Scratch for ``basis_into``: (work (6, 4), values (4,), derivatives (4,))."""
    return np.zeros((DEGREE + 3, DEGREE + 1)), np.empty(DEGREE + 1), np.empty(DEGREE + 1)


@numba.njit(cache=True, nogil=True)
def basis_into(knots, count, u, work, values, deriv):
    """``basis_at`` into caller-provided arrays (``basis_workspace``); returns the first index. Loops
    over thousands of observations call it: allocating the small tables per call cost more than
    the arithmetic."""
    k = DEGREE
    span = k
    while span < count - 1 and knots[span + 1] <= u:
        span += 1
    # Cox-de Boor, triangular table (The NURBS Book, algorithm A2.2 and A2.3 for one derivative).
    ndu = work[:k + 1]
    left = work[k + 1]
    right = work[k + 2]
    ndu[0, 0] = 1.0
    for j in range(1, k + 1):
        left[j] = u - knots[span + 1 - j]
        right[j] = knots[span + j] - u
        saved = 0.0
        for r in range(j):
            ndu[j, r] = right[r + 1] + left[j - r]
            temp = ndu[r, j - 1] / ndu[j, r] if ndu[j, r] != 0.0 else 0.0
            ndu[r, j] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j, j] = saved
    for j in range(k + 1):
        values[j] = ndu[j, k]
    for r in range(k + 1):
        # first derivative: k * (N_{r-1,k-1} / (u_{i+k} - u_i) - N_{r,k-1} / (u_{i+k+1} - u_{i+1}))
        d = 0.0
        if r >= 1:
            denom = ndu[k, r - 1]  # knot difference stored in the lower triangle
            if denom != 0.0:
                d += ndu[r - 1, k - 1] / denom
        if r <= k - 1:
            denom = ndu[k, r]
            if denom != 0.0:
                d -= ndu[r, k - 1] / denom
        deriv[r] = k * d
    return span - k


@numba.njit(cache=True, nogil=True)
def evaluate(knots, control, u):
    """(point (3,), derivative dC/du (3,)) of the curve at u."""
    first, values, deriv = basis(knots, control.shape[0], u)
    point = np.zeros(3)
    tangent = np.zeros(3)
    for j in range(DEGREE + 1):
        for c in range(3):
            point[c] += values[j] * control[first + j, c]
            tangent[c] += deriv[j] * control[first + j, c]
    return point, tangent


@numba.njit(cache=True, nogil=True)
def evaluate_many(knots, control, us):
    """(points (M, 3), derivatives (M, 3)) at every u."""
    m = us.shape[0]
    points = np.zeros((m, 3))
    tangents = np.zeros((m, 3))
    work, values, deriv = basis_workspace()
    for i in range(m):
        first = basis_into(knots, control.shape[0], min(max(us[i], 0.0), 1.0), work, values, deriv)
        for j in range(DEGREE + 1):
            for c in range(3):
                points[i, c] += values[j] * control[first + j, c]
                tangents[i, c] += deriv[j] * control[first + j, c]
    return points, tangents


def fit_control_points(points: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares control points of a curve through ordered (M, 3) points, u by chord length.

    Returns:
        (knots, control (count, 3)).
    """
    points = np.asarray(points, dtype=np.float64)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    us = arc / max(arc[-1], 1e-12)
    knots = clamped_knots(count)
    A = _design(knots, count, us)
    control, *_ = np.linalg.lstsq(A, points, rcond=None)
    return knots, control


@numba.njit(cache=True, nogil=True)
def _design(knots, count, us):
    """(M, count) the basis functions' values at every u: a least-squares fit's design matrix."""
    A = np.zeros((us.shape[0], count))
    work, values, deriv = basis_workspace()
    for i in range(us.shape[0]):
        first = basis_into(knots, count, min(max(us[i], 0.0), 1.0), work, values, deriv)
        for j in range(DEGREE + 1):
            A[i, first + j] = values[j]
    return A
