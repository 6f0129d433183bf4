"""Sub-pixel silhouette edges of the tube, from the image intensities along each chord.

A binary mask puts the tube's edges on whole or half pixels; at a metre, a bias of half a pixel
in disparity is six millimetres of depth, and on a straight tube it does not average out. Here
each chord of the 2D centerline is sampled across the tube in the image itself; on each side the
edge is where the profile crosses halfway between the arm's level just inside and the
background's level just outside (an anti-aliased or blurred step crosses its midpoint at the
true edge). The levels are read where the profile has settled: a first crossing tells how wide the
step is (a fast pan smears it over several pixels), and the levels are read again beyond it.

The profile is the colour projected onto the arm-minus-background difference in YCbCr, chroma
counted as much as luma. A lab's clutter is mostly luma (brick joints, wood grain, shadows) while
the arm differs from it mostly in chroma, so a profile weighted towards luma crossed halfway where
the texture said, not where the arm ended. The price is YUYV 4:2:2 (the ZED over UVC), whose
chroma is shared by horizontal pixel pairs: where chroma carries the edge, a blurred step can come
back 0.1-0.25 px off with the pair's phase (``tests/estimator/test_edges.py``). Where the two
levels barely differ (a background of the arm's colour, an occluder's shadow) no edge is reported.
"""

from __future__ import annotations

import math

import numba
import numpy as np

STEP_PX = 0.5  # sampling step along the normal
SEARCH_PX = 3.0  # how far from the mask's edge the intensity edge may lie
LEVEL_PX = 2.5  # the inside and outside levels are read over this span, just beyond the search window
CHROMA_WEIGHT = 1.0  # weight of Cb, Cr against luma in the profile (0.35 before 2026-12-02: benchmarks/MEASUREMENTS.md)
MIN_CONTRAST = 12.0  # weighted units (about digital numbers of luma): below it, no edge
AREA_WINDOW_PX = 1.5  # half the window of the area step; 0 keeps the interpolated crossing
MAX_BLUR_PX = 6.0  # how wide a blurred step may be for its levels to be read beyond it
LEVEL_PASSES = 2  # levels read again beyond the step this many times (a blurred step: the first read lies on its ramp)
# How far, and how many times, the levels are read again when measuring how wide a step is (``step_widths``):
# on the twin's lab images blurred along the rows, a 9 px pan's step is then read as 5.5 px, its true 20-80 %
# rise (with the fit's 6 px and 2 passes, 5.0, and 4.9 for a 12 px pan: the levels still lay on the ramp).
# The fit's own edges keep the shorter reach: read so, over 15 stored sequences they gave 2 more false valid
# frames (dim) and 15 fewer valid ones on blur.
WIDTH_MAX_BLUR_PX = 12.0
WIDTH_LEVEL_PASSES = 5

# The profile's helpers below are inlined into ``_edges`` (numba IR inlining): as calls, from its loop over
# every sample of every chord, they took half its time (401 -> 216 us a call on the lab ramp, bit for bit).


@numba.njit(cache=True, nogil=True, inline="always")
def _ycc(image, x, y, out):
    """Bilinear (Y, Cb, Cr) of a BGR uint8 image at (x, y); False outside."""
    h, w, _ = image.shape
    if x < 0.0 or y < 0.0 or x > w - 1.0 or y > h - 1.0:
        return False
    x0 = min(int(x), w - 2)
    y0 = min(int(y), h - 2)
    fx = x - x0
    fy = y - y0
    w00 = (1.0 - fx) * (1.0 - fy)
    w01 = fx * (1.0 - fy)
    w10 = (1.0 - fx) * fy
    w11 = fx * fy
    b = (image[y0, x0, 0] * w00 + image[y0, x0 + 1, 0] * w01 + image[y0 + 1, x0, 0] * w10
         + image[y0 + 1, x0 + 1, 0] * w11)
    g = (image[y0, x0, 1] * w00 + image[y0, x0 + 1, 1] * w01 + image[y0 + 1, x0, 1] * w10
         + image[y0 + 1, x0 + 1, 1] * w11)
    r = (image[y0, x0, 2] * w00 + image[y0, x0 + 1, 2] * w01 + image[y0 + 1, x0, 2] * w10
         + image[y0 + 1, x0 + 1, 2] * w11)
    out[0] = 0.299 * r + 0.587 * g + 0.114 * b
    out[1] = (-0.168736 * r - 0.331264 * g + 0.5 * b) * CHROMA_WEIGHT
    out[2] = (0.5 * r - 0.418688 * g - 0.081312 * b) * CHROMA_WEIGHT
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def _span(ts, total, lo, hi):
    """The sample indices [first, last] that cover the stretch [lo, hi] of the profile, with one
    sample to spare on each side (the profile is sampled every ``STEP_PX`` from ts[0])."""
    first = max(int(math.floor((lo - ts[0]) / STEP_PX)) - 1, 0)
    last = min(int(math.ceil((hi - ts[0]) / STEP_PX)) + 1, total - 1)
    return first, last


