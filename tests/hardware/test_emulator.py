"""The emulated board's state machine (what firmware must do), directly and over its pty."""

import numpy as np
import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from hardware.emulator import BoardEmulator, BoardStateMachine, main
from hardware.protocol import MAX_COUNT, BoardStatus, BoardVersion, LineSplitter, checksum, decode, encode
from tests.hardware.polling import wait_until


def ask(board, seq, verb, *args, now=0.0):
    return decode(board.receive(encode(seq, verb, *args).rstrip(b"\n"), now))


@pytest.fixture
def board():
    return BoardStateMachine(channels=3, max_pressure_bar=2.5, full_scale_bar=6.0, dac_bits=12, watchdog_ms=250)


def test_version_reports_limits_and_resolution(board):
    reply = ask(board, 1, "VER")
    assert reply.seq == 1 and reply.verb == "ACK"
    assert BoardVersion.parse(reply.args) == BoardVersion(1, "softarm-emu/0.1.0", 3, 2500, 1465, 250)


def test_set_rounds_to_the_dac_step_and_clamps_to_the_board_limit(board):
    status = BoardStatus.parse(ask(board, 2, "SET", 1234, 9000, 0).args)
    lsb_mbar = 6000 / 4095
    assert abs(board.setpoints_mbar[0] - 1234) <= lsb_mbar / 2
    assert board.setpoints_mbar[0] == pytest.approx(round(1234 / lsb_mbar) * lsb_mbar)
    assert board.setpoints_mbar[1] <= 2500 and board.setpoints_mbar[1] > 2500 - lsb_mbar
    assert status.setpoints_mbar == tuple(round(v) for v in board.setpoints_mbar)


@pytest.mark.parametrize(("verb", "args", "reason"), [
    ("SET", (1, 2), "ARGS"), ("SET", (1, 2, "x"), "ARGS"), ("SET", (1, 2, 65536), "ARGS"),
    ("SET", (1, 2, "-1"), "ARGS"),
    ("HB", (1,), "ARGS"), ("FLY", (), "VERB"),
])
def test_bad_commands_are_nakked_with_their_sequence_number(board, verb, args, reason):
    ask(board, 1, "SET", 100, 200, 300)
    reply = ask(board, 5, verb, *args)
    assert (reply.seq, reply.verb, reply.args) == (5, "NAK", (reason,))
    np.testing.assert_allclose(board.setpoints_mbar, [100, 200, 300], atol=1)  # nothing changed


@pytest.mark.parametrize("line", [b"hello", b"\xff\x00\xfe", b"$1 SET 1 2 3*0000", b"$ HB*1234", b"$?" + b" HB*27D3"])
def test_garbage_is_nakked_without_a_sequence_number(board, line):
    reply = decode(board.receive(line, 0.0))
    assert reply.seq is None and reply.verb == "NAK" and reply.args[0] in ("FRAME", "CRC")


def test_watchdog_vents_after_250_ms_without_a_valid_frame_and_reports_it_once(board):
    ask(board, 1, "SET", 1000, 1000, 1000, now=10.0)
    board.receive(b"garbage", 10.2)  # garbage does not feed the watchdog
    board.tick(10.249)
    assert np.all(board.setpoints_mbar > 0)
    board.tick(10.251)
    assert np.all(board.setpoints_mbar == 0) and board.watchdog_trips == 1
    assert board.events[-1].kind == "vent" and board.events[-1].cause == "watchdog"
    assert BoardStatus.parse(ask(board, 2, "HB", now=10.3).args).watchdog_tripped
    assert not BoardStatus.parse(ask(board, 3, "HB", now=10.31).args).watchdog_tripped


def test_heartbeats_keep_set_points(board):
    ask(board, 1, "SET", 1000, 0, 0, now=0.0)
    for i in range(1, 20):
        ask(board, 1 + i, "HB", now=0.2 * i)
        board.tick(0.2 * i + 0.1)
    assert board.setpoints_mbar[0] > 999 and board.watchdog_trips == 0


def test_estop_latches_until_cleared(board):
    ask(board, 1, "SET", 1000, 1000, 1000)
    board.press_estop(1.0)
    assert np.all(board.setpoints_mbar == 0)
    assert ask(board, 2, "SET", 500, 0, 0).args == ("ESTOP",)
    assert BoardStatus.parse(ask(board, 3, "STAT").args).estop
    assert BoardStatus.parse(ask(board, 4, "VENT").args).estop  # venting still works
    assert not BoardStatus.parse(ask(board, 5, "CLR").args).estop
    assert ask(board, 6, "SET", 500, 0, 0).verb == "ACK"
    assert [(e.kind, e.cause) for e in board.events] == [
        ("estop", "button"), ("vent", "estop"), ("vent", "VENT command"), ("clear", "CLR command")]


