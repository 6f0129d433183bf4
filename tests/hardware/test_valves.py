"""SerialValveBank against the emulated board over a pty: set, read back, refuse, vent, fail loudly.

No test sleeps a fixed time or asserts on elapsed time: each waits for what the board or the
bank did (``wait_until``), so a loaded machine makes it slower, never wrong.
"""

import os
import re
import select
import threading
import tty

import numpy as np
import pytest
import serial

from hardware.emulator import BoardEmulator
from hardware.errors import (
    BoardReplyError,
    DeviceError,
    EStopError,
    LinkLostError,
    NotConnectedError,
    VentedBySignalError,
)
from hardware.protocol import Frame, LineSplitter, decode
from hardware.valves import SerialValveBank
from tests.fakes import ARM_CHANNELS
from tests.hardware.polling import wait_until

# Generous, so a loaded machine does not turn a slow reply into a lost link; the tests of the
# timeout itself (a board that does not answer) use the default of 50 ms.
REPLY_TIMEOUT_S = 0.5


@pytest.fixture
def board():
    with BoardEmulator(channels=7, max_pressure_bar=2.5) as emulator:
        yield emulator


@pytest.fixture
def bank(board):
    valves = SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.5, reply_timeout_s=REPLY_TIMEOUT_S)
    valves.connect()
    yield valves
    valves.close()


def test_set_by_name_and_in_order_and_read_back(board, bank):
    bank.set_pressures({"s1_a": 1.234, "s3": 2.5})
    expected = [1.234, 0, 0, 0, 0, 0, 2.5]
    np.testing.assert_allclose(board.setpoints_bar, expected, atol=board.lsb_bar / 2 + 1e-9)
    assert bank.status().setpoints_mbar == (1234, 0, 0, 0, 0, 0, 2500)
    assert bank.setpoints_bar["s1_a"] == 1.234
    bank.set_pressures([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7])
    np.testing.assert_allclose(board.setpoints_bar, [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7], atol=board.lsb_bar / 2)


def test_channel_map_routes_names_to_board_channels():
    with BoardEmulator(channels=5) as board, \
            SerialValveBank(board.port, {"tip": 3, "base": 0}, max_pressure_bar=2.0,
                            reply_timeout_s=REPLY_TIMEOUT_S) as bank:
        bank.set_pressures({"tip": 1.5})
        np.testing.assert_allclose(board.setpoints_bar, [0, 0, 0, 1.5, 0], atol=board.lsb_bar)
        assert bank.board_channels == {"tip": 3, "base": 0}


@pytest.mark.parametrize("value", [2.6, -0.1, float("nan")])
def test_out_of_range_set_points_never_reach_the_wire(board, bank, value):
    bank.set_pressures({"s1_a": 1.0})
    with pytest.raises(ValueError, match="channel s1_b"):
        bank.set_pressures({"s1_b": value})
    np.testing.assert_allclose(board.setpoints_bar[:2], [1.0, 0.0], atol=board.lsb_bar)


def test_clamping_bank_clamps_to_its_limit(board):
    # within the clamping tolerance (10 % of the 2 bar limit); 9 bar is refused (test_contracts.py)
    with SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.0, clamp=True,
                         reply_timeout_s=REPLY_TIMEOUT_S) as bank:
        bank.set_pressures({"s1_a": 2.15, "s1_b": -0.15})
        assert bank.setpoints_bar["s1_a"] == 2.0
        assert 2.0 - board.lsb_bar < board.setpoints_bar[0] <= 2.0 and board.setpoints_bar[1] == 0


def test_garbage_on_the_line_is_nakked_and_the_bank_carries_on(board, bank):
    bank.set_pressures({"s1_a": 1.0})
    naks = board.naks_sent
    intruder = serial.Serial(board.port, timeout=0.1)  # a second writer on the same port
    try:
        intruder.write(b"\x00\xff garbage \xfe\n$5 SET 9*0000\n")
        intruder.flush()
        wait_until(lambda: board.naks_sent >= naks + 2)
    finally:
        intruder.close()
    assert board.naks_sent == naks + 2
    bank.set_pressures({"s1_a": 2.0})
    assert bank.status().setpoints_mbar[0] == 2000