@numba.njit(cache=True, nogil=True, inline="always")
def _levels(ts, prof, total, centre, sign, gap):
    """Mean colours just inside and just outside an edge near ``centre``, read from ``gap`` to
    ``gap + LEVEL_PX`` on each side; returns (inside, outside, counts ok)."""
    # (scalars and tuples, not arrays: this runs several times for each of thousands of edges a frame)
    i0 = i1 = i2 = o0 = o1 = o2 = 0.0
    ni = 0
    no = 0
    first, last = _span(ts, total, centre - gap - LEVEL_PX, centre + gap + LEVEL_PX)
    for k in range(first, last + 1):
        d = (ts[k] - centre) * sign  # > 0 outside
        if -gap - LEVEL_PX <= d <= -gap:
            i0 += prof[k, 0]
            i1 += prof[k, 1]
            i2 += prof[k, 2]
            ni += 1
        elif gap <= d <= gap + LEVEL_PX:
            o0 += prof[k, 0]
            o1 += prof[k, 1]
            o2 += prof[k, 2]
            no += 1
    if ni == 0 or no == 0:
        return (i0, i1, i2), (o0, o1, o2), False
    return (i0 / ni, i1 / ni, i2 / ni), (o0 / no, o1 / no, o2 / no), True


@numba.njit(cache=True, nogil=True, inline="always")
def _contrasting_levels(ts, prof, total, centre, sign, gap):
    """``_levels``, and the squared contrast between them; (inside, outside, contrast squared, ok),
    not ok where a side has no samples or the contrast is below ``MIN_CONTRAST`` (no edge)."""
    inside, outside, ok = _levels(ts, prof, total, centre, sign, gap)
    diff = (inside[0] - outside[0], inside[1] - outside[1], inside[2] - outside[2])
    norm2 = diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2]
    return inside, outside, norm2, ok and norm2 >= MIN_CONTRAST * MIN_CONTRAST


@numba.njit(cache=True, nogil=True, inline="always")
def _crossing(ts, prof, total, inside, outside, level, centre, reach):
    """Where the profile, normalised to 1 inside and 0 outside, crosses ``level`` nearest ``centre``
    (within ``reach``); NaN if it does not."""
    diff = (inside[0] - outside[0], inside[1] - outside[1], inside[2] - outside[2])
    norm2 = diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2]
    best = 1e9
    found = np.nan
    prev_p = 0.0
    prev_t = 0.0
    first, last = _span(ts, total, centre - reach, centre + reach)
    for k in range(first, last + 1):
        p = ((prof[k, 0] - outside[0]) * diff[0] + (prof[k, 1] - outside[1]) * diff[1]
             + (prof[k, 2] - outside[2]) * diff[2]) / norm2
        t = ts[k]
        if k > first and (prev_p - level) * (p - level) <= 0.0 and prev_p != p:
            tc = prev_t + (level - prev_p) * (t - prev_t) / (p - prev_p)
            if abs(tc - centre) <= reach and abs(tc - centre) < best:
                best = abs(tc - centre)
                found = tc
        prev_p = p
        prev_t = t
    return found


