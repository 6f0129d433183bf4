"""Absurd bench configs are config errors naming file, key and the allowed range, found before anything is
allocated or moved (not a NumPy memory error half way into a run); a config that needs only the camera
loads without a valve board; `softarm run` states its disk use and asks before a large run."""

import dataclasses
import math
import textwrap
import typing
from pathlib import Path
from types import SimpleNamespace

import pytest

from bench.config import (
    ARM_VALVE_CHANNELS,
    MAX_FRAMES,
    CameraConfig,
    ConfigError,
    DepthConfig,
    ExperimentConfig,
    RecordingConfig,
    ReportConfig,
    SimConfig,
    ValvesConfig,
    build_section,
    load_bench_config,
    staircase_count,
)
from bench.experiments import make_schedule, staircase
from bench.run import run_command


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bench.toml"
    path.write_text(textwrap.dedent(text))
    return path


RIG = """\
[rig.camera]
source = "session.mkv"
calibration = "calib.toml"
fps = 30
[rig.valves]
port = "loop://"
"""


@pytest.mark.parametrize(("text", "message"), [
    # the reported cases: a NumPy "Unable to allocate 7.28 TiB" before
    ("[experiment]\nframes = 1000000000000\n",
     rf"\[experiment\] frames: expected at most {MAX_FRAMES} frames, got 1000000000000 \(allowed: 1 to {MAX_FRAMES}\)"),
    ("[experiment]\nstep_bar = 1e-12\n",
     r"\[experiment\] step_bar: expected a step in \(0, max_bar - start_bar\] and at least 0.001 bar"),
    ("[experiment]\nduration_s = 1e300\n", r"\[experiment\] duration_s: expected a duration in \(0, 86400\] s"),
    ("[experiment]\nduration_s = inf\n", r"\[experiment\] duration_s: expected a finite number, got inf"),
    ("[experiment]\nlead_in_s = 1e9\n", r"\[experiment\] lead_in_s: expected a duration in \[0, 86400\] s"),
    ("[experiment]\nmax_bar = 1e6\n", r"\[experiment\] max_bar: expected 0 <= start_bar < max_bar <= 10 bar"),
    # derived quantities: the schedule's length and rates
    ("[experiment]\nkind = \"random\"\nhold_s = 1e-9\nduration_s = 100\n",
     r"\[experiment\] hold_s: duration_s / hold_s random levels make 100000000000 pressure changes; "
     r"expected at most 100000"),
    ("[experiment]\nmax_bar = 10\nstep_bar = 0.001\nduration_s = 2\n",
     r"\[experiment\] step_bar: .* over duration_s = 2 s make 5000 pressure changes per second; "
     r"expected at most 1000"),
    ("[experiment]\nkind = \"sweep\"\nchannels = [" + ", ".join(f'"v{i}"' for i in range(20)) + "]\n"
     "max_bar = 10\nstep_bar = 0.001\nduration_s = 86400\n",
     r"\[experiment\] step_bar: .* make 400020 pressure changes; expected at most 100000"),
    ("[experiment]\nframes = 1000000\nduration_s = 1\n",
     r"\[experiment\] frames: 1000000 frames over duration_s = 1 s is 1e\+06 captures per second; "
     r"expected at most 10000"),
    ("[experiment]\nchannels = [" + ", ".join(f'"v{i}"' for i in range(65)) + "]\n",
     r"\[experiment\] channels: expected at most 64 valves, got 65"),
    # the valve board and the camera: bools and non-finite values refused by key, ranges named
    (RIG + "max_pressure_bar = true\n", r"\[rig.valves\] max_pressure_bar: expected a number, got True \(a boolean\)"),
    (RIG + "reply_timeout_s = inf\n", r"\[rig.valves\] reply_timeout_s: expected a finite number, got inf"),
    (RIG + "max_pressure_bar = 1e9\n", r"\[rig.valves\] max_pressure_bar: expected a pressure in \(0, 10\] bar"),
    (RIG + "baud = 1000000000000\n", r"\[rig.valves\] baud: expected a rate in 1 .. 20000000"),
    (RIG + "clamp = 1\n", r"\[rig.valves\] clamp: expected true or false, got 1"),
    (RIG.replace("fps = 30", "fps = 1e9"), r"\[rig.camera\] fps: expected a frame rate in \(0, 1000\]"),
    ("[report]\nselected_frames = 1000000000000\n", r"\[report\] selected_frames: expected a count in 0 .. 1000000"),
])
def test_absurd_values_are_config_errors_naming_file_key_and_range(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError, match=message) as error:
        load_bench_config(path)
    assert str(error.value).startswith(f"{path}: ")