def test_heartbeats_hold_set_points_while_the_caller_is_idle(board, bank):
    bank.set_pressures({"s2_a": 1.5})
    beats = board.commands.get("HB", 0)
    # Five heartbeats, each sent after 80 ms of silence, span over 250 ms: without them the
    # watchdog would have vented first (the board handles frames in order, watchdog included).
    wait_until(lambda: board.commands.get("HB", 0) >= beats + 5 or board.watchdog_trips)
    assert board.commands.get("HB", 0) >= beats + 5
    assert board.watchdog_trips == 0
    bank.check()
    assert board.setpoints_bar[4] == pytest.approx(1.5, abs=board.lsb_bar)


def test_close_vents(board, bank):
    bank.set_pressures([1.0] * 7)
    bank.close()
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    assert board.events[-1].cause == "VENT command"
    assert not bank.is_connected
    bank.close()  # twice is harmless


def test_exception_in_the_with_block_vents_and_propagates(board):
    with pytest.raises(RuntimeError, match="experiment failed"), \
            SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.5, reply_timeout_s=REPLY_TIMEOUT_S) as bank:
        bank.set_pressures([1.0] * 7)
        raise RuntimeError("experiment failed")
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    assert board.events[-1].cause == "VENT command"


def test_lost_link_is_an_error_on_the_next_call_and_the_board_vents(board, bank):
    bank.set_pressures([1.0] * 7)
    board.cut_link()
    # heartbeats go unanswered; the board hears nothing and its watchdog vents
    wait_until(lambda: bank.fault is not None and board.watchdog_trips)
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    assert board.events[-1].cause == "watchdog"
    with pytest.raises(ConnectionError, match="did not answer HB") as error:
        bank.set_pressures([0.5] * 7)
    assert isinstance(error.value, LinkLostError)
    with pytest.raises(LinkLostError):  # and it stays an error
        bank.set_pressures([0.5] * 7)
    bank.close()  # already reported: closing does not raise again
    board.restore_link()
    bank.connect()  # a fresh connection works again
    bank.set_pressures([0.5] * 7)
    assert board.setpoints_bar[0] == pytest.approx(0.5, abs=board.lsb_bar)


def test_a_lost_link_noticed_only_by_the_heartbeat_is_raised_by_close(board, bank):
    bank.set_pressures([1.0] * 7)
    board.cut_link()
    assert wait_until(lambda: bank.fault is not None), "the heartbeat never noticed the cut link"
    with pytest.raises(LinkLostError, match="did not answer HB"):
        bank.close()
    assert not bank.is_connected


@pytest.mark.parametrize("then", ["set", "close", "with"])
def test_a_board_whose_end_of_the_link_is_gone_is_a_lost_link_naming_the_port(then):
    """The reported case: the emulator's pty closed under a connected bank, and the next call raised a raw
    termios.error (not an OSError, so not seen as a lost link), close() and a ``with`` block the same,
    while the heartbeat's record said "valves vented" although no VENT could be sent."""
    board = BoardEmulator()
    port = board.start_pty()
    bank = SerialValveBank(port, ARM_CHANNELS, max_pressure_bar=2.5)
    bank.connect()
    bank.set_pressures([1.0] * 7)
    board.stop()
    if then == "with":
        with pytest.raises(LinkLostError, match=re.escape(port)), bank:
            assert wait_until(lambda: bank.fault is not None), "the heartbeat never noticed"
            bank.set_pressures([0.5] * 7)
    elif then == "set":
        assert wait_until(lambda: bank.fault is not None), "the heartbeat never noticed"
        with pytest.raises(LinkLostError, match=f"{re.escape(port)}: serial I/O failed during HB.*link is lost"):
            bank.set_pressures([0.5] * 7)
        assert "valves vented" not in str(bank.fault)
        bank.close()  # reported already: closing releases the port without a raw error
    else:
        with pytest.raises(LinkLostError, match=re.escape(port)):  # the close noticed it, or the heartbeat did
            bank.close()
    assert not bank.is_connected


def test_a_board_that_does_not_answer_is_a_connection_error_with_a_hint():
    bank = SerialValveBank("loop://", ARM_CHANNELS, max_pressure_bar=2.5)  # hears only its own echo
    with pytest.raises(ConnectionError, match=r"did not answer VER \(3 attempts, 50 ms each\): check that the board"):
        bank.connect()
    assert not bank.is_connected