def test_estop_command_latches_like_the_button(board):
    assert BoardStatus.parse(ask(board, 1, "ESTOP").args).estop
    assert ask(board, 2, "SET", 1, 1, 1).args == ("ESTOP",)


def test_emulator_serves_the_state_machine_on_a_pty():
    with BoardEmulator(channels=2, max_pressure_bar=2.5) as board:
        link = serial.Serial(board.port, 115200, timeout=1.0)
        try:
            link.write(encode(1, "SET", 1500, 3000))
            reply = decode(link.readline())
            assert reply.seq == 1 and reply.verb == "ACK"
            np.testing.assert_allclose(board.setpoints_bar, [1.5, 2.5], atol=board.lsb_bar)
            assert board.setpoints_bar[1] <= 2.5
            link.write(b"\x00\xffnot a frame\n")
            assert decode(link.readline()).args == ("FRAME",)
            link.write(b"x" * 500 + b"\n")  # overlong
            assert decode(link.readline()).args == ("FRAME",)
            link.write(encode(2, "STAT"))
            assert BoardStatus.parse(decode(link.readline()).args).setpoints_mbar[0] == 1500
            wait_until(lambda: board.watchdog_trips)  # no heartbeat: the watchdog vents
            np.testing.assert_array_equal(board.setpoints_bar, [0.0, 0.0])
            assert board.watchdog_trips == 1 and board.naks_sent == 2
        finally:
            link.close()


def test_cut_link_answers_nothing():
    with BoardEmulator(channels=1) as board:
        link = serial.Serial(board.port, timeout=0.2)
        try:
            board.cut_link()
            link.write(encode(1, "VER"))
            assert link.readline() == b""
            board.restore_link()
            link.write(encode(2, "VER"))
            assert decode(link.readline()).seq == 2
        finally:
            link.close()


def test_constructor_checks_its_arguments():
    with pytest.raises(ValueError, match="channels"):
        BoardStateMachine(channels=0)
    with pytest.raises(ValueError, match="max_pressure_bar"):
        BoardStateMachine(max_pressure_bar=7.0, full_scale_bar=6.0)


_VERBS = ("VER", "STAT", "HB", "SET", "VENT", "ESTOP", "CLR", "FOO")
_step = st.one_of(
    st.tuples(st.just("frame"), st.integers(0, 9999), st.sampled_from(_VERBS),
              st.lists(st.integers(0, 70000).map(str) | st.text("0123456789x-.", max_size=6), max_size=9)),
    st.tuples(st.just("bytes"), st.binary(max_size=40)),
    st.tuples(st.just("wait"), st.floats(0.0, 0.4)),
    st.tuples(st.just("button")),
)


@settings(max_examples=200, deadline=None)
@given(steps=st.lists(_step, max_size=40))
def test_random_traffic_never_crashes_the_firmware_logic_or_breaks_its_safety(steps):
    """Whatever arrives (valid frames with any arguments, garbage, silence, the button): every
    line gets an ACK or a NAK, no channel ever exceeds the board's limit, a latched e-stop keeps
    every channel at 0 until CLR, and a silence past the watchdog leaves every channel at 0."""
    board = BoardStateMachine(channels=7, max_pressure_bar=2.5)
    now, last_valid = 0.0, None
    for step in steps:
        if step[0] == "frame":
            _, seq, verb, args = step
            try:
                line = encode(seq, verb, *args)
            except ValueError:
                continue  # not encodable: the host could not send it either
            reply = decode(board.receive(line.rstrip(b"\n"), now))
            assert reply.verb in ("ACK", "NAK")
            last_valid = now
        elif step[0] == "bytes":
            for line in step[1].split(b"\n"):
                assert decode(board.receive(line, now)).verb in ("ACK", "NAK")
        elif step[0] == "wait":
            now += step[1]
            board.tick(now)
            if last_valid is not None and now - last_valid > 0.25:
                assert not board.setpoints_mbar.any(), "the watchdog let a silent link keep pressure"
        else:
            board.press_estop(now)
        assert board.setpoints_mbar.max() <= board.max_mbar
        if board.estop:
            assert not board.setpoints_mbar.any()


# --- re-sent frames, unreadable lines, latency (issue 14) ------------------------------------


def test_a_re_sent_frame_is_answered_but_not_carried_out_again(board):
    first = ask(board, 5, "SET", 1000, 0, 0)
    board.receive(b"noise between the attempts", 0.0)  # does not make the re-send a new command
    again = ask(board, 5, "SET", 1000, 0, 0)
    assert (again.seq, again.verb, again.args[:3]) == (first.seq, first.verb, first.args[:3])
    assert again.args[3] == "bad=1"  # the status as it is now: the noise line is counted
    assert board.executed["SET"] == 1 and board.resends == 1
    assert board.commands["SET"] == 2  # both frames arrived intact
    ask(board, 6, "SET", 1000, 0, 0)  # the same set-points under a new seq: a new command
    ask(board, 6, "SET", 2000, 0, 0)  # the same seq with other arguments (a restarted host): a new command
    assert board.executed["SET"] == 3 and board.resends == 1
    assert board.setpoints_mbar[0] == pytest.approx(2000, abs=board.lsb_mbar)


