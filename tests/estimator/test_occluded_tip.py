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


def test_an_outline_the_fitted_end_cannot_explain_does_not_measure_the_tip():
    """Towards the camera, the cable 10 mm beside the axis: the tip came back valid and measured while
    79 mm off (its outline half the cable's edge), before the outline's residuals were checked."""
    points, _ = standard_shapes()["towards_camera"]
    result, score = _estimate("towards_camera", _along_the_tip(points, 1.0, 0.010))
    assert not result.valid or score["max_mm"] <= 10.0, (result.reason, score and score["max_mm"])


@pytest.mark.parametrize("shape, side, angle", [("c_bend", 1.0, 0.0), ("c_bend", 1.0, 0.15), ("three_d", 1.0, 0.0),
                                               ("towards_camera", 1.0, 0.0)])
def test_no_frame_is_valid_while_the_cable_along_its_tip_puts_it_far_off(shape, side, angle):
    """The cable 14 mm beside the axis: c_bend, three_d and towards_camera came back valid 16, 32 and
    32 mm off (the fit split the difference between one image's narrowed silhouette and the other's)
    until stretches of a silhouette line the tube does not follow were left out and the tube fitted
    again (c_bend: 7.6 mm then; the other two refused)."""
    points, _ = standard_shapes()[shape]
    result, score = _estimate(shape, _along_the_tip(points, side, 0.014, angle))
    assert not result.valid or score["max_mm"] <= 10.0, score and round(score["max_mm"], 1)


KNOWN_MISSES = {
    "straight": "a cable along the whole straight arm lies beside it in one image and across it in the other; "
                "the tube fits both images consistently, 100 mm off (measured: 104 mm, valid)",
    "s_curve": "after the refit without the stretch the tube did not follow, the tip is still 12.2 mm off "
               "(valid; 75 mm before the refit)",
}


@pytest.mark.parametrize("shape, side", [
    pytest.param("straight", -1.0, marks=pytest.mark.xfail(strict=True, reason=KNOWN_MISSES["straight"])),
    pytest.param("s_curve", 1.0, marks=pytest.mark.xfail(strict=True, reason=KNOWN_MISSES["s_curve"]))])
def test_known_cases_of_a_cable_along_the_arm_still_give_a_confident_wrong_answer(shape, side):
    points, _ = standard_shapes()[shape]
    result, score = _estimate(shape, _along_the_tip(points, side, 0.014))
    assert not result.valid or score["max_mm"] <= 10.0, score and round(score["max_mm"], 1)


@pytest.mark.parametrize("beyond_m", [-0.004, 0.0, 0.008])
def test_a_cable_across_the_tip_in_one_view_leaves_the_tip_unmeasured(beyond_m):
    """c_bend's tip runs along the rows: a cable across it a quarter metre nearer cuts the two views'
    silhouettes at places that are not one end of one tube (their ends 7-25 px from where one end
    at the tube's disparity would put them). Fitted to them, the tip came back valid 14-42 mm off;
    now the tube is fitted to the edges alone and its tip counts as hidden."""
    points, _ = standard_shapes()["c_bend"]
    result, score = _estimate("c_bend", _across_the_tip(points, beyond_m))
    assert not result.valid or score["max_mm"] <= 10.0, score and round(score["max_mm"], 1)
    assert not result.valid or not result.measured[-1]
