"""Sub-pixel silhouette edges (estimator.edges) on steps drawn at known sub-pixel columns.

Each image is a vertical orange band rendered at 8x supersampling and averaged down (an
anti-aliased edge like a camera's), so its two edges sit at exactly known columns. Pixel centres
are at integer columns (OpenCV's convention): the band [a, b) covers part of the pixels around a
and b. The whole point of the stage is that no half-pixel quantisation survives: a bias of 0.1 px
in disparity is a millimetre of depth at a metre.
"""

import cv2
import numpy as np
import pytest

from estimator.edges import subpixel_edges, subpixel_edges_and_steps

SS = 8  # supersampling of the test images
H, W = 64, 128
ORANGE = (20.0, 110.0, 245.0)  # BGR, the arm's dye in tests/scenes.py
BACKGROUNDS = {
    "grey": (128.0, 128.0, 128.0),  # a mid-grey wall: about the arm's luma, the difference is in the chroma
    "dark": (25.0, 22.0, 20.0),
    "light": (200.0, 190.0, 180.0),  # the backdrop of tests/scenes.py
}
PHASES = (0.0, 0.25, 0.5, 0.75)
WIDTH_PX = 36.0  # the arm at about a metre; both edges at the same phase
GUESS_ERROR_PX = 0.7  # the mask's chord is this much wider than the band, its centre off by 0.3 px

def _fine_columns() -> np.ndarray:
    return (np.arange(W * SS) + 0.5) / SS - 0.5  # the fine columns' centres in image pixels


def _bricks(shape_fine: tuple[int, int]) -> np.ndarray:
    """Painted bricks as seen 2 m away (courses 26 px, bricks 77 px, mortar 3.5 px), on the fine grid."""
    v = (np.arange(shape_fine[0]) + 0.5) / SS - 0.5
    u = _fine_columns()[: shape_fine[1]]
    U, V = np.meshgrid(u, v)
    course = np.floor(V / 26.0)
    along = U + 38.5 * (course % 2) + 11.0
    brick = np.floor(along / 77.0)
    mortar = ((V - course * 26.0) < 3.5) | ((along - brick * 77.0) < 3.5)
    h = np.sin(course * 12.9898 + brick * 78.233) * 43758.5453
    tint = 0.92 + 0.16 * (h - np.floor(h)) + 0.04 * np.sin(U / 5.0) * np.sin(V / 3.0)
    image = np.array([150.0, 160.0, 190.0]) * tint[..., None]
    image[mortar] = (185.0, 188.0, 190.0)
    return image


def band_image(a: float, b: float, background: str, fg=ORANGE) -> np.ndarray:
    """(H, W, 3) float image: the band of columns [a, b) in ``fg`` on a background, box-filtered from 8x."""
    if background == "bricks":
        fine = _bricks((H * SS, W * SS))
    else:
        fine = np.empty((H * SS, W * SS, 3))
        fine[:] = BACKGROUNDS[background]
    u = _fine_columns()
    fine[:, (u >= a) & (u < b)] = fg
    return fine.reshape(H, SS, W, SS, 3).mean(axis=(1, 3))


def to_uint8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def yuyv_round_trip(bgr: np.ndarray) -> np.ndarray:
    """Through YUYV 4:2:2 as a ZED delivers it: BT.601 studio-range Y per pixel, Cb and Cr averaged over
    horizontal pixel pairs, decoded by OpenCV (the decoder the camera driver uses)."""
    f = bgr.astype(np.float64)
    b, g, r = f[..., 0], f[..., 1], f[..., 2]
    y = 16.0 + 0.257 * r + 0.504 * g + 0.098 * b
    cb = 128.0 - 0.148 * r - 0.291 * g + 0.439 * b
    cr = 128.0 + 0.439 * r - 0.368 * g - 0.071 * b
    packed = np.empty(bgr.shape[:2] + (2,), np.uint8)
    packed[..., 0] = np.clip(np.round(y), 0, 255)
    packed[:, 0::2, 1] = np.clip(np.round(0.5 * (cb[:, 0::2] + cb[:, 1::2])), 0, 255)
    packed[:, 1::2, 1] = np.clip(np.round(0.5 * (cr[:, 0::2] + cr[:, 1::2])), 0, 255)
    return cv2.cvtColor(packed, cv2.COLOR_YUV2BGR_YUYV)