@pytest.fixture
def silent_board():
    """A pty whose far end never answers; returns (port, read_frames) where read_frames(until_verb)
    collects the frames the host wrote, up to and including the first ``until_verb``."""
    master, slave = os.openpty()
    tty.setraw(slave)
    splitter, frames = LineSplitter(), []

    def read_frames(until_verb: str) -> list[Frame]:
        def arrived():
            while select.select([master], [], [], 0)[0]:
                frames.extend(decode(line) for line in splitter.feed(os.read(master, 4096)))
            return any(f.verb == until_verb for f in frames)

        assert wait_until(arrived), f"the host never sent {until_verb}: {frames}"
        return list(frames)

    yield os.ttyname(slave), read_frames
    os.close(master)
    os.close(slave)


@pytest.mark.parametrize("retries", [0, 2, 5])
def test_a_silent_board_gets_one_attempt_plus_the_retries_then_a_vent(silent_board, retries):
    port, read_frames = silent_board
    bank = SerialValveBank(port, ARM_CHANNELS, max_pressure_bar=2.5, retries=retries)
    with pytest.raises(LinkLostError, match=rf"did not answer VER \({retries + 1} attempts, 50 ms each\)"):
        bank.connect()
    assert not bank.is_connected
    frames = read_frames("VENT")
    assert [f.verb for f in frames] == ["VER"] * (retries + 1) + ["VENT"]
    assert len({f.seq for f in frames[:-1]}) == 1  # a retry resends the identical frame


def test_a_port_that_cannot_be_opened_names_the_port():
    with pytest.raises(DeviceError, match=r"could not open valve port '/dev/no-such-valve-board'"):
        SerialValveBank("/dev/no-such-valve-board", ARM_CHANNELS, max_pressure_bar=2.5).connect()


def test_estop_refuses_set_points_until_cleared(board, bank):
    bank.set_pressures([1.0] * 7)
    board.press_estop()
    with pytest.raises(EStopError, match="e-stop is latched"):
        bank.set_pressures([1.0] * 7)
    assert bank.status().estop
    bank.clear_estop()
    bank.set_pressures([0.3] * 7)
    assert board.setpoints_bar[0] == pytest.approx(0.3, abs=board.lsb_bar)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"channels": ARM_CHANNELS, "max_pressure_bar": 3.0}, "exceeds the limit of the valve board"),
    ({"channels": {"a": 0, "b": 9}, "max_pressure_bar": 2.5},
     r"has 7 channels \(0 to 6\); the channel map puts b on 9"),
    ({"channels": ARM_CHANNELS, "max_pressure_bar": 2.5, "heartbeat_s": 0.2}, "too slow for the board"),
])
def test_connect_refuses_a_board_that_does_not_fit(board, kwargs, message):
    bank = SerialValveBank(board.port, reply_timeout_s=REPLY_TIMEOUT_S, **kwargs)
    with pytest.raises(DeviceError, match=message):
        bank.connect()
    assert not bank.is_connected


@pytest.mark.parametrize(("channels", "message"), [
    ({"a": 0, "b": 0}, "share a board channel"), ({"a": -1}, "non-negative"), (["a", "a"], "unique names"),
])
def test_bad_channel_maps_are_refused_at_construction(channels, message):
    with pytest.raises(ValueError, match=message):
        SerialValveBank("loop://", channels, max_pressure_bar=2.5)


# --- check(): faults recorded between commands ----------------------------------------------


def test_after_a_faulted_close_and_reconnect_unnamed_channels_stay_vented(board, bank):
    """A partial set-point after a reconnect must not bring back the pressures from before the fault."""
    bank.set_pressures([1.0] * 7)
    board.cut_link()
    assert wait_until(lambda: bank.fault is not None), "the heartbeat never noticed the cut link"
    with pytest.raises(LinkLostError):
        bank.close()  # the fault comes out of the vent; the set-points are forgotten all the same
    assert set(bank.setpoints_bar.values()) == {0.0}
    board.restore_link()
    bank.connect()
    bank.set_pressures({"s1_a": 0.5})
    assert wait_until(lambda: board.setpoints_bar[0] > 0)
    np.testing.assert_array_equal(board.setpoints_bar[1:], np.zeros(6))
    assert bank.setpoints_bar == {name: (0.5 if name == "s1_a" else 0.0) for name in ARM_CHANNELS}


