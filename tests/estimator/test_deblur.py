"""A linear motion blur measured from the edges' steps and taken out of the images (estimator.deblur).

The blurs here are made without the estimator's own kernel: OpenCV box filters along the rows and
a segment rotated by ``cv2.warpAffine``, so a shared mistake in ``line_kernel`` could not hide.
"""

import cv2
import numpy as np
import pytest

from estimator import CenterlineEstimator, EstimatorConfig
from estimator.deblur import FOCUSED_RISE_PX, MIN_STEPS, RAMP_RISE, LinearBlur, blur_from_steps, deblur, line_kernel
from estimator.edges import step_widths, subpixel_edges_and_steps
from estimator.metrics import score_against_backbone
from tests.scenes import Lab, render_lab_scenes, standard_shapes, zed_like_calibration

ORANGE = (20.0, 110.0, 245.0)  # BGR, the arm's dye in tests/scenes.py
WALL = (150.0, 160.0, 190.0)


def _model_widths(normals, length, angle_deg, rng, noise=0.1):
    d = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
    projected = length * np.abs(normals @ d)
    return np.sqrt(FOCUSED_RISE_PX**2 + (RAMP_RISE * projected) ** 2) + rng.normal(0.0, noise, len(normals))


def _normals(angles_deg):
    a = np.radians(np.asarray(angles_deg, float))
    return np.column_stack([np.cos(a), np.sin(a)])


@pytest.mark.parametrize("length, angle", [(6.0, 0.0), (9.0, 30.0), (12.0, 90.0), (9.0, 135.0)])
def test_blur_read_back_from_steps_of_every_orientation(length, angle):
    rng = np.random.default_rng(1)
    normals = _normals(rng.uniform(0, 360, 400))
    blur = blur_from_steps(normals, _model_widths(normals, length, angle, rng))
    assert blur is not None
    assert blur.length_px == pytest.approx(length, abs=0.3)
    assert abs((blur.angle_deg - angle + 90.0) % 180.0 - 90.0) < 3.0


def test_an_arm_hanging_straight_down_gives_the_blur_across_it():
    """Only horizontal normals: the blur's extent along the rows is measured, none is invented along the columns."""
    rng = np.random.default_rng(2)
    normals = _normals(rng.normal(0.0, 3.0, 300) + rng.choice([0.0, 180.0], 300))
    blur = blur_from_steps(normals, _model_widths(normals, 9.0, 0.0, rng))
    assert blur.length_px == pytest.approx(9.0, abs=0.3)
    assert abs((blur.angle_deg + 90.0) % 180.0 - 90.0) < 5.0


def test_outliers_do_not_move_the_blur():
    """A fifth of the edges read beside clutter (steps three times too wide) leave the blur where it was."""
    rng = np.random.default_rng(3)
    normals = _normals(rng.uniform(0, 360, 400))
    widths = _model_widths(normals, 8.0, 20.0, rng)
    widths[::5] *= 3.0
    blur = blur_from_steps(normals, widths)
    assert blur.length_px == pytest.approx(8.0, abs=0.5)


def test_a_blur_no_one_segment_explains_is_left_in():
    """The arm's own motion blur is not one segment: an arm hanging straight down and swinging sideways
    blurs nothing at its mount and most at its tip (here 0 to 14 px along the rows). Taken out as one
    segment, such a blur rang inside the arm; the camera's shake over the same edges is one segment."""
    rng = np.random.default_rng(6)
    along = rng.uniform(0.0, 1.0, 400)  # where each edge lies along the arm, mount 0, tip 1
    normals = _normals(rng.normal(0.0, 2.0, 400) + rng.choice([0.0, 180.0], 400))
    projected = 14.0 * along * np.abs(normals[:, 0])
    swing = np.sqrt(FOCUSED_RISE_PX**2 + (RAMP_RISE * projected) ** 2) + rng.normal(0.0, 0.1, 400)
    assert blur_from_steps(normals, swing) is None
    shake = blur_from_steps(normals, _model_widths(normals, 9.0, 0.0, rng))
    assert shake is not None and shake.length_px == pytest.approx(9.0, abs=0.3)


def test_focused_or_unmeasured_edges_give_no_blur():
    rng = np.random.default_rng(4)
    normals = _normals(rng.uniform(0, 360, 400))
    assert blur_from_steps(normals, _model_widths(normals, 0.0, 0.0, rng)) is None
    assert blur_from_steps(normals, _model_widths(normals, 2.0, 0.0, rng)) is None  # short blurs are left in
    few = normals[: MIN_STEPS - 1]
    assert blur_from_steps(few, _model_widths(few, 9.0, 0.0, rng)) is None
    widths = _model_widths(normals, 9.0, 0.0, rng)
    widths[MIN_STEPS - 1:] = np.nan  # unmeasured edges do not count
    assert blur_from_steps(normals, widths) is None


