"""OpenCV's stereo calibration, run on the twin's rendered checkerboard views, recovers the
calibration the twin renders with (issue 3: RMS < 0.3 px, baseline within 0.5 mm, focal within
0.5 %); the detected corners sit where the true corners project."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from estimator import StereoCalibration
from estimator.board_calibration import BoardSpec, calibrate_stereo, compare_calibrations, detect_pair
from twin.checkerboard import board_corners_left_camera, board_poses, board_prop, render_board_views
from twin.render import StereoRenderer
from twin.rig import ConfigFileError, StereoRig

REPO = Path(__file__).resolve().parents[2]
BOARD = BoardSpec(inner_cols=9, inner_rows=6, square_m=0.04)


@pytest.fixture(scope="module")
def rig() -> StereoRig:
    return StereoRig.load(REPO / "models" / "camera.toml")


@pytest.fixture(scope="module")
def views(rig):
    poses = board_poses(rig, BOARD, 12, seed=0)
    with StereoRenderer(rig, seed=5) as renderer:
        images = render_board_views(renderer, BOARD, poses)
    return poses, images


def _closest_numbering(found: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Corner errors under the one of OpenCV's four possible numberings that fits best."""
    grid = found.reshape(BOARD.inner_rows, BOARD.inner_cols, 2)
    candidates = (grid, grid[::-1], grid[:, ::-1], grid[::-1, ::-1])
    errors = [np.linalg.norm(c.reshape(-1, 2) - truth, axis=1) for c in candidates]
    return min(errors, key=np.mean)


def test_board_poses_keep_the_board_inside_both_images(rig):
    poses = board_poses(rig, BOARD, 14, seed=3)
    w, h = rig.image_size
    centres = []
    for T in poses:
        corners = board_corners_left_camera(rig, BOARD, T)
        for side in ("left", "right"):
            uv = rig.calibration.project(corners, side)
            assert uv.min() > 0 and uv[:, 0].max() < w and uv[:, 1].max() < h
        centres.append(rig.calibration.project(corners.mean(0, keepdims=True), "left")[0])
    centres = np.array(centres)
    # The views spread over the image (where distortion is strongest too).
    assert np.ptp(centres[:, 0]) > 0.45 * w and np.ptp(centres[:, 1]) > 0.4 * h


def test_detected_corners_lie_where_the_true_corners_project(rig, views):
    poses, images = views
    errors = []
    for T, pair in zip(poses, images, strict=True):
        found = detect_pair(pair.left, pair.right, BOARD)
        assert found is not None
        truth = board_corners_left_camera(rig, BOARD, T)
        for side, uv in zip(("left", "right"), found, strict=True):
            errors.append(_closest_numbering(uv, rig.calibration.project(truth, side)))
        # Both images number the corners alike (the stereo correspondence needs it).
        left, right = found
        flips = (lambda g: g, lambda g: g[::-1], lambda g: g[:, ::-1], lambda g: g[::-1, ::-1])
        grid_r = right.reshape(BOARD.inner_rows, BOARD.inner_cols, 2)
        disparity = [np.std(left - f(grid_r).reshape(-1, 2), axis=0).sum() for f in flips]
        assert int(np.argmin(disparity)) == 0
    errors = np.concatenate(errors)
    print(f"corner error vs truth: rms {np.sqrt(np.mean(errors**2)):.3f} px, max {errors.max():.3f} px")
    assert np.sqrt(np.mean(errors**2)) < 0.25
    assert errors.max() < 1.0


