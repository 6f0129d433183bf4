"""Issue 10's independent check: the default estimator in lab scenes it has never seen.

tests/scenes.py renders the five standard shapes through the raw ZED-like pair in front of a
painted brick wall 2 m away, with a wooden shelf board and box, a skin-coloured object and a thin
yellow cable beside the arm, under five conditions (``LAB_CONDITIONS``): the lab as it is, dim
light (45 %), warm over-exposure (red up, blue down), a 9 px horizontal pan blur, and a 12 mm dark
cable crossing in front of the arm at 40 % of its length. Every frame is estimated cold (a fresh
estimator), the hardest case for telling the arm from the rest.

Targets (issue 10): in lab, dim, warm and blur every frame valid, in occluded at least 4 of 5;
pooled RMSE of the valid frames <= 3 mm (5 mm occluded); never a frame valid while more than 10 mm
off. Paper mode assumes a single-colour background and may fail here; it must still say why.
"""

import numpy as np
import pytest

from estimator import CenterlineEstimator, EstimatorConfig
from estimator.metrics import score_against_backbone
from tests.scenes import LAB_CONDITIONS, Lab, box_layer, render_lab_scenes, standard_shapes, zed_like_calibration

FALSE_VALID_MM = 10.0
MIN_VALID = {"lab": 5, "dim": 5, "warm": 5, "blur": 5, "occluded": 4}
MAX_RMSE_MM = {"lab": 3.0, "dim": 3.0, "warm": 3.0, "blur": 3.0, "occluded": 5.0}
OCCLUDER_AT = 0.4  # fraction of the arm's length where the occluding cable crosses it (tests/scenes.py)


@pytest.fixture(scope="module")
def lab_scenes():
    """(shape, condition) -> Scene; each shape's tube is rasterised once for all conditions."""
    calib = zed_like_calibration()
    scenes = {}
    for k, (name, (points, joints)) in enumerate(standard_shapes().items()):
        for condition, scene in render_lab_scenes(calib, points, joints, seed=40 + 10 * k).items():
            scenes[name, condition] = scene
    return scenes


def _estimate(scene, mode="default"):
    result = CenterlineEstimator(scene.calibration, EstimatorConfig(mode=mode)).estimate(scene.left, scene.right)
    score = score_against_backbone(result.points, scene.gt_points) if result.valid else None
    return result, score


@pytest.fixture(scope="module")
def default_results(lab_scenes):
    return {key: _estimate(scene) for key, scene in lab_scenes.items()}


def _summary(results, condition):
    rows = {shape: (round(s["rmse_mm"], 2), round(s["max_mm"], 1)) if r.valid else r.reason
            for (shape, c), (r, s) in results.items() if c == condition}
    return rows


# Measured failures (default mode, these seeds, estimator at commit 59a18e3), each marked xfail(strict) until fixed.
# A 9 px pan over the brick wall is the hard case: without the wall the same frames are within 1 mm.
# blur's base 53 mm off came back valid until a hidden base was refused.
# blur's towards_camera came back valid 13.3 mm off once the coarse masks read the nearest pixels (2026-12-02),
# until a blurred edge's sigma grew by 0.6 of its excess step width rather than 0.3.
FALSE_VALID: dict[str, str] = {}
# blur was 4 of 5 valid at 5.4 mm (towards_camera 9.8) until blurred edges were weighted by their step's width.
INACCURATE: dict[str, str] = {}


def _conditions(known: dict):
    return [pytest.param(c, marks=pytest.mark.xfail(strict=True, reason=known[c])) if c in known else c
            for c in LAB_CONDITIONS]


@pytest.mark.parametrize("condition", _conditions(FALSE_VALID))
def test_no_frame_is_valid_while_more_than_10_mm_off(default_results, condition):
    wrong = {shape: round(s["max_mm"], 1) for (shape, c), (r, s) in default_results.items()
             if c == condition and r.valid and s["max_mm"] > FALSE_VALID_MM}
    assert not wrong, _summary(default_results, condition)


@pytest.mark.parametrize("condition", _conditions(INACCURATE))
def test_lab_frames_are_valid_and_accurate(default_results, condition):
    valid = [s for (_, c), (r, s) in default_results.items() if c == condition and r.valid]
    summary = _summary(default_results, condition)
    assert len(valid) >= MIN_VALID[condition], summary
    pooled = float(np.sqrt(np.mean([s["rmse_mm"] ** 2 for s in valid])))
    assert pooled <= MAX_RMSE_MM[condition], summary