@pytest.mark.parametrize("length, angle", [(1.0, 0.0), (9.0, 0.0), (7.3, 37.0), (12.0, 90.0), (5.0, 150.0)])
def test_line_kernel_is_the_segment(length, angle):
    kernel = line_kernel(LinearBlur(length, angle))
    size = kernel.shape[0]
    assert size % 2 == 1 and kernel.sum() == pytest.approx(1.0)
    y, x = np.mgrid[:size, :size] - (size - 1) / 2.0
    d = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    along, across = x * d[0] + y * d[1], -x * d[1] + y * d[0]
    assert np.sum(kernel * along) == pytest.approx(0.0, abs=1e-9)  # centred
    # a segment of length L: variance L^2 / 12 along it, plus the bilinear share's (1/6 px^2 on average)
    assert np.sum(kernel * along**2) == pytest.approx(length**2 / 12.0 + 1.0 / 6.0, abs=0.2)
    assert np.sum(kernel * across**2) < 0.2


def _bar_image(width_px=30.0, rows=120, cols=200, wall=WALL, texture=0.0, seed=0):
    """A vertical orange bar on a wall, anti-aliased edges at columns 85 and 85 + width, float."""
    fine = 8
    u = (np.arange(cols * fine) + 0.5) / fine - 0.5
    inside = ((u >= 85.0) & (u < 85.0 + width_px)).astype(float)
    row = inside.reshape(cols, fine).mean(axis=1)
    image = np.empty((rows, cols, 3))
    for c in range(3):
        image[:, :, c] = ORANGE[c] * row + wall[c] * (1 - row)
    if texture:
        rng = np.random.default_rng(seed)
        image += (1 - row)[None, :, None] * rng.normal(0.0, texture, (rows, cols, 1))
    return image


def _to_uint8(image):
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def _bar_chords(rows=120, width_px=30.0):
    v = np.arange(20, rows - 20, 2, dtype=float)
    points = np.column_stack([np.full(len(v), 85.0 + width_px / 2.0), v])
    normals = np.tile([1.0, 0.0], (len(v), 1))
    return points, normals, np.full(len(v), width_px / 2.0), np.ones(len(v), bool)


@pytest.mark.parametrize("length", [5, 9, 13])
def test_step_widths_read_a_pan_back(length):
    """A pan of 5 / 9 / 13 px over a textured wall: the steps' widths give its length within 8 %."""
    image = _to_uint8(cv2.blur(_bar_image(texture=6.0), (length, 1), borderType=cv2.BORDER_REPLICATE))
    points, normals, half, ok = _bar_chords()
    widths = step_widths(image, points, normals, half, ok)
    assert np.all(widths > 0)
    measured = np.sqrt(np.median(widths) ** 2 - FOCUSED_RISE_PX**2) / RAMP_RISE
    assert measured == pytest.approx(length, rel=0.08)