def test_a_re_send_after_the_watchdog_vented_reports_the_vent_and_does_not_re_pressurise(board):
    ask(board, 5, "SET", 1000, 1000, 1000, now=0.0)
    board.tick(0.3)  # the host went silent: vented
    again = BoardStatus.parse(ask(board, 5, "SET", 1000, 1000, 1000, now=0.31).args)
    assert again.watchdog_tripped and again.setpoints_mbar == (0, 0, 0)
    assert not board.setpoints_mbar.any() and board.executed["SET"] == 1


def test_a_watchdog_report_is_repeated_to_re_sends_of_the_command_that_carried_it(board):
    ask(board, 1, "SET", 1000, 0, 0, now=0.0)
    board.tick(0.3)
    assert BoardStatus.parse(ask(board, 2, "HB", now=0.4).args).watchdog_tripped
    assert BoardStatus.parse(ask(board, 2, "HB", now=0.41).args).watchdog_tripped  # the first answer may be lost
    assert not BoardStatus.parse(ask(board, 3, "HB", now=0.42).args).watchdog_tripped


def test_a_re_sent_refused_command_is_refused_again(board):
    board.press_estop(0.0)
    assert ask(board, 7, "SET", 1, 1, 1).args == ("ESTOP",)
    assert ask(board, 7, "SET", 1, 1, 1).args == ("ESTOP",)
    assert ask(board, 8, "FLY").args == ("VERB",) and ask(board, 8, "FLY").args == ("VERB",)
    assert board.resends == 2 and not board.setpoints_mbar.any()


def test_unreadable_lines_are_counted_in_the_status(board):
    for line in (b"hello", b"$1 SET 1 2 3*0000", LineSplitter.OVERFLOW, b"$? HB*" + checksum(b"? HB").encode()):
        assert decode(board.receive(line, 0.0)).seq is None
    ask(board, 1, "FLY")  # a numbered refusal is not an unreadable frame
    assert board.unreadable_frames == 4
    assert BoardStatus.parse(ask(board, 2, "STAT").args).unreadable_frames == 4
    board.unreadable_frames = MAX_COUNT
    board.receive(b"more", 0.0)
    assert BoardStatus.parse(ask(board, 3, "STAT").args).unreadable_frames == MAX_COUNT  # it stops, never wraps


def test_the_peak_set_point_is_remembered(board):
    ask(board, 1, "SET", 2000, 9000, 0)
    ask(board, 2, "VENT")
    assert not board.setpoints_mbar.any()
    assert 2500 - board.lsb_mbar < board.peak_mbar <= 2500


def test_a_late_emulator_keeps_reading_while_its_replies_wait():
    """``reply_delay_s`` is latency, not a board busy for that long: frames are read while replies wait."""
    with BoardEmulator(channels=2, reply_delay_s=1.0) as board:
        link = serial.Serial(board.port, timeout=5.0)
        try:
            link.write(encode(1, "STAT") + encode(2, "SET", 500, 0) + encode(3, "STAT"))
            assert wait_until(lambda: board.frames_received == 3)
            assert link.in_waiting == 0  # no reply leaves before its delay
            assert [decode(link.readline()).seq for _ in range(3)] == [1, 2, 3]
        finally:
            link.close()


@pytest.mark.parametrize(("argv", "said"), [
    (["--max-pressure-bar", "nan"], "--max-pressure-bar: expected 0 < nan"),
    (["--max-pressure-bar", "0"], "--max-pressure-bar: expected 0 < 0.0"),
    (["--channels", "0"], "--channels: expected 1..16, got 0"),
])
def test_the_emulator_command_line_refuses_a_bad_board_without_a_traceback(argv, said, capsys):
    """The reported case: each printed a Python traceback."""
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2 and said in capsys.readouterr().err


def test_the_emulator_link_must_not_replace_a_file_or_need_a_missing_folder(tmp_path, capsys):
    taken = tmp_path / "taken"
    taken.write_text("mine")
    for link, said in ((taken, "a file is there"), (tmp_path / "missing" / "x", "does not exist")):
        with pytest.raises(SystemExit) as stop:
            main(["--link", str(link)])
        err = capsys.readouterr().err
        assert stop.value.code == 2 and f"--link {link}: " in err and said in err
    assert taken.read_text() == "mine"
