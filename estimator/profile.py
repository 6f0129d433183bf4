"""The disparity along the arm: which row matches to trust, and what fills in where rows cannot.

Rectified stereo measures disparity by matching rows, which fails where the arm runs along the
rows and is biased next to the base mount. Two physical facts fill in: a tube's apparent width
scales with its disparity (in the ratio B / 2r, constant along a section), and the arm leaves its
fixed mount along the mount's axis.
"""

from __future__ import annotations

import numpy as np

from estimator.refinement import Centerline2D, window_medians

BASE_SKIP_WIDTHS = 0.5  # see base_ramp
BASE_RAMP_WIDTHS = 0.5
WIDTH_CUE_WEIGHT = 0.02  # a row crossing at ~8 degrees weighs as much as one width sample


def with_width_cue(tau: np.ndarray, disparity: np.ndarray, weight: np.ndarray, left: Centerline2D,
                    trust: np.ndarray):
    """Append the apparent tube width as a weak disparity observation.

    A tube's width and disparity both scale with 1/Z, in the ratio B / 2r. That ratio is
    measured where rows pin the disparity down, separately for each piece of constant radius
    (sections differ), and turns widths into disparities where rows cannot (the curve running
    along the rows). Its weight is small: it only matters where rows say nothing. ``trust``
    (0..1 per sample) scales it like the rows near the ends. A piece with no measured ratio of
    its own (a whole section along the rows) borrows its neighbour's only if their widths match
    across the joint, where both have the same depth: then they have the same radius. Never a
    nominal radius: 10 % off there would put the piece 10 % off in depth.
    """
    width = 2.0 * left.half_width_px
    has_width = np.isfinite(width)
    if np.count_nonzero(has_width) < 8:
        return tau, disparity, weight
    pieces = constant_radius_pieces(left.arc_px, width)
    sigma = 3.0 * float(np.nanmedian(width))  # about three arm widths of arc
    calibrator = (weight > 0.1) & has_width & (disparity > 0)
    labels = [int(p) for p in np.unique(pieces[has_width])]
    ratios: dict[int, np.ndarray] = {}  # piece -> local ratio at each of its members
    members_of = {p: np.flatnonzero((pieces == p) & has_width) for p in labels}
    for piece in labels:
        members = members_of[piece]
        known = np.flatnonzero((pieces == piece) & calibrator)
        if weight[known].sum() < 1.0:
            continue
        ratio = disparity[known] / width[known]
        near = weight[known] * np.exp(-0.5 * ((left.arc_px[members, None] - left.arc_px[None, known]) / sigma) ** 2)
        ratios[piece] = (near @ ratio) / np.maximum(near.sum(axis=1), 1e-12)
    for piece in labels:  # a piece without its own ratio may borrow a neighbour's of equal radius
        if piece in ratios:
            continue
        borrowed = _borrow_ratio(piece, labels, members_of, ratios, width, left.arc_px, sigma / 3.0)
        if borrowed is not None:
            ratios[piece] = np.full(len(members_of[piece]), borrowed)
    if not ratios:
        return tau, disparity, weight
    xs = [tau[members_of[p]] for p in ratios]
    ys = [ratios[p] * width[members_of[p]] for p in ratios]
    ws = [WIDTH_CUE_WEIGHT * trust[members_of[p]] for p in ratios]
    return (np.append(tau, np.concatenate(xs)), np.append(disparity, np.concatenate(ys)),
            np.append(weight, np.concatenate(ws)))


def _borrow_ratio(piece: int, labels: list[int], members_of: dict, ratios: dict, width: np.ndarray,
                  arc: np.ndarray, arm_width: float) -> float | None:
    """The ratio of an adjacent piece whose width matches across the joint (same depth, same radius)."""
    for neighbour in (piece - 1, piece + 1):
        if neighbour not in ratios:
            continue
        mine, theirs = members_of[piece], members_of[neighbour]
        joint = arc[mine[0]] if neighbour < piece else arc[mine[-1]]
        here = mine[np.abs(arc[mine] - joint) < 1.5 * arm_width]
        there_idx = np.abs(arc[theirs] - joint) < 1.5 * arm_width
        if len(here) < 3 or np.count_nonzero(there_idx) < 3:
            continue
        a, b = np.median(width[here]), np.median(width[theirs[there_idx]])
        if abs(a - b) <= 0.05 * b:
            return float(np.median(ratios[neighbour][there_idx]))
    return None


def constant_radius_pieces(arc: np.ndarray, width: np.ndarray) -> np.ndarray:
    """Label stretches of the arm that can share one radius: cut at gaps and abrupt width steps.

    Depth changes the width gradually; a different section (another radius) changes it within
    about one width, and baseplates leave gaps without a width.
    """
    has = np.isfinite(width)
    idx = np.flatnonzero(has)
    typical = float(np.median(width[idx]))
    cuts = np.zeros(len(arc), dtype=bool)
    gap = np.diff(arc[idx]) > 0.5 * typical
    cuts[idx[1:][gap]] = True
    # Width step: the medians over one width before and after differ by more than 10 %.
    here = np.arange(len(idx))
    before = window_medians(width[idx], np.searchsorted(arc[idx], arc[idx] - typical), here, np.nan)
    after = window_medians(width[idx], here, np.searchsorted(arc[idx], arc[idx] + typical), np.nan)
    step = np.abs(before - after) > 0.1 * np.minimum(before, after)
    cuts[idx[step & np.isfinite(before) & np.isfinite(after)]] = True
    return np.cumsum(cuts)


def base_ramp(curve: Centerline2D, skip_widths: float, ramp_widths: float) -> np.ndarray:
    """Weights that ignore the silhouette next to the base mount and rise to 1 beyond it.

    Where the arm leaves its mount, the silhouette's edges meet the dark plate instead of the
    background; an edge pixel mixed with dark stays saturated and passes as arm where one mixed
    with the light background does not, which biases those chords by a fraction of a pixel. The
    disparity there continues from the clean body below (the arm leaves a fixed mount).
    """
    if not curve.valid.any() or skip_widths + ramp_widths <= 0:
        return np.ones(len(curve.valid))
    width = 2.0 * float(np.nanmedian(curve.half_width_px))
    inside = curve.arc_px - curve.arc_px[curve.valid][0]
    return np.clip((inside - skip_widths * width) / max(ramp_widths * width, 1e-9), 0.0, 1.0)


def measured_radius_m(disparity: np.ndarray, weight: np.ndarray, left: Centerline2D, baseline_m: float,
                       near_end: int | None = None) -> float:
    """Tube radius from width and disparity (r = w B / 2d), over the arm or near one end; NaN if unknown."""
    good = (weight > 0.3) & np.isfinite(left.half_width_px) & (disparity > 0)
    if near_end is not None:
        reach = 6.0 * float(np.nanmedian(left.half_width_px))
        from_end = left.arc_px if near_end == 0 else left.arc_px[-1] - left.arc_px
        good &= from_end < reach
    if np.count_nonzero(good) < 3:
        return float("nan")
    return float(np.median(left.half_width_px[good] * baseline_m / disparity[good]))
