"""``softarm run`` on the rig backend against fake devices: a side-by-side video as the ZED, the valve
board emulator on a pty, depth maps from a folder (fixtures in ``conftest.py``). The valves must see
the commanded ramp and be vented at the end; bad input fails before anything moves; Ctrl-C and
SIGTERM vent and finish the files.
"""

import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from bench.recording import load_run
from bench.run import run_command
from estimator import CenterlineEstimator, EstimatorConfig
from tests.bench.child import interrupt_child
from tests.bench.rigkit import HEIGHT, WIDTH, arm_polyline_m, draw_pair, rig_config, run_args
from tests.fakes import small_calibration

REPO = Path(__file__).resolve().parents[2]
RAMP_BAR = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5]


def expected_sets(levels_bar) -> list[list[int]]:
    """SET frames of a ramp on s1_a (board channel 0), s2_a (4) and s3 (6), millibar."""
    return [[round(1000 * b) if ch in (0, 4, 6) else 0 for ch in range(7)] for b in levels_bar]


def test_rig_run_drives_the_commanded_ramp_and_vents(rig_folder, board, set_commands, capsys):
    out = rig_folder / "run"
    assert run_command(run_args(rig_config(rig_folder, board.port), out)) == 0
    # the valves saw exactly the ramp, each level once and in order, and were vented at the end
    assert set_commands == expected_sets(RAMP_BAR)
    assert board.events[-1].kind == "vent" and board.events[-1].cause == "VENT command"
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    assert board.watchdog_trips == 0
    run = load_run(out)
    assert run.complete and run.backend == "rig" and not run.has_ground_truth
    assert run.skipped == [] and run.summary_note is None  # every line a valid record; summary.json agrees
    assert len(run.frames) + run.summary["dropped_frames"] == 6
    commanded = [f.commanded_bar["s1_a"] for f in run.frames]
    assert commanded == sorted(commanded) and all(c in RAMP_BAR for c in commanded)
    assert all(f.commanded_bar["s1_b"] == 0 and f.chamber_bar is None for f in run.frames)
    # no ground truth: nothing scored against it; the depth folder gives the paper's Q'
    assert all(f.main.errors is None and f.gt_m is None for f in run.frames)
    valid = [f for f in run.frames if f.main.valid]
    assert valid, [f.main.reason for f in run.frames]
    assert all(f.main.qprime["count"] > 0 for f in valid)
    assert run.summary["qprime_rmse_xyz_mm"][2] < 30.0  # the drawn depth is the axis depth
    assert "depth maps from" in run.summary["depth_source"] and run.summary["ground_truth"] is False
    printed = capsys.readouterr().out
    assert "no ground truth on the rig" in printed and "Depth source: depth maps from" in printed
    report = out / "report"
    for name in ("summary.md", "fig12_axis_error.png", "fig13_fps.png", "fig10ab_overlay.png", "overlay.mp4"):
        assert (report / name).stat().st_size > 500, name
    assert "backend: **rig**" in (report / "summary.md").read_text()


def test_a_failing_estimate_is_recorded_and_the_run_goes_on(rig_folder, board, monkeypatch):
    calls = {"n": 0, "warming": False}
    original, original_warm_up = CenterlineEstimator.estimate, CenterlineEstimator.warm_up

    def flaky(self, left, right):
        if calls["warming"]:  # the warm-up before the run's clock starts is not a frame
            return original(self, left, right)
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("boom")
        return original(self, left, right)

    def warm_up(self):
        calls["warming"] = True
        try:
            original_warm_up(self)
        finally:
            calls["warming"] = False

    monkeypatch.setattr(CenterlineEstimator, "estimate", flaky)
    monkeypatch.setattr(CenterlineEstimator, "warm_up", warm_up)
    out = rig_folder / "run"
    assert run_command(run_args(rig_config(rig_folder, board.port), out, no_report=True)) == 0
    run = load_run(out)
    assert len(run.frames) >= 3 and calls["n"] == len(run.frames)
    assert run.frames[1].main.valid is False and run.frames[1].main.reason == "estimator error: RuntimeError: boom"
    # The error reset the warm start: the frame after it (the recording repeats one pair) is estimated as
    # the first frame was, cold.
    first, after = run.frames[0].main, run.frames[2].main
    assert first.valid and (after.valid, after.reason) == (first.valid, first.reason)
    np.testing.assert_allclose(after.points_m, first.points_m, atol=1e-6)
    assert run.summary["invalid_reasons"]["estimator error: RuntimeError: boom"] == 1


