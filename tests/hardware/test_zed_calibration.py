"""The Stereolabs factory-calibration parser on the real files and on the variants the issue lists."""

import re

import cv2
import numpy as np
import pytest

from estimator import CalibrationFileError
from hardware.zed import ZED_RESOLUTIONS, load_factory_calibration

REAL_FILES = ["SN1010.conf", "SN1267.conf", "SN20292994.conf"]


def rectified_row_mismatch_px(calib, seed=0):
    """Project points 0.5-3 m ahead into both raw images; return |v_left - v_right| after rectification."""
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(-0.6, 0.6, 300), rng.uniform(-0.4, 0.4, 300), rng.uniform(0.5, 3.0, 300)])
    w, h = calib.image_size
    uv_left, uv_right = calib.project(points, "left"), calib.project(points, "right")
    seen = np.all((uv_left >= 0) & (uv_left < (w, h)) & (uv_right >= 0) & (uv_right < (w, h)), axis=1)
    assert seen.sum() > 100
    rect = calib.rectification
    left, right = rect.rectify_points(uv_left[seen], "left"), rect.rectify_points(uv_right[seen], "right")
    return np.abs(left[:, 1] - right[:, 1]), left[:, 0] - right[:, 0], points[seen]


@pytest.mark.parametrize("name", REAL_FILES)
@pytest.mark.parametrize("resolution", ["HD", "FHD", "2K", "VGA"])
def test_real_files_rectify_synthetic_points_onto_equal_rows(zed_conf_dir, name, resolution):
    calib = load_factory_calibration(zed_conf_dir / name, resolution)
    assert calib.image_size == ZED_RESOLUTIONS[resolution]
    rows, disparity, points = rectified_row_mismatch_px(calib)
    assert rows.max() < 0.01
    # The right eye sits to the right: positive disparity f B / Z, B the file's baseline.
    rect = calib.rectification
    assert rect.baseline_m == pytest.approx(calib.baseline_m, rel=1e-9)
    np.testing.assert_allclose(disparity, rect.focal_px * rect.baseline_m / rect.from_left_camera(points)[:, 2],
                               rtol=1e-6)


def test_sn1010_hd_values_are_read_as_the_file_states(zed_conf_dir):
    calib = load_factory_calibration(zed_conf_dir / "SN1010.conf", "HD")
    np.testing.assert_allclose(calib.K_left, [[700.895, 0, 665.54], [0, 700.895, 371.155], [0, 0, 1]])
    np.testing.assert_allclose(calib.K_right, [[699.05, 0, 639.74], [0, 699.05, 374.974], [0, 0, 1]])
    np.testing.assert_allclose(calib.dist_left, [-0.175995, 0.0265533, 0, 0, 0])
    np.testing.assert_allclose(calib.dist_right, [-0.175152, 0.0267266, 0, 0, 0])
    np.testing.assert_allclose(cv2.Rodrigues(calib.R)[0].ravel(), [0.00612931, 0.006799, -0.00194124], rtol=1e-9)
    np.testing.assert_allclose(calib.T, [-0.12, 0.0, 0.0])


def test_newer_file_uses_unsuffixed_ty_tz_and_ignores_disto_sections(zed_conf_dir):
    calib = load_factory_calibration(zed_conf_dir / "SN20292994.conf", "HD")
    np.testing.assert_allclose(calib.T, [-0.120023, 0.0349145e-3, 0.0344261e-3])
    # The per-resolution k1..k3 terms, not [LEFT_DISTO] (k1=13.8851 there).
    np.testing.assert_allclose(calib.dist_left, [-0.0620423, 0.0355664, -2.4591e-06, -0.000245264, -0.0129101])


def test_file_without_ty_tz_has_them_zero(zed_conf_dir):
    calib = load_factory_calibration(zed_conf_dir / "SN1267.conf", "VGA")
    np.testing.assert_allclose(calib.T, [-0.12, 0.0, 0.0])
    assert calib.K_left[0, 0] == pytest.approx(350.179)


# --- generated variants -------------------------------------------------------------------


def variant(zed_conf_dir, tmp_path, edit, name="SN1010.conf", encoding="utf-8"):
    text = (zed_conf_dir / name).read_text()
    path = tmp_path / "variant.conf"
    path.write_text(edit(text), encoding=encoding)
    return path


