"""Eq. (7)-(8) triangulation: round trips on projected curves, cross-checked against OpenCV's DLT."""

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.triangulation import triangulate
from tests.scenes import zed_like_calibration


def rectified_projections(points_cam):
    rect = zed_like_calibration().rectification
    points_rect = rect.from_left_camera(points_cam)
    out = []
    for side in ("left", "right"):
        h = points_rect @ rect.P[side][:, :3].T + rect.P[side][:, 3]
        out.append(h[:, :2] / h[:, 2:])
    return rect, points_rect, out


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 100_000), depth=st.floats(0.6, 2.0))
def test_round_trip_on_a_projected_curve(seed, depth):
    rng = np.random.default_rng(seed)
    s = np.linspace(0, 1, 50)
    coeffs = rng.normal(0, 0.2, (3, 3))
    curve = np.column_stack([coeffs[0, 0] * s + coeffs[0, 1] * s**2, -0.3 + 0.6 * s + coeffs[1, 1] * s**2,
                             depth + coeffs[2, 0] * s**2])
    rect, points_rect, (uv_left, uv_right) = rectified_projections(curve)
    np.testing.assert_allclose(triangulate(rect.P["left"], rect.P["right"], uv_left, uv_right), points_rect,
                               atol=1e-9)


def test_agrees_with_opencv_dlt_on_noisy_pixels():
    rng = np.random.default_rng(0)
    points = rng.uniform([-0.3, -0.3, 0.8], [0.3, 0.3, 1.2], (100, 3))
    rect, _, (uv_left, uv_right) = rectified_projections(points)
    uv_left = uv_left + rng.normal(0, 0.3, uv_left.shape)
    uv_right = uv_right + rng.normal(0, 0.3, uv_right.shape)
    ours = triangulate(rect.P["left"], rect.P["right"], uv_left, uv_right)
    h = cv2.triangulatePoints(rect.P["left"], rect.P["right"], uv_left.T, uv_right.T)
    dlt = (h[:3] / h[3]).T
    # the two solvers minimise different algebraic errors: equal to well under a millimetre
    assert np.max(np.linalg.norm(ours - dlt, axis=1)) < 2e-4


def test_shape_errors_are_named():
    import pytest

    P = np.hstack([np.eye(3), np.zeros((3, 1))])
    with pytest.raises(ValueError, match="expected equal shapes"):
        triangulate(P, P, np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"projection matrix: expected shape \(3, 4\)"):
        triangulate(np.eye(3), P, np.zeros((3, 2)), np.zeros((3, 2)))
