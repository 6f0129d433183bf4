"""``softarm run`` on the rig when something goes wrong mid-run (the valve-board emulator on a pty, a
side-by-side recording as the ZED; fixtures in ``conftest.py``): a valve link lost while no set-point
changes, a failed write, a device that fails to close, Ctrl-C before the first set-point and during
the report. Each stops the run cleanly, says why, and the valves' last command is the vent.
"""

import json
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import bench.factory
import bench.recording
from bench.devices import PressureDriver, Stop
from bench.recording import load_run
from bench.report import report_command
from bench.run import run_command
from estimator import CenterlineEstimator
from hardware.errors import DeviceError
from tests.bench.child import interrupt_child
from tests.bench.rigkit import rig_config, run_args
from tests.fakes import FakeStereoCamera, FakeValveBank

REPO = Path(__file__).resolve().parents[2]


def test_a_valve_link_lost_while_holding_a_step_stops_the_run_and_reports(rig_folder, board, set_commands, capsys):
    """The reported case: a step to 1.5 bar, then the cable is pulled while the pressure holds (no SET
    to notice it): the run must stop at the next frame, say why, keep its frames and write its report."""
    out = rig_folder / "run"
    config = rig_config(rig_folder, board.port, kind="step", max_bar=1.5, step_bar=0.5, duration_s=3.0, frames=30,
                        experiment_extra="step_at_s = 0.2", extra="video = false")
    pressurised = threading.Event()

    def pull_the_cable():
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not board.setpoints_bar[0] > 1.0:
            time.sleep(0.01)
        if board.setpoints_bar[0] > 1.0:
            pressurised.set()
            board.cut_link()

    cutter = threading.Thread(target=pull_the_cable, daemon=True)
    cutter.start()
    code = run_command(run_args(config, out))
    cutter.join(timeout=60)
    err = capsys.readouterr().err
    assert pressurised.is_set(), "the run never stepped up to 1.5 bar"
    assert code == 1, err
    assert "nothing was moved" not in err
    assert "valve fault: LinkLostError" in err and "frames so far are kept" in err
    assert board.watchdog_trips == 1  # the board vented by itself once the host went silent
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    assert max(s[0] for s in set_commands) == 1500
    run = load_run(out)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stopped"].startswith("valve fault: LinkLostError") and "did not answer" in summary["stopped"]
    assert 1 <= len(run.frames) < 30 and summary["frames"] == len(run.frames)
    assert (out / "report" / "summary.md").is_file()  # the frames so far are reported


def test_a_failed_write_stops_the_pressure_thread_before_the_valves_are_vented(rig_folder, board, set_commands,
                                                                               vent_marks, monkeypatch, capsys):
    submits = {"n": 0}
    original_submit = bench.recording.RunWriter.submit

    def disk_full(self, *args, **kwargs):
        submits["n"] += 1
        if submits["n"] == 2:
            raise OSError(28, "No space left on device")
        return original_submit(self, *args, **kwargs)

    monkeypatch.setattr(bench.recording.RunWriter, "submit", disk_full)
    alive_at_close: list[list[str]] = []
    original_close = bench.factory.Devices.close

    def close(self):
        alive_at_close.append([t.name for t in threading.enumerate() if t.name == "pressure-driver" and t.is_alive()])
        original_close(self)

    monkeypatch.setattr(bench.factory.Devices, "close", close)
    out = rig_folder / "run"
    # a set-point every 24 ms, so the pressure thread is always about to send one
    config = rig_config(rig_folder, board.port, max_bar=1.0, step_bar=0.02, duration_s=1.2, frames=6)
    code = run_command(run_args(config, out, no_report=True))
    err = capsys.readouterr().err
    assert code == 1, err
    assert alive_at_close == [[]]  # the pressure thread was joined before the devices were closed
    assert len(set_commands) >= 2 and vent_marks[-1] == len(set_commands)  # no SET after the final VENT
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    assert "No space left on device" in json.loads((out / "summary.json").read_text())["stopped"]
    assert "nothing was moved" not in err


def test_an_error_while_closing_the_devices_is_recorded_not_misreported(rig_folder, board, monkeypatch, capsys):
    original_close = bench.factory.Devices.close

    def close_then_fail(self):
        original_close(self)
        raise DeviceError("the board did not confirm the vent")

    monkeypatch.setattr(bench.factory.Devices, "close", close_then_fail)
    out = rig_folder / "run"
    code = run_command(run_args(rig_config(rig_folder, board.port), out, no_report=True))
    err = capsys.readouterr().err
    assert code == 1, err
    assert "nothing was moved" not in err
    assert "closing the devices failed: DeviceError: the board did not confirm the vent" in err
    run = load_run(out)
    assert run.complete and run.frames
    assert run.summary["stopped"] == "closing the devices failed: DeviceError: the board did not confirm the vent"