@numba.njit(cache=True, nogil=True, inline="always")
def _area_edge(ts, prof, total, inside, outside, edge, sign, half_window):
    """The edge from the area under the normalised profile within ``half_window`` of a first
    estimate: for a step that fits in the window, that area is the distance from the window's inner
    end to the edge whatever the sampling phase (the interpolated halfway crossing of a crisp
    anti-aliased step is off by up to 0.08 px at quarter-pixel phases). The window is kept short:
    over a longer one the tube's shading towards its rim biases the area."""
    diff = (inside[0] - outside[0], inside[1] - outside[1], inside[2] - outside[2])
    norm2 = diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2]
    lo = edge - half_window
    hi = edge + half_window
    area = 0.0
    prev_p = 0.0
    prev_t = 0.0
    first, last = _span(ts, total, lo, hi)
    for k in range(first, last + 1):
        t = ts[k]
        p = ((prof[k, 0] - outside[0]) * diff[0] + (prof[k, 1] - outside[1]) * diff[1]
             + (prof[k, 2] - outside[2]) * diff[2]) / norm2
        p = min(max(p, 0.0), 1.0)
        if k > first and t > lo and prev_t < hi:
            # the part of the segment [prev_t, t] inside [lo, hi], with p interpolated at its ends
            a = max(prev_t, lo)
            b = min(t, hi)
            slope = (p - prev_p) / (t - prev_t)
            pa = prev_p + slope * (a - prev_t)
            pb = prev_p + slope * (b - prev_t)
            area += 0.5 * (pa + pb) * (b - a)
        prev_p = p
        prev_t = t
    # side +1: inside is t < edge (p = 1 there), so the area is edge - lo; side -1: inside is t > edge, hi - edge
    return lo + area if sign > 0.0 else hi - area


@numba.njit(cache=True, nogil=True)
def _edges(image, points, normals, half, ok, passes, max_blur):
    m = points.shape[0]
    out = np.full((m, 2), np.nan)  # signed distance of the edge from the point along -n (0) and +n (1)
    contrast = np.zeros((m, 2))
    step = np.zeros((m, 2))  # how wide each edge's step is (its rise from 20 to 80 %), px
    reach_max = 0.0
    for i in range(m):
        if ok[i] and half[i] > reach_max:
            reach_max = half[i]
    margin = SEARCH_PX + LEVEL_PX + max_blur + 1.0
    count = int((reach_max + margin + 1.0) / STEP_PX) + 1
    ts = np.empty(2 * count + 1)
    prof = np.empty((2 * count + 1, 3))
    sample = np.empty(3)
    for i in range(m):
        if not ok[i]:
            continue
        x, y = points[i, 0], points[i, 1]
        nx, ny = normals[i, 0], normals[i, 1]
        n = int((half[i] + margin) / STEP_PX)
        valid = True
        for k in range(-n, n + 1):
            t = k * STEP_PX
            if not _ycc(image, x + t * nx, y + t * ny, sample):
                valid = False
                break
            ts[k + n] = t
            prof[k + n, 0] = sample[0]
            prof[k + n, 1] = sample[1]
            prof[k + n, 2] = sample[2]
        if not valid:
            continue
        total = 2 * n + 1
        for side in range(2):
            sign = -1.0 if side == 0 else 1.0
            guess = sign * half[i]
            # Pass 1: levels just beyond the search window around the mask's edge.
            inside, outside, norm2, ok_levels = _contrasting_levels(ts, prof, total, guess, sign, SEARCH_PX)
            if not ok_levels:
                continue
            edge = _crossing(ts, prof, total, inside, outside, 0.5, guess, SEARCH_PX)
            if edge != edge:
                continue
            # Pass 2, for blur (a fast pan, defocus): how wide is the step? Read the levels beyond it.
            # (The area under the profile across the step is phase-proof on a synthetic step but
            # measured worse on the tube, whose shading changes towards its rim: 0.84 -> 1.57 mm.)
            gap = SEARCH_PX
            rise = 0.0
            for _ in range(passes):
                a = _crossing(ts, prof, total, inside, outside, 0.2, edge, SEARCH_PX + max_blur)
                b = _crossing(ts, prof, total, inside, outside, 0.8, edge, SEARCH_PX + max_blur)
                if not (a == a and b == b):
                    break
                rise = abs(a - b)
                gap = min(max(0.8 * abs(a - b) + 1.0, 2.0), SEARCH_PX + max_blur - LEVEL_PX)
                inside2, outside2, n2, ok2 = _contrasting_levels(ts, prof, total, edge, sign, gap)
                if not ok2:
                    break
                inside, outside, norm2 = inside2, outside2, n2
                moved = _crossing(ts, prof, total, inside, outside, 0.5, edge, gap)
                if moved == moved:
                    edge = moved
            refined = _crossing(ts, prof, total, inside, outside, 0.5, edge, gap)
            if refined == refined:
                edge = refined
                if AREA_WINDOW_PX > 0.0:
                    edge = _area_edge(ts, prof, total, inside, outside, edge, sign, AREA_WINDOW_PX)
            # A blurred step's halo passes the colour gate: the mask's edge lies out on it.
            if abs(edge - guess) <= SEARCH_PX + 1.0 + max(gap - SEARCH_PX, 0.0):
                out[i, side] = edge
                contrast[i, side] = np.sqrt(norm2)
                step[i, side] = rise
    return out, contrast, step


