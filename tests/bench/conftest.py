"""Fixtures of the rig-backend tests: a recorded session to replay as the ZED, and the valve-board
emulator on a pty with spies on the SET frames it accepts and the VENTs it receives."""

import cv2
import numpy as np
import pytest

from hardware.emulator import BoardEmulator, BoardStateMachine
from tests.bench.rigkit import HEIGHT, WIDTH, arm_polyline_m, draw_pair
from tests.fakes import small_calibration, write_side_by_side_video


@pytest.fixture
def rig_folder(tmp_path):
    """Calibration, a 12-frame side-by-side recording of an arm and its left depth maps (mm)."""
    folder = tmp_path / "rig"
    folder.mkdir()
    calibration = small_calibration(WIDTH, HEIGHT)
    calibration.save(folder / "calib.toml")
    left, right, depth = draw_pair(calibration, arm_polyline_m())
    write_side_by_side_video(folder / "session.mkv", [np.hstack([left, right])] * 12)
    (folder / "depth").mkdir()
    for i in range(12):
        cv2.imwrite(str(folder / "depth" / f"depth_{i:04d}.png"), depth)
    return folder


@pytest.fixture
def set_commands(monkeypatch):
    """Every SET frame the emulated board accepts, as millibar per board channel (a spy on the firmware)."""
    seen: list[list[int]] = []
    original = BoardStateMachine._on_set

    def spy(self, seq, args, now):
        reply = original(self, seq, args, now)
        if not self.estop:
            seen.append([int(a) for a in args])
        return reply

    monkeypatch.setattr(BoardStateMachine, "_on_set", spy)
    return seen


@pytest.fixture
def vent_marks(monkeypatch, set_commands):
    """For every VENT command the emulated board receives: how many SETs it had accepted before it."""
    seen: list[int] = []
    original = BoardStateMachine._on_vent

    def spy(self, seq, args, now):
        seen.append(len(set_commands))
        return original(self, seq, args, now)

    monkeypatch.setattr(BoardStateMachine, "_on_vent", spy)
    return seen


@pytest.fixture
def board(set_commands, vent_marks):
    # the spies patch the state machine's class before the emulator binds its handlers
    with BoardEmulator(channels=7, max_pressure_bar=2.5) as emulator:
        yield emulator
