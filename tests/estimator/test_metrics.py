"""Metrics with known answers."""

import numpy as np
import pytest

from estimator import metrics
from tests.scenes import zed_like_calibration


def test_topology_error_counts_non_adjacent_winners():
    nodes = np.array([[0.0, 0], [10, 0], [20, 0]])
    assert metrics.topology_error(np.array([[4.0, 1], [16, 1]]), nodes) == 0.0
    swapped = nodes[[0, 2, 1]]  # a chain folded back on itself
    assert metrics.topology_error(np.array([[4.0, 1], [16, 1]]), swapped) == 0.5


def test_quantization_and_misalignment_errors():
    nodes = np.array([[0.0, 0], [10, 0]])
    assert metrics.quantization_error(np.array([[0.0, 3], [10, 4]]), nodes) == pytest.approx(3.5)
    assert metrics.misalignment_error(np.array([[1.0, 2], [3, 4]]), np.array([[9.0, 3], [9, 1]])) == 2.0


def test_score_against_backbone():
    backbone = np.column_stack([np.zeros(101), np.linspace(0, 0.5, 101), np.ones(101)])
    estimate = backbone[::10] + [0.003, 0.0, 0.004]  # 5 mm off the curve everywhere
    score = metrics.score_against_backbone(estimate, backbone)
    assert score["rmse_mm"] == pytest.approx(5.0)
    assert score["rmse_x_mm"] == pytest.approx(3.0) and score["rmse_z_mm"] == pytest.approx(4.0)
    assert score["max_mm"] == pytest.approx(5.0) and score["tip_mm"] == pytest.approx(5.0)
    assert score["base_mm"] == pytest.approx(5.0) and score["arc_rmse_mm"] == pytest.approx(5.0)
    assert score["length_error_mm"] == pytest.approx(0.0, abs=1e-9)
    short = backbone[:51:5]  # stops half way: small point-to-curve error, large tip error
    score = metrics.score_against_backbone(short, backbone)
    assert score["rmse_mm"] < 1e-9 and score["tip_mm"] == pytest.approx(250.0)
    assert score["base_mm"] == pytest.approx(0.0, abs=1e-9)
    assert score["length_error_mm"] == pytest.approx(-250.0)
    # the point at arc fraction f = k/10 sits at 0.25 f instead of 0.5 f along the backbone:
    # RMSE 250 mm * sqrt(mean(f^2)) = 250 * sqrt(385 / 1100)
    assert score["arc_rmse_mm"] == pytest.approx(250.0 * np.sqrt(385 / 1100))
    tip_first = metrics.score_against_backbone(backbone[::-10], backbone)  # the right curve, reversed
    assert tip_first["rmse_mm"] < 1e-9 and tip_first["base_mm"] == pytest.approx(500.0)


def test_depth_camera_points_back_project_the_depth_map():
    calib = zed_like_calibration()
    points = np.array([[0.05, -0.1, 0.95], [-0.1, 0.2, 1.05]])
    uv = calib.project(points, "left")
    depth = np.zeros((720, 1280))
    for (u, v), z in zip(np.round(uv).astype(int), points[:, 2], strict=True):
        depth[v, u] = z
    # pixels are rounded to the depth map's grid: compare with the ray through the rounded pixel
    q = metrics.depth_camera_points(np.round(uv), depth, calib)
    np.testing.assert_allclose(q[:, 2], points[:, 2])
    np.testing.assert_allclose(q, points, atol=0.002)
    assert np.all(np.isnan(metrics.depth_camera_points(np.array([[5.0, 5.0]]), depth, calib)))
    with pytest.raises(ValueError, match="depth_left_m: expected 720x1280"):
        metrics.depth_camera_points(uv, np.zeros((10, 10)), calib)


def test_axis_rmse_skips_missing_depth():
    a = np.array([[0.0, 0, 1], [0, 0, 1], [0, 0, 1]])
    b = np.array([[0.003, 0, 1.004], [np.nan, np.nan, np.nan], [0.003, 0, 0.996]])
    result = metrics.axis_rmse(a, b)
    assert result == {"x_mm": pytest.approx(3.0), "y_mm": 0.0, "z_mm": pytest.approx(4.0), "count": 2}
