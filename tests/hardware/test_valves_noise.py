"""SerialValveBank and the emulated board fuzzed together: random noise between frames, both ways, over a pty.

The host's real code path runs (pyserial on the pty, the heartbeat thread, retries); hypothesis
chooses set-points, queries and bursts of noise. Noise toward the board is written on the pty
by a second writer, as a noisy cable would add it; noise toward the host is put in front of
the board's replies (``BoardEmulator.distort``). Invariants:

- no channel is ever driven above the host's limit;
- the link survives noise that leaves the frames intact, and every command is carried out once;
- a link that truly dies (cut, or noise that destroys every frame) is reported: the next call
  or ``check()`` raises ``LinkLostError``, and the board vents.
"""

import collections
import contextlib
import math
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hardware.emulator import BoardEmulator
from hardware.errors import DeviceError, LinkLostError
from hardware.protocol import LineSplitter
from hardware.valves import SerialValveBank
from tests.fakes import ARM_CHANNELS
from tests.hardware.polling import wait_until

LIMIT_BAR = 2.0  # the host's limit, under the board's own 2.5 bar

pressure = st.floats(0.0, LIMIT_BAR)
# Noise that ends with a line break lands between two frames: it is a line of its own.
noise = st.binary(min_size=1, max_size=80).map(lambda data: data + b"\n")
out_of_range = st.one_of(st.floats(LIMIT_BAR, 1e9, exclude_min=True), st.floats(max_value=-1e-6), st.just(math.nan))

step = st.one_of(
    st.tuples(st.just("set"), st.lists(pressure, min_size=len(ARM_CHANNELS), max_size=len(ARM_CHANNELS))),
    st.tuples(st.just("set by name"), st.dictionaries(st.sampled_from(ARM_CHANNELS), pressure, min_size=1)),
    st.tuples(st.just("refused set"), st.sampled_from(ARM_CHANNELS), out_of_range),
    st.tuples(st.just("noise to board"), noise),
    st.tuples(st.just("noise to host"), noise),
    st.tuples(st.just("status")),
)


class NoisyLine:
    """An emulated board with a second writer on its pty and a queue of noise to put before its replies."""

    def __init__(self, board: BoardEmulator) -> None:
        self.board = board
        self.to_host: collections.deque[bytes] = collections.deque()
        board.distort(to_host=lambda reply: (self.to_host.popleft() if self.to_host else b"") + reply)
        self.intruder = os.open(board.port, os.O_WRONLY | os.O_NOCTTY)
        self.lines_to_board = 0  # unreadable lines written toward the board

    def toward_board(self, data: bytes) -> None:
        os.write(self.intruder, data)
        self.lines_to_board += len(LineSplitter().feed(data))

    def close(self) -> None:
        os.close(self.intruder)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(steps=st.lists(step, min_size=1, max_size=20))
def test_noise_between_frames_never_breaks_the_link_nor_the_limit(steps):
    with BoardEmulator(channels=7, max_pressure_bar=2.5) as board:
        line = NoisyLine(board)
        # a generous timeout: intact frames are always answered, so no test waits for it
        bank = SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=LIMIT_BAR, reply_timeout_s=0.5)
        try:
            with bank:
                expected, sets = np.zeros(len(ARM_CHANNELS)), 0
                for kind, *args in steps:
                    if kind == "set":
                        bank.set_pressures(args[0])
                        expected, sets = np.array(args[0]), sets + 1
                    elif kind == "set by name":
                        bank.set_pressures(args[0])
                        for name, value in args[0].items():
                            expected[ARM_CHANNELS.index(name)] = value
                        sets += 1
                    elif kind == "refused set":
                        with pytest.raises(ValueError, match=f"channel {args[0]}"):
                            bank.set_pressures({args[0]: args[1]})
                    elif kind == "noise to board":
                        line.toward_board(args[0])
                    elif kind == "noise to host":
                        line.to_host.append(args[0])
                    else:
                        np.testing.assert_allclose(bank.status().setpoints_mbar, expected * 1000.0,
                                                   atol=board.lsb_bar * 500.0 + 1.0)  # DAC step, integer mbar
                    bank.check()
                    assert board.peak_setpoint_bar <= LIMIT_BAR + board.lsb_bar / 2
                np.testing.assert_allclose(board.setpoints_bar, expected, atol=board.lsb_bar)
                assert board.executed.get("SET", 0) == sets  # each command carried out once
                assert wait_until(lambda: board.unreadable_frames == line.lines_to_board)
                assert bank.status().unreadable_frames == line.lines_to_board
            assert not board.setpoints_bar.any() and board.watchdog_trips == 0
            assert board.peak_setpoint_bar <= LIMIT_BAR + board.lsb_bar / 2
        finally:
            line.close()


# Junk that, inserted before every line break, destroys every frame (a lone "\r" would not: it is ignored).
frame_destroying_junk = (st.binary(min_size=1, max_size=8).filter(lambda junk: junk.strip(b"\r\n") != b"")
                         .map(lambda junk: junk.replace(b"\n", b"")))
safe_step = st.one_of(
    st.tuples(st.just("set"), st.lists(pressure, min_size=len(ARM_CHANNELS), max_size=len(ARM_CHANNELS))),
    st.tuples(st.just("noise to board"), noise),
    st.tuples(st.just("noise to host"), noise),
)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(before=st.lists(safe_step, max_size=4), death=st.sampled_from(["cut", "destroy every frame"]),
       junk=frame_destroying_junk, noticed_by=st.sampled_from(["set", "check"]))
def test_a_link_that_dies_is_reported_and_the_board_vents(before, death, junk, noticed_by):
    with BoardEmulator(channels=7, max_pressure_bar=2.5) as board:
        line = NoisyLine(board)
        # short attempts (2 of 100 ms), so each death is noticed within a fraction of a second
        bank = SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=LIMIT_BAR, reply_timeout_s=0.1, retries=1)
        try:
            bank.connect()
            for kind, arg in before:
                if kind == "set":
                    bank.set_pressures(arg)
                elif kind == "noise to board":
                    line.toward_board(arg)
                else:
                    line.to_host.append(arg)
            bank.set_pressures([1.0] * len(ARM_CHANNELS))
            bank.check()
            if death == "cut":
                board.cut_link()
            else:
                board.distort(to_board=lambda data: data.replace(b"\n", junk + b"\n"))
            if noticed_by == "set":
                with pytest.raises(LinkLostError):
                    bank.set_pressures([0.5] * len(ARM_CHANNELS))
            else:
                assert wait_until(lambda: bank.fault is not None), "the heartbeat never noticed the dead link"
                with pytest.raises(LinkLostError):
                    bank.check()
            with pytest.raises(LinkLostError):  # and it stays reported
                bank.check()
            # nothing intact reaches the board, not even the host's VENT: its watchdog vents
            assert wait_until(lambda: not board.setpoints_bar.any()), "the valves kept their pressure"
            assert board.watchdog_trips == 1
            assert board.peak_setpoint_bar <= LIMIT_BAR + board.lsb_bar / 2
        finally:
            with contextlib.suppress(DeviceError):
                bank.close()
            line.close()
