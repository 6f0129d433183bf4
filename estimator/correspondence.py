"""Left/right correspondence on rectified images: the same 3D point lies on the same row.

``compensate_nodes`` is the paper's misalignment compensation (section 4.2): a cubic spline
through the right nodes, and for each left node the point of that spline on the left node's row.
Where the arm crosses a row twice (a U shape) the row has several such points; the paper does
not say which. The one nearest node j's place along the arm (arc length fractions) is the
default; the one nearest right node j in the image (``nearest="image"``) can jump to the other
branch. Where the arm runs along the rows the row has no reliable point at all; those nodes are
placed by arc length from the nodes the rows do pin. ``match_rows`` is the default mode's
version: only crossings near the same arc-length fraction count, and each match carries a
weight that says how well the row pins it down (a curve running along the rows cannot be
matched by row).
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.interpolate import CubicSpline

MIN_SINE = 0.25  # crossings flatter than ~15 degrees to the rows are not used


def row_crossings(curve: np.ndarray, row: float) -> tuple[np.ndarray, np.ndarray]:
    """Where a polyline crosses an image row.

    Args:
        curve: (K, 2) ordered (u, v) points.
        row: the image row v.

    Returns:
        (u values, fractional indices along the polyline) of every crossing.
    """
    v = curve[:, 1] - row
    sign_change = (v[:-1] == 0) | (v[:-1] * v[1:] < 0)
    idx = np.flatnonzero(sign_change)
    frac = np.where(v[idx] == v[idx + 1], 0.0, v[idx] / (v[idx] - v[idx + 1] + 1e-300))
    u = curve[idx, 0] + frac * (curve[idx + 1, 0] - curve[idx, 0])
    if v[-1] == 0:
        u, idx, frac = np.append(u, curve[-1, 0]), np.append(idx, len(curve) - 1), np.append(frac, 0.0)
    return u, idx + frac


NEAREST = ("parameter", "image")


def compensate_nodes(left_nodes: np.ndarray, right_nodes: np.ndarray, window: float | None = None,
                     samples_per_node: int = 50, nearest: str = "parameter",
                     min_sine: float | None = None) -> np.ndarray:
    """The paper's compensation: move each right node onto its left node's row.

    A cubic spline runs through the right nodes (parameter: node index); for left node j, the
    points of that spline on row v_L,j are candidates. Places along the arm are compared as arc
    length fractions, each on its own image's spline: the two SOMs spread their nodes
    differently (on the twin's ramp the right chain runs more than a node ahead of the left one
    round a bend), so node indices do not name the same place.

    Args:
        left_nodes, right_nodes: (n, 2) ordered SOM nodes in rectified pixels, base -> tip.
        window: None accepts every candidate; a number only those within that fraction of the
            arm's length of node j's place.
        samples_per_node: spline samples between two nodes (where the rows are crossed).
        nearest: which candidate wins: "parameter", the one nearest node j's place along the arm;
            "image", the one nearest right node j in the image (can lie on the other branch where
            the arm crosses a row twice).
        min_sine: None keeps node j where no candidate is left. A number also drops candidates
            where the spline crosses the row at an angle to it whose sine is below ``min_sine``
            (a crossing moves by e / sin for a row error e: along the rows the row says nothing),
            and places every node without a candidate along the right spline instead: at the
            arc length interpolated, in left arc length, between the nodes the rows pin down and
            the two ends (the same ends of the arm in both images).

    Returns:
        (n, 2) compensated right nodes W*_R.
    """
    if nearest not in NEAREST:
        raise ValueError(f"nearest: expected one of {NEAREST}, got {nearest!r}")
    left_nodes = np.asarray(left_nodes, dtype=np.float64)
    right_nodes = np.asarray(right_nodes, dtype=np.float64)
    if left_nodes.shape != right_nodes.shape or left_nodes.ndim != 2 or left_nodes.shape[1] != 2:
        raise ValueError(f"left_nodes, right_nodes: expected two (n, 2) arrays of the same shape, got "
                         f"{left_nodes.shape} and {right_nodes.shape}")
    n = len(right_nodes)
    knots = np.arange(n)
    grid = np.linspace(0, n - 1, (n - 1) * samples_per_node + 1)
    spline = CubicSpline(knots, right_nodes, axis=0)
    dense = spline(grid)
    arc_right = _arc(dense)
    arc_left = _arc(CubicSpline(knots, left_nodes, axis=0)(grid))
    place_left = arc_left[::samples_per_node] / max(arc_left[-1], 1e-12)  # node j's arc fraction
    samples = np.arange(len(dense))
    out = right_nodes.copy()
    pinned = np.full(n, np.nan)  # right arc length matched to left node j by its row
    for j in range(n):
        u, where = row_crossings(dense, left_nodes[j, 1])
        place = np.interp(where, samples, arc_right) / max(arc_right[-1], 1e-12)
        keep = np.ones(len(u), bool)
        if window is not None:
            keep &= np.abs(place - place_left[j]) <= window
        if min_sine is not None and keep.any():
            slope = spline(where / samples_per_node, 1)
            keep &= np.abs(slope[:, 1]) >= min_sine * np.hypot(slope[:, 0], slope[:, 1])
        if not keep.any():
            continue
        u, where, place = u[keep], where[keep], place[keep]
        if nearest == "image":
            candidates = np.column_stack([u, np.full(len(u), left_nodes[j, 1])])
            pick = int(np.argmin(np.linalg.norm(candidates - right_nodes[j], axis=1)))
        else:
            pick = int(np.argmin(np.abs(place - place_left[j])))
        out[j] = (u[pick], left_nodes[j, 1])
        pinned[j] = np.interp(where[pick], samples, arc_right)
    if min_sine is not None:
        out = _carry_along_arc(out, left_nodes, arc_left[::samples_per_node], pinned, dense, arc_right)
    return out


def _carry_along_arc(out: np.ndarray, left_nodes: np.ndarray, left_arc: np.ndarray, pinned: np.ndarray,
                     dense: np.ndarray, arc_right: np.ndarray) -> np.ndarray:
    """Nodes the rows do not pin: the right spline's point at the arc length interpolated between
    the pinned nodes and the ends, on the left node's row."""
    free = ~np.isfinite(pinned)
    if not free.any():
        return out
    known = ~free
    xs, ys = left_arc[known], pinned[known]
    if not known[0]:
        xs, ys = np.r_[0.0, xs], np.r_[0.0, ys]
    if not known[-1]:
        xs, ys = np.r_[xs, left_arc[-1]], np.r_[ys, arc_right[-1]]
    target = np.interp(left_arc[free], xs, ys)
    u = np.interp(target, arc_right, dense[:, 0])
    out[free] = np.column_stack([u, left_nodes[free, 1]])
    return out


