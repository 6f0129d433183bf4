"""Runs that end early on the twin: killed with SIGKILL (every frame but possibly the last is kept and
``softarm report`` works on it), and stopped by a twin instability (clean stop, frames kept, vented)."""

import json
import signal
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

import bench.factory
from bench.config import DEFAULT_CONFIG, load_bench_config
from bench.recording import load_run
from bench.report import write_report
from bench.run import RunOptions, run_experiment
from tests.bench.child import frames_written, interrupt_child


def short_config(folder: Path, frames: int, duration_s: float) -> Path:
    """The twin with a short ramp (so frames come quickly), report options small."""
    path = folder / "bench.toml"
    path.write_text(textwrap.dedent(f"""\
        backend = "sim"
        [sim]
        twin = "{DEFAULT_CONFIG.parent / 'twin.toml'}"
        [experiment]
        max_bar = 1.0
        step_bar = 0.1
        duration_s = {duration_s}
        frames = {frames}
        [report]
        selected_frames = 3
        compensation_frames = 2
        video_scale = 0.25
        """))
    return path


def test_a_killed_run_keeps_its_frames_and_reports(tmp_path):
    out = tmp_path / "run"
    config = short_config(tmp_path, frames=200, duration_s=20.0)
    code, _, _ = interrupt_child(["-m", "bench.cli", "run", "--config", str(config), "--out", str(out)],
                                 lambda: frames_written(out) >= 4, signal.SIGKILL)
    assert code == -signal.SIGKILL
    run = load_run(out)
    assert not run.complete and run.summary["stopped"] == "killed (no summary.json)"
    assert len(run.frames) >= 4 and run.skipped_lines <= 1
    assert [f.index for f in run.frames] == list(range(len(run.frames)))  # none missing but the last
    for f in run.frames:  # a line in frames.jsonl means its images are on disk
        assert run.image(f, "left") is not None and run.image(f, "right") is not None and run.depth(f) is not None
    assert run.summary["frames"] == len(run.frames)
    assert not list((out / "frames").glob("*.png.tmp*"))
    report = write_report(out)
    text = (report / "summary.md").read_text()
    assert "the run was killed" in text
    for name in ("fig12_axis_error.png", "fig13_fps.png", "fig10c_centerlines_3d.png", "overlay.mp4"):
        assert (report / name).stat().st_size > 500, name


def test_a_twin_instability_stops_the_run_cleanly(tmp_path, monkeypatch):
    from twin.physics import SimulationError
    from twin.twin import Twin

    opened = []
    original_make = bench.factory.make_devices
    def make_and_keep(config):
        opened.append(original_make(config))
        return opened[-1]

    monkeypatch.setattr(bench.factory, "make_devices", make_and_keep)
    calls = {"n": 0}
    original_advance = Twin.advance

    def unstable(self, duration_s):
        calls["n"] += 1
        if calls["n"] == 12:
            raise SimulationError("simulation failed at step 1234 (t = 2.4680 s, timestep 0.002 s): qpos[3] is nan",
                                  1234, 2.468)
        return original_advance(self, duration_s)

    monkeypatch.setattr(Twin, "advance", unstable)
    config = load_bench_config(short_config(tmp_path, frames=8, duration_s=4.0))
    outcome = run_experiment(config, RunOptions(out=tmp_path / "run", progress=False))
    assert outcome.exit_code == 1
    assert outcome.stopped.startswith("twin instability: simulation failed at step 1234")
    run = load_run(tmp_path / "run")
    assert run.complete and run.summary["stopped"] == outcome.stopped
    assert 1 <= len(run.frames) < 8 and run.summary["frames"] == len(run.frames)
    devices = opened[-1]
    assert not devices.camera.is_connected and not devices.valves.is_connected
    np.testing.assert_array_equal(list(devices.valves.setpoints_bar.values()), np.zeros(7))
    assert (tmp_path / "run" / "report" / "summary.md").is_file()  # the frames so far are reported


def test_ctrl_c_on_the_twin_stops_and_finishes_the_files(tmp_path):
    out = tmp_path / "run"
    config = short_config(tmp_path, frames=200, duration_s=20.0)
    code, stdout, stderr = interrupt_child(["-m", "bench.cli", "run", "--config", str(config), "--out", str(out)],
                                           lambda: frames_written(out) >= 3)
    assert code == 130, stderr
    run = load_run(out)
    assert run.complete and run.summary["stopped"] == "interrupted by SIGINT"
    assert 3 <= len(run.frames) < 200 and run.skipped_lines == 0
    assert [f.index for f in run.frames] == list(range(len(run.frames)))
    assert "SIGINT: stopping" in stderr and "report skipped" in stdout