def edge_errors(image: np.ndarray, a: float, b: float, rows=None) -> tuple[np.ndarray, np.ndarray]:
    """Found minus true column of the left and right edge on each row (NaN where none was found)."""
    rows = np.arange(6, H - 6, dtype=np.float64) if rows is None else rows
    centre = 0.5 * (a + b) + 0.3
    points = np.column_stack([np.full(len(rows), centre), rows])
    normals = np.tile([1.0, 0.0], (len(rows), 1))
    half = np.full(len(rows), 0.5 * (b - a) + GUESS_ERROR_PX)
    offsets, _ = subpixel_edges(image, points, normals, half, np.ones(len(rows), bool))
    return centre + offsets[:, 0] - a, centre + offsets[:, 1] - b


def band(phase: float) -> tuple[float, float]:
    a = 40.0 + phase
    return a, a + WIDTH_PX


def test_yuyv_round_trip_keeps_flat_colours():
    """The test's own encoder matches OpenCV's decoder: a flat colour comes back within 2 levels."""
    for colour in (ORANGE, *BACKGROUNDS.values()):
        flat = np.empty((4, 8, 3))
        flat[:] = colour
        assert np.abs(yuyv_round_trip(to_uint8(flat)).astype(float) - flat).max() <= 2.0


@pytest.mark.parametrize("background", ["grey", "dark", "light"])
@pytest.mark.parametrize("phase", PHASES)
def test_crisp_step_is_found_at_its_sub_pixel_column(phase, background):
    a, b = band(phase)
    left, right = edge_errors(to_uint8(band_image(a, b, background)), a, b)
    assert np.all(np.isfinite(left)) and np.all(np.isfinite(right))
    assert abs(np.mean(left)) <= 0.05 and abs(np.mean(right)) <= 0.05, (np.mean(left), np.mean(right))


def test_half_pixel_phases_are_not_quantised():
    """Edges half a pixel apart are found half a pixel apart (a mask would put both on one pixel edge)."""
    found = []
    for phase in (0.0, 0.5):
        a, b = band(phase)
        left, right = edge_errors(to_uint8(band_image(a, b, "dark")), a, b)
        found.append((np.mean(left) + a, np.mean(right) + b))
    assert found[1][0] - found[0][0] == pytest.approx(0.5, abs=0.03)
    assert found[1][1] - found[0][1] == pytest.approx(0.5, abs=0.03)


@pytest.mark.parametrize("blur", ["gaussian_1.5", "box_9"])
@pytest.mark.parametrize("background", ["grey", "dark", "light"])
def test_blurred_step_is_found_within_0_15_px(blur, background):
    """Optics (Gaussian, sigma 1.5 px) and a fast pan (9 px horizontal box): the levels are read beyond
    the blurred step, so a blur symmetric about the edge does not move it."""
    worst = 0.0
    for phase in PHASES:
        a, b = band(phase)
        left, right = edge_errors(to_uint8(_blurred(band_image(a, b, background), blur)), a, b)
        assert np.all(np.isfinite(left)) and np.all(np.isfinite(right)), phase
        worst = max(worst, abs(np.mean(left)), abs(np.mean(right)))
    assert worst <= 0.15


def test_step_on_bricks_is_found_where_no_joint_touches_it():
    """A textured wall: on most rows the edge is where it is; a mortar joint right at the edge may pull
    a few chords (the tube fit's robust loss takes those), but not the typical one."""
    errors = []
    for phase in PHASES:
        a, b = band(phase)
        left, right = edge_errors(to_uint8(band_image(a, b, "bricks")), a, b)
        errors += [left, right]
    errors = np.concatenate(errors)
    assert np.isfinite(errors).mean() >= 0.9
    errors = errors[np.isfinite(errors)]
    assert abs(np.median(errors)) <= 0.05
    assert np.mean(np.abs(errors) <= 0.15) >= 0.8