# Required keys of each section, so that one float key at a time can be set to a bad value.
SECTIONS = [(SimConfig, "sim", {}), (CameraConfig, "rig.camera", {"source": 0, "calibration": "x.conf"}),
            (ValvesConfig, "rig.valves", {"port": "loop://"}), (DepthConfig, "rig.depth", {"source": "d"}),
            (ExperimentConfig, "experiment", {}), (RecordingConfig, "recording", {}), (ReportConfig, "report", {})]


@pytest.mark.parametrize("bad", [math.inf, -math.inf, math.nan, True])
def test_every_number_key_of_every_section_refuses_bools_and_non_finite_values(tmp_path, bad):
    checked = 0
    for cls, section, required in SECTIONS:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if hints[f.name] is not float:
                continue
            with pytest.raises(ConfigError, match=rf"\[{section}\] {f.name}: expected a (finite )?number") as error:
                build_section(cls, {**required, f.name: bad}, tmp_path / "bench.toml", section)
            assert str(error.value).startswith(f"{tmp_path / 'bench.toml'}: ")
            checked += 1
    assert checked >= 12  # every float key of the bench (12 today), not none


def test_the_schedule_length_the_config_checks_is_the_one_built():
    for start, top, step in [(0.0, 2.5, 0.05), (0.0, 1.0, 0.3), (0.5, 1.0, 0.25), (0.0, 2.5, 0.001), (0.1, 0.7, 0.2)]:
        assert staircase_count(start, top, step) == len(staircase(start, top, step)), (start, top, step)
    for kind in ("ramp", "step", "sweep", "random"):
        config = ExperimentConfig(kind=kind, channels=("s1_a", "s3"), max_bar=1.0, step_bar=0.1, duration_s=10.0,
                                  hold_s=0.3, frames=5)
        assert config.change_count() == len(make_schedule(config).change_times_s), kind


def test_an_absurd_frames_option_is_refused_before_anything_is_allocated(capsys):
    config = ExperimentConfig()
    with pytest.raises(ValueError, match=rf"--frames: expected at most {MAX_FRAMES} frames, got 1000000000000"):
        make_schedule(config, frames=10**12)
    args = SimpleNamespace(config=None, backend=None, mode=None, compare=False, frames=10**12, out=None,
                           no_report=False)
    assert run_command(args) == 2  # a usage error, not a MemoryError traceback
    err = capsys.readouterr().err
    assert "--frames: expected at most 1000000 frames" in err and "nothing was moved" in err


# --- the rig without a valve board ------------------------------------------------------------


def test_a_camera_only_rig_loads_and_valves_default_to_the_arms_channels(tmp_path):
    camera_only = write(tmp_path, 'backend = "rig"\n' + RIG.split("[rig.valves]")[0])
    config = load_bench_config(camera_only)
    assert config.rig.valves is None and config.rig.camera.fps == 30
    config = load_bench_config(write(tmp_path, RIG))  # [rig.valves] with its port only
    assert dict(config.rig.valves.channels) == ARM_VALVE_CHANNELS
    assert list(config.rig.valves.channels) == ["s1_a", "s1_b", "s1_c", "s1_d", "s2_a", "s2_b", "s3"]


def test_a_run_on_a_rig_without_valves_says_so_before_opening_anything(tmp_path, capsys):
    path = write(tmp_path, 'backend = "rig"\n' + RIG.split("[rig.valves]")[0])
    args = SimpleNamespace(config=str(path), backend=None, mode=None, compare=False, frames=None,
                           out=str(tmp_path / "run"), no_report=False)
    assert run_command(args) == 2
    err = capsys.readouterr().err
    assert f"{path.resolve()} [rig.valves]: the rig backend drives the valve board" in err
    assert "calibration file not found" not in err  # refused before the calibration or camera was opened
    assert not (tmp_path / "run").exists()
