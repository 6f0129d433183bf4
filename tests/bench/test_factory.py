"""The one flag: config loading and its errors, the factory's two branches, and `softarm rig check`."""

import dataclasses
import re
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import pytest

import twin as twin_package
from bench.config import DEFAULT_CONFIG, MODELS, BenchConfig, ConfigError, build_section, load_bench_config
from bench.factory import Devices, make_devices
from bench.rig_check import rig_command
from estimator import CalibrationFileError, StereoCalibration
from hardware.emulator import BoardEmulator
from hardware.errors import DeviceError
from hardware.interfaces import StereoCamera, ValveBank
from tests.fakes import (
    ARM_CHANNELS,
    FakeTwin,
    side_by_side_frames,
    small_calibration,
    write_side_by_side_video,
)

REPO = Path(__file__).resolve().parents[2]
CHANNEL_TABLE = "\n".join(f"{name} = {i}" for i, name in enumerate(ARM_CHANNELS))


def write_config(folder: Path, *, backend="sim", port="/dev/null-valves", source="session.mkv",
                 calibration="calib.toml", extra="", camera_extra="") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "bench.toml"
    path.write_text(textwrap.dedent(f"""\
        backend = "{backend}"
        {extra}
        [sim]
        twin = "twin.toml"

        [rig.camera]
        source = "{source}"
        calibration = "{calibration}"
        fps = 30
        {camera_extra}

        [rig.valves]
        port = "{port}"
        max_pressure_bar = 2.5

        [rig.valves.channels]
        """) + CHANNEL_TABLE + "\n")
    return path


@pytest.fixture
def recorded_rig(tmp_path):
    """A rig folder with a side-by-side recording and its calibration (what the camera replays)."""
    calibration = small_calibration()
    calibration.save(tmp_path / "rig" / "calib.toml")
    write_side_by_side_video(tmp_path / "rig" / "session.mkv", side_by_side_frames(calibration, 8))
    return tmp_path / "rig"


@pytest.fixture
def board():
    with BoardEmulator(channels=7, max_pressure_bar=2.5) as emulator:
        yield emulator


# --- loading ------------------------------------------------------------------------------


def test_default_config_is_sim_with_a_complete_rig_section():
    config = load_bench_config()
    assert config.path == DEFAULT_CONFIG and config.backend == "sim"
    assert config.sim.twin == DEFAULT_CONFIG.parent / "twin.toml"
    assert tuple(config.rig.valves.channels) == ARM_CHANNELS
    assert list(config.rig.valves.channels.values()) == list(range(7))
    assert config.rig.camera.resolution == "HD" and config.rig.valves.max_pressure_bar == 2.5


def test_relative_paths_resolve_against_the_config_folder(tmp_path, monkeypatch):
    path = write_config(tmp_path / "deep" / "er")
    monkeypatch.chdir(tmp_path)
    config = load_bench_config(Path("deep/er/bench.toml"))
    folder = (tmp_path / "deep" / "er").resolve()
    assert config.sim.twin == folder / "twin.toml"
    assert config.rig.camera.source == folder / "session.mkv"
    assert config.rig.camera.calibration == folder / "calib.toml"
    assert config.path == path.resolve()


def test_left_out_defaults_resolve_against_models_not_the_users_folder(tmp_path, monkeypatch):
    """A config elsewhere that leaves a section out gets the shipped defaults (models/twin.toml), not
    files beside itself, and runs go to runs/ under the working directory; the paths it does write
    resolve against its own folder."""
    path = tmp_path / "x.toml"
    path.write_text('[recording]\nlossless_frames = true\n')
    config = load_bench_config(path)
    assert config.sim.twin == MODELS / "twin.toml" and config.sim.twin.is_file()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert config.recording.root is None and config.recording.runs_root() == elsewhere / "runs"
    path.write_text('[sim]\ntwin = "my_twin.toml"\n[recording]\nroot = "my_runs"\n')
    config = load_bench_config(path)
    assert config.sim.twin == tmp_path / "my_twin.toml" and config.recording.root == tmp_path / "my_runs"


