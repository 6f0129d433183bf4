"""The issue's accuracy targets on rendered scenes (raw ZED-like pair and an ideal rectified pair).

Default mode, cold single frames: pooled point-to-curve RMSE <= 2.5 mm, max <= 10 mm, mean tip
error <= 10 mm. Warm 30-frame bending sequence: RMSE <= 2 mm, mean tip <= 6 mm. Paper mode, the
reproduction baseline: RMSE <= 25 mm over the same frames.
"""

import numpy as np
import pytest

from estimator import CenterlineEstimator, EstimatorConfig
from estimator.metrics import score_against_backbone
from tests.scenes import render_scene, u_shapes, zed_like_calibration


def cold_scores(scenes, mode):
    scores = {}
    for name, scene in scenes.items():
        result = CenterlineEstimator(scene.calibration, EstimatorConfig(mode=mode)).estimate(scene.left, scene.right)
        assert result.valid, f"{name}: {result.reason}"
        scores[name] = score_against_backbone(result.points, scene.gt_points)
    return scores


def sequence_scores(frames, mode):
    est = CenterlineEstimator(frames[0].calibration, EstimatorConfig(mode=mode))
    scores = []
    for i, frame in enumerate(frames):
        result = est.estimate(frame.left, frame.right)
        assert result.valid, f"frame {i}: {result.reason}"
        scores.append(score_against_backbone(result.points, frame.gt_points))
    return scores


def pooled(scores, key="rmse_mm"):
    return float(np.sqrt(np.mean([s[key] ** 2 for s in scores])))


def test_default_mode_cold_frames(cold_scenes):
    scores = cold_scores(cold_scenes, "default")
    table = {name: round(s["rmse_mm"], 2) for name, s in scores.items()}
    assert pooled(scores.values()) <= 2.5, table
    assert max(s["max_mm"] for s in scores.values()) <= 10.0, table
    assert np.mean([s["tip_mm"] for s in scores.values()]) <= 10.0


def test_default_mode_warm_sequence(bending_sequence):
    scores = sequence_scores(bending_sequence, "default")
    assert pooled(scores) <= 2.0
    assert np.mean([s["tip_mm"] for s in scores]) <= 6.0


def test_paper_mode_stays_in_its_band(cold_scenes, bending_sequence):
    """The reproduction baseline: <= 25 mm on each scene set the default mode's targets use.

    Measured: cold single frames 22.0 mm pooled (raw pair 23.2, rectified pair 20.8), the warm
    sequence 24.5 mm (OpenCV 5, numpy 2.4). The online SOM's last epochs (alpha near 0.1) leave
    each node a few pixels off, differently in each image, and a pixel of disparity is about
    12 mm of depth at 1 m. The band is not tuned, and it has a floor: a paper mode within a few
    times the default mode's error would no longer reproduce the paper as written.
    """
    cold = list(cold_scores(cold_scenes, "paper").values())
    warm = sequence_scores(bending_sequence, "paper")
    assert pooled(cold) <= 25.0
    assert pooled(warm) <= 25.0
    assert pooled(cold) >= 8.0 and pooled(warm) >= 8.0


@pytest.mark.parametrize("name", sorted(u_shapes()))
def test_default_mode_holds_where_the_arm_crosses_rows_twice(name):
    """U shapes defeat the paper's literal compensation (it jumps branches); the default holds.

    Where a whole section runs along the image rows, stereo by rows sees no depth there; the
    default mode carries the depth across from its neighbours, so it degrades, but gracefully.
    """
    calib = zed_like_calibration()
    points, joints = u_shapes()[name]
    scene = render_scene(calib, points, joints)
    default = cold_scores({name: scene}, "default")[name]
    assert default["rmse_mm"] < 5.0 and default["tip_mm"] < 15.0
    # the paper mode either flags the frame (its estimate is implausibly long) or is far off
    paper = CenterlineEstimator(calib, EstimatorConfig(mode="paper")).estimate(scene.left, scene.right)
    if paper.valid:
        assert score_against_backbone(paper.points, scene.gt_points)["rmse_mm"] > 5 * default["rmse_mm"]
    else:
        assert "implausible" in paper.reason
