"""A dark cable running in front of the arm along its tip's edge (tests/scenes.py, the raw ZED-like
pair, the lab's brick wall; one cold frame per case).

The cable hides a sliver of the tube's side in one image and lends its own edge to the outline
around the tip. The tube then does not follow that stretch of silhouette line, and the fitted end
cannot explain that outline: neither may count as a measurement, and a frame far off must not come
back valid.
"""

import numpy as np
import pytest

from estimator import CenterlineEstimator
from estimator.metrics import score_against_backbone
from estimator.pipeline import EXPLAINED_SIGMAS, _explained, _measured, _outline_inliers
from tests.scenes import DARK_BGR, Lab, cable_layer, render_lab_scenes, standard_shapes, zed_like_calibration

CABLE_Z_M = 0.75  # the cable's depth: a quarter metre in front of the arm
CABLE_WIDTH_M = 0.008


def _along_the_tip(points: np.ndarray, side: float, offset_m: float, angle: float = 0.0) -> Lab:
    """The lab with a dark cable parallel to the tip's last stretch (turned by ``angle`` radians), its
    centre ``offset_m`` to one side of the axis (metres at the cable's depth), running past the tip."""
    z = CABLE_Z_M
    tip, before = points[-1][:2] * z / points[-1][2], points[-8][:2] * z / points[-8][2]
    along = (tip - before) / np.linalg.norm(tip - before)
    across = np.array([-along[1], along[0]])
    direction = along * np.cos(angle) + across * np.sin(angle) * side
    centre = tip + across * offset_m * side
    return Lab(extra=(cable_layer(z, np.array([centre - 0.5 * direction, centre + 0.3 * direction]), CABLE_WIDTH_M,
                                  DARK_BGR),))


def _across_the_tip(points: np.ndarray, beyond_m: float) -> Lab:
    """The lab with a dark cable across the tip's last stretch, its centre ``beyond_m`` past the axis's
    end along it (metres at the cable's depth)."""
    z = CABLE_Z_M
    tip, before = points[-1][:2] * z / points[-1][2], points[-6][:2] * z / points[-6][2]
    along = (tip - before) / np.linalg.norm(tip - before)
    across = np.array([-along[1], along[0]])
    centre = tip + along * beyond_m
    return Lab(extra=(cable_layer(z, np.array([centre - 0.6 * across, centre + 0.6 * across]), CABLE_WIDTH_M,
                                  DARK_BGR),))


def _estimate(shape: str, lab: Lab):
    calib = zed_like_calibration()
    points, joints = standard_shapes()[shape]
    scene = render_lab_scenes(calib, points, joints, conditions={"cable": lab}, seed=7)["cable"]
    result = CenterlineEstimator(calib).estimate(scene.left, scene.right)
    return result, (score_against_backbone(result.points, scene.gt_points) if result.valid else None)


# What an estimate may say of these frames: valid within 10 mm, or refused for what the cable does to the
# silhouette. A refusal for another reason ("no arm found") would pass a check of validity alone.
# Refusals that name what the cable does: the tube leaves a silhouette line, the tip counts as hidden,
# or the cable is taken in past the tip and the arm comes out longer than it can be (straight, the
# cable along the whole arm in one image: 812 mm for the 685 mm arm since the 1.15 length bound), or the
# fitted tip misses the outline the cable lent its edge to (s_curve since the fifteenth session's cap model,
# whose silhouette lines end at the cap: valid 8.4 mm off before), or the tip's edges beside the cable are
# left out and too few remain to place its end along the arm (s_curve since the twenty-first session,
# which leaves out the whole stretch the cable lends its edge to).
HONEST_REASONS = ("follows neither side", "the tip is hidden", "implausible estimate",
                  "the fitted tip misses its outline", "standard deviation along the arm")


def _honest(result, score) -> bool:
    if result.valid:
        return score["max_mm"] <= 10.0
    return any(reason in result.reason for reason in HONEST_REASONS)


def test_a_cable_close_beside_the_tip_does_not_leave_a_confident_wrong_tip():
    """Towards the camera, the cable 10 mm beside the axis: the tip came back valid and measured while
    79 mm off (its outline half the cable's edge). Either check refuses it now: the stretch of
    silhouette the tube does not follow (both lines of the left image), or the outline it cannot
    explain; the test fails only with both off."""
    points, _ = standard_shapes()["towards_camera"]
    result, score = _estimate("towards_camera", _along_the_tip(points, 1.0, 0.010))
    assert _honest(result, score), (result.reason, score and score["max_mm"])


# Measured 2026-12-02 once the coarse masks read the nearest pixels (OpenCV 5.0's misread coarse masks had
# both as the tests say): marked xfail(strict) until fixed. The straight tube's case (valid 101.7 mm off in
# depth, its tip outline 1.48 sigmas from the fitted end) holds since chroma counts as much as luma in the
# edge profile (2026-12-02, fourth session).
_TURNED_CABLE = pytest.param("c_bend", 1.0, 0.15, marks=pytest.mark.xfail(strict=True, reason=(
    "refused, but as 'left and right centerlines do not match row by row', not for what the cable does")))