def test_device_index_and_absolute_paths_stay_as_given(tmp_path):
    path = write_config(tmp_path, source="/dev/video0", calibration=str(tmp_path / "x.conf"))
    assert load_bench_config(path).rig.camera.source == Path("/dev/video0")
    text = path.read_text().replace('source = "/dev/video0"', "source = 2")
    path.write_text(text)
    assert load_bench_config(path).rig.camera.source == 2


def test_backend_override_and_wrong_backends_list_the_allowed_values(tmp_path):
    path = write_config(tmp_path)
    assert load_bench_config(path, backend="rig").backend == "rig"
    with pytest.raises(ConfigError, match=r"backend: expected one of 'sim', 'rig', got 'hw'"):
        load_bench_config(path, backend="hw")
    path.write_text(path.read_text().replace('backend = "sim"', 'backend = "real"'))
    with pytest.raises(ConfigError, match=rf"{path}: backend: expected one of 'sim', 'rig', got 'real'"):
        load_bench_config(path)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda t: t + "\n[experiments]\nframes = 10\n", r"unknown key experiments; did you mean .experiment.\?"),
    (lambda t: t.replace("fps = 30", "fsp = 30"), r"unknown key \[rig.camera\] fsp; did you mean 'fps'\?"),
    (lambda t: t.replace("fps = 30", 'fps = "30"'), r"\[rig.camera\] fps: expected a number, got '30' \(a string\)"),
    (lambda t: t.replace("fps = 30", "fps = 45"), r"\[rig.camera\] fps: the ZED offers 15, 30, 60 fps at HD"),
    (lambda t: t.replace('source = "/dev/video0"', "source = true"),
     r"\[rig.camera\] source: expected an integer or a path string, got True"),
    (lambda t: t.replace('port = "/dev/null-valves"\n', ""), r"missing key \[rig.valves\] port"),
    (lambda t: t.replace("s3 = 6", "s3 = 0"), r"\[rig.valves\] channels: s1_a and s3 both use board channel 0"),
    (lambda t: t.replace("s3 = 6", 's3 = "six"'), r"\[rig.valves\] channels.s3: expected an integer"),
    (lambda t: t.replace("max_pressure_bar = 2.5", "max_pressure_bar = -1"), r"\[rig.valves\] max_pressure_bar"),
    (lambda t: t.replace("max_pressure_bar = 2.5", "max_pressure_bar = 2.5\nreply_timeout_s = 0"),
     r"\[rig.valves\] reply_timeout_s: expected 0 < seconds <= 1"),
    (lambda t: t.replace('resolution = "HD"', 'resolution = "4K"'), r"\[rig.camera\] resolution: expected one of"),
    (lambda t: t.replace("x.conf", "x.yaml"), r"\[rig.camera\] calibration: expected a Stereolabs .conf"),
    (lambda t: t.replace("[sim]", "sim = 3\n[simulation]"), r"unknown key simulation"),
    (lambda t: t.replace("[rig.camera]", "[rig.camera]\n[rig.camera]"), r"not valid TOML"),
])
def test_bad_keys_and_values_name_the_file_and_the_key(tmp_path, edit, message):
    path = write_config(tmp_path, source="/dev/video0", calibration="x.conf", camera_extra='resolution = "HD"')
    path.write_text(edit(path.read_text()))
    with pytest.raises(ConfigError, match=message) as error:
        load_bench_config(path)
    assert str(path) in str(error.value)


def test_rig_backend_needs_a_rig_section_and_a_missing_file_is_named(tmp_path):
    path = tmp_path / "bench.toml"
    path.write_text('backend = "rig"\n')
    with pytest.raises(ConfigError, match=r"rig: backend 'rig' needs a \[rig\] section"):
        load_bench_config(path)
    path.write_text("")
    config = load_bench_config(path)  # an empty file is the sim default
    assert config.backend == "sim" and config.rig is None
    with pytest.raises(ConfigError, match="config file not found"):
        load_bench_config(tmp_path / "nope.toml")