def test_pan_over_bricks_spreads_edges_but_does_not_bias_them():
    """A 9 px pan blurs the wall's texture into the step (measured: 53 % of chords within 0.15 px, 94 % within
    0.5 px, median 0.006 px): the edges scatter, which the tube fit's robust loss must carry, but stay centred."""
    errors = []
    for phase in PHASES:
        a, b = band(phase)
        left, right = edge_errors(to_uint8(cv2.blur(band_image(a, b, "bricks"), (9, 1))), a, b)
        errors += [left, right]
    errors = np.concatenate(errors)
    assert np.isfinite(errors).mean() >= 0.9
    errors = errors[np.isfinite(errors)]
    assert abs(np.median(errors)) <= 0.05
    assert np.mean(np.abs(errors) <= 0.5) >= 0.9


def _blurred(image: np.ndarray, blur: str) -> np.ndarray:
    if blur == "gaussian_1.5":
        return cv2.GaussianBlur(image, (0, 0), 1.5)
    if blur == "box_9":
        return cv2.blur(image, (9, 1))
    return image


# YUYV shares Cb and Cr between the two pixels of a pair; where the edge's contrast is mostly chroma
# (orange on a grey of about its luma), a blurred step comes back with its chroma ramp on pair
# boundaries. Measured worst |mean| over the four phases, as the test computes it, with chroma counted
# as much as luma (CHROMA_WEIGHT 1.0, 2026-12-02; at 0.35 before, in brackets): grey 0.098 (0.085)
# crisp / 0.16 (0.15) Gaussian / 0.25 (0.27) px box; light 0.083 (0.03) / 0.17 (0.08) / 0.22 (0.14) px;
# dark 0.045 / 0.07 / 0.13 (all <= 0.05) px. The weight went up for the lab scenes' textured walls
# (benchmarks/MEASUREMENTS.md, "Chroma counts as much as luma"); the two cases it moved over the line are marked here.
YUYV_CHROMA_BIAS = {
    ("grey", "gaussian_1.5"): "0.16 px", ("grey", "box_9"): "0.25 px", ("light", "gaussian_1.5"): "0.17 px",
    ("light", "box_9"): "0.22 px", ("dark", "box_9"): "0.13 px"}


def _yuyv_case(background: str, blur: str):
    bias = YUYV_CHROMA_BIAS.get((background, blur))
    marks = () if bias is None else pytest.mark.xfail(
        strict=True, reason=f"estimator/edges.py _ycc: after YUYV 4:2:2 a blurred orange step on {background} is "
                            f"{bias} off (chroma, shared by pixel pairs, carries much of the profile's contrast)")
    return pytest.param(background, blur, marks=marks, id=f"{background}-{blur}")


@pytest.mark.parametrize("background, blur", [_yuyv_case(bg, blur) for bg in ("grey", "dark", "light")
                                              for blur in ("none", "gaussian_1.5", "box_9")])
def test_yuyv_round_trip_moves_edges_less_than_0_1_px(background, blur):
    worst = 0.0
    for phase in PHASES:
        a, b = band(phase)
        left, right = edge_errors(yuyv_round_trip(to_uint8(_blurred(band_image(a, b, background), blur))), a, b)
        assert np.all(np.isfinite(left)) and np.all(np.isfinite(right)), phase
        worst = max(worst, abs(np.mean(left)), abs(np.mean(right)))
    assert worst <= 0.1


def test_low_contrast_edges_are_not_reported():
    """An arm in front of something of nearly its colour: no edge rather than a guessed one."""
    a, b = band(0.25)
    fine = np.empty((H * SS, W * SS, 3))
    fine[:] = (26.0, 114.0, 238.0)  # a few levels from the arm's dye
    u = _fine_columns()
    fine[:, (u >= a) & (u < b)] = ORANGE
    image = to_uint8(fine.reshape(H, SS, W, SS, 3).mean(axis=(1, 3)))
    left, right = edge_errors(image, a, b)
    assert np.all(np.isnan(left)) and np.all(np.isnan(right))
    # while the same band on the dark background has both
    left, right = edge_errors(to_uint8(band_image(a, b, "dark")), a, b)
    assert np.all(np.isfinite(left)) and np.all(np.isfinite(right))