# The recording's pair (320x240, a 9 px wide tube, no mount) was invalid warm ("the base is hidden") until the
# chords a ragged mask calls unclean were measured from the image (2026-12-02). Drawn with round caps its ends
# came out 19-21 mm off, and are refused since a tip that misses its outline is (2026-12-03); rendered with the
# flat ends the estimator models, they are within 3 mm, warm and cold alike.
def test_a_repeated_pair_is_estimated_warm_as_it_was_cold():
    calibration = small_calibration(WIDTH, HEIGHT)
    left, right, _ = draw_pair(calibration, arm_polyline_m())
    estimator = CenterlineEstimator(calibration, EstimatorConfig(mode="default", base_mount=True))  # as the rig's
    results = [estimator.estimate(left, right) for _ in range(3)]
    assert all(r.valid for r in results), [r.reason for r in results]


def test_the_end_of_a_recording_stops_the_run_cleanly(rig_folder, board, capsys):
    out = rig_folder / "run"
    config = rig_config(rig_folder, board.port, duration_s=6.0, frames=30, loop="false")
    assert run_command(run_args(config, out, no_report=True)) == 1
    run = load_run(out)
    assert run.complete and len(run.frames) == 12  # the recording's 12 frames, then it ended
    assert run.summary["stopped"].startswith("the camera's recording ended")
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    assert "the 12 frames so far are kept" in capsys.readouterr().err


def test_a_missing_calibration_fails_before_anything_moves(rig_folder, board, capsys):
    out = rig_folder / "run"
    assert run_command(run_args(rig_config(rig_folder, board.port, calibration="SN404.conf"), out)) == 1
    err = capsys.readouterr().err
    assert "SN404.conf: calibration file not found" in err and "nothing was moved" in err
    assert board.frames_received == 0 and not out.exists()


@pytest.mark.parametrize(("edits", "message"), [
    ({"max_bar": 2.5, "valves_max": 2.0}, r"\[experiment\] max_bar: 2.5 bar exceeds the valves' limit of 2 bar"),
    ({"channels": '["s1_a", "s4"]'}, r"\[experiment\] channels: s4 not among the valves"),
])
def test_a_schedule_the_valves_cannot_take_fails_before_anything_moves(rig_folder, board, capsys, edits, message):
    out = rig_folder / "run"
    path = rig_config(rig_folder, board.port, **edits)
    assert run_command(run_args(path, out)) == 2
    assert f"{path}: " + message.replace("\\", "") in capsys.readouterr().err  # the file, the key, the value
    assert "SET" not in board.commands and board.commands.get("VENT", 0) >= 2  # connected, vented, closed
    assert not out.exists()


def test_an_out_folder_that_takes_no_file_fails_before_the_devices_open(rig_folder, board, capsys):
    """The reported case: --out /proc/x warned "may fill the disk (0 B free)" before saying the folder
    cannot be written; now the folder is checked first and the board never hears from the run."""
    assert run_command(run_args(rig_config(rig_folder, board.port), Path("/proc/softarm-run-test"))) == 2
    err = capsys.readouterr().err
    assert "--out /proc/softarm-run-test: cannot be written" in err and "nothing was moved" in err
    assert "fill the disk" not in err and board.frames_received == 0 and not board.commands


def test_a_board_that_does_not_fit_the_config_names_the_file_and_section(rig_folder, board, capsys):
    """Reported: "max_pressure_bar 3.0 exceeds the limit of the valve board ...; lower it in the config"
    said neither which config nor where in it."""
    path = rig_config(rig_folder, board.port, valves_max=3.0)
    assert run_command(run_args(path, rig_folder / "run")) == 1
    err = capsys.readouterr().err
    assert f"{path} [rig.valves]: max_pressure_bar 3.0 exceeds the limit of the valve board" in err
    assert "nothing was moved" in err and "SET" not in board.commands


