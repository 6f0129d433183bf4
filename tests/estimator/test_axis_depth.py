"""Table 2's axis-depth variant of Q': the estimate's own pixels back-projected at the axis's depth."""

import numpy as np

from estimator.metrics import axis_depth_points, axis_rmse, depth_camera_points


def test_axis_depth_points_return_the_axis_where_the_pixels_see_it(zed_calibration):
    calib = zed_calibration
    t = np.linspace(0, 1, 60)
    backbone = np.column_stack([0.05 * np.sin(2 * t), -0.3 + 0.6 * t, 1.0 + 0.2 * t])  # tilted away from the camera
    uv = calib.project(backbone[::6], "left")
    q_axis = axis_depth_points(uv, backbone, calib)
    np.testing.assert_allclose(q_axis, backbone[::6], atol=1e-4)  # pixels on the axis: the axis itself
    # the surface seen 25 mm nearer: the paper's Q' carries that offset in z, the axis variant does not
    h, w = calib.image_size[1], calib.image_size[0]
    surface = np.full((h, w), np.inf, np.float32)
    cols, rows = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    surface[rows, cols] = backbone[::6, 2] - 0.025
    q_surface = depth_camera_points(uv, surface, calib)
    assert axis_rmse(backbone[::6], q_surface)["z_mm"] > 20.0
    assert axis_rmse(backbone[::6], q_axis)["z_mm"] < 0.5