def test_after_a_signal_vent_no_set_point_reaches_the_board_until_reconnect(board, bank):
    """A SET racing SIGINT (already past the caller's checks) must not re-pressurise vented valves."""
    bank.set_pressures([1.0] * 7)
    bank._emergency_vent()  # what the SIGINT/SIGTERM handler runs
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    sets = board.commands["SET"]
    with pytest.raises(VentedBySignalError, match="a signal vented the valves"):
        bank.set_pressures([0.5] * 7)
    assert board.commands["SET"] == sets and not board.setpoints_bar.any()
    bank.close()
    bank.connect()
    bank.set_pressures({"s1_a": 0.5})
    assert board.setpoints_bar[0] == pytest.approx(0.5, abs=board.lsb_bar)


def test_check_raises_a_link_lost_between_commands_until_reconnect(board, bank):
    bank.set_pressures([1.0] * 7)
    bank.check()
    board.cut_link()
    assert wait_until(lambda: bank.fault is not None), "the heartbeat never noticed the cut link"
    for _ in range(2):  # a fault stays until the bank reconnects
        with pytest.raises(LinkLostError, match="did not answer HB"):
            bank.check()
    bank.close()  # reported by check(): closing does not raise it again
    bank.check()  # a closed bank has nothing to report
    board.restore_link()
    bank.connect()
    bank.check()


def test_check_raises_a_watchdog_vent_between_commands(board):
    # Long reply timeouts: the heartbeat the cut link swallowed is resent once the link is back,
    # and the board's answer reports that its watchdog vented in between.
    with SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.5, reply_timeout_s=2.0, retries=3) as bank:
        bank.set_pressures([1.0] * 7)
        board.cut_link()
        assert wait_until(lambda: board.watchdog_trips), "the board's watchdog never vented"
        board.restore_link()
        assert wait_until(lambda: bank.fault is not None), "the heartbeat never reported the watchdog vent"
        with pytest.raises(LinkLostError, match="watchdog vented every valve"):
            bank.check()
        with pytest.raises(LinkLostError, match="watchdog vented every valve"):
            bank.set_pressures([1.0] * 7)
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))


def test_check_raises_an_estop_pressed_between_commands_until_cleared(board, bank):
    bank.set_pressures([1.0] * 7)
    board.press_estop()
    assert wait_until(lambda: bank.fault is not None), "the heartbeat never reported the e-stop"
    with pytest.raises(EStopError, match="e-stop is latched"):
        bank.check()
    bank.clear_estop()
    bank.check()
    bank.set_pressures([0.3] * 7)


# --- replies the host cannot read ------------------------------------------------------------

GARBLED_STATUS = {
    "short set-point list": ("estop=0", "wdt=0", "mbar=1,2"),
    "unreadable flag": ("estop=maybe", "wdt=0", "mbar=0,0,0,0,0,0,0"),
    "missing fields": ("hello",),
}


@pytest.mark.parametrize("args", GARBLED_STATUS.values(), ids=GARBLED_STATUS.keys())
def test_unreadable_heartbeat_replies_are_recorded_vented_and_raised_by_check(board, bank, args):
    bank.set_pressures([1.0] * 7)
    board.rewrite_replies(lambda command, reply: Frame(reply.seq, "ACK", args))
    assert wait_until(lambda: bank.fault is not None), "the heartbeat never reported the unreadable reply"
    received = re.escape(" ".join(("ACK", *args)))
    with pytest.raises(BoardReplyError, match=f"answered HB with '{received}'"):
        bank.check()
    assert wait_until(lambda: not np.any(board.setpoints_bar)), "the bank did not vent"
    assert board.events[-1].cause == "VENT command" and board.watchdog_trips == 0
    with pytest.raises(BoardReplyError):
        bank.set_pressures([1.0] * 7)
    board.rewrite_replies(None)
    bank.close()  # the vent is answered properly again
    bank.connect()  # and a fresh connection starts clean
    bank.check()
    bank.set_pressures([0.5] * 7)


def test_a_refused_heartbeat_is_recorded_not_just_logged(board, bank):
    bank.set_pressures([1.0] * 7)
    board.rewrite_replies(lambda command, reply: Frame(reply.seq, "NAK", ("VERB",)) if command.verb == "HB" else reply)
    assert wait_until(lambda: bank.fault is not None), "the refused heartbeat was never recorded"
    with pytest.raises(DeviceError, match=r"refused HB \(VERB\)"):
        bank.check()
    assert wait_until(lambda: not np.any(board.setpoints_bar)), "the bank did not vent"


