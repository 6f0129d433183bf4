"""StereoCalibration: validation, files, projection matrices and rectification."""

import numpy as np
import pytest

from estimator import CalibrationFileError, StereoCalibration
from tests.scenes import rectified_calibration, zed_like_calibration


def random_points(n=200, seed=0):
    return np.random.default_rng(seed).uniform([-0.4, -0.4, 0.7], [0.4, 0.4, 1.4], (n, 3))


def test_rectified_rows_agree_for_any_3d_point():
    calib = zed_like_calibration()
    rect = calib.rectification
    points = random_points()
    left = rect.rectify_points(calib.project(points, "left"), "left")
    right = rect.rectify_points(calib.project(points, "right"), "right")
    assert np.max(np.abs(left[:, 1] - right[:, 1])) < 1e-6
    # and disparity gives the depth in the rectified frame
    depth = rect.focal_px * rect.baseline_m / (left[:, 0] - right[:, 0])
    np.testing.assert_allclose(depth, rect.from_left_camera(points)[:, 2], rtol=1e-9)


def test_rectification_keeps_focal_and_crops_nothing():
    calib = zed_like_calibration()
    rect = calib.rectification
    assert rect.focal_px == pytest.approx(calib.K_left[0, 0], rel=0.01)
    w, h = calib.image_size
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [w / 2, 0], [0, h / 2]], float)
    for side in ("left", "right"):
        uv = rect.rectify_points(corners, side)
        assert np.all(uv >= 0) and np.all(uv[:, 0] < rect.size[0]) and np.all(uv[:, 1] < rect.size[1])


def test_unrectify_inverts_rectify():
    calib = zed_like_calibration()
    uv = np.random.default_rng(1).uniform([50, 50], [1230, 670], (100, 2))
    for side in ("left", "right"):
        back = calib.rectification.unrectify_points(calib.rectification.rectify_points(uv, side), side)
        np.testing.assert_allclose(back, uv, atol=1e-6)


def test_rectified_image_matches_rectified_points():
    """A dot drawn in the raw image lands where rectify_points says."""
    import cv2

    calib = zed_like_calibration()
    raw = np.zeros((720, 1280, 3), np.uint8)
    cv2.circle(raw, (1000, 150), 6, (255, 255, 255), -1)
    image = calib.rectification.rectify_image(raw, "left")
    ys, xs = np.nonzero(image[:, :, 0] > 127)
    expected = calib.rectification.rectify_points(np.array([[1000.0, 150.0]]), "left")[0]
    assert np.hypot(xs.mean() - expected[0], ys.mean() - expected[1]) < 0.3


def test_save_load_round_trip(tmp_path):
    calib = zed_like_calibration()
    path = tmp_path / "calib.toml"
    calib.save(path)
    assert "x_right = R x_left + T" in path.read_text()  # a person can read what it means
    loaded = StereoCalibration.load(path)
    for name in ("K_left", "dist_left", "K_right", "dist_right", "R", "T"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(calib, name))
    assert loaded.image_size == calib.image_size


def test_from_projection_matrices_gives_the_rectified_pair():
    calib = rectified_calibration()
    np.testing.assert_allclose(calib.R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(calib.T, [-0.12, 0, 0], atol=1e-12)
    np.testing.assert_array_equal(calib.dist_left, np.zeros(5))
    points = random_points()
    K = calib.K_left
    P1 = np.hstack([K, np.zeros((3, 1))])
    h = points @ P1[:, :3].T
    np.testing.assert_allclose(calib.project(points, "left"), h[:, :2] / h[:, 2:], atol=1e-9)


def test_from_projection_matrices_with_a_general_pose():
    calib = zed_like_calibration()
    rvec, tvec = np.array([0.1, -0.2, 0.05]), np.array([0.3, -0.1, 0.2])
    import cv2

    R0 = cv2.Rodrigues(rvec)[0]
    P1 = calib.K_left @ np.hstack([R0, tvec[:, None]])
    P2 = calib.K_right @ np.hstack([calib.R @ R0, (calib.R @ tvec + calib.T)[:, None]])
    rebuilt = StereoCalibration.from_projection_matrices(P1, P2, calib.image_size)
    np.testing.assert_allclose(rebuilt.R, calib.R, atol=1e-9)
    np.testing.assert_allclose(rebuilt.T, calib.T, atol=1e-9)
    np.testing.assert_allclose(rebuilt.K_right, calib.K_right, atol=1e-6)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"K_left": np.eye(2)}, "K_left: expected shape (3, 3)"),
        ({"dist_right": np.zeros(6)}, "dist_right"),
        ({"R": np.diag([1.0, 1.0, -1.0])}, "R: expected a proper rotation"),
        ({"T": [0.0, 0.0, 0.0]}, "T: the baseline is zero"),
        ({"image_size": (1280,)}, "image_size"),
        ({"K_right": np.full((3, 3), np.nan)}, "K_right: contains NaN"),
    ],
)
def test_bad_values_are_named(change, message):
    calib = zed_like_calibration()
    values = {name: getattr(calib, name) for name in
              ("K_left", "dist_left", "K_right", "dist_right", "R", "T", "image_size")}
    values.update(change)
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        StereoCalibration(**values)


def test_short_distortion_is_padded():
    calib = zed_like_calibration()
    short = StereoCalibration(calib.K_left, [-0.1, 0.01], calib.K_right, [], calib.R, calib.T, (1280, 720))
    np.testing.assert_array_equal(short.dist_left, [-0.1, 0.01, 0, 0, 0])
    np.testing.assert_array_equal(short.dist_right, np.zeros(5))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace("T_m", "T_mm"), r"missing key \[extrinsics\] T_m"),
        (lambda t: t.replace("[right]", "[rite]"), r"missing key \[right\] K"),
        (lambda t: t.replace("image_size = [1280, 720]", 'image_size = "hd"'), "key image_size"),
        (lambda t: t.replace("dist = [", "dist = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, ", 1), r"key \[left\] dist"),
        (lambda t: t.replace("[extrinsics]", "[extrinsics"), "not a TOML calibration file"),
    ],
)
def test_malformed_file_names_file_and_key(tmp_path, edit, message):
    path = tmp_path / "calib.toml"
    zed_like_calibration().save(path)
    path.write_text(edit(path.read_text()))
    with pytest.raises(CalibrationFileError, match=message) as info:
        StereoCalibration.load(path)
    assert str(path) in str(info.value)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(CalibrationFileError, match="nothere.toml: calibration file not found"):
        StereoCalibration.load(tmp_path / "nothere.toml")
