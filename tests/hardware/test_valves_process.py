"""Venting when the process ends (SIGTERM, SIGINT, exit without close) or stalls, in a real child process.

The emulated board lives in this process; a child drives it through SerialValveBank, so the
test sees what the valves saw. Each vent must come from the host's VENT, not from the board's
watchdog (which would vent 250 ms later anyway and hide a missing host-side vent).
"""

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hardware.emulator import BoardEmulator
from tests.hardware.polling import wait_until

REPO = Path(__file__).resolve().parents[2]

CHILD = """
import sys, time
from hardware.errors import LinkLostError
from hardware.valves import SerialValveBank

port, mode = sys.argv[1], sys.argv[2]
bank = SerialValveBank(port, ["a", "b"], max_pressure_bar=2.5)
bank.connect()
bank.set_pressures([1.0, 2.0])
print("ready", flush=True)
if mode == "exit":
    sys.stdin.readline()  # wait until the parent has seen the set-points
    sys.exit(0)  # no close(): the atexit hook must vent
if mode == "stall":
    sys.stdin.readline()  # the parent stops us (SIGSTOP) before this returns
    try:
        bank.set_pressures([1.0, 1.0])
    except LinkLostError as e:
        print("LinkLostError:", e, flush=True)
        sys.exit(0)
    print("no error", flush=True)
    sys.exit(1)
time.sleep(30)
"""


def start_child(port: str, mode: str) -> subprocess.Popen:
    child = subprocess.Popen([sys.executable, "-c", CHILD, port, mode], cwd=REPO, stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = child.stdout.readline()
    if line.strip() != "ready":
        child.kill()
        raise AssertionError(f"child did not start: {line!r} {child.stderr.read()}")
    return child


def wait_for_vent(board: BoardEmulator) -> None:
    wait_until(lambda: not np.any(board.setpoints_bar))


@pytest.mark.parametrize(("mode", "signum"), [("sleep", signal.SIGTERM), ("sleep", signal.SIGINT), ("exit", None)])
def test_the_process_vents_on_its_way_out(mode, signum):
    with BoardEmulator(channels=2) as board:
        child = start_child(board.port, mode)
        try:
            np.testing.assert_allclose(board.setpoints_bar, [1.0, 2.0], atol=board.lsb_bar)
            if signum is not None:
                child.send_signal(signum)
            else:
                child.stdin.write("exit now\n")
                child.stdin.flush()
            child.wait(timeout=10)
        finally:
            child.kill()
            child.communicate()
        wait_for_vent(board)
        np.testing.assert_array_equal(board.setpoints_bar, [0.0, 0.0])
        assert board.events[-1].cause == "VENT command" and board.watchdog_trips == 0
    if signum == signal.SIGTERM:
        assert child.returncode == -signal.SIGTERM  # the default action still ends the process
    elif mode == "exit":
        assert child.returncode == 0


def test_a_stalled_host_is_vented_by_the_watchdog_and_then_told():
    with BoardEmulator(channels=2) as board:
        child = start_child(board.port, "stall")
        try:
            child.send_signal(signal.SIGSTOP)
            wait_until(lambda: board.watchdog_trips)  # the stopped host sends nothing; the watchdog must vent
            np.testing.assert_array_equal(board.setpoints_bar, [0.0, 0.0])
            assert board.events[-1].cause == "watchdog"
            child.send_signal(signal.SIGCONT)
            out, err = child.communicate("go\n", timeout=10)
        finally:
            child.kill()
        assert child.returncode == 0, out + err
        assert "LinkLostError:" in out and "watchdog vented every valve" in out
