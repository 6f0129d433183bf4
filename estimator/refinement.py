"""Sub-pixel 2D centerline of a tube silhouette, starting from ordered SOM nodes.

The SOM leaves its nodes near, not on, the centre: online updates jitter, contour input pulls
them towards the outer side of bends, and end nodes sit half a node spacing inside the ends.
Here the curve through the nodes is sampled densely; each sample moves to the midpoint of the
silhouette chord normal to the curve (for a tube of constant width this midpoint lies on the
projected axis, on bends too), and the ends are extended along the curve to where the
silhouette stops.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from estimator.spline_curve import evaluate, interpolating_spline, least_squares_spline

SAMPLE_SPACING_PX = 3.0
END_TOLERANCE = 0.04
RAGGED_SPREADS = 3.0  # a chord within this many robust spreads of its neighbours' width counts as full
KNOT_SPACING_PX = 24.0


@dataclass(frozen=True, eq=False)
class Centerline2D:
    """A dense ordered 2D centerline in one rectified image.

    Attributes:
        points: (M, 2) (u, v) pixels, base -> tip, from the silhouette's base end to its tip end.
        valid: (M,) True where a silhouette chord supports the point (False across baseplates).
        half_width_px: (M,) half the silhouette width at each point (NaN where not valid).
        arc_px: (M,) arc length from the base end, pixels.
    """

    points: np.ndarray
    valid: np.ndarray
    half_width_px: np.ndarray
    arc_px: np.ndarray

    def shifted(self, offset: np.ndarray) -> Centerline2D:
        return Centerline2D(self.points + offset, self.valid, self.half_width_px, self.arc_px)

    def longest_unsupported_px(self) -> float:
        """Longest stretch without a clean silhouette chord (ends included), pixels of arc."""
        edges = np.diff(np.concatenate([[1], self.valid.astype(np.int8), [1]]))
        starts, stops = np.flatnonzero(edges == -1), np.flatnonzero(edges == 1)
        if len(starts) == 0:
            return 0.0
        arc = np.append(self.arc_px, self.arc_px[-1])
        return float(np.max(arc[stops] - arc[starts]))


@numba.njit(cache=True, nogil=True)
def _sample(mask, x, y):
    """Bilinear value of a float mask at (x, y); 0 outside."""
    h, w = mask.shape
    if x < 0.0 or y < 0.0 or x > w - 1.0 or y > h - 1.0:
        return 0.0
    x0 = min(int(x), w - 2)
    y0 = min(int(y), h - 2)
    fx = x - x0
    fy = y - y0
    top = mask[y0, x0] * (1.0 - fx) + mask[y0, x0 + 1] * fx
    bottom = mask[y0 + 1, x0] * (1.0 - fx) + mask[y0 + 1, x0 + 1] * fx
    return top * (1.0 - fy) + bottom * fy


@numba.njit(cache=True, nogil=True)
def _edge_distance(mask, x, y, dx, dy, max_px, step):
    """Distance along (dx, dy) from an inside point to the first 0.5 crossing; -1 if none."""
    previous = _sample(mask, x, y)
    t = 0.0
    while t < max_px:
        t += step
        value = _sample(mask, x + t * dx, y + t * dy)
        if value < 0.5:
            return t - step + step * (previous - 0.5) / max(previous - value, 1e-9)
        previous = value
    return -1.0


@numba.njit(cache=True, nogil=True)
def _chords(mask, points, normals, max_half_px, step):
    m = points.shape[0]
    mids = points.copy()
    half = np.full(m, np.nan)
    ok = np.zeros(m, dtype=np.bool_)
    for i in range(m):
        x = points[i, 0]
        y = points[i, 1]
        if _sample(mask, x, y) < 0.5:
            continue
        a = _edge_distance(mask, x, y, normals[i, 0], normals[i, 1], max_half_px, step)
        b = _edge_distance(mask, x, y, -normals[i, 0], -normals[i, 1], max_half_px, step)
        if a < 0.0 or b < 0.0:
            continue
        shift = 0.5 * (a - b)
        mids[i, 0] = x + shift * normals[i, 0]
        mids[i, 1] = y + shift * normals[i, 1]
        half[i] = 0.5 * (a + b)
        ok[i] = True
    return mids, half, ok


def edge_distances(mask01: np.ndarray, start: np.ndarray, directions: np.ndarray, max_px: float) -> np.ndarray:
    """Distance from ``start`` to the silhouette's edge (the mask's 0.5 crossing) along each of several
    directions (K, 2), or -1 where it is not reached within ``max_px``: (K,)."""
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return _edge_distances(mask01, float(start[0]), float(start[1]), d, float(max_px), 0.5)


@numba.njit(cache=True, nogil=True)
def _edge_distances(mask, x, y, directions, max_px, step):
    out = np.empty(directions.shape[0])
    for i in range(directions.shape[0]):
        out[i] = _edge_distance(mask, x, y, directions[i, 0], directions[i, 1], max_px, step)
    return out


@numba.njit(cache=True, nogil=True)
def _arc(points):
    """Arc length from the first point at every point of a polyline."""
    arc = np.empty(points.shape[0])
    arc[0] = 0.0
    for i in range(1, points.shape[0]):
        dx = points[i, 0] - points[i - 1, 0]
        dy = points[i, 1] - points[i - 1, 1]
        arc[i] = arc[i - 1] + math.sqrt(dx * dx + dy * dy)
    return arc


@numba.njit(cache=True, nogil=True)
def _unit_rows(vectors):
    out = np.empty_like(vectors)
    for i in range(vectors.shape[0]):
        norm = math.sqrt(vectors[i, 0] ** 2 + vectors[i, 1] ** 2) + 1e-12
        out[i, 0] = vectors[i, 0] / norm
        out[i, 1] = vectors[i, 1] / norm
    return out


@numba.njit(cache=True, nogil=True)
def _fit(arc, points, at):
    """Least-squares cubic spline of points(arc): (positions at ``at``, unit tangents there, solvable)."""
    span = arc[-1] - arc[0]
    inner = max(int(span / KNOT_SPACING_PX) - 1, 0)
    candidates = np.linspace(arc[0], arc[-1], inner + 2)[1:-1]
    # Each knot interval needs data (Schoenberg-Whitney); drop interior knots in empty stretches
    # (a knot more than half a spacing from every sample: across a long gap, consecutive empty
    # intervals make the fit ill-conditioned and the curve swings off by thousands of pixels).
    half = 0.5 * KNOT_SPACING_PX
    kept = np.zeros(candidates.shape[0], np.bool_)
    for j in range(candidates.shape[0]):
        after = min(np.searchsorted(arc, candidates[j] - half, side="right"), arc.shape[0] - 1)
        kept[j] = candidates[j] - half < arc[after] < candidates[j] + half
    inner_knots = candidates[kept]
    knots = np.empty(inner_knots.shape[0] + 8)
    knots[:4] = arc[0]
    knots[4:-4] = inner_knots
    knots[-4:] = arc[-1]
    coefficients, solvable = least_squares_spline(arc, points, knots)
    if not solvable:
        return np.zeros((0, 2)), np.zeros((0, 2)), False
    values, tangent = evaluate(knots, coefficients, at)
    return values, _unit_rows(tangent), True


def densify(nodes: np.ndarray, spacing_px: float = SAMPLE_SPACING_PX) -> tuple[np.ndarray, np.ndarray]:
    """Smooth curve through ordered nodes sampled every ``spacing_px``: (points, unit tangents)."""
    nodes = np.asarray(nodes, dtype=np.float64)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(nodes, axis=0), axis=1) > 1e-6])
    nodes = nodes[keep]
    arc = _arc(nodes)
    count = max(int(arc[-1] / spacing_px) + 1, 8)
    at = np.linspace(0.0, arc[-1], count)
    solved = False
    if len(nodes) >= 4:
        knots, coefficients, solved = interpolating_spline(arc, nodes)
    if not solved:  # too few nodes for a cubic: straight between them
        points = np.column_stack([np.interp(at, arc, nodes[:, k]) for k in range(2)])
        tangent = np.gradient(points, axis=0)
        return points, tangent / (np.linalg.norm(tangent, axis=1, keepdims=True) + 1e-12)
    points, tangent = evaluate(knots, coefficients, at)
    return points, tangent / (np.linalg.norm(tangent, axis=1, keepdims=True) + 1e-12)


def refine_centerline(mask: np.ndarray, nodes: np.ndarray, *, iterations: int = 2,
                      extend_ends: bool = True) -> Centerline2D | None:
    """Move a node chain onto the silhouette's medial axis and out to its ends.

    Args:
        mask: (H, W) uint8 arm mask (the same image region the nodes refer to).
        nodes: (n, 2) ordered nodes, base first.
        iterations: chord-midpoint passes (normals improve with each pass).
        extend_ends: march from the outermost supported points along the curve to the
            silhouette's ends; otherwise the curve ends at the outermost supported points.

    Returns:
        The refined centerline, or None when too few chords cross the silhouette.
    """
    passes = refinement_passes(mask, nodes, extend_ends=extend_ends)
    curve = None
    for _ in range(max(iterations, 1)):
        curve = next(passes, None)
    return curve


def refinement_passes(mask: np.ndarray, nodes: np.ndarray, *, extend_ends: bool = True):
    """``refine_centerline`` one pass at a time: the centerline after each chord-midpoint pass, so
    that a caller can decide after a pass whether another one is needed without starting over.
    Yields None, and stops, where a pass finds too few chords."""
    mask01 = (mask > 0).astype(np.float32)
    points, tangent = densify(nodes)
    points, tangent = np.ascontiguousarray(points), np.ascontiguousarray(tangent)
    max_half = 0.5 * max(mask.shape)  # first pass: search as far as the largest plausible tube
    while True:
        status, points, tangent, max_half, curve, supported, half = _refine_pass(mask01, points, tangent, max_half,
                                                                                 extend_ends)
        if status == _STOP:
            yield None
            return
        yield Centerline2D(curve, supported, half, _arc(curve)) if status == _CURVE else None


_STOP, _CURVE, _NO_CURVE = 0, 1, 2  # see _refine_pass


@numba.njit(cache=True, nogil=True)
def _refine_pass(mask01, points, tangent, max_half, extend_ends):
    """One chord-midpoint pass over the sampled curve (points, unit tangents).

    Returns (status, the curve's samples and tangents for the next pass, the next pass's search
    reach, and this pass's centerline: points, supported, half widths). Status ``_STOP``: too few
    chords, or the smoothing fit failed or swung off (stop); ``_NO_CURVE``: too little support
    left beside gaps, but another pass may find more; ``_CURVE``: the centerline."""
    no_points, no_flags, no_values = np.zeros((0, 2)), np.zeros(0, np.bool_), np.zeros(0)
    normals = np.empty_like(tangent)
    normals[:, 0] = -tangent[:, 1]
    normals[:, 1] = tangent[:, 0]
    mids, half, ok = _chords(mask01, points, normals, max_half, 0.5)
    if ok.sum() < 6:
        return _STOP, points, tangent, max_half, no_points, no_flags, no_values
    arc = _arc(points)
    ok &= _full_width(arc, half, ok, 0.08, END_TOLERANCE)
    if ok.sum() < 6:
        return _STOP, points, tangent, max_half, no_points, no_flags, no_values
    typical = np.median(half[ok])
    fitted, fitted_tangent, solved = _fit(arc[ok], mids[ok], arc)
    if not solved or not _follows(fitted, points, ok, mids, typical):
        return _STOP, points, tangent, max_half, no_points, no_flags, no_values
    # Keep only the stretch between the outermost supported samples; ends are found next.
    support = np.flatnonzero(ok)
    first, stop = support[0], support[-1] + 1
    points, tangent = fitted[first:stop].copy(), fitted_tangent[first:stop].copy()
    status, curve, supported, curve_half = _finished(mask01, points, tangent, ok[first:stop].copy(),
                                                     half[first:stop].copy(), extend_ends)
    return status, points, tangent, 2.0 * typical, curve, supported, curve_half


@numba.njit(cache=True, nogil=True)
def _finished(mask01, points, tangent, ok, half, extend_ends):
    """The centerline after a pass: support withdrawn beside gaps, the ends extended to the silhouette's.
    (status, points, supported, half widths (NaN where not supported))."""
    typical = np.median(half[ok])
    ok = _away_from_gaps(ok, _arc(points), typical)
    if ok.sum() < 6:
        return _NO_CURVE, np.zeros((0, 2)), np.zeros(0, np.bool_), np.zeros(0)
    if extend_ends:
        head = _extend(mask01, points[0], -tangent[0], 4.0 * typical + 20.0)[::-1]
        tail = _extend(mask01, points[-1], tangent[-1], 4.0 * typical + 20.0)
        m, a, b = points.shape[0], head.shape[0], tail.shape[0]
        grown = np.empty((a + m + b, 2))
        grown[:a] = head
        grown[a:a + m] = points
        grown[a + m:] = tail
        grown_ok = np.zeros(a + m + b, np.bool_)
        grown_ok[a:a + m] = ok
        grown_half = np.full(a + m + b, np.nan)
        grown_half[a:a + m] = half
        points, ok, half = grown, grown_ok, grown_half
    return _CURVE, points, ok, np.where(ok, half, np.nan)


@numba.njit(cache=True, nogil=True)
def _follows(fitted, before, ok, mids, half_width):
    """The smoothing fit stays near the curve it refines: finite, within a tube width of the chord
    midpoints it was fitted to, and, across unsupported stretches, within a few widths of the curve
    before the pass (an ill-posed fit through disordered nodes swings off by thousands of pixels)."""
    support = np.flatnonzero(ok)
    for i in range(support[0], support[-1] + 1):
        if not (np.isfinite(fitted[i, 0]) and np.isfinite(fitted[i, 1])):
            return False
    for i in range(support[0], support[-1] + 1):
        if math.hypot(fitted[i, 0] - before[i, 0], fitted[i, 1] - before[i, 1]) > 6.0 * half_width:
            return False
        if ok[i] and math.hypot(fitted[i, 0] - mids[i, 0], fitted[i, 1] - mids[i, 1]) > 2.0 * half_width:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _full_width(arc, half, ok, tolerance, end_tolerance):
    """Chords as wide as the tube around them: the rest are cut by a baseplate or lie in the end cap.

    The end cap's image is tilted when seen off-axis, so chords inside it are off-centre;
    they are also narrower than the body, which is what singles them out. Width is compared
    with a running median over about two tube widths, since depth changes it along the arm.
    """
    typical = np.median(half[ok])
    coarse = (half > 0.5 * typical) & (half < 1.6 * typical) & ok
    idx = np.flatnonzero(coarse)
    if len(idx) < 3:
        return coarse
    window = 4.0 * typical  # two widths of arc
    lo = np.searchsorted(arc[idx], arc - window / 2)
    hi = np.searchsorted(arc[idx], arc + window / 2)
    local = window_medians(half[idx], lo, hi, typical)
    # Within a width of the ends, chords that cross the end cap's tilted image are off-centre
    # while still nearly full width: hold them to a tighter tolerance.
    near_end = (arc - arc[idx[0]] < 2.0 * typical) | (arc[idx[-1]] - arc < 2.0 * typical)
    # A ragged silhouette (a blurred step's halo half passes the colour gate) spreads every chord's
    # width: the tolerance grows with that spread, measured along the whole arm.
    spread = RAGGED_SPREADS * 1.4826 * np.median(np.abs(half[idx] / local[idx] - 1.0))
    allowed = np.maximum(np.where(near_end, end_tolerance, tolerance), spread) * local
    return coarse & (np.abs(half - local) <= allowed)


@numba.njit(cache=True, nogil=True)
def window_medians(values, lo, hi, fallback):
    """Median of values[lo[i]:hi[i]] for every i (``fallback`` for an empty window)."""
    out = np.empty(len(lo))
    for i in range(len(lo)):
        out[i] = np.median(values[lo[i]:hi[i]]) if hi[i] > lo[i] else fallback
    return out


@numba.njit(cache=True, nogil=True)
def _away_from_gaps(ok, arc, half_width):
    """Withdraw support within half a width of an unsupported stretch inside the curve.

    A chord beside a baseplate is partly cut by it, so its midpoint is biased sideways even
    when its length passes the width test. Chords across the end cap stay: the cap's image is
    symmetric about the axis, so their midpoints are unbiased, only shorter.
    """
    unsupported = arc[~ok]
    if len(unsupported) == 0:
        return ok
    last = len(unsupported) - 1
    out = ok.copy()
    for i in range(arc.shape[0]):
        j = np.searchsorted(unsupported, arc[i])
        nearest = min(abs(arc[i] - unsupported[min(max(j - 1, 0), last)]), abs(arc[i] - unsupported[min(j, last)]))
        if nearest <= 0.5 * half_width:
            out[i] = False
    return out


@numba.njit(cache=True, nogil=True)
def _extend(mask01, start, direction, max_px):
    """Points from ``start`` (exclusive) along ``direction`` up to the silhouette edge (inclusive)."""
    norm = math.hypot(direction[0], direction[1])
    dx, dy = direction[0] / norm, direction[1] / norm
    distance = _edge_distance(mask01, start[0], start[1], dx, dy, max_px, 0.5)
    if distance <= 0:
        return np.zeros((0, 2))
    steps = np.append(np.arange(SAMPLE_SPACING_PX, distance, SAMPLE_SPACING_PX), distance)
    out = np.empty((steps.shape[0], 2))
    out[:, 0] = start[0] + steps * dx
    out[:, 1] = start[1] + steps * dy
    return out
