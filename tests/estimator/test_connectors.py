"""The connectors between sections as stereo features (estimator.pipeline._connector_centres, the tube
fit's ``connectors``): where the band a disc makes across the tube is centred in each image, and what
that says of depth where the silhouette's lines say nothing (a section along the image rows).

The band's centre is checked against a small ray caster (two tubes and a disc, first hit along each
ray), not against the formula the fit uses.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from estimator import EstimatorConfig
from estimator.pipeline import MAX_CONNECTOR_ROW_PX, _connector_centres, _paired_connectors, _paired_views
from estimator.refinement import Centerline2D
from estimator.tube_fit import _connector_pair_residual, _connector_residual, _end_residual
from tests.estimator.test_tube_fit import CENTRES, B, F, _middle_depth_error_mm, _rows_curve, fit, tube_edges

R_TUBE, R_DISC, THICKNESS = 0.026, 0.032, 0.008  # the twin's arm: sections' and baseplates' radii, plate thickness


def _cylinder_hits(origin, rays, centre, axis, radius, lo, hi):
    """Distance along each unit ray (K, 3) from ``origin`` to a finite cylinder (mantle between axial
    positions lo and hi, and its two end discs); inf where missed."""
    w = origin - centre
    d_along = rays @ axis
    w_along = w @ axis
    d_perp = rays - d_along[:, None] * axis
    w_perp = w - w_along * axis
    a = np.sum(d_perp * d_perp, axis=1)
    b = 2.0 * d_perp @ w_perp
    c = w_perp @ w_perp - radius * radius
    disc = b * b - 4.0 * a * c
    best = np.full(len(rays), np.inf)
    root = np.sqrt(np.maximum(disc, 0.0))
    for s in ((-b - root) / (2.0 * a), (-b + root) / (2.0 * a)):
        at = w_along + s * d_along
        ok = (disc >= 0.0) & (s > 0.0) & (at >= lo) & (at <= hi)
        best = np.where(ok & (s < best), s, best)
    for plane in (lo, hi):
        if not np.isfinite(plane):
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (plane - w_along) / d_along
        p = w + s[:, None] * rays
        inside = np.linalg.norm(p - (p @ axis)[:, None] * axis, axis=1) <= radius
        ok = (s > 0.0) & inside
        best = np.where(ok & (s < best), s, best)
    return best


def rendered_band_centre(centre: np.ndarray, axis: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """Where the disc's band is centred along the tube's image, by casting rays along the projected axis
    from ``camera`` (a point in the left frame) and taking the middle of the run of rays that hit the
    disc first (normalised coordinates of that camera)."""
    axis = axis / np.linalg.norm(axis)
    c, ahead = centre - camera, centre + 0.01 * axis - camera
    p0, p1 = c[:2] / c[2], ahead[:2] / ahead[2]
    along = (p1 - p0) / np.linalg.norm(p1 - p0)
    steps = np.arange(-40.0, 40.0, 0.005) / F
    image = p0[None] + steps[:, None] * along[None]
    rays = np.column_stack([image, np.ones(len(image))])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    half = THICKNESS / 2.0
    hits = np.vstack([_cylinder_hits(np.zeros(3), rays, c, axis, R_TUBE, -np.inf, -half),
                      _cylinder_hits(np.zeros(3), rays, c, axis, R_DISC, -half, half),
                      _cylinder_hits(np.zeros(3), rays, c, axis, R_TUBE, half, np.inf)])
    disc = (np.argmin(hits, axis=0) == 1) & np.isfinite(hits.min(axis=0))
    run = np.flatnonzero(disc)
    assert len(run) and np.all(np.diff(run) == 1), "one band"
    return image[(run[0] + run[-1]) // 2]


@pytest.mark.parametrize("tilt_deg", [0.0, 10.0, 25.0, 45.0, -30.0])
def test_the_band_is_centred_where_the_model_says_not_on_the_axis(tilt_deg):
    """Tilted towards the camera, the disc's band moves along the tube's image by up to a disc radius:
    seen by the ray caster from both cameras, the fit's model puts it within 0.05 px, the axis point's
    own image 1-10 px off."""
    tilt = math.radians(tilt_deg)
    axis = np.array([math.cos(tilt) * 0.6, math.cos(tilt) * 0.8, math.sin(tilt)])  # in the image: down-right
    centre = np.array([-0.05, 0.02, 1.1])
    for O in CENTRES:
        x, y = rendered_band_centre(centre, axis, O)
        C = centre - O
        model = _connector_residual(C, axis, R_TUBE, x, y, R_DISC) * F
        assert abs(model) < 0.05, (tilt_deg, model)
        raw = _end_residual(C, axis, R_TUBE, x, y, 0.0) * F
        if abs(tilt_deg) >= 10.0:
            assert abs(raw) > 1.0, (tilt_deg, raw)


def test_the_pair_residual_reads_disparity_not_the_place_along_the_axis():
    """Sliding the place 10 mm along the axis (7 px along the tube's image) moves the pair's residual
    by a tenth of a pixel (the axis runs a little in depth, so the two images' scales differ); moving
    the axis 12 mm in depth moves it by half a pixel."""
    axis = np.array([1.0, 0.0, 0.3]) / math.hypot(1.0, 0.3)
    centre = np.array([0.0, 0.05, 1.2])
    views = [rendered_band_centre(centre, axis, O) for O in CENTRES]
    at = _connector_pair_residual(centre, axis, R_TUBE, *views[0], *views[1], R_DISC, B) * F
    slid = _connector_pair_residual(centre + 0.01 * axis, axis, R_TUBE, *views[0], *views[1], R_DISC, B) * F
    deeper = _connector_pair_residual(centre * 1.01, axis, R_TUBE, *views[0], *views[1], R_DISC, B) * F
    assert abs(at) < 0.05
    assert abs(slid - at) < 0.2  # measured 0.12 px
    assert abs(deeper - at) > 0.4  # measured 0.6 px


def test_a_connector_fixes_depth_where_the_tube_runs_along_the_rows():
    """The stretch along the rows started 20 mm towards the camera, the radius 2 mm too small and held
    only loosely (4 mm): its silhouette's lines carry no disparity there, and its width says little;
    one connector in its middle, seen as the ray caster sees it, fixes its depth."""
    axis = _rows_curve()
    edges = tube_edges(axis, R_TUBE, noise_px=0.05)
    start = _rows_curve(0.02)
    alone = fit(edges, axis, start, radius=R_TUBE - 0.002, sigma=0.004)
    middle = np.argmin(np.abs(axis[:, 0] - 0.05) + 10.0 * np.abs(axis[:, 1]))
    direction = axis[middle + 1] - axis[middle - 1]
    views = np.array([[rendered_band_centre(axis[middle], direction, O) for O in CENTRES]])
    joined = fit(edges, axis, start, radius=R_TUBE - 0.002, sigma=0.004, connectors=views, connector_radius_m=R_DISC)
    assert abs(_middle_depth_error_mm(alone)) > 5.0  # measured 6.4 mm
    assert abs(_middle_depth_error_mm(joined)) < 1.5  # measured 0.9 mm


def _tube_image(band_x: float, gap_px: float = 6.0, shake_px: float = 9.0) -> np.ndarray:
    """An orange tube along row 120 on a grey wall, a dark band of ``gap_px`` centred at ``band_x``
    (drawn 8x finer, then averaged down), smeared by a horizontal pan of ``shake_px``."""
    s = 8
    big = np.full((240 * s, 640 * s, 3), (150, 160, 170), np.uint8)
    cv2.rectangle(big, (40 * s, 105 * s), (600 * s, 135 * s), (30, 110, 235), -1)
    # fine pixels lo..hi (inclusive) cover [band_x - gap / 2, band_x + gap / 2] once averaged down
    # (pixel centres on integers)
    lo, hi = int(round((band_x - gap_px / 2 + 0.5) * s)), int(round((band_x + gap_px / 2 + 0.5) * s)) - 1
    cv2.rectangle(big, (lo, 101 * s), (hi, 139 * s), (40, 40, 45), -1)
    image = cv2.resize(big, (640, 240), interpolation=cv2.INTER_AREA)
    if shake_px:
        kernel = np.ones((1, int(shake_px)), np.float32) / int(shake_px)
        image = cv2.filter2D(image, -1, kernel, borderType=cv2.BORDER_REPLICATE)
    return image


def _curve_with_gaps(gaps: list[tuple[float, float]]) -> Centerline2D:
    """A centerline along row 120 (the tube's axis), unsupported over each (from, to) column range."""
    x = np.arange(45.0, 596.0, 3.0)
    valid = np.ones(len(x), bool)
    for lo, hi in gaps:
        valid &= ~((x >= lo) & (x <= hi))
    half = np.where(valid, 15.0, np.nan)
    return Centerline2D(np.column_stack([x, np.full_like(x, 120.0)]), valid, half, x - x[0])


@pytest.mark.parametrize("band_x", [300.0, 300.35, 300.7])
def test_a_connectors_centre_is_found_to_a_tenth_of_a_pixel_under_a_pan(band_x):
    """The dip's centroid along the centerline: the pan spreads it symmetrically and does not move it."""
    curve = _curve_with_gaps([(band_x - 18.0, band_x + 18.0)])
    for shake in (0.0, 9.0):
        found = _connector_centres(_tube_image(band_x, shake_px=shake), curve, np.zeros(2))
        assert found.shape == (1, 2)
        assert abs(found[0, 0] - band_x) < 0.1, (shake, found)


def test_a_long_stretch_without_clean_chords_is_not_taken_for_a_connector():
    """An occluder hides three widths of the arm: no connector there."""
    curve = _curve_with_gaps([(260.0, 350.0)])
    assert len(_connector_centres(_tube_image(300.0, gap_px=60.0), curve, np.zeros(2))) == 0


def test_connectors_are_paired_only_when_both_images_show_as_many_on_about_the_same_rows():
    left = np.array([[400.0, 300.0], [420.0, 500.0]])
    right = left - [80.0, 0.0]
    assert _paired_connectors(left, right).shape == (2, 2, 2)
    assert _paired_connectors(left, right[:1]) is None
    assert _paired_connectors(left[:0], right[:0]) is None
    shifted = right + [0.0, MAX_CONNECTOR_ROW_PX + 1.0]
    assert _paired_connectors(left, shifted) is None


@pytest.mark.parametrize("shake", [0.0, 9.0])
def test_a_thin_band_the_mask_closed_over_is_found_in_the_image_colour(shake):
    """A connector seen at a slant is a band of a few pixels that the mask's median and closing fill in:
    every chord is clean, so only the colour along the centerline shows it (with ``bands``)."""
    curve = _curve_with_gaps([])
    image = _tube_image(300.3, gap_px=4.0, shake_px=shake)
    assert len(_connector_centres(image, curve, np.zeros(2))) == 0
    found = _connector_centres(image, curve, np.zeros(2), bands=True)
    assert found.shape == (1, 2)
    assert abs(found[0, 0] - 300.3) < 0.15, found


def test_shading_along_the_tube_is_not_taken_for_a_band():
    """A tube lit from one end (its colour fading by half over its length) and a dark mount at its
    base: no band between them."""
    curve = _curve_with_gaps([])
    image = _tube_image(700.0, shake_px=0.0)  # the band off the image
    fade = np.linspace(1.0, 0.5, image.shape[1])[None, :, None]
    shaded = np.clip(image * fade, 0, 255).astype(np.uint8)
    shaded[:, :48] = (40, 40, 45)  # the mount, where the centerline starts
    assert len(_connector_centres(shaded, curve, np.zeros(2), bands=True)) == 0


def test_bands_are_looked_for_only_where_the_gaps_leave_the_images_disagreeing():
    left = np.array([[400.0, 300.0], [420.0, 500.0]])
    right = left - [80.0, 0.0]
    at_gaps = _paired_connectors(left, right)
    asked = []

    def bands(shown):
        def with_bands(k):
            asked.append(k)
            return shown[k]
        return with_bands

    # the gaps pair: the bands are not looked for
    assert np.array_equal(_paired_views([left, right], bands([left, np.vstack([right, [[500.0, 600.0]]])])), at_gaps)
    assert asked == []
    # one image's mask closed over a connector: its bands complete the pairs
    assert np.array_equal(_paired_views([left[:1], right], bands([left, right])), at_gaps)
    assert np.array_equal(_paired_views([left, right[1:]], bands([left, right])), at_gaps)
    assert _paired_views([left[:1], right], bands([left[:1], right])) is None


def test_connector_radius_is_checked():
    assert EstimatorConfig(connector_radius_m=0.032).connector_radius_m == 0.032
    assert EstimatorConfig().connector_radius_m is None
    for bad in (-0.01, 0.0, "0.03", True):
        with pytest.raises(ValueError, match="connector_radius_m"):
            EstimatorConfig(connector_radius_m=bad)