def _arc(curve: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])


@numba.njit(cache=True, nogil=True)
def _match(left, tau_left, right, tau_right, window):
    m = left.shape[0]
    k = right.shape[0]
    u_out = np.full(m, np.nan)
    slope = np.zeros(m)
    where = np.full(m, -1.0)
    for i in range(m):
        row = left[i, 1]
        best = np.inf
        for j in range(k - 1):
            if abs(tau_right[j] - tau_left[i]) > window and abs(tau_right[j + 1] - tau_left[i]) > window:
                continue
            v0 = right[j, 1] - row
            v1 = right[j + 1, 1] - row
            if v0 == v1 or v0 * v1 > 0:
                continue
            f = v0 / (v0 - v1)
            tau = tau_right[j] + f * (tau_right[j + 1] - tau_right[j])
            if abs(tau - tau_left[i]) < best:
                best = abs(tau - tau_left[i])
                u_out[i] = right[j, 0] + f * (right[j + 1, 0] - right[j, 0])
                where[i] = j + f
                du = right[j + 1, 0] - right[j, 0]
                dv = right[j + 1, 1] - right[j, 1]
                slope[i] = abs(dv) / max(np.sqrt(du * du + dv * dv), 1e-12)
    return u_out, slope, where


def match_rows(left: np.ndarray, right: np.ndarray, window: float = 0.08,
               right_valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Disparities of a dense left centerline against a dense right one, by rows, near the same place.

    Both curves run base -> tip; positions are compared by normalised arc length tau in [0, 1].

    Args:
        left, right: (M, 2) and (K, 2) rectified pixels.
        window: largest |tau_right - tau_left| accepted for a crossing.
        right_valid: (K,) False where the right curve is not supported by the silhouette (end
            caps, baseplates); crossings there get weight 0.

    Returns:
        disparity (M,) pixels (NaN where no crossing) and weight (M,) in [0, 1]: the squared
        sine of the angle between the curves and the rows (0 = running along a row).
    """
    tau_left = _tau(left)
    tau_right = _tau(right)
    u_right, slope_right, where = _match(np.ascontiguousarray(left), tau_left, np.ascontiguousarray(right),
                                         tau_right, float(window))
    d = np.gradient(left, axis=0)
    slope_left = np.abs(d[:, 1]) / (np.linalg.norm(d, axis=1) + 1e-12)
    # A crossing at angle b to the rows moves by e / sin b for a lateral error e, so its variance
    # grows as 1 / sin^2 b; below about 15 degrees the crossing says nothing reliable.
    weight = np.where(np.isfinite(u_right), slope_left * slope_right, 0.0)
    weight = np.where(np.minimum(slope_left, slope_right) < MIN_SINE, 0.0, weight)
    if right_valid is not None:
        found = where >= 0
        j = np.clip(where.astype(np.int64), 0, len(right) - 2)
        supported = right_valid[j] & right_valid[j + 1]
        weight = np.where(found & supported, weight, 0.0)
    return left[:, 0] - u_right, weight


def _tau(curve: np.ndarray) -> np.ndarray:
    arc = _arc(curve)
    return arc / max(arc[-1], 1e-12)