def test_unsupported_chords_and_chords_off_the_image_give_nan():
    a, b = band(0.0)
    image = to_uint8(band_image(a, b, "dark"))
    points = np.array([[0.5 * (a + b), 20.0], [0.5 * (a + b), 30.0], [3.0, 30.0]])
    normals = np.tile([1.0, 0.0], (3, 1))
    half = np.array([0.5 * (b - a)] * 3)
    offsets, contrast = subpixel_edges(image, points, normals, half, np.array([True, False, True]))
    assert np.all(np.isfinite(offsets[0])) and contrast[0].min() > 50
    assert np.all(np.isnan(offsets[1:]))  # not asked for; the third runs off the image's left edge


def test_edges_follow_a_slanted_normal():
    """A band at 30 degrees: chords along its normal find the edges at their true distance."""
    angle = np.radians(30.0)
    n = np.array([np.cos(angle), -np.sin(angle)])  # normal of the band's edges
    yy, xx = np.mgrid[0:H * SS, 0:W * SS]
    u, v = (xx + 0.5) / SS - 0.5, (yy + 0.5) / SS - 0.5
    centre = np.array([64.0, 32.0])
    d = (u - centre[0]) * n[0] + (v - centre[1]) * n[1]
    fine = np.empty((H * SS, W * SS, 3))
    fine[:] = BACKGROUNDS["dark"]
    fine[np.abs(d) < 11.1] = ORANGE
    image = cv2.GaussianBlur(fine.reshape(H, SS, W, SS, 3).mean(axis=(1, 3)), (0, 0), 0.8)
    along = np.array([n[1], -n[0]])
    points = centre + np.outer(np.linspace(-20, 20, 9), along) + 0.4 * n
    offsets, _ = subpixel_edges(to_uint8(image), points, np.tile(n, (9, 1)), np.full(9, 11.5), np.ones(9, bool))
    np.testing.assert_allclose(offsets[:, 0], -11.1 - 0.4, atol=0.1)
    np.testing.assert_allclose(offsets[:, 1], 11.1 - 0.4, atol=0.1)


@pytest.mark.parametrize("blur, lo, hi", [("none", 0.6, 1.3), ("gaussian_1.5", 2.3, 3.0), ("box_9", 5.0, 5.8)])
def test_each_edge_reports_how_wide_its_step_is(blur, lo, hi):
    """The 20-80 % rise: under a pixel or so for a focused anti-aliased step, about 1.7 sigma for a
    Gaussian blur and 0.6 of a pan's length; the tube fit trusts a wide step less."""
    a, b = band(0.25)
    image = to_uint8(_blurred(band_image(a, b, "light"), blur))
    rows = np.arange(6, H - 6, dtype=np.float64)
    points = np.column_stack([np.full(len(rows), 0.5 * (a + b)), rows])
    normals = np.tile([1.0, 0.0], (len(rows), 1))
    offsets, _, steps = subpixel_edges_and_steps(image, points, normals, np.full(len(rows), 0.5 * (b - a)),
                                                 np.ones(len(rows), bool))
    assert np.all(np.isfinite(offsets))
    assert lo <= np.min(steps) and np.max(steps) <= hi, (np.min(steps), np.max(steps))


def test_edges_not_found_report_no_step():
    image = to_uint8(band_image(*band(0.0), "light"))
    points = np.array([[58.0, 20.0], [58.0, 30.0]])
    _, _, steps = subpixel_edges_and_steps(image, points, np.tile([1.0, 0.0], (2, 1)), np.full(2, 18.0),
                                           np.array([False, True]))
    assert np.all(steps[0] == 0.0) and np.all(steps[1] > 0.0)