def test_the_heartbeat_outlives_an_unreadable_reply(board, bank):
    bank.set_pressures([1.0] * 7)
    board.rewrite_replies(lambda command, reply: Frame(reply.seq, "ACK", ("hello",)))
    assert wait_until(lambda: bank.fault is not None)
    board.rewrite_replies(None)
    beats = board.commands.get("HB", 0)
    # Still beating: five more heartbeats arrive and the board's watchdog never fires.
    wait_until(lambda: board.commands.get("HB", 0) >= beats + 5 or board.watchdog_trips)
    assert board.commands.get("HB", 0) >= beats + 5 and board.watchdog_trips == 0
    with pytest.raises(BoardReplyError, match="answered HB with 'ACK hello'"):  # the board recovered, the fault stays
        bank.check()


def test_an_unexpected_error_in_the_heartbeat_is_recorded(board, bank, monkeypatch):
    def broken_write(data):
        raise TypeError("a bug below the heartbeat")

    bank.set_pressures([1.0] * 7)
    monkeypatch.setattr(bank._serial, "write", broken_write)
    assert wait_until(lambda: bank.fault is not None), "the heartbeat died without recording why"
    with pytest.raises(DeviceError, match=r"the heartbeat failed \(TypeError: a bug below the heartbeat\)"):
        bank.check()
    monkeypatch.undo()
    bank.close()
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))


def short_status(command: Frame, reply: Frame) -> Frame:
    """The board's status, but listing only the first two set-points (they match what was sent)."""
    if command.verb != "SET":
        return reply
    return Frame(reply.seq, "ACK", ("estop=0", "wdt=0", "mbar=" + ",".join(command.args[:2])))


def unreadable_status(command: Frame, reply: Frame) -> Frame:
    return Frame(reply.seq, "ACK", ("estop=yes", "wdt=0", "mbar=0")) if command.verb == "SET" else reply


@pytest.mark.parametrize("rewrite", [short_status, unreadable_status])
def test_an_unreadable_reply_to_set_is_a_device_error_not_a_value_error(board, bank, rewrite):
    bank.set_pressures([1.0] * 7)
    board.rewrite_replies(rewrite)
    with pytest.raises(DeviceError) as error:
        bank.set_pressures([0.5] * 7)
    assert isinstance(error.value, BoardReplyError) and not isinstance(error.value, ValueError | IndexError)
    assert "answered SET with 'ACK estop=" in str(error.value)
    assert wait_until(lambda: not np.any(board.setpoints_bar)), "the bank did not vent"
    assert board.events[-1].cause == "VENT command"
    with pytest.raises(BoardReplyError):  # recorded: refused until reconnect
        bank.check()


def test_an_unreadable_version_fails_connect_with_a_device_error(board):
    board.rewrite_replies(lambda command, reply: Frame(reply.seq, "ACK", ("proto=one",)) if command.verb == "VER"
                          else reply)
    bank = SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.5, reply_timeout_s=REPLY_TIMEOUT_S)
    with pytest.raises(BoardReplyError, match=r"answered VER with 'ACK proto=one'.*lacks field"):
        bank.connect()
    assert not bank.is_connected
    board.rewrite_replies(None)
    bank.connect()
    bank.close()


# --- close() against set_pressures() in another thread ----------------------------------------


def test_close_against_a_thread_setting_pressures_ends_with_the_vent(board, bank):
    started, outcome = threading.Event(), []

    def keep_setting():
        sent = 0
        try:
            while True:
                bank.set_pressures([0.5 + 0.1 * (sent % 10)] * 7)
                sent += 1
                if sent == 3:
                    started.set()
        except NotConnectedError as e:
            outcome.append(e)
        except BaseException as e:  # anything else fails the test below, with its message
            outcome.append(e)
            started.set()

    setter = threading.Thread(target=keep_setting, name="setter")
    setter.start()
    try:
        assert started.wait(30), "the setter never got going"
        bank.close()
    finally:
        setter.join(30)
    assert not setter.is_alive()
    assert len(outcome) == 1 and isinstance(outcome[0], NotConnectedError), outcome
    assert re.search("closing|after close", str(outcome[0]))
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    assert board.recent_commands[-1] == "VENT" and board.events[-1].cause == "VENT command"


# --- line noise, late replies, re-sends (issue 14) --------------------------------------------


