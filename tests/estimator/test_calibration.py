"""StereoCalibration: validation, files, projection matrices and rectification."""

import cv2
import numpy as np
import pytest

from estimator import CalibrationFileError, CenterlineEstimator, EstimatorConfig, StereoCalibration
from estimator.calibration import CalibrationValueError
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


@pytest.mark.parametrize("step", [1, 4])
def test_nearest_lookups_take_the_nearest_raw_pixel_on_every_opencv(step):
    """OpenCV 5.0 took the other neighbour under INTER_NEAREST with a fixed-point map pair (3.1 -> 4,
    3.9 -> 3), so the coarse masks, and every estimate after them, depended on the installed release.
    The rounded map gives the raw pixel nearest the exact float map's position on any release."""
    rect = zed_like_calibration().rectification
    w, h = rect.calibration.image_size
    # Each raw pixel holds its own coordinates, so the lookup says which pixel it read.
    xs, ys = np.meshgrid(np.arange(w, dtype=np.uint16), np.arange(h, dtype=np.uint16))
    raw = np.dstack([xs, ys, np.zeros_like(xs)])
    looked_up = rect.rectify_image(raw, "left", interpolation=cv2.INTER_NEAREST)[::step, ::step]
    coarse = cv2.remap(raw, rect.nearest_map("left", step), None, cv2.INTER_NEAREST)
    fx, fy = cv2.initUndistortRectifyMap(rect.calibration.K("left"), rect.calibration.dist("left").reshape(1, -1),
                                         rect.R_rect["left"], rect.P["left"][:, :3], rect.size, cv2.CV_32FC1)
    fx, fy = fx[::step, ::step], fy[::step, ::step]
    inside = (fx > 1) & (fx < w - 2) & (fy > 1) & (fy < h - 2)
    # The fixed-point maps hold the position to 1/32 pixel: a position within that of a half pixel may go either way.
    clear = inside & (np.abs(fx - np.floor(fx) - 0.5) > 1 / 32) & (np.abs(fy - np.floor(fy) - 0.5) > 1 / 32)
    for image in (looked_up, coarse):
        assert np.array_equal(image[..., 0][clear], np.round(fx[clear])), "x"
        assert np.array_equal(image[..., 1][clear], np.round(fy[clear])), "y"
        assert np.all(np.abs(image[..., 0][inside].astype(float) - fx[inside]) <= 0.5 + 1 / 32)


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
        (lambda t: t.replace("[right]", "[rite]"), r"unknown key rite; did you mean 'right'\?"),
        (lambda t: t.replace("[left]\n", "[left]\nfoo = 1\n"), r"unknown key \[left\] foo \(known keys: K, dist\)"),
        (lambda t: t.replace("[extrinsics]\n", "[extrinsics]\nT = [-0.12, 0.0, 0.0]\n"),
         r"unknown key \[extrinsics\] T \(known keys: R, T_m\)"),
        (lambda t: t.replace("[left]\n", "image_sise = [1280, 720]\n\n[left]\n", 1), r"unknown key image_sise"),
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


# --- plausibility: what a real stereo rig looks like (issue 14) ----------------------------


def _values(**change):
    calib = zed_like_calibration()
    values = {name: getattr(calib, name) for name in
              ("K_left", "dist_left", "K_right", "dist_right", "R", "T", "image_size")}
    values.update(change)
    return values


def _K(fx=700.9, fy=None, cx=645.5, cy=361.2):
    return np.array([[fx, 0, cx], [0, fx if fy is None else fy, cy], [0, 0, 1.0]])


def _dist(**terms):
    names = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y")
    size = max(5, *(names.index(n) + 1 for n in terms)) if terms else 5
    size = 5 if size <= 5 else 8 if size <= 8 else 12 if size <= 12 else 14
    return [terms.get(n, 0.0) for n in names[:size]]


