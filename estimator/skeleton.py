"""Skeleton-based centerlines: thinning (section 4.3) and an ordered skeleton traversal.

``thinning_centerline`` reproduces the paper's baseline: a one-pixel skeleton sampled at equal
intervals in image-row order, which scrambles the order once the arm is not monotonic along the
rows (Fig. 8b). ``ordered_skeleton_path`` walks the skeleton from the base instead, choosing the
least-bending branch at junctions and bridging short gaps (baseplates hide the tube), in the
spirit of mBEST; the default mode uses it to start the SOM when there is no previous frame.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numba
import numpy as np

_OFFSETS = ((-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1))  # p2..p9 clockwise


@numba.njit(cache=True, nogil=True)
def _zhang_suen(image):
    img = image.copy()
    h, w = img.shape
    ys, xs = np.nonzero(img)
    count = len(ys)
    marked = np.zeros(count, dtype=np.bool_)
    changed = True
    while changed:
        changed = False
        for step in range(2):
            for idx in range(count):
                marked[idx] = False
                y = ys[idx]
                x = xs[idx]
                if img[y, x] == 0 or y == 0 or x == 0 or y == h - 1 or x == w - 1:
                    continue
                p2 = img[y - 1, x]
                p3 = img[y - 1, x + 1]
                p4 = img[y, x + 1]
                p5 = img[y + 1, x + 1]
                p6 = img[y + 1, x]
                p7 = img[y + 1, x - 1]
                p8 = img[y, x - 1]
                p9 = img[y - 1, x - 1]
                b = p2 + p3 + p4 + p5 + p6 + p7 + p8 + p9
                if b < 2 or b > 6:
                    continue
                a = ((p2 == 0) & (p3 == 1)) + ((p3 == 0) & (p4 == 1)) + ((p4 == 0) & (p5 == 1)) \
                    + ((p5 == 0) & (p6 == 1)) + ((p6 == 0) & (p7 == 1)) + ((p7 == 0) & (p8 == 1)) \
                    + ((p8 == 0) & (p9 == 1)) + ((p9 == 0) & (p2 == 1))
                if a != 1:
                    continue
                first = step == 0 and p2 * p4 * p6 == 0 and p4 * p6 * p8 == 0
                second = step == 1 and p2 * p4 * p8 == 0 and p2 * p6 * p8 == 0
                marked[idx] = first or second
            for idx in range(count):
                if marked[idx]:
                    img[ys[idx], xs[idx]] = 0
                    changed = True
    return img


def thin(mask: np.ndarray) -> np.ndarray:
    """Zhang-Suen thinning of a binary mask to a one-pixel-wide skeleton (uint8, 0/1)."""
    binary = np.zeros((mask.shape[0] + 2, mask.shape[1] + 2), np.uint8)
    binary[1:-1, 1:-1] = mask > 0
    return _zhang_suen(binary)[1:-1, 1:-1]


def thinning_centerline(mask: np.ndarray, n: int) -> np.ndarray:
    """The paper's thinning baseline: skeleton pixels in row order, n taken at equal intervals.

    Returns:
        (n, 2) (u, v) points; fewer if the skeleton has fewer pixels, empty if none.
    """
    skeleton = thin(mask)
    vs, us = np.nonzero(skeleton)  # row-major: sorted by row, then column
    if len(us) == 0:
        return np.zeros((0, 2))
    picks = np.round(np.linspace(0, len(us) - 1, min(n, len(us)))).astype(int)
    return np.column_stack([us[picks], vs[picks]]).astype(np.float64)


def _neighbours(skeleton: np.ndarray) -> tuple[np.ndarray, list[list[int]]]:
    """Pixel coordinates and m-adjacency: a diagonal step counts only without an orthogonal detour.

    Plain 8-adjacency gives every staircase pixel of a thinned line three neighbours, which
    would look like junctions everywhere.
    """
    vs, us = np.nonzero(skeleton)
    h, w = skeleton.shape
    padded = np.zeros((h + 2, w + 2), dtype=bool)
    padded[1:-1, 1:-1] = skeleton > 0
    index = -np.ones((h + 2, w + 2), dtype=np.int64)
    index[vs + 1, us + 1] = np.arange(len(vs))
    adjacency: list[list[int]] = [[] for _ in range(len(vs))]
    pv, pu = vs + 1, us + 1
    for dv, du in _OFFSETS:
        other = index[pv + dv, pu + du]
        ok = other >= 0
        if dv != 0 and du != 0:  # diagonal: drop it when a 4-connected path exists
            ok &= ~padded[pv + dv, pu] & ~padded[pv, pu + du]
        for i in np.flatnonzero(ok):
            adjacency[i].append(int(other[i]))
    return np.column_stack([us, vs]).astype(np.float64), adjacency


def _branches(points: np.ndarray, adjacency: list[list[int]]) -> list[list[int]]:
    """Split the skeleton graph into pixel paths between endpoints and junctions."""
    degree = np.array([len(a) for a in adjacency])
    is_node = degree != 2
    seen_edges: set[tuple[int, int]] = set()
    branches = []
    for start in np.flatnonzero(is_node):
        for nxt in adjacency[start]:
            if (start, nxt) in seen_edges:
                continue
            path = [int(start), nxt]
            seen_edges.add((start, nxt))
            seen_edges.add((nxt, start))
            while not is_node[path[-1]]:
                candidates = [c for c in adjacency[path[-1]] if c != path[-2] and (path[-1], c) not in seen_edges]
                if not candidates:
                    break
                seen_edges.add((path[-1], candidates[0]))
                seen_edges.add((candidates[0], path[-1]))
                path.append(candidates[0])
            branches.append(path)
    # Closed loops without nodes (a ring) have no endpoint; they are not an arm.
    return branches


STONE_HALF = 0.5  # a skeleton-less piece whose half width is at least this share of the tube's is a stepping stone


def with_stepping_stones(mask: np.ndarray, points: np.ndarray, adjacency: list[list[int]],
                         branches: list[list[int]], half_px: float, distance: np.ndarray | None = None
                         ) -> tuple[np.ndarray, list[list[int]], list[list[int]], set[int]]:
    """The skeleton graph with a short branch through each piece of the mask that thinning left
    without one: a stretch of the tube about as long as it is wide, cut out between an occluder
    crossing in front of it and a baseplate, thins to one pixel or to none, so the walk met a gap
    of both cuts and the piece together (over 3 widths where each cut was under one) and stopped.

    Each such piece at least ``STONE_HALF`` of ``half_px`` thick (not a speck) gets a two-point
    branch through its centroid along its longer axis. Returns (points, adjacency, branches, the
    indices of the branches added); the added points have no neighbours, so a walk reaches and
    leaves them only across gaps. ``distance``: the mask's distance transform, where already made.
    """
    count, labels, stats, centroids = cv2.connectedComponentsWithStats((mask > 0).astype(np.uint8), connectivity=8)
    if count <= 1:
        return points, adjacency, branches, set()
    covered = np.zeros(count, bool)
    for b in branches:
        if len(b) >= 2:
            at = points[b].astype(int)
            covered[labels[at[:, 1], at[:, 0]]] = True
    if distance is None:
        distance = cv2.distanceTransform((mask > 0).astype(np.uint8), cv2.DIST_L2, 3)
    new_points, new_branches = [], []
    for k in np.flatnonzero(~covered[1:]) + 1:
        x, y, w, h, _ = stats[k]
        piece = labels[y:y + h, x:x + w] == k
        if float(distance[y:y + h, x:x + w][piece].max()) < STONE_HALF * half_px:
            continue
        vs, us = np.nonzero(piece)
        xy = np.column_stack([us + x, vs + y]).astype(np.float64)
        centre = centroids[k]
        spread = np.cov((xy - centre).T) if len(xy) > 2 else np.eye(2)
        axis = np.linalg.eigh(spread)[1][:, -1]
        first = len(points) + len(new_points)
        new_points += [centre - 0.5 * axis, centre + 0.5 * axis]
        new_branches.append([first, first + 1])
    if not new_points:
        return points, adjacency, branches, set()
    added = set(range(len(branches), len(branches) + len(new_branches)))
    return (np.vstack([points, np.array(new_points)]), adjacency + [[] for _ in new_points],
            branches + new_branches, added)


def _direction(points: np.ndarray, path: list[int], at_end: bool, span: int = 8) -> np.ndarray:
    """Unit direction of travel over the last (or first) ``span`` pixels of a path."""
    seg = points[path[-span:]] if at_end else points[path[:span]]
    d = seg[-1] - seg[0]
    norm = np.linalg.norm(d)
    return d / norm if norm > 0 else d


def end_reaches(mask: np.ndarray, points: np.ndarray, branches: list[list[int]], adjacency: list[list[int]],
                span: int, min_length: float) -> dict[int, float]:
    """For each free end of a branch (a skeleton point with at most one neighbour), how far the mask
    goes on beyond it, along the branch's direction there: thinning retracts an end by about half
    the tube's width where the tube is cut square across, but by far more where the cut is slanted
    (a baseplate seen at an angle), so gaps between skeleton ends overstate the gaps in the mask.

    Only branches at least ``min_length`` pixels long: a blob's skeleton (a skin-coloured ball past
    a blurred tip, ``tests/estimator/test_lab_scenes.py``) is short and retracts as far from its
    ends, and credited so it was jumped to."""
    h, w = mask.shape
    out: dict[int, float] = {}
    for b in branches:
        if len(b) < min_length:
            continue
        for at_end in (False, True):
            tip = b[-1] if at_end else b[0]
            if len(adjacency[tip]) > 1 or tip in out:
                continue
            direction = _direction(points, b, at_end=True, span=span) if at_end else \
                -_direction(points, b, at_end=False, span=span)
            reach = 0.0
            while reach < max(h, w):
                x, y = points[tip] + (reach + 0.5) * direction
                if not (0 <= int(round(x)) < w and 0 <= int(round(y)) < h) or not mask[int(round(y)), int(round(x))]:
                    break
                reach += 0.5
            out[tip] = reach
    return out


def least_bending_walk(points: np.ndarray, adjacency: list[list[int]], branches: list[list[int]],
                       start: tuple[int, bool], *, span: int, gap_px: float,
                       keep: Callable[[list[int]], bool] | None = None, turn_back: bool = True,
                       sideways_px: float | None = None, reaches: dict[int, float] | None = None,
                       usual_reach: float = 0.0) -> list[int]:
    """Indices into ``points`` of a walk over skeleton branches from one branch's end (``start``:
    the branch and whether it is walked from its first point): at each junction, or across a gap of
    at most ``gap_px`` from a free end, it continues along the branch that bends least from the
    heading over the last ``span`` points.

    Args:
        keep: a candidate branch (in walking order) may be taken only where this holds.
        turn_back: whether the walk may leave a junction at more than 90 degrees from its heading.
        sideways_px: a gap is jumped only where its far side lies at most this far across the
            heading (None: no limit).
        reaches: how far the mask goes on beyond free skeleton ends (``end_reaches``); across a gap
            between two ends both listed there, what each goes further than ``usual_reach`` (the
            retraction ``gap_px`` allows for) is taken off the gap.
    """
    bi, first = start
    used = {bi}
    path = list(branches[bi] if first else branches[bi][::-1])
    while True:
        tail = path[-1]
        heading = _direction(points, path, at_end=True, span=span)
        best, best_cost = None, np.inf
        for cj, cand in enumerate(branches):
            if cj in used:
                continue
            for reverse in (False, True):
                c = cand[::-1] if reverse else cand
                gap = float(np.linalg.norm(points[c[0]] - points[tail]))
                connected = c[0] == tail or c[0] in adjacency[tail]
                if not connected and reaches and tail in reaches and c[0] in reaches:
                    gap = max(gap - max(reaches[tail] - usual_reach, 0.0) - max(reaches[c[0]] - usual_reach, 0.0), 0.0)
                if not connected and gap > gap_px:
                    continue
                if keep is not None and not keep(c):
                    continue
                out = _direction(points, c, at_end=False, span=span)
                if not connected:
                    back = points[path[max(0, len(path) - span)]]
                    step = (points[c[0]] - back) / max(float(np.linalg.norm(points[c[0]] - back)), 1e-9)
                    if step @ heading < 0.5:
                        continue
                    if sideways_px is not None:
                        jump = points[c[0]] - points[tail]
                        if abs(float(heading[0] * jump[1] - heading[1] * jump[0])) > sideways_px:
                            continue
                    out = (out + step) / 2
                if not turn_back and out @ heading < 0.0:
                    continue
                cost = 1.0 - float(out @ heading) + (0.0 if connected else gap / gap_px)
                if cost < best_cost:
                    best, best_cost = (cj, c), cost
        if best is None:
            return path
        used.add(best[0])
        path.extend(best[1][1:] if best[1][0] == tail else best[1])


def ordered_skeleton_path(mask: np.ndarray, base_hint: np.ndarray | None = None, spur_px: float | None = None,
                          gap_px: float | None = None) -> np.ndarray:
    """Walk the mask's skeleton from the base end to the far end.

    Args:
        mask: (H, W) uint8 arm mask.
        base_hint: (2,) pixel near the base; None selects the skeleton end nearest the top edge.
        spur_px: branches ending freely and shorter than this are pruned (skeleton whiskers);
            default: the arm's width in pixels.
        gap_px: largest gap between skeleton pieces that the walk bridges (hidden baseplates);
            default: three arm widths, since skeleton ends retract by half a width on each side.

    Returns:
        (M, 2) ordered (u, v) pixels, base first; empty if the mask has no skeleton.
    """
    skeleton = thin(mask)
    points, adjacency = _neighbours(skeleton)
    if len(points) < 2:
        return np.zeros((0, 2))
    width = arm_width_px(mask, skeleton)
    spur_px = width if spur_px is None else spur_px
    gap_px = 3.0 * width if gap_px is None else gap_px
    branches = _branches(points, adjacency)
    degree = np.array([len(a) for a in adjacency])
    # Prune short whiskers that end freely at a junction.
    pruned = [b for b in branches
              if not (len(b) < spur_px and ((degree[b[0]] == 1) != (degree[b[-1]] == 1)))]
    branches = pruned or branches
    ends = [(bi, first) for bi, b in enumerate(branches) for first in (True, False)
            if degree[b[0] if first else b[-1]] <= 1]
    if not ends:
        return np.zeros((0, 2))
    if base_hint is None:
        key = [points[branches[bi][0 if first else -1]][1] for bi, first in ends]
    else:
        key = [np.linalg.norm(points[branches[bi][0 if first else -1]] - base_hint) for bi, first in ends]
    bi, first = ends[int(np.argmin(key))]
    span = max(8, int(width))  # long enough to look past the hooked ends thinning leaves
    return points[least_bending_walk(points, adjacency, branches, (bi, first), span=span, gap_px=gap_px)]


def arm_width_px(mask: np.ndarray, skeleton: np.ndarray | None = None) -> float:
    """Typical arm width in pixels: twice the median distance to the background on the skeleton."""
    skeleton = thin(mask) if skeleton is None else skeleton
    if not skeleton.any():
        return 0.0
    distance = cv2.distanceTransform((mask > 0).astype(np.uint8), cv2.DIST_L2, 5)
    return float(2.0 * np.median(distance[skeleton > 0]))


def resample_polyline(points: np.ndarray, n: int) -> np.ndarray:
    """n points at equal arc length along an ordered polyline (first and last kept)."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return np.repeat(points[:1], n, axis=0) if len(points) else np.zeros((0, 2))
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    target = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(target, s, points[:, k]) for k in range(points.shape[1])])