def test_build_section_is_generic_for_new_sections(tmp_path):
    """What the bench author relies on to add [experiment], [estimator], [recording]."""

    @dataclasses.dataclass(frozen=True)
    class Step:
        at_s: float
        bar: float = 0.0

    @dataclasses.dataclass(frozen=True)
    class Experiment:
        kind: Literal["ramp", "steps"]
        frames: int | None = None
        channels: tuple[str, ...] = ()
        out: Path = Path("runs")
        step: Step = dataclasses.field(default_factory=lambda: Step(0.0))

        def __post_init__(self):
            if self.frames is not None and self.frames <= 0:
                raise ValueError(f"frames: expected a positive count, got {self.frames}")

    where = tmp_path / "bench.toml"
    built = build_section(Experiment, {"kind": "steps", "channels": ["s1_a"], "step": {"at_s": 2}}, where, "experiment",
                          defaults_dir=tmp_path / "defaults")
    assert built == Experiment("steps", None, ("s1_a",), tmp_path / "defaults" / "runs", Step(2.0, 0.0))
    assert build_section(Experiment, {"kind": "ramp", "out": "o"}, where, "experiment").out == tmp_path / "o"
    for table, message in [
        ({"kind": "sweep"}, r"\[experiment\] kind: expected one of 'ramp', 'steps'"),
        ({"kind": "ramp", "frames": 0}, r"\[experiment\] frames: expected a positive count"),
        ({"kind": "ramp", "channels": "s1_a"}, r"\[experiment\] channels: expected an array"),
        ({"kind": "ramp", "step": {"bar": 1}}, r"missing key \[experiment.step\] at_s"),
        ({}, r"missing key \[experiment\] kind"),
    ]:
        with pytest.raises(ConfigError, match=message):
            build_section(Experiment, table, where, "experiment")


def test_bench_config_is_frozen():
    config = load_bench_config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.backend = "rig"
    with pytest.raises(TypeError):
        config.rig.valves.channels["s1_a"] = 5
    assert isinstance(config, BenchConfig)


# --- the rig branch -----------------------------------------------------------------------


def test_rig_backend_opens_the_zed_driver_and_the_serial_bank(recorded_rig, board):
    config = load_bench_config(write_config(recorded_rig, backend="rig", port=board.port))
    with make_devices(config) as devices:
        assert type(devices.camera).__name__ == "ZedCamera" and devices.twin is None
        assert type(devices.valves).__name__ == "SerialValveBank"
        assert devices.valves.channels == ARM_CHANNELS
        frame = devices.camera.grab()
        assert frame.left.shape == (48, 64, 3) and frame.index == 0
        devices.valves.set_pressures({"s2_b": 1.5})
        assert board.setpoints_bar[5] == pytest.approx(1.5, abs=board.lsb_bar)
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    assert board.events[-1].cause == "VENT command"
    assert not devices.camera.is_connected and not devices.valves.is_connected


RIG_CHILD = """
import sys
from bench.config import load_bench_config
from bench.factory import make_devices
with make_devices(load_bench_config(sys.argv[1])) as devices:
    devices.camera.grab()
    devices.valves.set_pressures({"s1_a": 0.5})
print(sorted(m for m in sys.modules if m.split(".")[0] in ("mujoco", "pyrender", "twin", "trimesh", "OpenGL")))
"""


