"""Which pixels of the colour mask are the arm, and not the wood, skin or orange things around it.

The paper segments by colour alone in front of a single-colour backdrop. In a lab the colour
range also takes in wooden shelves, skin, orange tool cases and warm-lit walls. What sets the
arm apart is its shape and its history, so this stage keeps, of the colour mask:

- when the previous frame was trusted, what lies in a corridor around the previous centerline
  (the arm moves little between frames); pieces of a distractor that touch the arm are cut off at
  the corridor's edge;
- otherwise (cold start, or the arm left its corridor), the tube: a component of nearly constant
  width along its medial axis whose width and length agree with a tube of the configured radius
  and length at the depth the two images give it, the one reaching furthest towards the base
  (the base hint, or the top edge where the arm hangs from its mount), plus the tube-like pieces
  that continue it across short gaps (baseplates, an occluder).

Everything here works on the coarse (1/4-scale) rectified masks the region-of-interest search
already computes, so it costs about a millisecond per image.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from estimator.segmentation import region_areas

MIN_ASPECT = 2.5  # a tube is at least this many widths long (a folded arm still is)
MIN_CONSISTENCY = 0.55  # share of the medial axis whose half width is near the typical one
WIDTH_AT_DEPTH = (0.6, 1.7)  # measured width / the configured tube's width at the measured depth
GAP_WIDTHS = 3.0  # pieces of one tube are at most this many widths apart (baseplates, occluders)
# ... and the far piece lies at most this many widths across the heading: a tube comes out of a gap
# where it was heading (over baseplates and occluders 0.1 widths aside, 99 % within 0.8: 1105 jumps
# on the twin's sequences), while from the tip to a shelf or a rod beside it the walk jumped 1.6
# widths aside (median) and went on along it.
SIDEWAYS_WIDTHS = 1.0
# A trace that runs over another and on beyond it extends it where it stays within this many of its
# half widths there: a tube drawn wider nearer the camera (1.6 times past a wide connector, seed 13 of
# benchmarks/unseen_scenes.py), not a box the tip rests against (3 times, tests/estimator/test_arm_region.py).
EXTENSION_WIDTHS = 2.0
COVERED = 0.9  # share of a trace's path another must run over to extend it (``_fullest_match``)
STRAY_WIDTHS = 2.0  # a region cut at the tracked corridor this many tube widths wide is not the arm ...
CARRY_HALVES = 1.3  # a path's end is carried on while the gate there is no wider than this many half widths ...
MAX_CARRY_HALVES = 4.0  # ... to where it ends, if it ends within this many half widths
STRAY_OVERLAP = 0.25  # ... where it overlaps the corridor along the curve by at most this many square widths


def corridor(shape: tuple[int, int], curve_px: np.ndarray, half_width_px: float) -> np.ndarray:
    """(H, W) uint8 mask, 255 within ``half_width_px`` of a polyline."""
    out = np.zeros(shape, np.uint8)
    if len(curve_px) < 2:
        return out
    thickness = max(int(round(2.0 * half_width_px)), 1)
    pts = np.round(curve_px * 16.0).astype(np.int32).reshape(-1, 1, 2)  # 4 fractional bits
    cv2.polylines(out, [pts], False, 255, thickness=thickness, lineType=cv2.LINE_8, shift=4)
    return out


def keep_in_corridor(mask: np.ndarray, curve_px: np.ndarray, reach_px: float, clip_px: float,
                     with_cut: bool = False, min_area_px: int = 0):
    """The components of ``mask`` that come within ``reach_px`` of the previous centerline,
    cut to within ``clip_px`` of it (a distractor the arm touches is cut off at the corridor).

    With ``with_cut``, also returns what the cut removed (uint8 mask): much of it, or any of it
    next to the curve's ends, means a distractor touches the arm or the arm itself left the
    corridor (a fast swing of the tip), and the caller should look for the arm afresh.
    Components smaller than ``min_area_px`` are left out as ``remove_small_regions`` would have.
    """
    labels_count, labels = cv2.connectedComponents(mask, connectivity=8)
    large = region_areas(mask, labels, labels_count) >= min_area_px
    near = corridor(mask.shape, curve_px, reach_px)
    touching = np.unique(labels[(near > 0) & (mask > 0)])
    touching = touching[(touching > 0) & large[touching]]
    if len(touching) == 0:
        empty = np.zeros_like(mask)
        return (empty, empty) if with_cut else empty
    keep = np.zeros(labels_count, np.uint8)
    keep[touching] = 255
    kept = keep[labels]
    clipped = cv2.bitwise_and(kept, near if clip_px == reach_px else corridor(mask.shape, curve_px, clip_px))
    if not with_cut:
        return clipped
    return clipped, cv2.subtract(kept, clipped)


def without_wide_strays(kept: np.ndarray, cut: np.ndarray, curve_px: np.ndarray, reach_px: float,
                        width_px: float) -> tuple[np.ndarray, np.ndarray]:
    """``keep_in_corridor``'s kept and cut masks without the regions that reach the corridor only past the
    curve's ends (within ``STRAY_OVERLAP`` square widths of the corridor along the curve itself) and are far
    wider than the tube (``STRAY_WIDTHS``): something of the arm's colour ahead of the tip (a wooden box as
    the dim light's value floor falls), not the tip swung out of the corridor, which is a tube's width.
    Cut, such a region made the tracked corridor give up and the cold search lose the arm's far section
    (an unseen dim frame: "only 467 mm of the 685 mm arm is visible")."""
    if not cut.any():  # the usual tracked frame: nothing cut, nothing to look at
        return kept, cut
    union = cv2.bitwise_or(kept, cut)
    count, labels = cv2.connectedComponents(union, connectivity=8)
    strays = np.unique(labels[cut > 0])
    strays = strays[strays > 0]
    if len(strays) == 0:
        return kept, cut
    along = corridor(union.shape, curve_px, reach_px) > 0
    # closed first: a dim wooden box passes the gate speckled, and its holes would hide its width
    solid = cv2.morphologyEx((union > 0).astype(np.uint8), cv2.MORPH_CLOSE,
                             cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5)))
    depth = cv2.distanceTransform(solid, cv2.DIST_L2, 3)
    drop = np.zeros(count, bool)
    for label in strays:
        region = labels == label
        drop[label] = (np.count_nonzero(region & along) <= STRAY_OVERLAP * width_px**2
                       and float(depth[region].max()) > STRAY_WIDTHS * 0.5 * width_px)
    if not drop.any():
        return kept, cut
    gone = drop[labels]
    kept, cut = kept.copy(), cut.copy()
    kept[gone] = 0
    cut[gone] = 0
    return kept, cut


@dataclass(frozen=True)
class TubeGeometry:
    """What the estimator's configuration says of the tube and the rig, in coarse pixels.

    Attributes:
        focal_px: focal length of the coarse rectified images.
        baseline_m: stereo baseline.
        radius_m: the tube's radius (configured).
        length_m: the arm's length (configured), or None.
        base_hint_px: (u, v) of the base in the coarse left image, or None (the top edge).
    """

    focal_px: float
    baseline_m: float
    radius_m: float
    length_m: float | None
    base_hint_px: tuple[float, float] | None = None

    def width_at(self, disparity_px: float) -> float:
        """Expected width (coarse pixels) of the tube at the depth of this disparity: 2 r d / B."""
        return 2.0 * self.radius_m * disparity_px / self.baseline_m


@dataclass(frozen=True, eq=False)
class Trace:
    """A tube traced along the skeleton of a coarse mask from one of its ends.

    Attributes:
        path: (M, 2) ordered (u, v) skeleton pixels, from the start end.
        half_width: median distance to the background along the path (half the tube's width).
        consistency: share of the path whose distance to the background is near ``half_width``.
        halves: (M,) the distance to the background at each point of the path (None: ``half_width`` everywhere).
    """

    path: np.ndarray
    half_width: float
    consistency: float
    halves: np.ndarray | None = None

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.path, axis=0), axis=1).sum()) if len(self.path) > 1 else 0.0

    @property
    def tube_like(self) -> bool:
        return self.length >= MIN_ASPECT * 2.0 * self.half_width and self.consistency >= MIN_CONSISTENCY

    def mask(self, gate: np.ndarray) -> np.ndarray:
        """The gate's pixels within the tube's reach of the path, the path carried on at each end as far
        as the gate goes on no wider than the tube: what touches it but is wider is cut off.

        A skeleton's end stops short of the tube's, by half a width where the tube ends square across
        but by up to three where it ends slanted in the image (a tip pointing down and aside): the
        reach round the path's end left the tip's last 4-5 coarse pixels out of the mask, and the tube
        was fitted 12-23 mm short (benchmarks/unseen_scenes.py, seed 62, frames 6 and 7). Round each
        end the reach is the tube's own half width there where that is wider than the median: an end
        nearer the camera is wider in the image (seed 79: a tip showing its cap, 8.5 coarse pixels
        against the median's 6.0, cut 24 mm short)."""
        if len(self.path) < 2:
            return cv2.bitwise_and(gate, corridor(gate.shape, self.path, 1.3 * self.half_width + 1.0))
        distance = cv2.distanceTransform((gate > 0).astype(np.uint8), cv2.DIST_L2, 3)
        span = max(2, min(len(self.path) - 1, int(4 * self.half_width)))
        halves = self.halves if self.halves is not None else np.full(len(self.path), self.half_width)
        near_head = max(self.half_width, float(np.median(halves[:span + 1])))
        near_tail = max(self.half_width, float(np.median(halves[-span - 1:])))
        head = _carried_on(self.path[0], self.path[0] - self.path[span], gate, distance, near_head)
        tail = _carried_on(self.path[-1], self.path[-1] - self.path[-1 - span], gate, distance, near_tail)
        reach = corridor(gate.shape, np.vstack([head[::-1], self.path, tail]), 1.3 * self.half_width + 1.0)
        for piece, half in ((np.vstack([head[::-1], self.path[:span + 1]]), near_head),
                            (np.vstack([self.path[-span - 1:], tail]), near_tail)):
            if half > self.half_width:
                reach = cv2.bitwise_or(reach, corridor(gate.shape, piece, 1.3 * half + 1.0))
        return cv2.bitwise_and(gate, reach)


def _carried_on(end: np.ndarray, direction: np.ndarray, gate: np.ndarray, distance: np.ndarray,
                half_width: float) -> np.ndarray:
    """Points from a path's ``end`` on along ``direction`` to where the gate ends, if it ends within
    ``MAX_CARRY_HALVES`` half widths and is no wider than the tube on the way (its distance to the
    background at most ``CARRY_HALVES`` half widths): (K, 2), none otherwise. What goes on further
    (a plank in line with the tube) or widens (a box the tip touches) is not the tube's end."""
    norm = float(np.linalg.norm(direction))
    if norm == 0.0:
        return np.zeros((0, 2))
    step = direction / norm
    h, w = gate.shape
    out = []
    for k in range(1, int(MAX_CARRY_HALVES * half_width) + 1):
        x, y = end + k * step
        u, v = int(round(x)), int(round(y))
        if not (0 <= u < w and 0 <= v < h) or not gate[v, u]:
            return np.array(out).reshape(-1, 2)
        if distance[v, u] > CARRY_HALVES * half_width:
            break
        out.append((x, y))
    return np.zeros((0, 2))


def _walk(points: np.ndarray, adjacency: list[list[int]], branches: list[list[int]], distance: np.ndarray,
          start: tuple[int, bool], reaches: dict[int, float] | None = None) -> list[int]:
    """Walk from a skeleton end: at each junction or gap the least-bending branch of about the
    tube's width (indices into ``points``, starting with the start branch)."""
    from estimator.skeleton import least_bending_walk

    def half_of(ids):
        return float(np.median(distance[points[ids, 1].astype(int), points[ids, 0].astype(int)]))

    half = half_of(branches[start[0]])
    # A branch about the tube's width may continue it, and a tube does not turn back on itself at a junction.
    path = least_bending_walk(points, adjacency, branches, start, span=max(4, int(2 * half)),
                              gap_px=GAP_WIDTHS * 2.0 * half, sideways_px=SIDEWAYS_WIDTHS * 2.0 * half,
                              keep=lambda c: 0.5 <= half_of(c) / max(half, 1e-9) <= 2.0, turn_back=False,
                              reaches=reaches, usual_reach=half)
    return path


def _as_trace(points: np.ndarray, path: list[int], distance: np.ndarray) -> Trace:
    """A walk as a trace; a branch that widens (a distractor the tube touches) ends it there."""
    ids = np.array(path)
    values = distance[points[ids, 1].astype(int), points[ids, 0].astype(int)]
    half = float(np.median(values))
    # Cut the far end where the walk ran into something wider than the tube.
    wide = values > 1.6 * half
    if wide.any():
        tail_ok = np.flatnonzero(~wide)
        keep_to = tail_ok[-1] + 1 if len(tail_ok) else 0
        first_wide = np.flatnonzero(wide)
        cut = first_wide[first_wide > len(ids) // 2]
        if len(cut):
            keep_to = min(keep_to, int(cut[0]))
        ids, values = ids[:keep_to], values[:keep_to]
    if len(ids) < 2:
        return Trace(points[ids], half, 0.0, values)
    half = float(np.median(values))
    consistency = float(np.mean((values >= 0.6 * half) & (values <= 1.5 * half)))
    return Trace(points[ids], half, consistency, values)


MAX_SKELETON_PX = 3000  # a coarse mask with more skeleton than this is a wall or a floor, not a few objects
MAX_STARTS = 8  # skeleton ends tried as the base, nearest the base hint (or the top) first


def trace_tubes(mask: np.ndarray, base_hint: tuple[float, float] | None, min_area_px: int) -> list[Trace]:
    """Tube-like traces of a coarse mask, from the end nearest the base hint (or the top edge) first.

    Returns no trace for a mask that is mostly one colour field (warm light on a wall): its skeleton
    is a maze; the caller raises the saturation floor first.
    """
    return walked_and_turned(mask, base_hint, min_area_px)[0]


def walked_and_turned(mask: np.ndarray, base_hint: tuple[float, float] | None,
                      min_area_px: int) -> tuple[list[Trace], list[Trace]]:
    """The tube-like traces of a coarse mask walked from its ends (nearest the base hint, or the top
    edge, first), and the ones from the other end: where both ends of a piece of tube between two gaps
    were walked from and each walk went on beyond it, the two joined through it; and each trace that
    starts further from the hint than it ends, reversed. Both lists start at their end nearer the hint.
    """
    from estimator.skeleton import _branches, _neighbours, end_reaches, thin, with_stepping_stones

    skeleton = thin(mask)
    if np.count_nonzero(skeleton) > MAX_SKELETON_PX:
        return [], []
    points, adjacency = _neighbours(skeleton)
    if len(points) < 2:
        return [], []
    distance = cv2.distanceTransform((mask > 0).astype(np.uint8), cv2.DIST_L2, 3)
    branches = [b for b in _branches(points, adjacency) if len(b) >= 2]
    typical_half = float(np.median(distance[points[:, 1].astype(int), points[:, 0].astype(int)]))
    points, adjacency, branches, stones = with_stepping_stones(mask, points, adjacency, branches, typical_half,
                                                               distance)
    degree = np.array([len(a) for a in adjacency])
    reaches = end_reaches(mask, points, branches, adjacency, span=max(4, int(4 * typical_half)),
                          min_length=2.0 * typical_half)
    ends = [(bi, first) for bi, b in enumerate(branches) if bi not in stones for first in (True, False)
            if degree[b[0] if first else b[-1]] <= 1]
    if base_hint is None:
        key = [points[branches[bi][0 if first else -1]][1] for bi, first in ends]
    else:
        key = [float(np.linalg.norm(points[branches[bi][0 if first else -1]] - np.asarray(base_hint)))
               for bi, first in ends]
    order = np.argsort(key, kind="stable")
    # ... and the end furthest from it: the walk from the tip crosses gaps the walk from the base stops at
    started = order[:MAX_STARTS] if len(order) <= MAX_STARTS else np.append(order[:MAX_STARTS], order[-1])
    walks = {ends[index]: _walk(points, adjacency, branches, distance, ends[index], reaches) for index in started}
    joined = _joined_walks(walks, branches)

    def flipped(trace):  # the trace from its other end, or None where it starts nearer the base hint (the top)
        a, b = trace.path[0], trace.path[-1]
        if base_hint is None:
            ahead = a[1] <= b[1]
        else:
            ahead = np.linalg.norm(a - np.asarray(base_hint)) <= np.linalg.norm(b - np.asarray(base_hint))
        return None if ahead else Trace(trace.path[::-1], trace.half_width, trace.consistency, trace.halves[::-1])

    def kept(path):  # the walk cut where it widens, in walking order, if it is tube-like and big enough
        trace = _as_trace(points, path, distance)
        big = trace.tube_like and trace.half_width * trace.length * 2.0 >= min_area_px and len(trace.path) >= 2
        return trace if big else None

    walked = [t for t in (kept(walks[ends[index]]) for index in started) if t is not None]
    turned = [other for t in walked if (other := flipped(t)) is not None]
    turned += [flipped(t) or t for t in (kept(path) for path in joined) if t is not None]
    return walked, turned


def _joined_walks(walks: dict[tuple[int, bool], list[int]], branches: list[list[int]]) -> list[list[int]]:
    """Where both ends of one branch were walked from and each walk went on beyond the branch, the
    two as one walk through it. A piece of tube between two gaps (a section between connectors)
    walked from its upper end reaches the tip, from its lower end the base: neither alone is the arm,
    when the base's own end starts no walk (pinholes in a dim section leave its skeleton loops
    without a free end)."""
    joined = []
    for (bi, first), forward in walks.items():
        backward = walks.get((bi, not first))
        n = len(branches[bi])
        if not first or backward is None or len(forward) <= n or len(backward) <= n:
            continue
        joined.append(backward[::-1] + forward[n:])
    return joined


def _stereo_match(left: Trace, right: Trace, geometry: TubeGeometry) -> bool:
    """The right trace shows the same tube: it starts on about the same row (rectified), to the left
    (positive disparity), with a width that fits a tube of the configured radius at that depth."""
    a, b = left.path[0], right.path[0]
    if abs(a[1] - b[1]) > max(2.0 * left.half_width, 3.0):
        return False
    disparity = float(a[0] - b[0])
    if disparity <= 0:
        return False
    ratio = (left.half_width + right.half_width) / geometry.width_at(disparity)
    length_ratio = right.length / max(left.length, 1e-9)
    return WIDTH_AT_DEPTH[0] <= ratio <= WIDTH_AT_DEPTH[1] and 0.5 <= length_ratio <= 2.0


def _covers(trace: Trace, other: Trace, shape: tuple[int, int]) -> bool:
    """Whether ``trace`` runs over all of ``other`` (every point of its path within the tube's reach)
    and, beyond it, stays about as wide as ``other`` (a tube drawn wider nearer the camera, not a box)."""
    reach = corridor(shape, trace.path, 1.3 * trace.half_width + 1.0)
    u, v = np.round(other.path).astype(int).T
    inside = (u >= 0) & (v >= 0) & (u < shape[1]) & (v < shape[0])
    if not inside.all() or float(np.mean(reach[v, u] > 0)) < COVERED:
        return False
    if trace.halves is None:
        return True
    own = corridor(shape, other.path, 1.3 * other.half_width + 1.0)
    u, v = np.round(trace.path).astype(int).T
    inside = (u >= 0) & (v >= 0) & (u < shape[1]) & (v < shape[0])
    beyond = np.ones(len(u), bool)
    beyond[inside] = own[v[inside], u[inside]] == 0
    return not beyond.any() or float(np.median(trace.halves[beyond])) <= EXTENSION_WIDTHS * other.half_width


def _ends_on_one_row(left: Trace, right: Trace) -> bool:
    """The two traces also end on about the same row (rectified): a walk joined through a piece of
    tube that ran on past the tip, into something beside it, ends where the other image's does not."""
    return abs(left.path[-1][1] - right.path[-1][1]) <= max(1.5 * max(left.half_width, right.half_width), 3.0)


def _fullest_match(left: Trace, right: Trace, lefts: list[Trace], rights: list[Trace], geometry: TubeGeometry,
                   shape: tuple[int, int], turned: tuple[list[Trace], list[Trace]] = ([], [])) -> tuple[Trace, Trace]:
    """Of the stereo pairs that run over the first match (``left``, ``right``: the tube reached from its
    base end) and stay about as wide beyond it (``_covers``), the one whose shorter trace is the longest.
    A walk may stop at a gap that the walk from the tip's end crosses: a slanted connector, wide where
    the arm comes towards the camera, past which the far section is drawn wider and turned. One
    image's trace then ended there and the other's did not (refused as a length mismatch), or both did
    (refused as too short). A pair with a trace of ``turned`` (the traces from their other ends,
    ``walked_and_turned``) must also end on one row."""
    extra = {id(t) for side in turned for t in side}
    over_left = [t for t in lefts + turned[0] if t is left or _covers(t, left, shape)]
    over_right = [t for t in rights + turned[1] if t is right or _covers(t, right, shape)]
    best, best_length = (left, right), min(left.length, right.length)
    for other_left in over_left:
        for other_right in over_right:
            length = min(other_left.length, other_right.length)
            if length > best_length and _stereo_match(other_left, other_right, geometry) and (
                    not {id(other_left), id(other_right)} & extra or _ends_on_one_row(other_left, other_right)):
                best, best_length = (other_left, other_right), length
    return best


def find_tube(masks: dict[str, np.ndarray], geometry: TubeGeometry,
              min_area_px: int) -> tuple[dict[str, np.ndarray] | None, str]:
    """Cold start: the arm's pixels in both coarse rectified masks, or None and why not.

    Each mask's skeleton is traced from its ends (the end nearest the base hint, or the top edge,
    first); the first left trace that is tube-like and has a right-image trace starting on the
    same row with a width fitting the configured radius at their disparity is the arm. Of each
    mask, only what lies within the tube's reach of its trace is kept. The traces from their other ends
    (``walked_and_turned``) only extend a match of the walked ones (``_fullest_match``): on their own
    they pair the walls of an over-exposed mask, where the walked ones find nothing and the caller
    raises the saturation floor.
    """
    lefts, lefts_turned = walked_and_turned(masks["left"], geometry.base_hint_px, min_area_px)
    rights, rights_turned = walked_and_turned(masks["right"], None, min_area_px)  # the hint is a left-image pixel
    radius = f"{geometry.radius_m * 1e3:.0f} mm"
    if not lefts or not rights:
        return None, (f"no arm found in the {'left' if not lefts else 'right'} image: nothing of the arm's colour "
                      "has the shape of a tube")
    behind = same_place = False
    for left in lefts:
        for right in rights:
            if _stereo_match(left, right, geometry):
                left, right = _fullest_match(left, right, lefts, rights, geometry, masks["left"].shape,
                                             (lefts_turned, rights_turned))
                return {"left": left.mask(masks["left"]), "right": right.mask(masks["right"])}, ""
            same_row = abs(left.path[0][1] - right.path[0][1]) <= max(2.0 * left.half_width, 3.0)
            shift = left.path[0][0] - right.path[0][0]  # the disparity of the tubes' first points
            same_place |= same_row and abs(shift) < 0.5
            behind |= same_row and shift <= -0.5
    # The calibration's baseline sign is checked before any image is looked at: what remains is the images.
    if same_place:
        return None, ("no depth: the tube is at the same place in both images (zero disparity: the same image "
                      "given as left and right?)")
    if behind:
        return None, ("points behind the camera: the tube appears further right in the right image than in the "
                      "left one (negative disparity): are the left and right images swapped?")
    return None, (f"no arm found: no tube in the left image matches one in the right image with the width of a "
                  f"{radius} radius at its depth (check arm_radius_m and the calibration)")


def saturation_split(image_hsv: np.ndarray, gate: np.ndarray, floor: int) -> int:
    """A saturation threshold that separates the most saturated in-range pixels from the rest.

    Under warm or over-exposed light a wall or a floor falls into the arm's hue range at a lower
    saturation than the arm's dye. Otsu's threshold on the saturation of the in-range pixels
    splits them; it is never below the configured floor.
    """
    saturation = image_hsv[..., 1][gate > 0]
    if len(saturation) < 16:
        return floor
    threshold, _ = cv2.threshold(saturation.reshape(1, -1), 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    return int(max(floor, threshold))
