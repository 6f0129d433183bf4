"""Sub-pixel 2D centerline of a tube silhouette, starting from ordered SOM nodes.

The SOM leaves its nodes near, not on, the centre: online updates jitter, contour input pulls
them towards the outer side of bends, and end nodes sit half a node spacing inside the ends.
Here the curve through the nodes is sampled densely; each sample moves to the midpoint of the
silhouette chord normal to the curve (for a tube of constant width this midpoint lies on the
projected axis, on bends too), and the ends are extended along the curve to where the
silhouette stops.
"""

from __future__ import annotations

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


def edge_distance(mask01: np.ndarray, start: np.ndarray, direction: np.ndarray, max_px: float) -> float:
    """Distance from ``start`` along ``direction`` to the silhouette edge (-1 if not reached)."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    return float(_edge_distance(mask01, float(start[0]), float(start[1]), d[0], d[1], float(max_px), 0.5))


def edge_distances(mask01: np.ndarray, start: np.ndarray, directions: np.ndarray, max_px: float) -> np.ndarray:
    """``edge_distance`` along each of several directions (K, 2) from one start: (K,)."""
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return _edge_distances(mask01, float(start[0]), float(start[1]), d, float(max_px), 0.5)


@numba.njit(cache=True, nogil=True)
def _edge_distances(mask, x, y, directions, max_px, step):
    out = np.empty(directions.shape[0])
    for i in range(directions.shape[0]):
        out[i] = _edge_distance(mask, x, y, directions[i, 0], directions[i, 1], max_px, step)
    return out


def _arc(points: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def _fit(arc: np.ndarray, points: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares cubic spline of points(arc); returns positions and unit tangents at ``at``."""
    span = arc[-1] - arc[0]
    inner = max(int(span / KNOT_SPACING_PX) - 1, 0)
    knots = np.concatenate([[arc[0]] * 4, np.linspace(arc[0], arc[-1], inner + 2)[1:-1], [arc[-1]] * 4])
    # Each knot interval needs data (Schoenberg-Whitney); drop interior knots in empty stretches
    # (a knot more than half a spacing from every sample: across a long gap, consecutive empty
    # intervals make the fit ill-conditioned and the curve swings off by thousands of pixels).
    half = 0.5 * KNOT_SPACING_PX
    inner_knots = knots[4:-4]
    nearest_after = np.minimum(np.searchsorted(arc, inner_knots - half, side="right"), len(arc) - 1)
    keep = inner_knots[(arc[nearest_after] > inner_knots - half) & (arc[nearest_after] < inner_knots + half)]
    knots = np.concatenate([[arc[0]] * 4, keep, [arc[-1]] * 4])
    coefficients, solvable = least_squares_spline(arc, np.ascontiguousarray(points, np.float64), knots)
    if not solvable:
        raise ValueError("a knot interval without samples (Schoenberg-Whitney)")
    values, tangent = evaluate(knots, coefficients, np.ascontiguousarray(at, np.float64))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True) + 1e-12
    return values, tangent


def densify(nodes: np.ndarray, spacing_px: float = SAMPLE_SPACING_PX) -> tuple[np.ndarray, np.ndarray]:
    """Smooth curve through ordered nodes sampled every ``spacing_px``: (points, unit tangents)."""
    nodes = np.asarray(nodes, dtype=np.float64)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(nodes, axis=0), axis=1) > 1e-6])
    nodes = nodes[keep]
    arc = _arc(nodes)
    count = max(int(arc[-1] / spacing_px) + 1, 8)
    at = np.linspace(0.0, arc[-1], count)
    if len(nodes) < 4:
        points = np.column_stack([np.interp(at, arc, nodes[:, k]) for k in range(2)])
        tangent = np.gradient(points, axis=0)
        return points, tangent / (np.linalg.norm(tangent, axis=1, keepdims=True) + 1e-12)
    points, tangent = evaluate(*interpolating_spline(arc, nodes), at)
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
    max_half = 0.5 * max(mask.shape)  # first pass: search as far as the largest plausible tube
    while True:
        normals = np.column_stack([-tangent[:, 1], tangent[:, 0]])
        mids, half, ok = _chords(mask01, points, normals, max_half, 0.5)
        if ok.sum() < 6:
            yield None
            return
        arc = _arc(points)
        ok &= _full_width(arc, half, ok)
        if ok.sum() < 6:
            yield None
            return
        max_half = 2.0 * float(np.median(half[ok]))
        before = points
        try:
            points, tangent = _fit(arc[ok], mids[ok], arc)
        except (ValueError, np.linalg.LinAlgError):  # too few chords for the spline's knots (Schoenberg-Whitney)
            yield None
            return
        if not _follows(points, before, ok, mids, float(np.median(half[ok]))):
            yield None  # nodes too disordered for a curve through them (a baseline's zig-zag)
            return
        # Keep only the stretch between the outermost supported samples; ends are found next.
        first, last = np.flatnonzero(ok)[[0, -1]]
        points, tangent, ok, half = (points[first:last + 1], tangent[first:last + 1], ok[first:last + 1],
                                     half[first:last + 1])
        yield _finished(mask01, points, tangent, ok, half, extend_ends)