def test_ctrl_c_during_warm_up_moves_nothing_and_the_folder_already_loads(rig_folder, board, set_commands,
                                                                          monkeypatch, capsys):
    """While the estimators warm up, the run folder must already load (what a SIGKILL would leave), and a
    Ctrl-C then must keep every set-point off the wire."""
    out = rig_folder / "run"
    during: dict = {}
    original_warm_up = CenterlineEstimator.warm_up

    def warm_up(self):
        if not during:
            run = load_run(out)  # raises if config.json or frames.jsonl is missing
            during.update(frames=len(run.frames), backend=run.backend, size=run.calibration.image_size,
                          report=report_command(type("Args", (), {"run_dir": str(out)})()))
            signal.raise_signal(signal.SIGINT)  # Ctrl-C, through whatever handlers the run installed
        original_warm_up(self)

    monkeypatch.setattr(CenterlineEstimator, "warm_up", warm_up)
    code = run_command(run_args(rig_config(rig_folder, board.port), out))
    captured = capsys.readouterr()
    assert during == {"frames": 0, "backend": "rig", "size": (320, 240), "report": 0}
    assert code == 130, captured.err
    assert set_commands == [] and "SET" not in board.commands  # not even the start pressure
    assert board.events[-1].kind == "vent"
    assert "nothing was moved" in captured.err and "report skipped" in captured.out
    run = load_run(out)
    assert run.complete and run.frames == [] and run.summary["stopped"] == "interrupted by SIGINT"


REPORT_CHILD = """
import sys, time
from pathlib import Path
import bench.report

def slow_report(run_dir, progress=False, options=None):
    Path(sys.argv[1]).touch()  # the report has started
    for _ in range(400):  # 20 s unless interrupted
        time.sleep(0.05)
    return Path(run_dir) / "report"

bench.report.write_report = slow_report
from bench.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.parametrize(("signum", "name"), [(signal.SIGINT, "Ctrl-C"), (signal.SIGTERM, "SIGTERM")])
def test_a_signal_during_the_report_stops_only_the_report(rig_folder, board, tmp_path, signum, name):
    """SIGTERM as Ctrl-C: it ended the process without a word, an empty report/ left behind (reported)."""
    out = rig_folder / "run"
    started = tmp_path / "report-started"
    config = rig_config(rig_folder, board.port)
    code, stdout, stderr = interrupt_child(["-c", REPORT_CHILD, str(started), "run", "--config", str(config),
                                            "--out", str(out)], started.exists, signum, timeout_s=60)
    assert code == 128 + signum, stderr
    assert f"report stopped by {name}; the run folder is complete" in stderr and f"softarm report {out}" in stderr
    assert "stopping: venting the valves" not in stderr  # the run's handler was gone: the run had ended
    run = load_run(out)
    assert run.complete and run.summary["stopped"] is None and len(run.frames) >= 1
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))


class _HeldValves(FakeValveBank):
    """Valves whose non-zero set-points hang on the wire until ``release`` is set (a slow link)."""

    def __init__(self) -> None:
        super().__init__()
        self.entered, self.release = threading.Event(), threading.Event()
        self.applying = False

    def _apply(self, setpoints_bar) -> None:
        if np.any(setpoints_bar):
            self.applying = True
            self.entered.set()
            self.release.wait(10)
        super()._apply(setpoints_bar)
        self.applying = False


class _DueNow:
    """A schedule whose every pressure step is already due."""

    change_times_s = [0.0, 0.0, 0.0]

    def command(self, k: int) -> dict[str, float]:
        return {"s1_a": 0.5 * k}


def test_a_set_point_under_way_when_the_run_stops_still_comes_before_the_vent(monkeypatch):
    """The pressure thread may outlive its join (a set-point hanging on a slow link); finish() must
    still not return before that set-point is done, so the vent that follows is the last command."""
    monkeypatch.setattr(PressureDriver, "JOIN_TIMEOUT_S", 0.05)
    valves = _HeldValves()
    valves.connect()
    stop = Stop()
    driver = PressureDriver(valves, _DueNow(), time.monotonic(), stop)
    driver.start()
    assert valves.entered.wait(10), "the pressure thread sent nothing"
    threading.Timer(0.3, valves.release.set).start()  # longer than the join waits
    driver.finish()
    assert not valves.applying  # finish() waited for the set-point under way
    stop.close_devices(bench.factory.Devices(FakeStereoCamera(), valves))
    driver.join(timeout=10)
    assert not driver.is_alive()
    assert [h.tolist()[0] for h in valves.history] == [0.5, 0.0]  # one step, then the vent; the second step never