# Prints, after the run, what the valves were left at (the run closes them: vented, disconnected).
VALVES_CHILD = """
import json, sys
import bench.factory
opened = []
original = bench.factory.make_devices

def keep(config):
    opened.append(original(config))
    return opened[-1]

bench.factory.make_devices = keep
from bench.cli import main
code = main(sys.argv[1:])
valves = opened[-1].valves
print("VALVES " + json.dumps({"setpoints_bar": list(valves.setpoints_bar.values()), "connected": valves.is_connected}))
sys.exit(code)
"""


def long_step_config(folder: Path, duration_s: float) -> Path:
    """A step to 1.5 bar on s2_a, then one capture at the start and one at the very end of ``duration_s``."""
    path = folder / "bench.toml"
    path.write_text(textwrap.dedent(f"""\
        [sim]
        twin = "{DEFAULT_CONFIG.parent / 'twin.toml'}"
        [experiment]
        kind = "step"
        channels = ["s2_a"]
        max_bar = 1.5
        step_at_s = 1.0
        duration_s = {duration_s}
        frames = 2
        [recording]
        lossless_frames = false
        depth = false
        """))
    return path


@pytest.mark.parametrize(("signum", "duration_s"), [(signal.SIGINT, 600.0), (signal.SIGTERM, 86400.0)])
def test_a_signal_during_a_long_capture_interval_stops_the_twin_at_once(tmp_path, signum, duration_s):
    """The whole interval between the two captures is physics (600 s simulated: about half a minute of
    computing; 24 h: over an hour): the signal must end the run within a few seconds anyway, vent the
    valves, and the capture at the end of the interval must not be taken or recorded."""
    out = tmp_path / "run"
    config = long_step_config(tmp_path, duration_s)
    first_frame_at: list[float] = []

    def inside_the_interval() -> bool:
        """A second after the first frame: the step is commanded, the twin is deep in the long interval."""
        if not first_frame_at and frames_written(out) >= 1:
            first_frame_at.append(time.monotonic())
        return bool(first_frame_at) and time.monotonic() - first_frame_at[0] > 1.0

    timing: dict = {}
    code, stdout, stderr = interrupt_child(["-c", VALVES_CHILD, "run", "--config", str(config), "--out", str(out)],
                                           inside_the_interval, signum, timing=timing)
    name = signal.Signals(signum).name
    assert code == {signal.SIGINT: 130, signal.SIGTERM: 143}[signum], stderr
    assert timing["after_signal_s"] < 10.0, timing  # liveness: the interval's physics alone takes 30 s or more
    valves = json.loads(next(line for line in stdout.splitlines() if line.startswith("VALVES "))[len("VALVES "):])
    assert valves == {"setpoints_bar": [0.0] * 7, "connected": False}
    run = load_run(out)
    assert run.complete and run.summary["stopped"] == f"interrupted by {name}"
    assert [f.index for f in run.frames] == [0] and run.skipped_lines == 0
    assert f"{name}: stopping" in stderr and "report skipped" in stdout


def test_the_twin_is_advanced_in_slices_that_add_up_to_the_same_steps(monkeypatch):
    """The slicing is whole physics steps: the twin ends at the same step as one long advance would,
    and a stop request between two slices leaves the rest of the interval unsimulated."""
    from bench.devices import SIM_SLICE_S, Stop, advance_sliced

    class Sim:
        timestep_s = 0.002

    class CountingTwin:
        sim = Sim()

        def __init__(self):
            self.steps, self.calls = 0, []

        def advance(self, duration_s):
            n = round(duration_s / self.sim.timestep_s)
            self.calls.append(n)
            self.steps += n
            if len(self.calls) == 3 and stop_after_three:
                stop.request("test")

    stop_after_three = False
    twin, stop = CountingTwin(), Stop()
    assert advance_sliced(twin, 1.2345, stop)
    assert twin.steps == round(1.2345 / 0.002) and max(twin.calls) <= round(SIM_SLICE_S / 0.002)
    stop_after_three = True
    twin = CountingTwin()
    assert not advance_sliced(twin, 600.0, stop)
    assert len(twin.calls) == 3 and twin.steps == 3 * round(SIM_SLICE_S / 0.002)