def _finished(mask01: np.ndarray, points: np.ndarray, tangent: np.ndarray, ok: np.ndarray, half: np.ndarray,
              extend_ends: bool) -> Centerline2D | None:
    """The centerline after a pass: support withdrawn beside gaps, the ends extended to the silhouette's."""
    typical = float(np.median(half[ok]))
    ok = _away_from_gaps(ok, _arc(points), typical)
    if ok.sum() < 6:
        return None
    if extend_ends:
        head = _extend(mask01, points[0], -tangent[0], 4.0 * typical + 20.0)
        tail = _extend(mask01, points[-1], tangent[-1], 4.0 * typical + 20.0)
        points = np.vstack([head[::-1], points, tail])
        ok = np.concatenate([np.zeros(len(head), bool), ok, np.zeros(len(tail), bool)])
        half = np.concatenate([np.full(len(head), np.nan), half, np.full(len(tail), np.nan)])
    return Centerline2D(points, ok, np.where(ok, half, np.nan), _arc(points))


def _follows(fitted: np.ndarray, before: np.ndarray, ok: np.ndarray, mids: np.ndarray, half_width: float) -> bool:
    """The smoothing fit stays near the curve it refines: finite, within a tube width of the chord
    midpoints it was fitted to, and, across unsupported stretches, within a few widths of the curve
    before the pass (an ill-posed fit through disordered nodes swings off by thousands of pixels)."""
    inside = slice(*np.flatnonzero(ok)[[0, -1]] + (0, 1))
    fitted, before = fitted[inside], before[inside]
    if not np.all(np.isfinite(fitted)):
        return False
    near_mids = np.max(np.linalg.norm(fitted[ok[inside]] - mids[inside][ok[inside]], axis=1)) <= 2.0 * half_width
    return bool(near_mids and np.max(np.linalg.norm(fitted - before, axis=1)) <= 6.0 * half_width)


def _full_width(arc: np.ndarray, half: np.ndarray, ok: np.ndarray, tolerance: float = 0.08,
                end_tolerance: float = END_TOLERANCE) -> np.ndarray:
    """Chords as wide as the tube around them: the rest are cut by a baseplate or lie in the end cap.

    The end cap's image is tilted when seen off-axis, so chords inside it are off-centre;
    they are also narrower than the body, which is what singles them out. Width is compared
    with a running median over about two tube widths, since depth changes it along the arm.
    """
    idx = np.flatnonzero(ok)
    typical = float(np.median(half[idx]))
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
    spread = RAGGED_SPREADS * 1.4826 * float(np.median(np.abs(half[idx] / local[idx] - 1.0)))
    allowed = np.maximum(np.where(near_end, end_tolerance, tolerance), spread) * local
    return coarse & (np.abs(half - local) <= allowed)


@numba.njit(cache=True, nogil=True)
def window_medians(values, lo, hi, fallback):
    """Median of values[lo[i]:hi[i]] for every i (``fallback`` for an empty window)."""
    out = np.empty(len(lo))
    for i in range(len(lo)):
        out[i] = np.median(values[lo[i]:hi[i]]) if hi[i] > lo[i] else fallback
    return out


def _away_from_gaps(ok: np.ndarray, arc: np.ndarray, half_width: float) -> np.ndarray:
    """Withdraw support within half a width of an unsupported stretch inside the curve.

    A chord beside a baseplate is partly cut by it, so its midpoint is biased sideways even
    when its length passes the width test. Chords across the end cap stay: the cap's image is
    symmetric about the axis, so their midpoints are unbiased, only shorter.
    """
    unsupported = arc[~ok]
    reach = 0.5 * half_width
    near = np.zeros_like(ok)
    if len(unsupported):
        idx = np.searchsorted(unsupported, arc)
        lo = np.abs(arc - unsupported[np.clip(idx - 1, 0, len(unsupported) - 1)])
        hi = np.abs(arc - unsupported[np.clip(idx, 0, len(unsupported) - 1)])
        near = np.minimum(lo, hi) <= reach
    return ok & ~near


def _extend(mask01: np.ndarray, start: np.ndarray, direction: np.ndarray, max_px: float) -> np.ndarray:
    """Points from ``start`` (exclusive) along ``direction`` up to the silhouette edge (inclusive)."""
    distance = edge_distance(mask01, start, direction, max_px)
    if distance <= 0:
        return np.zeros((0, 2))
    steps = np.append(np.arange(SAMPLE_SPACING_PX, distance, SAMPLE_SPACING_PX), distance)
    return start + steps[:, None] * (direction / np.linalg.norm(direction))
