"""A tip pointing away from the camera, nearly along a line of sight (tests/scenes.py, the raw ZED-like
pair, one cold frame per shape; and the tube fit alone on exact edges).

Sliding such a tip along the arm barely moves its end in either image, so where it ends is poorly
known, although every point stays on the curve (a point's ``point_std_m`` leaves sliding out). The
twin's random pressure sequences showed it: tips 10-74 mm off along the arm, valid. The fit's
standard deviation along the arm at the tip now refuses most of them; this independent scene shows
where the bound falls short.
"""

import numpy as np
import pytest

from estimator import CenterlineEstimator, EstimatorConfig
from estimator.metrics import score_against_backbone
from estimator.pipeline import MAX_TIP_ALONG_STD_M
from tests.estimator.test_tube_fit import fit, tube_edges
from tests.scenes import Section, backbone, render_scene, zed_like_calibration

L = (0.235, 0.23, 0.22)


def _curling_away(phi_last: float, tilt_rad: float = 0.0):
    """The arm curls away from the camera (bending planes at -90 degrees): the tip's last stretch
    points within a few degrees of the line of sight (``phi_last`` -1.57), or 20 degrees off it
    (the tilted variant)."""
    if tilt_rad:
        return backbone([Section(L[0], 1.5, -1.57), Section(L[1], 2.0, -1.4), Section(L[2], 2.0, phi_last)],
                        (0.0, -0.30, 0.9), tilt_rad=tilt_rad)
    return backbone([Section(L[0], 0.5, 0.0), Section(L[1], 2.5, -1.57), Section(L[2], 4.5, phi_last)],
                    (0.0, -0.34, 0.95))


def _tip_cosine(points: np.ndarray) -> float:
    """Cosine between the tip's direction and the line of sight to it (1: straight away)."""
    t = points[-1] - points[-5]
    return float(t @ points[-1] / (np.linalg.norm(t) * np.linalg.norm(points[-1])))


@pytest.mark.xfail(strict=True, reason=(
    "estimator/pipeline.py MAX_TIP_ALONG_STD_M: valid, the tip 26 mm off along the arm, with 7.6 mm standard "
    "deviation along it, under the 10 mm bound. The fit counts the tip outline's points as independent; "
    "counted as four observations this frame had 14 mm, but on the twin the good frames' grew as much "
    "(at 7.8 mm, 96 of 488 good frames refused instead of 12 of 511)"))
def test_a_tip_pointing_along_the_line_of_sight_is_refused_not_returned_far_off():
    """A scene the bound was not chosen on: the tip points within 8 degrees of the line of sight."""
    points, joints = _curling_away(-1.57)
    assert _tip_cosine(points) > 0.98
    scene = render_scene(zed_like_calibration(), points, joints, seed=3)
    result = CenterlineEstimator(scene.calibration, EstimatorConfig()).estimate(scene.left, scene.right)
    if result.valid:
        score = score_against_backbone(result.points, scene.gt_points)
        assert score["tip_mm"] <= 10.0 and score["max_mm"] <= 10.0, score
    else:
        assert "where the tip ends is uncertain" in result.reason, result.reason


def test_a_tip_turned_away_but_seen_across_stays_valid():
    """The check is not against tips pointing away: 20 degrees off the line of sight, the end's image
    moves enough (valid, tip 0.6 mm off; 3.6 mm standard deviation along the arm)."""
    points, joints = _curling_away(-1.8, tilt_rad=0.3)
    assert 0.85 < _tip_cosine(points) < 0.97
    scene = render_scene(zed_like_calibration(), points, joints, seed=3)
    result = CenterlineEstimator(scene.calibration, EstimatorConfig()).estimate(scene.left, scene.right)
    assert result.valid, result.reason
    assert score_against_backbone(result.points, scene.gt_points)["tip_mm"] <= 3.0


@pytest.mark.parametrize("phi, pointing", [(-1.5708, "away"), (0.0, "across")])
def test_along_std_at_the_tip_grows_as_it_points_along_the_line_of_sight(phi, pointing):
    """Exact edges (0.1 px noise) and ends seen as points: a 90 degree bend that ends pointing away
    from the camera has the tip's place along the arm known to 25 mm (one standard deviation), the
    same bend in the image plane to 4 mm, although both are fitted to within 5 mm."""
    axis, _ = backbone([Section(0.3, 0.0, 0.0), Section(0.3, 5.2, phi)], (0.0, -0.35, 1.0), n=600)
    t = np.linspace(0.0, 1.0, len(axis))
    initial = axis + np.column_stack([0.004 * np.sin(3 * t), 0.003 * np.cos(2 * t), 0.01 * np.sin(4 * t)])
    with np.errstate(invalid="ignore"):  # where the line of sight runs inside the tube, no silhouette
        edges = tube_edges(axis, 0.022, noise_px=0.1)
    edges = edges.subset(np.all(np.isfinite(edges.xy), axis=1))
    result = fit(edges, axis, initial, radius=0.022)
    assert np.linalg.norm(result.points(np.array([1.0]))[0] - axis[-1]) <= 0.005
    along = float(result.along_std_m(np.array([1.0]))[0])
    if pointing == "away":
        assert along > 2.0 * MAX_TIP_ALONG_STD_M, along
    else:
        assert along < 0.75 * MAX_TIP_ALONG_STD_M, along