def test_bom_spaces_around_equals_and_key_case_are_tolerated(zed_conf_dir, tmp_path):
    def messy(text):
        text = re.sub(r"^(\w+)=", lambda m: f"  {m.group(1).upper()} =  ", text, flags=re.M)
        return text.replace("[STEREO]", "[stereo]")

    path = variant(zed_conf_dir, tmp_path, messy, encoding="utf-8-sig")
    assert path.read_bytes().startswith(b"\xef\xbb\xbf")
    reference = load_factory_calibration(zed_conf_dir / "SN1010.conf", "HD")
    calib = load_factory_calibration(path, "HD")
    for attribute in ("K_left", "K_right", "dist_left", "dist_right", "R", "T"):
        np.testing.assert_array_equal(getattr(calib, attribute), getattr(reference, attribute))


def test_old_baseline_spelling(zed_conf_dir, tmp_path):
    path = variant(zed_conf_dir, tmp_path, lambda t: t.replace("Baseline=120", "BaseLine=118.5"))
    assert load_factory_calibration(path, "HD").T[0] == pytest.approx(-0.1185)


def test_suffixed_ty_tz_of_the_chosen_resolution_win(zed_conf_dir, tmp_path):
    path = variant(zed_conf_dir, tmp_path, lambda t: t.replace("TY=0\nTZ=0", "TY_HD=0.5\nTZ_HD=-0.25\nTY_VGA=9"))
    np.testing.assert_allclose(load_factory_calibration(path, "HD").T, [-0.12, -0.0005, 0.00025])


def test_missing_distortion_terms_default_to_zero(zed_conf_dir, tmp_path):
    path = variant(zed_conf_dir, tmp_path, lambda t: re.sub(r"^(k2|k3|p1|p2)=.*\n", "", t, flags=re.M))
    calib = load_factory_calibration(path, "HD")
    np.testing.assert_allclose(calib.dist_left, [-0.175995, 0, 0, 0, 0])
    path = variant(zed_conf_dir, tmp_path, lambda t: re.sub(r"^(k2|k3)=.*$", r"\1=", t, flags=re.M))
    np.testing.assert_allclose(load_factory_calibration(path, "HD").dist_left, [-0.175995, 0, 0, 0, 0])


@pytest.mark.parametrize(("remove", "section", "key"), [
    (r"^\[RIGHT_CAM_HD\]\n(.*\n){9}", "RIGHT_CAM_HD", None),
    (r"(?<=\[LEFT_CAM_HD\]\n)fx=.*\n", "LEFT_CAM_HD", "fx"),
    (r"^CV_HD=.*\n", "STEREO", "CV_HD"),
    (r"^Baseline=.*\n", "STEREO", "Baseline"),
])
def test_missing_section_or_key_names_file_section_and_key(zed_conf_dir, tmp_path, remove, section, key):
    path = variant(zed_conf_dir, tmp_path, lambda t: re.sub(remove, "", t, count=1, flags=re.M))
    with pytest.raises(CalibrationFileError) as error:
        load_factory_calibration(path, "HD")
    message = str(error.value)
    assert str(path) in message and f"[{section}]" in message
    if key is not None:
        assert key in message


def test_a_missing_key_of_another_resolution_does_not_matter(zed_conf_dir, tmp_path):
    path = variant(zed_conf_dir, tmp_path, lambda t: re.sub(r"^CV_2K=.*\n", "", t, flags=re.M))
    load_factory_calibration(path, "HD")


def test_bad_number_and_bad_file_are_named(zed_conf_dir, tmp_path):
    path = variant(zed_conf_dir, tmp_path, lambda t: t.replace("RZ_HD=-0.00194124", "RZ_HD=-0,0019"))
    with pytest.raises(CalibrationFileError, match=r"\[STEREO\] RZ_HD: '-0,0019' is not a finite number"):
        load_factory_calibration(path, "HD")
    with pytest.raises(CalibrationFileError, match="not found"):
        load_factory_calibration(tmp_path / "SN0.conf")
    junk = tmp_path / "junk.conf"
    junk.write_text("not an ini file\n")
    with pytest.raises(CalibrationFileError, match="line 1"):
        load_factory_calibration(junk)


