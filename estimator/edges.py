"""Sub-pixel silhouette edges of the tube, from the image intensities along each chord.

A binary mask puts the tube's edges on whole or half pixels; at a metre, a bias of half a pixel
in disparity is six millimetres of depth, and on a straight tube it does not average out. Here
each chord of the 2D centerline is sampled across the tube in the image itself; on each side the
edge is where the profile crosses halfway between the arm's level just inside and the
background's level just outside (an anti-aliased or blurred step crosses its midpoint at the
true edge).

The profile is the colour projected onto the arm-minus-background difference in a luma-weighted
space: a ZED delivers YUYV 4:2:2, whose chroma is shared by horizontal pixel pairs, so chroma
edges can sit half a pixel off; luma is sampled at every pixel. Where the two levels barely
differ (a background of the arm's colour, an occluder's shadow) no edge is reported.
"""

from __future__ import annotations

import numba
import numpy as np

STEP_PX = 0.5  # sampling step along the normal
SEARCH_PX = 3.0  # how far from the mask's edge the intensity edge may lie
LEVEL_PX = 2.5  # the inside and outside levels are read over this span, just beyond the search window
CHROMA_WEIGHT = 0.35  # weight of Cb, Cr against luma in the profile
MIN_CONTRAST = 12.0  # weighted units (about digital numbers of luma): below it, no edge


@numba.njit(cache=True, nogil=True)
def _ycc(image, x, y, out):
    """Bilinear (Y, Cb, Cr) of a BGR uint8 image at (x, y); False outside."""
    h, w, _ = image.shape
    if x < 0.0 or y < 0.0 or x > w - 1.0 or y > h - 1.0:
        return False
    x0 = min(int(x), w - 2)
    y0 = min(int(y), h - 2)
    fx = x - x0
    fy = y - y0
    bgr = np.zeros(3)
    for c in range(3):
        top = image[y0, x0, c] * (1.0 - fx) + image[y0, x0 + 1, c] * fx
        bottom = image[y0 + 1, x0, c] * (1.0 - fx) + image[y0 + 1, x0 + 1, c] * fx
        bgr[c] = top * (1.0 - fy) + bottom * fy
    b, g, r = bgr[0], bgr[1], bgr[2]
    out[0] = 0.299 * r + 0.587 * g + 0.114 * b
    out[1] = (-0.168736 * r - 0.331264 * g + 0.5 * b) * CHROMA_WEIGHT
    out[2] = (0.5 * r - 0.418688 * g - 0.081312 * b) * CHROMA_WEIGHT
    return True


@numba.njit(cache=True, nogil=True)
def _edges(image, points, normals, half, ok):
    m = points.shape[0]
    out = np.full((m, 2), np.nan)  # signed distance of the edge from the point along -n (0) and +n (1)
    contrast = np.zeros((m, 2))
    reach_max = 0.0
    for i in range(m):
        if ok[i] and half[i] > reach_max:
            reach_max = half[i]
    count = int((reach_max + SEARCH_PX + LEVEL_PX + 2.0) / STEP_PX) + 1
    ts = np.empty(2 * count + 1)
    prof = np.empty((2 * count + 1, 3))
    sample = np.empty(3)
    for i in range(m):
        if not ok[i]:
            continue
        x, y = points[i, 0], points[i, 1]
        nx, ny = normals[i, 0], normals[i, 1]
        reach = half[i] + SEARCH_PX + LEVEL_PX + 1.0
        n = int(reach / STEP_PX)
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
            # Inside and outside colours around the mask's edge.
            inside = np.zeros(3)
            outside = np.zeros(3)
            ni = 0
            no = 0
            for k in range(total):
                d = (ts[k] - guess) * sign  # > 0 outside
                if -SEARCH_PX - LEVEL_PX <= d <= -SEARCH_PX:
                    inside += prof[k]
                    ni += 1
                elif SEARCH_PX <= d <= SEARCH_PX + LEVEL_PX:
                    outside += prof[k]
                    no += 1
            if ni == 0 or no == 0:
                continue
            inside /= ni
            outside /= no
            diff = inside - outside
            norm2 = diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2]
            if norm2 < MIN_CONTRAST * MIN_CONTRAST:
                continue
            # Normalised profile: 1 inside, 0 outside; crossing of 0.5 nearest the guess.
            best = 1e9
            found = np.nan
            prev_p = 0.0
            prev_t = 0.0
            for k in range(total):
                p = ((prof[k, 0] - outside[0]) * diff[0] + (prof[k, 1] - outside[1]) * diff[1]
                     + (prof[k, 2] - outside[2]) * diff[2]) / norm2
                t = ts[k]
                if k > 0 and (prev_p - 0.5) * (p - 0.5) <= 0.0 and prev_p != p:
                    tc = prev_t + (0.5 - prev_p) * (t - prev_t) / (p - prev_p)
                    if abs(tc - guess) <= SEARCH_PX and abs(tc - guess) < best:
                        best = abs(tc - guess)
                        found = tc
                prev_p = p
                prev_t = t
            if found == found:
                out[i, side] = found
                contrast[i, side] = np.sqrt(norm2)
    return out, contrast


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
    half = np.where(np.isfinite(half_width_px), half_width_px, 0.0).astype(np.float64)
    return _edges(np.ascontiguousarray(image_bgr), np.ascontiguousarray(points, np.float64),
                  np.ascontiguousarray(normals, np.float64), half, np.asarray(supported, np.bool_) & (half > 1.0))