def test_a_rig_run_never_imports_the_twin_mujoco_or_pyrender(recorded_rig, board):
    path = write_config(recorded_rig, backend="rig", port=board.port)
    result = subprocess.run([sys.executable, "-c", RIG_CHILD, str(path)], cwd=REPO, capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"
    assert board.commands.get("SET") == 1  # the child really drove the board


def test_a_missing_calibration_fails_before_anything_moves(recorded_rig, board):
    path = write_config(recorded_rig, backend="rig", port=board.port, calibration="SN1.conf")
    with pytest.raises(CalibrationFileError) as error:
        make_devices(load_bench_config(path))
    assert str(error.value) == (f"{path.resolve()} [rig.camera] calibration: {recorded_rig.resolve() / 'SN1.conf'}: "
                                "calibration file not found")
    assert board.frames_received == 0


def test_a_missing_camera_fails_before_anything_moves(recorded_rig, board):
    path = write_config(recorded_rig, backend="rig", port=board.port, source="gone.mkv")
    with pytest.raises(ValueError, match="gone.mkv' does not exist") as error:
        make_devices(load_bench_config(path))
    assert str(error.value).startswith(f"{path.resolve()} [rig.camera] source: ")
    assert board.frames_received == 0


def test_a_camera_that_cannot_be_opened_is_named_by_its_key(recorded_rig, board):
    (recorded_rig / "notes.mkv").write_text("not a video")
    path = write_config(recorded_rig, backend="rig", port=board.port, source="notes.mkv")
    with pytest.raises(DeviceError) as error:
        make_devices(load_bench_config(path))
    assert str(error.value).startswith(f"{path.resolve()} [rig.camera] source: could not open video")
    assert board.frames_received == 0


def test_a_missing_twin_file_is_named_by_its_key(tmp_path):
    path = write_config(tmp_path)  # [sim] twin = "twin.toml", which is not there
    with pytest.raises(ConfigError) as error:
        make_devices(load_bench_config(path))
    assert str(error.value) == f"{path.resolve()} [sim] twin: {tmp_path.resolve() / 'twin.toml'}: twin file not found"


def test_a_silent_board_closes_the_camera_it_had_opened(recorded_rig, board, monkeypatch):
    from hardware import zed

    opened = []
    original = zed.ZedCamera.connect
    monkeypatch.setattr(zed.ZedCamera, "connect", lambda self: (original(self), opened.append(self))[0])
    board.cut_link()
    config = load_bench_config(write_config(recorded_rig, backend="rig", port=board.port))
    with pytest.raises(ConnectionError, match="did not answer VER"):
        make_devices(config)
    assert len(opened) == 1 and not opened[0].is_connected


# --- the sim branch -----------------------------------------------------------------------


def test_sim_backend_builds_the_twin_from_its_config(tmp_path, monkeypatch):
    monkeypatch.setattr(twin_package, "Twin", FakeTwin, raising=False)
    config = load_bench_config(write_config(tmp_path / "cfg"))
    (tmp_path / "cfg" / "twin.toml").touch()  # the factory checks that [sim] twin exists; the fake ignores it
    with make_devices(config) as devices:
        assert isinstance(devices.twin, FakeTwin)
        assert devices.twin.config_path == (tmp_path / "cfg" / "twin.toml").resolve()
        assert devices.camera is devices.twin.camera and devices.valves is devices.twin.valves
        assert devices.camera.is_connected and devices.valves.is_connected
        devices.valves.set_pressures({"s1_a": 2.0})
    assert devices.twin.closed and not devices.camera.is_connected
    np.testing.assert_array_equal(devices.twin.valves.applied_bar, np.zeros(7))  # vented before closing


SIM_CHILD = """
import sys, types
import tests.fakes as fakes
if sys.argv[2] == "fake":
    sys.modules["twin"] = types.SimpleNamespace(Twin=fakes.FakeTwin)
from bench.config import load_bench_config
from bench.factory import make_devices
with make_devices(load_bench_config(sys.argv[1], backend="sim")) as devices:
    devices.camera.grab()
    devices.valves.set_pressures({"s1_a": 0.5})
print(sorted(m for m in sys.modules if m.split(".")[0] == "serial" or m == "hardware.valves"))
"""


def test_a_sim_run_never_imports_pyserial(tmp_path):
    path = write_config(tmp_path, port="/dev/ttyACM0")
    (tmp_path / "twin.toml").touch()  # the fake twin ignores it
    result = subprocess.run([sys.executable, "-c", SIM_CHILD, str(path), "fake"], cwd=REPO, capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def test_devices_close_everything_even_when_venting_fails():
    class BrokenVent(FakeTwin):
        pass

    twin = BrokenVent(Path("x"))
    twin.camera.connect()
    twin.valves.connect()

    def fail():
        raise ConnectionError("link lost")

    twin.valves._vent = fail
    devices = Devices(twin.camera, twin.valves, twin=twin)
    with pytest.raises(ConnectionError):
        devices.close()
    assert not twin.camera.is_connected and not twin.valves.is_connected and twin.closed


def test_default_config_opens_the_real_twin():
    with make_devices(load_bench_config()) as devices:
        assert isinstance(devices.camera, StereoCamera) and isinstance(devices.valves, ValveBank)
        assert tuple(devices.valves.channels) == ARM_CHANNELS
        frame = devices.camera.grab()
        width, height = devices.camera.calibration.image_size
        assert frame.left.shape == frame.right.shape == (height, width, 3)
        devices.valves.set_pressures({"s1_a": 1.0})
    assert all(v == 0 for v in devices.valves.setpoints_bar.values())


def test_a_sim_run_with_the_real_twin_never_imports_pyserial():
    result = subprocess.run([sys.executable, "-c", SIM_CHILD, str(DEFAULT_CONFIG), "real"], cwd=REPO,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


# --- softarm rig check --------------------------------------------------------------------


def test_rig_check_reports_everything_and_moves_nothing(tmp_path, zed_conf_dir, board, capsys):
    calibration = zed_conf_dir / "SN1010.conf"
    frames = [np.full((720, 2560, 3), 90, np.uint8)] * 2
    write_side_by_side_video(tmp_path / "zed.mkv", frames)
    path = write_config(tmp_path, backend="sim", port=board.port, source="zed.mkv", calibration=str(calibration))
    assert rig_command(type("Args", (), {"config": str(path)})()) == 0
    out = capsys.readouterr().out
    for expected in ["2560x720 side-by-side = 2 x 1280x720", "focal left 700.9/700.9 px", "baseline 120.00 mm",
                     "row mismatch after rectification: not measured (only 0 features matched",  # a blank frame
                     "firmware softarm-emu/0.1.0",
                     "7 channels, limit 2.5 bar", "e-stop released", "s3(ch6)=0", "rig OK"]:
        assert expected in out, out
    assert "SET" not in board.commands and board.commands["VENT"] >= 2
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))


def test_rig_check_fails_clearly(tmp_path, capsys):
    path = write_config(tmp_path, calibration="SN404.conf", source="/dev/video0")
    assert rig_command(type("Args", (), {"config": str(path)})()) == 1
    assert "FAILED" in capsys.readouterr().err
    (tmp_path / "norig.toml").write_text('backend = "sim"\n')
    assert rig_command(type("Args", (), {"config": str(tmp_path / "norig.toml")})()) == 1
    assert "no [rig] section to check" in capsys.readouterr().err


def test_rig_check_on_the_default_config_names_the_missing_calibration(capsys):
    assert rig_command(type("Args", (), {"config": None})()) == 1
    assert (f"{DEFAULT_CONFIG} [rig.camera] calibration: {MODELS / 'SN00000.conf'}: calibration file not found"
            in capsys.readouterr().err)


def textured_plane_pair(calibration, depth_m: float = 1.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Raw left and right BGR images of a randomly textured plane ``depth_m`` in front of the left
    camera, parallel to its image, seen through ``calibration`` (distortion, R and T included)."""
    rng = np.random.default_rng(seed)
    mm_per_texel, half = 5.0, 300
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (2 * half, 2 * half)).astype(np.float32), (0, 0), 2.0)
    texture = cv2.normalize(texture, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    w, h = calibration.image_size
    uv = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1).reshape(-1, 1, 2)
    R, T = calibration.R, calibration.T.reshape(3)
    images = []
    for side in ("left", "right"):
        xy = cv2.undistortPoints(uv, calibration.K(side), calibration.dist(side).reshape(1, -1)).reshape(-1, 2)
        rays = np.column_stack([xy, np.ones(len(xy))])  # in this camera's frame
        if side == "left":
            points = rays * depth_m
        else:  # x_right = R x_left + T: the ray's points in the left frame are R^T (s r - T); meet z = depth_m
            rays_left, origin_left = rays @ R, R.T @ T
            s = (depth_m + origin_left[2]) / rays_left[:, 2]
            points = rays_left * s[:, None] - origin_left
        map_x = (points[:, 0] * 1000 / mm_per_texel + half).reshape(h, w).astype(np.float32)
        map_y = (points[:, 1] * 1000 / mm_per_texel + half).reshape(h, w).astype(np.float32)
        images.append(cv2.cvtColor(cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR), cv2.COLOR_GRAY2BGR))
    return images[0], images[1]


def test_rig_check_measures_the_calibration_against_the_camera(tmp_path, board, capsys):
    """The row mismatch comes from the grabbed frame: near 0 with the camera's own calibration, about
    f * angle with a file whose right eye is tilted by 0.01 rad (what a knocked camera looks like)."""
    true = small_calibration(320, 240)
    left, right = textured_plane_pair(true)
    write_side_by_side_video(tmp_path / "scene.mkv", [np.hstack([left, right])] * 2)
    true.save(tmp_path / "true.toml")
    tilted_R = cv2.Rodrigues(np.array([0.01, 0.0, 0.0]))[0] @ true.R
    StereoCalibration(true.K_left, true.dist_left, true.K_right, true.dist_right, tilted_R, true.T,
                      true.image_size).save(tmp_path / "tilted.toml")
    medians = {}
    for name in ("true", "tilted"):
        path = write_config(tmp_path, port=board.port, source="scene.mkv", calibration=f"{name}.toml")
        assert rig_command(type("Args", (), {"config": str(path)})()) == 0
        out = capsys.readouterr().out
        found = re.search(r"row mismatch after rectification: median ([0-9.]+) px, 90 % under [0-9.]+ px "
                          r"\((\d+) features matched", out)
        assert found, out
        medians[name] = float(found.group(1))
        assert int(found.group(2)) >= 100
    assert medians["true"] < 0.2
    expected_px = 0.01 * true.K_right[1, 1]  # about 1.8 px
    assert abs(medians["tilted"] - expected_px) < 0.4 * expected_px, medians


def test_rig_check_reports_the_devices_that_are_fine_when_the_calibration_is_missing(recorded_rig, board, capsys):
    """It used to stop at the first failure: now the camera and the board are still opened and reported."""
    path = write_config(recorded_rig, port=board.port, calibration="SN404.conf")
    assert rig_command(type("Args", (), {"config": str(path)})()) == 1
    captured = capsys.readouterr()
    assert "calibration  FAILED: " in captured.err and "SN404.conf: calibration file not found" in captured.err
    assert "128x48 side-by-side = 2 x 64x48" in captured.out and "grabbed frame 0: 2 x 64x48" in captured.out
    assert "firmware softarm-emu/0.1.0" in captured.out and "e-stop released" in captured.out
    assert "FAILED: calibration (the other devices are reported above); nothing was moved" in captured.err
    assert "rig OK" not in captured.out
    assert "SET" not in board.commands and board.commands["VENT"] >= 2  # connected, vented, closed


def test_rig_check_reports_the_camera_and_calibration_when_the_board_is_silent(recorded_rig, board, capsys):
    board.cut_link()
    path = write_config(recorded_rig, port=board.port)
    assert rig_command(type("Args", (), {"config": str(path)})()) == 1
    captured = capsys.readouterr()
    assert "valve board  FAILED: " in captured.err and "did not answer VER" in captured.err
    assert "focal left 35.2/35.2 px" in captured.out and "grabbed frame 0: 2 x 64x48" in captured.out
    assert "FAILED: valves (the other devices are reported above)" in captured.err


def test_a_one_resolution_calibration_must_match_the_cameras_resolution(tmp_path):
    """The reported case: resolution = "VGA" beside an HD .toml calibration was ignored; frames of one size
    would then meet a calibration of another. A .conf holds every resolution and is read for the one set."""
    from bench.config import CameraConfig
    from bench.factory import rig_calibration
    from tests.scenes import zed_like_calibration

    path = tmp_path / "calib.toml"
    zed_like_calibration().save(path)  # 1280 x 720: HD
    assert rig_calibration(CameraConfig(0, path, "HD"), tmp_path / "rig.toml").image_size == (1280, 720)
    with pytest.raises(CalibrationFileError, match=r"rig.toml \[rig.camera\] calibration: .*calib.toml is for "
                                                   r"1280x720 images, but resolution = 'VGA' gives 672x376 per eye"):
        rig_calibration(CameraConfig(0, path, "VGA"), tmp_path / "rig.toml")
    # a recording stands in for the camera: its own frames' size is what counts, not the resolution
    assert rig_calibration(CameraConfig(tmp_path / "session.mkv", path, "VGA"), tmp_path / "rig.toml")
