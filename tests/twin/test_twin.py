"""The ``Twin`` facade as the bench uses it (issue 3's API), its devices' contracts and its
configuration errors."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from hardware.errors import DeviceError, NotConnectedError
from hardware.interfaces import StereoFrame
from tests.twin.test_render import silhouette_offsets
from twin import Twin
from twin.rig import ConfigFileError, StereoRig
from twin.twin import TwinConfig

REPO = Path(__file__).resolve().parents[2]
MODELS = REPO / "models"


@pytest.fixture(scope="module")
def tw():
    with Twin() as twin:
        yield twin


def test_at_rest_the_arm_hangs_straight_down_from_the_base(tw):
    tw.reset()
    tw.settle()
    world = tw.backbone(frame="world")
    assert world.shape[0] >= 100 and world.shape[1] == 3
    assert np.allclose(world[0], 0.0, atol=1e-6)
    assert np.allclose(world[-1, :2], 0.0, atol=2e-3)
    assert world[-1, 2] == pytest.approx(-0.685, abs=0.01)


def test_backbone_frames_are_related_by_the_rigs_pose(tw):
    cam = tw.backbone()
    world = tw.backbone(frame="world")
    np.testing.assert_allclose(cam, tw.rig.world_to_left_camera(world), atol=1e-12)
    # The base is ~1 m in front of the left camera, a little right of it (x right, y down, z forward).
    assert cam[0] == pytest.approx([0.06, -0.34, 1.0], abs=1e-9)
    # Base to tip, evenly spaced in arc length.
    steps = np.linalg.norm(np.diff(world, axis=0), axis=1)
    assert np.ptp(steps) < 0.02 * steps.mean()
    assert tw.backbone(n_points=150).shape == (150, 3)
    with pytest.raises(ValueError, match="frame"):
        tw.backbone(frame="left")


def test_pressures_move_the_arm_and_grab_shows_it_where_the_calibration_says(tw):
    tw.reset()
    rest_tip = tw.backbone(frame="world")[-1]
    tw.valves.set_pressures({"s1_b": 2.0, "s2_a": 1.5})
    tw.advance(0.5)
    assert tw.time_s == pytest.approx(0.5, abs=1e-9)
    assert tw.settle()
    tip = tw.backbone(frame="world")[-1]
    assert np.linalg.norm(tip - rest_tip) > 0.05, "pressure did not move the tip"
    assert np.allclose(tw.sim.commanded_bar[[1, 4]], [2.0, 1.5])

    frame = tw.camera.grab()
    assert isinstance(frame, StereoFrame)
    w, h = tw.camera.calibration.image_size
    for image in (frame.left, frame.right):
        assert image.shape == (h, w, 3) and image.dtype == np.uint8
    assert frame.timestamp_s == pytest.approx(tw.time_s)
    # The projection proof on a physics shape, end to end through the facade.
    shape = tw.shape()
    gt = tw.backbone()
    assert len(gt) == len(shape.points_world)
    near_plate = np.zeros(len(gt), bool)
    for plate in shape.plates:
        near_plate |= np.linalg.norm(shape.points_world - plate.center_world, axis=1) < 0.06
    usable = ~near_plate & (shape.s_m > 0.03) & (shape.s_m < shape.s_m[-1] - 0.04)
    calib = tw.camera.calibration
    for side, image in (("left", frame.left), ("right", frame.right)):
        uv = calib.project(gt, side)
        cam = gt if side == "left" else gt @ calib.R.T + calib.T
        offsets = silhouette_offsets(image, uv, calib.K(side)[0, 0] * shape.radius_m / cam[:, 2], usable)
        assert np.isfinite(offsets).sum() > 50
        assert np.nanmax(np.abs(offsets)) < 1.0, side
    # The arm is orange where the backbone projects.
    hsv = cv2.cvtColor(frame.left, cv2.COLOR_BGR2HSV)
    on_arm = cv2.inRange(hsv, (5, 100, 50), (25, 255, 255)) > 0
    cols, rows = np.round(calib.project(gt[usable], "left")).astype(int).T
    assert on_arm[rows, cols].mean() > 0.95
    # The depth map belongs to the same frame.
    depth = tw.camera.depth_left()
    assert depth.shape == (h, w) and depth.dtype == np.float32
    assert np.all(np.abs(depth[rows, cols] - gt[usable, 2]) < 0.05)


def test_frames_count_up_and_carry_simulated_time(tw):
    first = tw.camera.grab()
    tw.advance(0.1)
    second = tw.camera.grab()
    assert second.index == first.index + 1
    assert second.timestamp_s == pytest.approx(first.timestamp_s + 0.1)


def test_camera_contract_connect_close_and_use():
    twin = Twin()
    try:
        camera = twin.camera
        assert camera.is_connected
        with pytest.raises(DeviceError, match="already connected"):
            camera.connect()
        with pytest.raises(DeviceError, match="before the first grab"):
            camera.depth_left()
        camera.close()
        camera.close()  # harmless
        assert not camera.is_connected
        with pytest.raises(NotConnectedError):
            camera.grab()
        with pytest.raises(NotConnectedError):
            camera.depth_left()
        camera.connect()
        assert camera.grab().index == 0  # indices restart with a connection
        assert camera.calibration is twin.rig.calibration
    finally:
        twin.close()
    assert not twin.camera.is_connected and not twin.valves.is_connected
    with pytest.raises(NotConnectedError):
        twin.valves.set_pressures({"s3": 1.0})


def test_valves_reject_bad_set_points_naming_the_channel(tw):
    with pytest.raises(ValueError, match="s9"):
        tw.valves.set_pressures({"s9": 1.0})
    with pytest.raises(ValueError, match="s1_a"):
        tw.valves.set_pressures({"s1_a": 3.5})
    with pytest.raises(ValueError, match="s3"):
        tw.valves.set_pressures({"s3": float("nan")})


def test_closing_the_twin_vents_the_valves():
    twin = Twin()
    twin.valves.set_pressures({"s1_a": 2.0})
    twin.close()
    assert np.all(twin.sim.commanded_bar == 0)


# --- configuration errors ------------------------------------------------------------------


def _copy_models(tmp_path: Path) -> Path:
    for name in ("twin.toml", "camera.toml", "arm.toml", "scene.toml"):
        shutil.copy(MODELS / name, tmp_path / name)
    return tmp_path / "twin.toml"


def test_twin_toml_relative_paths_and_a_copy_load(tmp_path):
    config = TwinConfig.load(_copy_models(tmp_path))
    assert config.arm == tmp_path / "arm.toml" and config.camera == tmp_path / "camera.toml"
    assert config.backbone_points >= 100


@pytest.mark.parametrize(("edit", "key"), [
    (lambda t: t + "\nframe_rate = 30\n", "frame_rate"),
    (lambda t: t.replace("seed = 0", "seed = 0\nsed = 1"), "[render] sed"),
    (lambda t: t.replace("timestep_s = 0.002", "timestep_s = -1.0"), "[physics] timestep_s"),
    (lambda t: t.replace('camera = "camera.toml"', 'camera = "nowhere.toml"'), "camera"),
    (lambda t: t.replace("backbone_points = 200", "backbone_points = 20"), "[truth] backbone_points"),
])
def test_a_bad_twin_toml_names_the_file_and_the_key(tmp_path, edit, key):
    path = _copy_models(tmp_path)
    path.write_text(edit(path.read_text()))
    with pytest.raises(ConfigFileError) as info:
        TwinConfig.load(path)
    assert str(path) in str(info.value) and key in str(info.value)


@pytest.mark.parametrize(("edit", "key"), [
    (lambda t: t.replace("fx_px = 699.82", 'fx_px = "700"'), "[left] fx_px"),
    (lambda t: t.replace("fx_px = 699.82", "fx_px = -5.0"), "[left] fx_px"),
    (lambda t: t.replace("noise_std_dn = 1.5", "noise_std_dn = 1.5\nnoise_dn = 2"), "[sensor] noise_dn"),
    (lambda t: t.replace("T_m = [-0.12, 0.00021, -0.00035]", "T_m = [0.0, 0.0, 0.0]"), "[extrinsics] T_m"),
    (lambda t: t.replace("dist = [-0.1712, 0.02647, 0.00031, -0.00019, 0.0]", "dist = [1, 2]"), "[left] dist"),
    (lambda t: t.replace("look_at_m = [-0.06, 0.0, -0.34]", "look_at_m = [-0.06, -1.0, -0.34]"),
     "[pose] look_at_m"),
    (lambda t: t.replace("[image]\nwidth_px = 1280\n", "[image]\n"), "[image] width_px"),
    (lambda t: t.replace("arm_rgb = [1.0, 0.47, 0.1]", "arm_rgb = [255, 120, 25]"), "[appearance] arm_rgb"),
])
def test_a_malformed_camera_toml_names_the_file_and_the_key(tmp_path, edit, key):
    path = tmp_path / "camera.toml"
    text = (MODELS / "camera.toml").read_text()
    edited = edit(text)
    assert edited != text, "the edit did not apply"
    path.write_text(edited)
    with pytest.raises(ConfigFileError) as info:
        StereoRig.load(path)
    assert str(path) in str(info.value) and key in str(info.value)


def test_a_missing_or_broken_camera_file(tmp_path):
    with pytest.raises(ConfigFileError, match="not found"):
        StereoRig.load(tmp_path / "none.toml")
    (tmp_path / "bad.toml").write_text("[image\nwidth_px = 3")
    with pytest.raises(ConfigFileError, match="bad.toml"):
        StereoRig.load(tmp_path / "bad.toml")


def test_the_exposed_calibration_is_the_files(tmp_path):
    rig = StereoRig.load(MODELS / "camera.toml")
    c = rig.calibration
    assert c.image_size == (1280, 720)
    assert c.K_left[0, 0] == 699.82 and c.K_right[1, 2] == 357.64
    assert c.baseline_m == pytest.approx(0.12, abs=1e-3)
    assert np.allclose(c.dist_left, [-0.1712, 0.02647, 0.00031, -0.00019, 0.0])
    # Saved and loaded through the estimator's file format, it is the same calibration.
    c.save(tmp_path / "calib.toml")
    from estimator import StereoCalibration

    again = StereoCalibration.load(tmp_path / "calib.toml")
    for name in ("K_left", "K_right", "dist_left", "dist_right", "R", "T"):
        np.testing.assert_array_equal(getattr(again, name), getattr(c, name))