def test_points_hidden_by_the_occluder_are_not_called_measured(default_results):
    """Where the dark cable crosses the arm, the estimate says a point there was bridged, not seen."""
    checked = 0
    for (shape, condition), (result, _) in default_results.items():
        if condition != "occluded" or not result.valid:
            continue
        assert len(result.measured) == len(result.points)
        fractions = np.linspace(0.0, 1.0, len(result.points))
        near = np.abs(fractions - OCCLUDER_AT) <= 1.5 / (len(fractions) - 1)  # the points either side of it
        assert not result.measured[near].all(), shape
        assert result.measured[[0, -1]].all(), shape  # the ends are in plain view
        checked += 1
    assert checked >= MIN_VALID["occluded"]


def test_every_valid_lab_frame_says_how_well_each_point_is_known(default_results):
    for key, (result, _) in default_results.items():
        if not result.valid:
            assert result.reason, key
            continue
        n = len(result.points)
        assert result.measured.shape == (n,) and result.point_std_m.shape == (n,), key
        assert np.all(np.isfinite(result.point_std_m)) and np.all(result.point_std_m > 0), key
        assert result.radius_source == "configured" and result.radius_m == pytest.approx(0.025, abs=0.003), key


def test_paper_mode_in_clutter_fails_loudly_or_not_at_all(lab_scenes):
    """The paper assumes a single-colour background: in these scenes it may fail (measured: see the report),
    but an invalid frame names its reason and a valid one has every point in front of the camera."""
    for key, scene in lab_scenes.items():
        if key[1] not in ("lab", "warm"):
            continue
        result, _ = _estimate(scene, "paper")
        if result.valid:
            assert result.points.shape == (EstimatorConfig(mode="paper").n_points, 3), key
            assert np.all(np.isfinite(result.points)), key
        else:
            assert result.reason, key


def _behind_the_tip(points: np.ndarray) -> Lab:
    """The lab with the shelf board moved to pass behind the arm's last section (the arm's silhouette
    touches wood of about its own width and colour; 0.5 m behind it)."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    p = np.array([np.interp(0.85 * arc[-1], arc, points[:, k]) for k in range(3)])
    z = 1.5
    x, y = p[0] * z / p[2], p[1] * z / p[2]
    from tests.scenes import WOOD_BGR

    return Lab(extra=(box_layer(z, (x - 0.15, x + 0.9), (y - 0.025, y + 0.03), WOOD_BGR, grain_m=0.011),))


@pytest.fixture(scope="module")
def shelf_results():
    calib = zed_like_calibration()
    out = {}
    for k, (name, (points, joints)) in enumerate(standard_shapes().items()):
        scene = render_lab_scenes(calib, points, joints, {"shelf": _behind_the_tip(points)}, seed=90 + k)["shelf"]
        out[name] = _estimate(scene)
    return out


def test_wood_behind_the_arm_is_never_taken_for_it(shelf_results):
    """A shelf board behind the arm's last section: the estimate may give up, but not follow the board."""
    wrong = {name: round(s["max_mm"], 1) for name, (r, s) in shelf_results.items()
             if r.valid and s["max_mm"] > FALSE_VALID_MM}
    assert not wrong, {name: (round(s["max_mm"], 1) if r.valid else r.reason) for name, (r, s) in shelf_results.items()}
    # and giving up is the exception: an estimator that refused every frame would pass the check above
    valid = sum(r.valid for r, _ in shelf_results.values())
    assert valid >= len(shelf_results) - 1, {name: r.reason for name, (r, _) in shelf_results.items() if not r.valid}


def test_the_lab_renderer_puts_the_wall_at_its_disparity():
    """On the ideal rectified rig a wall parallel to the image at 2 m is the left image moved by f B / Z = 42 px."""
    from tests.scenes import paint_layers, rectified_calibration, wall_layer

    calib = rectified_calibration()
    w, h = calib.image_size
    blank = np.zeros((h, w, 3))
    left = paint_layers(calib, "left", [wall_layer("bricks", 2.0)], blank)
    right = paint_layers(calib, "right", [wall_layer("bricks", 2.0)], blank)
    shift = round(700.0 * 0.12 / 2.0)
    differs = np.abs(right[:, : w - shift] - left[:, shift:]).max(axis=2) > 1e-6
    assert differs.mean() < 0.01  # (pixels exactly on a mortar line's edge may round either way: 0.2 %)
    assert np.abs(right - left).max() > 50  # and the wall has texture to match


def test_a_bare_lab_scene_is_the_plain_scene():
    """Without wall, distractors, light or noise, the layered renderer gives the plain one's image (the tube's
    coverage composited over the backdrop) to within rounding."""
    from tests.scenes import rectified_calibration, render_scene

    calib = rectified_calibration()
    points, joints = standard_shapes()["c_bend"]
    plain = render_scene(calib, points, joints, noise_std=0.0)
    bare = render_scene(calib, points, joints, lab=Lab(wall=None, distractors=False, noise_std=0.0))
    for a, b in ((plain.left, bare.left), (plain.right, bare.right)):
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 2