def line_noise(seed: int) -> bytes:
    """The issue's garbage plus random bytes: several unreadable lines, ending with a line break."""
    noise = np.random.default_rng(seed).integers(0, 256, 300, dtype=np.uint8).tobytes()
    return b"\x00\xff garbage\r\n$$$\n" + noise + b"\n"


def test_noise_written_toward_the_board_does_not_cost_the_link(board, bank):
    """The board NAKs each unreadable line without a seq; those NAKs must not answer the SET."""
    intruder = serial.Serial(board.port, timeout=0.1)  # noise on the cable: a second writer on the port
    try:
        for i in range(5):
            naks = board.naks_sent
            intruder.write(line_noise(i))
            intruder.flush()
            bank.set_pressures([0.2 * (i + 1)] * 7)  # at once: the NAKs to the noise arrive during the SET
            np.testing.assert_allclose(board.setpoints_bar, 0.2 * (i + 1), atol=board.lsb_bar)
            assert board.naks_sent >= naks + 3
    finally:
        intruder.close()
    bank.check()
    assert board.executed["SET"] == 5 and board.watchdog_trips == 0


def test_naks_without_a_sequence_number_never_answer_a_command(board, bank):
    # Three "could not read a line" NAKs in front of every reply: each used to be taken for the reply.
    board.distort(to_host=lambda reply: b"$? NAK CRC*51C6\n" * 3 + reply)
    bank.set_pressures({"s1_a": 1.5})
    assert bank.status().setpoints_mbar[0] == 1500
    bank.check()
    assert board.executed["SET"] == 1 and board.commands["SET"] == 1  # answered on the first attempt


def test_the_board_counts_unreadable_frames_and_the_host_shows_the_count(board, bank):
    before = bank.status().unreadable_frames
    assert before == board.unreadable_frames
    intruder = serial.Serial(board.port, timeout=0.1)
    try:
        intruder.write(b"\x00\xff garbage\r\n$$$\n$1 SET 5*0000\n")
        intruder.flush()
        assert wait_until(lambda: board.unreadable_frames == before + 3)
    finally:
        intruder.close()
    assert bank.status().unreadable_frames == before + 3


def test_half_a_line_of_noise_left_in_the_input_is_dropped_before_the_next_command():
    # No heartbeat in between (a long watchdog allows a slow one): the SET is the next command.
    with BoardEmulator(channels=7, watchdog_ms=20_000) as board, \
            SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.5, reply_timeout_s=REPLY_TIMEOUT_S,
                            heartbeat_s=5.0) as bank:
        board.distort(to_host=lambda reply: reply + b"\x07half a line of noise, no line break")
        bank.status()  # its reply arrives with the noise glued behind it
        board.distort(to_host=None)
        sets = board.commands.get("SET", 0)
        bank.set_pressures({"s1_a": 1.0})
        # Kept, the noise would have been glued to the front of the ACK: unreadable, a timeout, a re-send.
        assert board.commands["SET"] == sets + 1 and bank.unreadable_replies == 0


def test_a_reply_garbled_on_its_way_back_is_recovered_by_a_re_send_carried_out_once(board):
    # A timeout well inside the board's 250 ms watchdog: the wire is silent while the host waits.
    bank = SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.5, reply_timeout_s=0.1)
    garbled = []

    def garble_first_set_reply(reply: bytes) -> bytes:
        if not garbled and b" ACK " in reply and board.commands.get("SET", 0) == 1:
            garbled.append(reply)
            return reply.replace(b"ACK", b"ACX")  # the checksum no longer matches
        return reply

    with bank:
        board.distort(to_host=garble_first_set_reply)
        bank.set_pressures({"s2_a": 2.0})
        assert garbled, "the test never garbled a reply"
        assert board.commands["SET"] == 2 and board.executed["SET"] == 1 and board.resends == 1
        assert bank.unreadable_replies == 1
        assert board.setpoints_bar[4] == pytest.approx(2.0, abs=board.lsb_bar)


def test_a_board_that_answers_late_is_heard_and_carries_each_command_out_once():
    """60 ms replies against the default 50 ms timeout: every attempt used to queue another command."""
    with BoardEmulator(channels=7, reply_delay_s=0.06) as board:
        bank = SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.5)  # 50 ms, 2 retries
        with bank:
            for i in range(5):
                bank.set_pressures([0.3 * (i + 1)] * 7)
                np.testing.assert_allclose(board.setpoints_bar, 0.3 * (i + 1), atol=board.lsb_bar)
            bank.check()
        executed = board.executed
        assert executed["VER"] == 1 and executed["SET"] == 5 and executed["VENT"] == 2
        assert board.resends >= 1  # the re-sends happened, and were recognised as such
        assert board.watchdog_trips == 0