def subpixel_edges(image_bgr: np.ndarray, points: np.ndarray, normals: np.ndarray, half_width_px: np.ndarray,
                   supported: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both silhouette edges of every supported chord, from the image.

    Args:
        image_bgr: (H, W, 3) uint8 BGR image (a rectified region of interest).
        points: (M, 2) chord centres (u, v) in that image.
        normals: (M, 2) unit normals of the centerline there.
        half_width_px: (M,) half the mask's chord length (the edge guesses are at -+ it).
        supported: (M,) bool, chords to measure.

    Returns:
        offsets: (M, 2) signed distance along the normal of the edge on the -n side (column 0,
            negative) and on the +n side (column 1); NaN where no edge was found.
        contrast: (M, 2) the colour difference across each edge (luma-weighted units).
    """
    offsets, contrast, _ = subpixel_edges_and_steps(image_bgr, points, normals, half_width_px, supported)
    return offsets, contrast


def subpixel_edges_and_steps(image_bgr: np.ndarray, points: np.ndarray, normals: np.ndarray,
                             half_width_px: np.ndarray, supported: np.ndarray
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``subpixel_edges`` and, for each edge found, how wide its step is: the distance over which the
    profile rises from 20 to 80 % (about 1 px for a focused edge, 0.6 times a pan's length). A wide
    step locates its edge less well: over a textured background the levels on either side of it
    are not flat, and the halfway crossing moves with them.

    Returns:
        (offsets (M, 2), contrast (M, 2), step widths (M, 2) in pixels, 0 where no edge was found).
    """
    return _measured(image_bgr, points, normals, half_width_px, supported, LEVEL_PASSES, MAX_BLUR_PX)


def step_widths(image_bgr: np.ndarray, points: np.ndarray, normals: np.ndarray, half_width_px: np.ndarray,
                supported: np.ndarray) -> np.ndarray:
    """How wide each edge's step is (20-80 % rise, px; 0 where no edge), its levels read until they
    settle beyond the step: what a blur's length is measured from (``estimator.deblur``). Arguments as
    for ``subpixel_edges``; (M, 2) like its offsets."""
    return _measured(image_bgr, points, normals, half_width_px, supported, WIDTH_LEVEL_PASSES, WIDTH_MAX_BLUR_PX)[2]


def _measured(image_bgr, points, normals, half_width_px, supported, passes, max_blur):
    half = np.where(np.isfinite(half_width_px), half_width_px, 0.0).astype(np.float64)
    return _edges(np.ascontiguousarray(image_bgr), np.ascontiguousarray(points, np.float64),
                  np.ascontiguousarray(normals, np.float64), half, np.asarray(supported, np.bool_) & (half > 1.0),
                  int(passes), float(max_blur))