def test_stereo_calibration_on_rendered_boards_recovers_the_twins_calibration(rig, views):
    _, images = views
    result = calibrate_stereo([(v.left, v.right) for v in images], BOARD)
    truth = rig.calibration
    diff = compare_calibrations(result.calibration, truth)
    print(f"rms {result.rms_px:.3f} px; " + ", ".join(f"{k} {v:+.3f}" for k, v in diff.items()))
    assert len(result.views) == len(images)
    assert result.per_view_rms_px.shape == (len(images), 2)
    assert result.rms_px < 0.3
    assert abs(diff["baseline_mm"]) < 0.5
    for key in ("fx_left_pct", "fy_left_pct", "fx_right_pct", "fy_right_pct"):
        assert abs(diff[key]) < 0.5, key
    for key in ("cx_left_px", "cy_left_px", "cx_right_px", "cy_right_px"):
        assert abs(diff[key]) < 3.0, key
    assert diff["rotation_mrad"] < 2.0
    assert np.allclose(result.calibration.dist_left[:2], truth.dist_left[:2], atol=0.01)
    assert isinstance(result.calibration, StereoCalibration)


def test_a_wrong_calibration_is_told_apart(rig):
    """compare_calibrations is not blind: a 1 % focal error and a 1 mm longer baseline show."""
    c = rig.calibration
    K = c.K_left.copy()
    K[0, 0] *= 1.01
    other = StereoCalibration(K, c.dist_left, c.K_right, c.dist_right, c.R, c.T * (1 + 0.001 / c.baseline_m),
                              c.image_size)
    diff = compare_calibrations(other, c)
    assert diff["fx_left_pct"] == pytest.approx(1.0)
    assert diff["baseline_mm"] == pytest.approx(1.0)
    assert diff["fy_left_pct"] == 0.0 and diff["rotation_mrad"] == pytest.approx(0.0, abs=1e-6)


def test_too_few_views_with_the_board_is_an_error(rig):
    blank = np.full((rig.image_size[1], rig.image_size[0], 3), 180, np.uint8)
    with pytest.raises(ValueError, match="found in both images of 0 views"):
        calibrate_stereo([(blank, blank)] * 3, BOARD)


def test_the_board_is_flat_geometry_facing_its_z_axis():
    prop = board_prop(BOARD, np.eye(4))
    (black_pos, black_n, _, _), (white_pos, _, _, _) = prop.parts
    assert np.all(black_pos[:, 2] == 0) and np.all(black_n[:, 2] == 1)
    # (cols + 1) x (rows + 1) squares, half of them black (rounded up), four vertices each.
    assert len(black_pos) == 4 * (((BOARD.inner_cols + 1) * (BOARD.inner_rows + 1) + 1) // 2)
    assert white_pos[:, 0].min() < -BOARD.square_m and white_pos[:, 0].max() > BOARD.inner_cols * BOARD.square_m


@pytest.mark.parametrize(("edit", "message"), [
    (lambda t: t.replace("T_m = [-0.12,", "T_m = [0.12,"), r"key \[extrinsics\] T_m: .* to the LEFT .*T_x < 0"),
    (lambda t: t.replace("fx_px = 699.82", "fx_px = 7e307"),
     r"key \[left\] fx_px = 7e\+307 px is outside \[64, 7680\]"),
    (lambda t: t.replace("cx_px = 637.92", "cx_px = -5000.0"), r"key \[right\] cx_px = -5000 px is outside the image"),
    (lambda t: t.replace("dist = [-0.1712,", "dist = [5.0,"), r"key \[left\] dist: k1 = 5 is outside \[-2, 2\]"),
    (lambda t: t.replace("rotation_mrad = [1.8, -2.6, 0.9]", "rotation_mrad = [1.8, 600.0, 0.9]"),
     r"key \[extrinsics\] rotation_mrad: turns the right eye by 34.4 degrees"),
])
def test_an_implausible_camera_toml_names_its_own_key(tmp_path, edit, message):
    """The twin's camera.toml goes through the same plausibility checks as every calibration, and
    the error names camera.toml's key (fx_px, T_m), not StereoCalibration's argument."""
    text = (REPO / "models" / "camera.toml").read_text()
    path = tmp_path / "camera.toml"
    path.write_text(edit(text))
    assert path.read_text() != text, "the edit did not apply"
    with pytest.raises(ConfigFileError, match=message) as info:
        StereoRig.load(path)
    assert str(path) in str(info.value)