@pytest.mark.parametrize(("change", "message"), [
    ({"K_left": _K(fx=7e307)}, r"K_left: fx = 7e\+307 px is outside \[64, 7680\] px \(0.05 to 6 times the image width"),
    ({"K_left": _K(fx=0.0)}, r"K_left: fx = 0 px is outside \[64, 7680\] px"),
    ({"K_right": _K(fx=50.0)}, r"K_right: fx = 50 px is outside \[64, 7680\] px"),
    ({"K_right": _K(fy=-700.0)}, r"K_right: fy = -700 px is outside \[36, 4320\] px \(0.05 to 6 times the image "
                                 r"height"),
    ({"K_left": _K(fy=1500.0)}, r"K_left: fy = 1500 px is 2.14 times fx"),
    ({"K_left": _K(cx=-5000.0)}, r"K_left: cx = -5000 px is outside the image: expected -0.5 to 1279.5 px"),
    ({"K_right": _K(cy=720.0)}, r"K_right: cy = 720 px is outside the image: expected -0.5 to 719.5 px"),
    ({"dist_left": _dist(k1=1e6)}, r"dist_left: k1 = 1e\+06 is outside \[-2, 2\]"),
    ({"dist_right": _dist(k2=-40.0)}, r"dist_right: k2 = -40 is outside \[-10, 10\]"),
    ({"dist_left": _dist(k3=80.0)}, r"dist_left: k3 = 80 is outside \[-50, 50\]"),
    ({"dist_left": _dist(p1=0.3)}, r"dist_left: p1 = 0.3 is outside \[-0.1, 0.1\]"),
    ({"dist_right": _dist(p2=-0.2)}, r"dist_right: p2 = -0.2 is outside \[-0.1, 0.1\]"),
    ({"dist_left": _dist(k1=500.0, k4=400.0)}, r"dist_left: k1 = 500 is outside \[-100, 100\] \(the rational model"),
    ({"dist_left": _dist(k6=-150.0)}, r"dist_left: k6 = -150 is outside \[-100, 100\]"),
    ({"dist_right": _dist(s3=0.5)}, r"dist_right: s3 = 0.5 is outside \[-0.1, 0.1\]"),
    ({"dist_right": _dist(tau_x=1.0)}, r"dist_right: tau_x = 1 is outside \[-0.5, 0.5\]"),
    ({"R": cv2.Rodrigues(np.array([0.0, np.radians(40.0), 0.0]))[0]}, r"R: turns the right eye by 40.0 degrees"),
    ({"R": cv2.Rodrigues(np.array([100.0, 0.0, 0.0]))[0]}, r"R: turns the right eye by 30.4 degrees"),
    ({"T": [0.12, 0.0003, -0.0002]}, r"T: \(\+0.12, \+0.0003, -0.0002\) m puts the right camera 0.12 m to the LEFT"),
    ({"T": [0.005, 0.0, 0.0]}, r"T: the baseline \|T\| = 0.005 m is outside \[0.01, 1\] m"),
    ({"T": [-120.0, 0.0, 0.0]}, r"T: the baseline \|T\| = 120 m is outside \[0.01, 1\] m \(T is in metres\)"),
    ({"T": [0.0, -0.12, 0.0]}, r"T: \(\+0, -0.12, \+0\) m puts the right camera 90 degrees away from the left "
                               r"camera's \+x axis"),
    ({"T": [-0.05, 0.0, -0.1]}, r"T: \(-0.05, \+0, -0.1\) m puts the right camera 6\d degrees away"),
    ({"image_size": (True, True)}, r"image_size: expected \(width, height\) as two integers in \[16, 16384\] px, "
                                   r"got \(True, True\)"),
    ({"image_size": (1280.0, 720.0)}, r"image_size: expected .* got \(1280.0, 720.0\)"),
    ({"image_size": ("1280", "720")}, r"image_size: expected"),
    ({"image_size": (8, 8)}, r"image_size: expected .*\[16, 16384\]"),
    ({"image_size": (100_000, 720)}, r"image_size: expected .*\[16, 16384\]"),
])
def test_an_implausible_calibration_is_refused_naming_the_argument_and_the_range(change, message):
    with pytest.raises(CalibrationValueError, match=message) as info:
        StereoCalibration(**_values(**change))
    assert isinstance(info.value, ValueError)  # callers that catch ValueError still do


def test_the_sign_refusal_explains_the_convention():
    with pytest.raises(ValueError) as info:
        StereoCalibration(**_values(T=[0.12, 0.0, 0.0]))
    message = str(info.value)
    assert "x_right = R x_left + T" in message and "T_x < 0" in message and "T = (-0.12, 0, 0)" in message


