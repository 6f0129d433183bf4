"""Contour segmentation (section 3.1): median filter, HSV threshold, morphology, Canny contour.

Every function works on a rectified image or a region of it; pixel coordinates returned are
(u, v) = (column, row) in that image.
"""

from __future__ import annotations

import cv2
import numpy as np

from estimator.config import EstimatorConfig


def hsv_mask(image_bgr: np.ndarray, low: tuple[int, int, int], high: tuple[int, int, int]) -> np.ndarray:
    """Binary mask (uint8, 0/255) of pixels inside the inclusive HSV range; hue may wrap past 180."""
    return hsv_in_range(cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV), low, high)


def hsv_in_range(hsv: np.ndarray, low: tuple[int, int, int], high: tuple[int, int, int]) -> np.ndarray:
    """:func:`hsv_mask` of an image already converted to HSV (OpenCV units)."""
    if low[0] <= high[0]:
        return cv2.inRange(hsv, np.array(low, np.uint8), np.array(high, np.uint8))
    upper = cv2.inRange(hsv, np.array(low, np.uint8), np.array((180, high[1], high[2]), np.uint8))
    lower = cv2.inRange(hsv, np.array((0, low[1], low[2]), np.uint8), np.array(high, np.uint8))
    return cv2.bitwise_or(upper, lower)


def arm_mask(image_bgr: np.ndarray, config: EstimatorConfig,
             hsv_low: tuple[int, int, int] | None = None) -> np.ndarray:
    """Segment the arm: median filter, HSV threshold, opening and closing, small regions removed.

    Args:
        image_bgr: (H, W, 3) uint8, rectified (or a region of it).
        config: HSV range, filter sizes and the minimum region area.
        hsv_low: overrides ``config.hsv_low`` (the estimator raises its saturation floor under warm light).

    Returns:
        (H, W) uint8 mask, 255 on the arm.
    """
    return segment(image_bgr, config, hsv_low)[0]


def segment(image_bgr: np.ndarray, config: EstimatorConfig, hsv_low: tuple[int, int, int] | None = None,
            colour_filter=None, drop_small: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`arm_mask` that also returns what a colour model learns from.

    Args:
        colour_filter: ``f(hsv, gate) -> mask`` applied to the gate before the morphology (a
            learned colour model removing background colours), or None.
        drop_small: remove regions smaller than ``config.min_area_px`` (unneeded when the caller
            keeps only what lies near the arm anyway).

    Returns:
        (mask, hsv, gate): the arm mask, the median-filtered image in HSV, the raw colour gate.
    """
    image = cv2.medianBlur(image_bgr, config.median_ksize) if config.median_ksize > 1 else image_bgr
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    gate = hsv_in_range(hsv, config.hsv_low if hsv_low is None else hsv_low, config.hsv_high)
    mask = gate if colour_filter is None else colour_filter(hsv, gate)
    if config.open_ksize > 1:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (config.open_ksize, config.open_ksize))
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
    if config.close_ksize > 1:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (config.close_ksize, config.close_ksize))
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
    return (remove_small_regions(mask, config.min_area_px) if drop_small else mask), hsv, gate


def remove_small_regions(mask: np.ndarray, min_area_px: int) -> np.ndarray:
    """Drop 8-connected regions smaller than ``min_area_px`` (isolated noise, reflections)."""
    if min_area_px <= 1:
        return mask
    count, labels = cv2.connectedComponents(mask, connectivity=8)
    keep = region_areas(mask, labels, count) >= min_area_px
    keep[0] = False
    if keep[1:].all():
        return mask
    return np.where(keep, 255, 0).astype(np.uint8)[labels]


def region_areas(mask: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
    """(count,) pixels of each labelled region of a mask (the background's, label 0, is not counted).

    Counted from the mask's pixels alone: ``cv2.connectedComponentsWithStats`` computes every
    region's box and centroid over the whole image too, 0.25 ms more per coarse image.
    """
    return np.bincount(labels[mask > 0], minlength=count)


def contour_points(mask: np.ndarray, canny_low: int, canny_high: int, step: int) -> np.ndarray:
    """Canny edge of the mask traced as contours, downsampled at equal intervals along them.

    Args:
        mask: (H, W) uint8 arm mask.
        canny_low, canny_high: Canny hysteresis thresholds.
        step: keep every ``step``-th contour point (equal-interval downsampling).

    Returns:
        (K, 2) float64 (u, v) contour points; empty when there is no contour.
    """
    edges = cv2.Canny(mask, canny_low, canny_high)
    contours, _ = cv2.findContours(edges, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros((0, 2))
    traced = np.concatenate([c.reshape(-1, 2) for c in contours])
    return traced[::step].astype(np.float64)


def mask_points(mask: np.ndarray, stride: int) -> np.ndarray:
    """(K, 2) float64 (u, v) of the arm pixels on a ``stride`` grid (all pixels when stride = 1)."""
    sub = mask[::stride, ::stride] if stride > 1 else mask
    found = cv2.findNonZero(sub)
    if found is None:
        return np.zeros((0, 2))
    return found.reshape(-1, 2).astype(np.float64) * stride


def bounding_box(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) exclusive bounds of the non-zero pixels, or None for an empty mask."""
    found = cv2.findNonZero(mask)
    if found is None:
        return None
    x, y, w, h = cv2.boundingRect(found)
    return x, y, x + w, y + h


def has_holes(mask: np.ndarray, min_hole_px: int) -> bool:
    """True when the arm region encloses background: a loop, e.g. the tip folded onto the arm."""
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return False
    for contour, (_, _, _, parent) in zip(contours, hierarchy[0], strict=True):
        if parent >= 0 and cv2.contourArea(contour) >= min_hole_px:
            return True
    return False