@pytest.mark.parametrize("shape, side, angle", [("c_bend", 1.0, 0.0), _TURNED_CABLE, ("three_d", 1.0, 0.0),
                                               ("towards_camera", 1.0, 0.0)])
def test_no_frame_is_valid_while_the_cable_along_its_tip_puts_it_far_off(shape, side, angle):
    """The cable 14 mm beside the axis: c_bend, three_d and towards_camera came back valid 16, 32 and
    32 mm off (the fit split the difference between one image's narrowed silhouette and the other's).
    Now the stretches of silhouette line the tube does not follow are found: where only one line of
    an image is off the tube is fitted again without it, where both are the frame is refused (three_d,
    towards_camera, the turned cable), and c_bend's tip, its outline half the cable's edge, is hidden."""
    points, _ = standard_shapes()[shape]
    result, score = _estimate(shape, _along_the_tip(points, side, 0.014, angle))
    assert _honest(result, score), score and round(score["max_mm"], 1)


@pytest.mark.parametrize("shape, side", [("straight", -1.0), ("s_curve", 1.0)])
def test_a_tip_outline_the_fitted_end_cannot_explain_is_left_out(shape, side):
    """straight: the cable lies along the whole arm in one image and across it in the other (valid
    104 mm off); s_curve: valid 12.2 mm off after the refit without the stretch the tube did not
    follow (75 mm before it). In both the outline round the tip is half the cable's edge: the tube is
    fitted again without it, and the tip, now seen in neither image, counts as hidden."""
    points, _ = standard_shapes()[shape]
    result, score = _estimate(shape, _along_the_tip(points, side, 0.014))
    assert _honest(result, score), score and round(score["max_mm"], 1)


@pytest.mark.parametrize("beyond_m", [-0.004, 0.0, 0.008])
def test_a_cable_across_the_tip_in_one_view_leaves_the_tip_unmeasured(beyond_m):
    """c_bend's tip runs along the rows: a cable across it a quarter metre nearer cuts the two views'
    silhouettes at places that are not one end of one tube (their ends 7-25 px from where one end
    at the tube's disparity would put them). Fitted to them, the tip came back valid 14-42 mm off;
    now the tube is fitted to the edges alone and its tip counts as hidden."""
    points, _ = standard_shapes()["c_bend"]
    result, score = _estimate("c_bend", _across_the_tip(points, beyond_m))
    assert _honest(result, score), score and round(score["max_mm"], 1)
    assert not result.valid or not result.measured[-1]


def test_explained_compares_the_rms_residual_with_the_sigma():
    sigma = 0.7
    assert _explained(np.full(15, 0.9 * EXPLAINED_SIGMAS * sigma), sigma)
    assert not _explained(np.full(15, 1.1 * EXPLAINED_SIGMAS * sigma), sigma)
    assert not _explained(np.zeros(0), sigma) and not _explained(None, sigma)


def test_one_ray_far_off_the_tip_is_left_out_alone():
    """One ray of eight that met a notch in the mask (the twin's bright_warm ramp at t = 53 s: 4.8 px off,
    the rest 0.3 px RMS) is left out; the image's tip outline is kept."""
    sigma = 0.7
    residuals = np.array([0.42, 0.08, 0.14, 4.79, 0.11, 0.04, 0.33, 0.9])
    assert not _explained(residuals, sigma)
    keep = _outline_inliers(residuals, len(residuals), sigma)
    assert keep is not None and keep.tolist() == [True, True, True, False, True, True, True, True]
    assert _outline_inliers(np.full(8, 0.1), 8, sigma).all()


def test_an_outline_several_rays_miss_is_left_out_whole():
    """Two far rays (an occluder along the cap), or every ray a little off: the tip outline is not the tube's."""
    sigma = 0.7
    two = np.array([0.1, -5.2, 0.14, 4.79, 0.11, 0.04, 0.33, 0.2])
    assert _outline_inliers(two, len(two), sigma) is None
    assert _outline_inliers(np.full(8, 1.2 * EXPLAINED_SIGMAS * sigma), 8, sigma) is None
    one_of_four = np.array([0.1, 0.1, 0.1, 5.0])  # a quarter of the rays, more than one in eight
    assert _outline_inliers(one_of_four, 4, sigma) is None
    assert _outline_inliers(np.full(8, 0.1), 9, sigma) is None  # not this outline's residuals
    assert _outline_inliers(None, 8, sigma) is None


def test_without_the_tip_nothing_beyond_the_last_edges_is_measured():
    """Edges every 0.01 of the axis up to 0.8 in both images, and some attached at its very end (edges
    past the tube's end attach there): with the tip seen, a gap of 0.2 over ``gap_u`` = 0.3 is measured;
    with it unseen in one image, nothing past 0.8 is, and the tip itself is not."""
    u = np.concatenate([np.arange(0.0, 0.805, 0.01), [1.0, 1.0]])
    edge_u, edge_side = np.concatenate([u, u]), np.repeat([0, 1], len(u))
    at = np.linspace(0.0, 1.0, 11)
    seen = _measured(at, edge_u, edge_side, 0.3)
    assert seen.all()
    unseen = _measured(at, edge_u, edge_side, 0.3, (True, False))
    assert unseen[at <= 0.8].all() and not unseen[at > 0.8].any()