@pytest.mark.parametrize(("left", "right", "R", "T"), [
    # a wide-angle webcam calibrated with OpenCV, k3 poorly constrained
    (_dist(k1=-0.404856, k2=0.266958, p1=0.001336, p2=0.00019, k3=-0.130004),
     _dist(k1=0.297, k2=-2.49, k3=7.01), np.eye(3), [-0.06, 0.0, 0.0]),
    # the rational model with numerator and denominator terms as large as a ZED 2's
    (_dist(k1=13.8851, k2=-9.63451, p1=5.0e-05, p2=-5.4e-05, k3=1.37335, k4=14.2664, k5=-9.54115, k6=1.24705),
     _dist(k1=1.688, k2=0.71, k3=0.029, k4=2.036, k5=1.218, k6=0.157, s1=0.0012, s2=-7.6e-05, tau_x=-0.0016,
           tau_y=0.0031), np.eye(3), [-0.12, 0.0, 0.0]),
    # a converging rig: each eye turned 10 degrees inwards, a 30 cm baseline
    (_dist(), _dist(), cv2.Rodrigues(np.array([0.0, np.radians(-20.0), 0.0]))[0],
     -cv2.Rodrigues(np.array([0.0, np.radians(-20.0), 0.0]))[0] @ (0.3 * np.array([np.cos(np.radians(10.0)), 0.0,
                                                                                  np.sin(np.radians(10.0))]))),
])
def test_real_lenses_and_rigs_are_accepted(left, right, R, T):
    calib = StereoCalibration(**_values(dist_left=left, dist_right=right, R=R, T=T))
    assert calib.rectification.baseline_m == pytest.approx(calib.baseline_m)  # the right eye sits to the right


def test_the_extremes_of_the_ranges_are_accepted():
    """The limits are inclusive and the principal point may sit anywhere in the image."""
    StereoCalibration(**_values(K_left=_K(fx=64.0, fy=64.0, cx=-0.5, cy=719.5), K_right=_K(fx=6 * 720, fy=6 * 720),
                                dist_left=_dist(k1=-2.0, k2=10.0, p1=0.1, p2=-0.1, k3=-50.0),
                                T=[-1.0, 0.0, 0.0]))
    StereoCalibration(**_values(T=[-0.01, 0.0, 0.0], image_size=(np.int64(1280), np.int32(720))))


@pytest.mark.parametrize(("edit", "key", "expected"), [
    (lambda t: t.replace("T_m = [-0.12,", "T_m = [0.12,"), r"\[extrinsics\] T_m", r"T_x < 0"),
    (lambda t: t.replace("image_size = [1280, 720]", "image_size = [true, true]"), "image_size",
     r"two integers in \[16, 16384\] px, got \(True, True\)"),
    (lambda t: t.replace("[700.9, 0.0, 645.5]", "[7e307, 0.0, 645.5]"), r"\[left\] K", r"fx = 7e\+307 px is outside"),
    (lambda t: t.replace("[700.9, 0.0, 645.5]", "[700.9, 0.0, -5000.0]"), r"\[left\] K", r"cx = -5000 px is outside"),
    (lambda t: t.replace("dist = [-0.175,", "dist = [1e6,"), r"\[right\] dist", r"k1 = 1e\+06 is outside \[-2, 2\]"),
])
def test_an_implausible_file_names_the_file_the_key_and_the_range(tmp_path, edit, key, expected):
    path = tmp_path / "calib.toml"
    zed_like_calibration().save(path)
    text = path.read_text()
    path.write_text(edit(text))
    assert path.read_text() != text, "the edit did not apply"
    with pytest.raises(CalibrationFileError, match=rf"key {key}: .*{expected}") as info:
        StereoCalibration.load(path)
    assert str(path) in str(info.value)


def _past_the_checks(calib: StereoCalibration, **values) -> StereoCalibration:
    """A calibration whose fields were changed after validation: what a future loader that forgot
    the checks, or a caller that patched the arrays, would hand the estimator."""
    for name, value in values.items():
        object.__setattr__(calib, name, value)
    return calib


@pytest.mark.parametrize("mode", ["default", "paper"])
def test_a_reversed_baseline_never_gives_a_valid_estimate(cold_scenes, mode):
    """Issue 14: T with its sign flipped returned valid=True with the arm about 1 m behind the camera.
    Such a calibration is refused now, and an estimate behind the camera is never valid either."""
    scene = cold_scenes["raw/three_d"]
    good = scene.calibration
    with pytest.raises(CalibrationValueError, match="T_x < 0"):
        StereoCalibration(good.K_left, good.dist_left, good.K_right, good.dist_right, good.R, -good.T,
                          good.image_size)
    flipped = _past_the_checks(zed_like_calibration(), T=-good.T)
    result = CenterlineEstimator(flipped, EstimatorConfig(mode=mode)).estimate(scene.left, scene.right)
    assert not result.valid and result.points.shape == (0, 3)
    assert "behind the camera" in result.reason
    # the same scene with the right calibration is in front of the camera, valid
    result = CenterlineEstimator(good, EstimatorConfig(mode=mode)).estimate(scene.left, scene.right)
    assert result.valid and np.all(result.points[:, 2] > 0.5)
