"""The issue's accuracy targets on rendered scenes (raw ZED-like pair and an ideal rectified pair).

Default mode, cold single frames: pooled point-to-curve RMSE <= 1.0 mm (issue 11's target for the
project's static scenes; measured 0.73), max <= 5 mm (2.2), mean tip error <= 2 mm (0.67). Warm
30-frame bending sequence: RMSE <= 1.0 mm (0.60), mean tip <= 1.5 mm (0.56). Paper mode, the
reproduction baseline (issue 12): RMSE <= 8 mm cold, <= 3.5 mm on the sequence, and compensation
at most 0.7x the error without it.
"""

import numpy as np
import pytest

from estimator import CenterlineEstimator, EstimatorConfig
from estimator.metrics import score_against_backbone
from tests.scenes import render_scene, u_shapes, zed_like_calibration


def cold_scores(scenes, mode, **overrides):
    scores = {}
    for name, scene in scenes.items():
        config = EstimatorConfig(mode=mode, **overrides)
        result = CenterlineEstimator(scene.calibration, config).estimate(scene.left, scene.right)
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
    assert pooled(scores.values()) <= 1.0, table
    assert max(s["max_mm"] for s in scores.values()) <= 5.0, table
    assert np.mean([s["tip_mm"] for s in scores.values()]) <= 2.0


def test_default_mode_warm_sequence(bending_sequence):
    scores = sequence_scores(bending_sequence, "default")
    assert pooled(scores) <= 1.0
    assert np.mean([s["tip_mm"] for s in scores]) <= 1.5


def test_paper_mode_stays_in_its_band(cold_scenes, bending_sequence):
    """The reproduction baseline on each scene set the default mode's targets use.

    Measured with the paper preset (t in eq. 3 counting presented samples, contour order,
    compensation by the nearest crossing along the spline's parameter): cold single frames
    6.9 mm pooled, the warm sequence 2.8 mm (OpenCV 5, numpy 2.4); the issue's targets are 10 and
    5 mm. Under the epoch clock they were 22.0 and 24.5 mm: each node jittered by ~2 px, and a
    pixel of disparity is about 12 mm of depth at 1 m. The band has a floor: a paper mode as
    good as the default mode would no longer reproduce the paper as written.
    """
    cold = list(cold_scores(cold_scenes, "paper").values())
    warm = sequence_scores(bending_sequence, "paper")
    assert pooled(cold) <= 8.0
    assert pooled(warm) <= 3.5
    assert pooled(cold) >= 3.0 and pooled(warm) >= 1.4


def test_paper_compensation_cuts_the_error(cold_scenes):
    """Fig 12's claim: misalignment compensation lowers the error clearly (measured 6.9 mm against
    12.9 mm without on the cold frames: 0.54x; the issue's target is 0.7x)."""
    with_compensation = pooled(cold_scores(cold_scenes, "paper").values())
    without = pooled(cold_scores(cold_scenes, "paper", compensation="none").values())
    assert with_compensation <= 0.7 * without


def test_paper_mode_does_not_depend_on_a_seed(cold_scenes):
    """The paper preset presents the contour in its own order: no seed enters the result."""
    scene = cold_scenes["raw/three_d"]
    points = [CenterlineEstimator(scene.calibration, EstimatorConfig(mode="paper", som_seed=seed))
              .estimate(scene.left, scene.right).points for seed in (0, 5)]
    np.testing.assert_array_equal(points[0], points[1])


@pytest.mark.parametrize("name", sorted(u_shapes()))
def test_default_mode_holds_where_the_arm_crosses_rows_twice(name):
    """U shapes defeat the paper's node-by-node stereo (measured: hook 49 mm, curl 64 mm); the default holds.

    Where a whole section runs along the image rows, stereo by rows sees no depth there; the
    default mode carries the depth across from its neighbours, so it degrades, but gracefully.
    """
    calib = zed_like_calibration()
    points, joints = u_shapes()[name]
    scene = render_scene(calib, points, joints)
    default = cold_scores({name: scene}, "default")[name]
    assert default["rmse_mm"] < 5.0 and default["tip_mm"] < 15.0
    # the paper mode reports the frame (as the paper does) and is far off, or (checks on) drops it
    paper = CenterlineEstimator(calib, EstimatorConfig(mode="paper")).estimate(scene.left, scene.right)
    if paper.valid:
        assert score_against_backbone(paper.points, scene.gt_points)["rmse_mm"] > 5 * default["rmse_mm"]
    else:
        assert "implausible" in paper.reason