def _rotated_segment_blur(image, length, angle_deg):
    """Blur by a segment along ``angle_deg``: rotate the image, box-filter the rows, rotate back."""
    h, w = image.shape[:2]
    centre = (w / 2.0, h / 2.0)
    turn = cv2.getRotationMatrix2D(centre, angle_deg, 1.0)  # the segment's direction onto the rows
    back = cv2.getRotationMatrix2D(centre, -angle_deg, 1.0)
    flags = dict(flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    rotated = cv2.warpAffine(image, turn, (w, h), **flags)
    return cv2.warpAffine(cv2.blur(rotated, (length, 1), borderType=cv2.BORDER_REFLECT), back, (w, h), **flags)


def _disc_image(size=160, radius=40.0, noise=1.5, seed=0):
    fine = 4
    c = (np.arange(size * fine) + 0.5) / fine - 0.5
    X, Y = np.meshgrid(c, c)
    inside = (np.hypot(X - size / 2, Y - size / 2) < radius).reshape(size, fine, size, fine).mean(axis=(1, 3))
    image = np.empty((size, size, 3))
    for k in range(3):
        image[:, :, k] = ORANGE[k] * inside + WALL[k] * (1 - inside)
    return image, np.random.default_rng(seed).normal(0.0, noise, image.shape)


@pytest.mark.parametrize("length, angle", [(9, 0.0), (11, 35.0)])
def test_deblur_gives_back_sharp_edges_in_place(length, angle):
    """A disc (edges of every orientation) blurred along a segment, with noise: deblurred, its edges
    rise over about two pixels again (blurred: up to 0.6 of the segment) and lie on its rim."""
    sharp, noise = _disc_image()
    blurred = _to_uint8(_rotated_segment_blur(sharp, length, angle) + noise)
    restored = deblur(blurred, LinearBlur(float(length), angle))
    assert restored.shape == blurred.shape and restored.dtype == np.uint8
    angles = np.radians(np.arange(0.0, 180.0, 7.5))
    normals = np.column_stack([np.cos(angles), np.sin(angles)])
    centres = np.full((len(angles), 2), 80.0)  # the disc's centre (pixel centres at whole numbers)
    half, ok = np.full(len(angles), 40.0), np.ones(len(angles), bool)
    _, _, before = subpixel_edges_and_steps(blurred, centres, normals, half, ok)
    offsets, _, after = subpixel_edges_and_steps(restored, centres, normals, half, ok)
    assert np.max(before) > 0.5 * RAMP_RISE * length
    assert np.median(after) < 2.2 and np.max(after) < 3.0, np.round(after, 2)
    assert np.all(np.isfinite(offsets))
    assert np.max(np.abs(np.abs(offsets) - 40.0)) < 0.35, np.round(np.abs(offsets) - 40.0, 2)


def test_a_crop_deblurs_as_the_whole_image_does_away_from_its_borders():
    """The mirrored border, faded to the mean, keeps the filter's wrap-around from carrying one border's
    content onto the other: a region cut from a blurred image (a dark wall on its left, a light one on
    its right, the arm between) deblurs as the whole image does, to within 2 DN from 12 px inwards
    (mirrored without the fade: 11 DN at the border, 3 DN 20 px in)."""
    rng = np.random.default_rng(5)
    wall = cv2.GaussianBlur(rng.uniform(-20, 20, (160, 400, 3)), (0, 0), 3.0)
    wall[:, :200] += 50.0
    wall[:, 200:] += 190.0
    wall[:, 240:270] = ORANGE
    blurred = _to_uint8(cv2.blur(wall, (9, 1), borderType=cv2.BORDER_REFLECT))
    blur = LinearBlur(9.0, 0.0)
    whole = deblur(blurred, blur).astype(int)
    crop = deblur(blurred[30:130, 120:320], blur).astype(int)
    inner = (slice(12, -12), slice(12, -12))
    assert np.abs(crop[inner] - whole[30:130, 120:320][inner]).max() <= 2


def test_differs_from():
    blur = LinearBlur(9.0, 2.0)
    assert blur.differs_from(None, 1.5, 20.0)
    assert not blur.differs_from(LinearBlur(8.0, 178.0), 1.5, 20.0)  # 4 degrees apart across the wrap
    assert blur.differs_from(LinearBlur(7.0, 2.0), 1.5, 20.0)
    assert blur.differs_from(LinearBlur(9.0, 40.0), 1.5, 20.0)


# --- in the estimator -------------------------------------------------------------------------

@pytest.fixture(scope="module")
def pan_scenes():
    """tests/scenes.py's lab with and without a 9 px pan along the rows, the c_bend and three_d shapes."""
    calib = zed_like_calibration()
    shapes = standard_shapes()
    conditions = {"lab": Lab(), "blur": Lab(motion_blur_px=9)}
    out = {}
    for k, name in enumerate(("c_bend", "three_d")):
        points, joints = shapes[name]
        out[name] = render_lab_scenes(calib, points, joints, conditions=conditions, seed=70 + k)
    return out


@pytest.mark.parametrize("shape", ["c_bend", "three_d"])
def test_the_estimator_measures_the_pan_and_takes_it_out(pan_scenes, shape):
    """Cold on a blurred frame: the blur is measured in the first pass and the frame done again without
    it; the result is the one a second frame gets with the blur already known."""
    scene = pan_scenes[shape]["blur"]
    estimator = CenterlineEstimator(scene.calibration, EstimatorConfig())
    first = estimator.estimate(scene.left, scene.right)
    assert first.valid, first.reason
    assert estimator._blur is not None
    assert estimator._blur.length_px == pytest.approx(9.0, abs=0.8)
    assert abs((estimator._blur.angle_deg + 90.0) % 180.0 - 90.0) < 8.0
    assert "deblur" in first.timings_ms
    assert score_against_backbone(first.points, scene.gt_points)["max_mm"] < 6.0
    without = CenterlineEstimator(scene.calibration, EstimatorConfig(deblur=False)).estimate(scene.left, scene.right)
    assert "deblur" not in without.timings_ms


@pytest.mark.parametrize("shape", ["c_bend", "three_d"])
def test_a_focused_frame_is_not_touched(pan_scenes, shape):
    """No blur: the same result with or without the stage, bit for bit, and no deblur time spent."""
    scene = pan_scenes[shape]["lab"]
    on = CenterlineEstimator(scene.calibration, EstimatorConfig())
    result = on.estimate(scene.left, scene.right)
    off = CenterlineEstimator(scene.calibration, EstimatorConfig(deblur=False)).estimate(scene.left, scene.right)
    assert result.valid and off.valid
    assert on._blur is None and "deblur" not in result.timings_ms
    np.testing.assert_array_equal(result.points, off.points)


def test_reset_forgets_the_blur(pan_scenes):
    scene = pan_scenes["c_bend"]["blur"]
    estimator = CenterlineEstimator(scene.calibration, EstimatorConfig())
    estimator.estimate(scene.left, scene.right)
    assert estimator._blur is not None
    estimator.reset()
    assert estimator._blur is None


def test_paper_mode_does_not_deblur():
    assert EstimatorConfig(mode="paper").deblur is False
    assert EstimatorConfig().deblur is True
    with pytest.raises(ValueError, match="deblur"):
        EstimatorConfig(deblur="yes")