def test_unknown_resolution_lists_the_allowed_ones(zed_conf_dir):
    with pytest.raises(ValueError, match="2K, FHD, HD, VGA"):
        load_factory_calibration(zed_conf_dir / "SN1010.conf", "4K")
    assert load_factory_calibration(zed_conf_dir / "SN1010.conf", "hd720").image_size == (1280, 720)


# --- the conversion against a rig built by hand -------------------------------------------


def _axis_rotation(axis: int, angle: float) -> np.ndarray:
    """Rotation by ``angle`` about the x (0), y (1) or z (2) axis, written out (no Rodrigues)."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _hand_rig_conf(path, key: str, angle: float, ty_mm: float, tz_mm: float) -> None:
    """An HD-only factory file: ideal pinhole eyes, 120 mm baseline, one rotation key set."""
    eye = "fx=700\nfy=700\ncx=640\ncy=360\n"
    stereo = {"RX_HD": 0.0, "CV_HD": 0.0, "RZ_HD": 0.0, key: angle}
    path.write_text(f"[LEFT_CAM_HD]\n{eye}\n[RIGHT_CAM_HD]\n{eye}\n[STEREO]\nBaseline=120\nTY={ty_mm}\nTZ={tz_mm}\n"
                    + "".join(f"{k}={v}\n" for k, v in stereo.items()))


def _project_by_hand(points: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    cam = points @ R.T + t
    return np.column_stack([700 * cam[:, 0] / cam[:, 2] + 640, 700 * cam[:, 1] / cam[:, 2] + 360])


@pytest.mark.parametrize(("key", "axis"), [("RX_HD", 0), ("CV_HD", 1), ("RZ_HD", 2)])
def test_rotation_keys_and_translation_map_to_the_axes_of_a_hand_built_rig(tmp_path, key, axis):
    """RX tilts about x, CV converges about y, RZ rolls about z, and (Baseline, TY, TZ) place the
    right eye in the left frame: a rig built by hand from that reading, with points projected
    without the calibration, rectifies onto equal rows with the parsed file. The same points
    projected with the axes swapped do not, so the test tells the readings apart."""
    angle, ty_mm, tz_mm = 0.02, 1.5, -2.0
    path = tmp_path / "SN1.conf"
    _hand_rig_conf(path, key, angle, ty_mm, tz_mm)
    calib = load_factory_calibration(path, "HD")
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(-0.4, 0.4, 200), rng.uniform(-0.3, 0.3, 200), rng.uniform(0.6, 2.5, 200)])
    t = -np.array([120.0, ty_mm, tz_mm]) / 1000.0
    uv_left = _project_by_hand(points, np.eye(3), np.zeros(3))
    rect = calib.rectification

    def row_mismatch(R_right: np.ndarray) -> float:
        uv_right = _project_by_hand(points, R_right, t)
        rows = rect.rectify_points(uv_left, "left")[:, 1] - rect.rectify_points(uv_right, "right")[:, 1]
        return float(np.max(np.abs(rows)))

    assert row_mismatch(_axis_rotation(axis, angle)) < 0.01
    for wrong in (_axis_rotation((axis + 1) % 3, angle), _axis_rotation(axis, -angle)):
        assert row_mismatch(wrong) > 0.5  # another reading of the key leaves a vertical disparity
    # the right eye sits to the right: positive disparity f B / Z in the rectified pair
    uv_right = _project_by_hand(points, _axis_rotation(axis, angle), t)
    disparity = rect.rectify_points(uv_left, "left")[:, 0] - rect.rectify_points(uv_right, "right")[:, 0]
    depth = rect.from_left_camera(points)[:, 2]
    np.testing.assert_allclose(disparity, rect.focal_px * rect.baseline_m / depth, rtol=1e-6)
    assert rect.baseline_m == pytest.approx(np.linalg.norm(t), rel=1e-9)


# --- implausible values (issue 14) ---------------------------------------------------------


@pytest.mark.parametrize(("old", "new", "message"), [
    ("fx=700.895", "fx=7e307", r"\[LEFT_CAM_HD\] fx = 7e\+307 px is outside \[64, 7680\] px"),
    ("fy=699.05", "fy=0", r"\[RIGHT_CAM_HD\] fy = 0 px is outside \[36, 4320\] px"),
    ("cx=665.54", "cx=-5000", r"\[LEFT_CAM_HD\] cx = -5000 px is outside the image: expected -0.5 to 1279.5 px"),
    ("cy=374.974", "cy=7500", r"\[RIGHT_CAM_HD\] cy = 7500 px is outside the image: expected -0.5 to 719.5 px"),
    ("k1=-0.175995\nk2=0.0265533\nk3=0\np1=0\np2=0\n\n[RIGHT_CAM_HD]",
     "k1=1e6\nk2=0.0265533\nk3=0\np1=0\np2=0\n\n[RIGHT_CAM_HD]", r"\[LEFT_CAM_HD\] k1 = 1e\+06 is outside \[-2, 2\]"),
    ("p2=0\n\n[LEFT_CAM_VGA]", "p2=0.5\n\n[LEFT_CAM_VGA]", r"\[RIGHT_CAM_HD\] p2 = 0.5 is outside \[-0.1, 0.1\]"),
    ("RX_HD=0.00612931", "RX_HD=100", r"\[STEREO\] RX_HD = 100 rad is outside \[-0.5236, 0.5236\] rad"),
    ("CV_HD=0.006799", "CV_HD=-0.6", r"\[STEREO\] CV_HD = -0.6 rad is outside \[-0.5236, 0.5236\] rad"),
    ("Baseline=120", "Baseline=-120", r"\[STEREO\] Baseline = -120 is outside \[10, 1000\] mm: Stereolabs files store "
                                      r"the baseline as a positive distance in millimetres"),
    ("Baseline=120", "Baseline=0.12", r"\[STEREO\] Baseline = 0.12 is outside \[10, 1000\] mm"),
    ("Baseline=120", "Baseline=120000", r"\[STEREO\] Baseline = 120000 is outside \[10, 1000\] mm"),
    ("TY=0", "TY=500", r"\[STEREO\] Baseline, TY, TZ \(the right eye at \(120, 500, 0\) mm from the left one\): .* 77 "
                       r"degrees away"),
])
def test_an_implausible_value_names_the_section_the_key_and_the_range(zed_conf_dir, tmp_path, old, new, message):
    """Issue 14: such values loaded silently, and a negative Baseline was negated into a reversed T."""
    path = variant(zed_conf_dir, tmp_path, lambda t: t.replace(old, new, 1))
    assert path.read_text() != (zed_conf_dir / "SN1010.conf").read_text(), "the edit did not apply"
    with pytest.raises(CalibrationFileError, match=message) as error:
        load_factory_calibration(path, "HD")
    assert str(path) in str(error.value)


def test_keys_of_other_resolutions_do_not_matter_for_plausibility(zed_conf_dir, tmp_path):
    path = variant(zed_conf_dir, tmp_path, lambda t: t.replace("RX_VGA=0.00612931", "RX_VGA=100"))
    load_factory_calibration(path, "HD")
    with pytest.raises(CalibrationFileError, match=r"\[STEREO\] RX_VGA = 100 rad"):
        load_factory_calibration(path, "VGA")


def test_rotation_keys_each_in_range_but_too_much_together_name_all_three(zed_conf_dir, tmp_path):
    path = variant(zed_conf_dir, tmp_path, lambda t: t.replace("CV_HD=0.006799", "CV_HD=0.45")
                   .replace("RZ_HD=-0.00194124", "RZ_HD=0.45"))
    with pytest.raises(CalibrationFileError, match=r"\[STEREO\] RX_HD, CV_HD, RZ_HD: turns the right eye by 36\.\d "
                                                   r"degrees against the left; a stereo rig's eyes differ by at most "
                                                   r"30"):
        load_factory_calibration(path, "HD")


@pytest.mark.parametrize("name", REAL_FILES)
def test_every_real_file_puts_the_right_eye_to_the_right(zed_conf_dir, name):
    """Stereolabs write Baseline positive; OpenCV's T then has T_x < 0 at every resolution."""
    for resolution in ZED_RESOLUTIONS:
        calib = load_factory_calibration(zed_conf_dir / name, resolution)
        assert calib.T[0] < 0 and (-calib.R.T @ calib.T)[0] == pytest.approx(0.12, abs=0.001)