def test_bad_config_names_file_and_key(rig_folder, board, capsys):
    path = rig_config(rig_folder, board.port, extra="colour = \"red\"\n")
    assert run_command(run_args(path, rig_folder / "run")) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "unknown key [report] colour" in err
    assert board.frames_received == 0


CHILD = """
import sys
from bench.cli import main
code = main(sys.argv[1:])
print("HEAVY", sorted(m for m in sys.modules if m.split(".")[0] in ("mujoco", "pyrender", "twin", "OpenGL")))
sys.exit(code)
"""


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_vents_closes_and_finishes_the_files(rig_folder, board, set_commands, signum):
    out = rig_folder / "run"
    config = rig_config(rig_folder, board.port, duration_s=12.0, frames=120, max_bar=2.5, step_bar=0.5)
    def pressurised():
        return any(s[0] > 0 for s in set_commands) and board.setpoints_bar.any()

    code, stdout, stderr = interrupt_child(["-c", CHILD, "run", "--config", str(config), "--out", str(out)],
                                           pressurised, signum)
    assert code == {signal.SIGINT: 130, signal.SIGTERM: 143}[signum], stderr
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    assert board.events[-1].kind == "vent"
    name = signal.Signals(signum).name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stopped"] == f"interrupted by {name}"
    run = load_run(out)
    assert run.complete and 1 <= len(run.frames) < 120 and run.skipped_lines == 0
    assert all(Path(out / f.images["left"]).is_file() for f in run.frames)
    assert f"{name}: stopping" in stderr and "report skipped" in stdout
    assert "HEAVY []" in stdout  # a rig run never loads MuJoCo, pyrender or the twin
    assert not os.path.exists(out / "report")


def test_a_run_needing_more_than_2_gb_states_its_size_and_asks_for_yes(rig_folder, board, capsys):
    """`--frames 100000` used to start a run of hundreds of GB without a word."""
    out = rig_folder / "run"
    config = rig_config(rig_folder, board.port, duration_s=200.0)
    assert run_command(run_args(config, out, frames=100000)) == 2
    captured = capsys.readouterr()
    # two 320x240 eyes as lossless PNG (0.39 bytes per byte, measured) and a 10 kB record: 189.7 kB a frame
    assert "expected disk use about 19.0 GB (100000 frames x 189.7 kB)" in captured.out
    assert "this run would write about 19.0 GB (100000 frames x 189.7 kB), more than 2.0 GB" in captured.err
    assert "run it again with --yes" in captured.err and "nothing was moved" in captured.err
    assert "SET" not in board.commands and not out.exists()


def test_yes_lets_a_large_run_go_ahead(tmp_path, capsys):
    from bench.config import load_bench_config
    from bench.experiments import make_schedule
    from bench.recording import frame_bytes
    from bench.run import RunOptions, check_disk

    config = load_bench_config()
    # the twin's frames: two noise-free eyes (0.014 bytes a pixel, measured), depth (0.012) and a 10 kB record
    per_frame = frame_bytes(config.recording, (1280, 720), depth=True, compare=False, noise_free=True)
    schedule = make_schedule(config.experiment, frames=100000)
    with pytest.raises(ValueError, match=r"this run would write about 4.7 GB .* run it again with --yes"):
        check_disk(config, RunOptions(out=tmp_path / "run"), schedule, per_frame)
    check_disk(config, RunOptions(out=tmp_path / "run", yes=True), schedule, per_frame)
    assert "expected disk use about 4.7 GB (100000 frames x 46.9 kB)" in capsys.readouterr().out
    small = make_schedule(config.experiment)  # the default run, 690 frames: no question asked
    check_disk(config, RunOptions(out=tmp_path / "run"), small, per_frame)
    assert "expected disk use about 32.3 MB (690 frames x 46.9 kB)" in capsys.readouterr().out