# --- constructor arguments ---------------------------------------------------------------------

BAD_ARGUMENTS = [
    ({"max_pressure_bar": True}, TypeError, r"max_pressure_bar: expected a number in \(0, 65.535\] bar, got True"),
    ({"max_pressure_bar": float("nan")}, ValueError, r"max_pressure_bar: expected a finite number in \(0, 65.535\]"),
    ({"max_pressure_bar": float("inf")}, ValueError, r"max_pressure_bar: .*\(0, 65.535\] bar, got inf"),
    ({"max_pressure_bar": 0.0}, ValueError, r"max_pressure_bar: .*\(0, 65.535\] bar, got 0.0"),
    ({"max_pressure_bar": 70.0}, ValueError, r"max_pressure_bar: .*\(0, 65.535\] bar, got 70.0"),
    ({"max_pressure_bar": "2.5"}, TypeError, r"max_pressure_bar: .* got '2.5' \(a str\)"),
    ({"reply_timeout_s": float("inf")}, ValueError, r"reply_timeout_s: expected a finite number in \(0, 10\] s"),
    ({"reply_timeout_s": float("nan")}, ValueError, r"reply_timeout_s: .*\(0, 10\] s, got nan"),
    ({"reply_timeout_s": 0}, ValueError, r"reply_timeout_s: .*\(0, 10\] s, got 0"),
    ({"reply_timeout_s": True}, TypeError, r"reply_timeout_s: .* got True \(a boolean\)"),
    ({"heartbeat_s": float("inf")}, ValueError, r"heartbeat_s: expected a finite number in \(0, 10\] s"),
    ({"heartbeat_s": -0.08}, ValueError, r"heartbeat_s: .*\(0, 10\] s"),
    ({"retries": 2.0}, TypeError, r"retries: expected an integer in \[0, 10\], got 2.0 \(a float\)"),
    ({"retries": -1}, ValueError, r"retries: expected an integer in \[0, 10\], got -1"),
    ({"retries": 1000}, ValueError, r"retries: expected an integer in \[0, 10\], got 1000"),
    ({"retries": True}, TypeError, r"retries: .* \(a boolean\)"),
    ({"baud": 921600.0}, TypeError, r"baud: expected an integer in \[300, 20000000\], got 921600.0"),
    ({"baud": 0}, ValueError, r"baud: expected an integer in \[300, 20000000\], got 0"),
    ({"baud": True}, TypeError, r"baud: .* \(a boolean\)"),
    ({"clamp": "yes"}, TypeError, r"clamp: expected True or False, got 'yes'"),
    ({"clamp_tolerance": 0.6}, ValueError, r"clamp_tolerance: expected a finite number in \[0, 0.5\]"),
    ({"clamp_tolerance": float("nan")}, ValueError, r"clamp_tolerance: .*\[0, 0.5\]"),
    ({"port": None}, TypeError, r"port: expected a serial device path or a pyserial URL, got None"),
    ({"port": " "}, ValueError, r"port: .* got an empty string"),
    ({"channels": "abc"}, TypeError, r"channels: expected a list of valve names or a mapping"),
    ({"channels": {"a": True}}, ValueError, r"channel a: board channel must be a non-negative integer"),
    ({"channels": {"a": 256}}, ValueError, r"channel a: board channel .*\(0 \.\. 255\), got 256"),
]


@pytest.mark.parametrize(("kwargs", "error", "message"), BAD_ARGUMENTS,
                         ids=[next(iter(k)) + "=" + repr(next(iter(k.values()))) for k, _, _ in BAD_ARGUMENTS])
def test_constructor_arguments_are_checked_by_type_finiteness_and_range(kwargs, error, message):
    arguments = {"port": "loop://", "channels": ARM_CHANNELS, "max_pressure_bar": 2.5, **kwargs}
    with pytest.raises(error, match=message) as raised:
        SerialValveBank(**arguments)
    assert isinstance(raised.value, ValueError)  # a TypeError here is a WrongTypeError: bench handlers catch both
