"""SerialValveBank against the emulated board over a pty: set, read back, refuse, vent, fail loudly."""

import time

import numpy as np
import pytest
import serial

from hardware.emulator import BoardEmulator
from hardware.errors import DeviceError, EStopError, LinkLostError
from hardware.valves import SerialValveBank
from tests.fakes import ARM_CHANNELS


@pytest.fixture
def board():
    with BoardEmulator(channels=7, max_pressure_bar=2.5) as emulator:
        yield emulator


@pytest.fixture
def bank(board):
    valves = SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.5)
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
            SerialValveBank(board.port, {"tip": 3, "base": 0}, max_pressure_bar=2.0) as bank:
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
    with SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.0, clamp=True) as bank:
        bank.set_pressures({"s1_a": 9.0, "s1_b": -1.0})
        assert bank.setpoints_bar["s1_a"] == 2.0
        assert 2.0 - board.lsb_bar < board.setpoints_bar[0] <= 2.0 and board.setpoints_bar[1] == 0


def test_garbage_on_the_line_is_nakked_and_the_bank_carries_on(board, bank):
    bank.set_pressures({"s1_a": 1.0})
    naks = board.naks_sent
    intruder = serial.Serial(board.port, timeout=0.1)  # a second writer on the same port
    try:
        intruder.write(b"\x00\xff garbage \xfe\n$5 SET 9*0000\n")
        time.sleep(0.2)
    finally:
        intruder.close()
    assert board.naks_sent == naks + 2
    bank.set_pressures({"s1_a": 2.0})
    assert bank.status().setpoints_mbar[0] == 2000


def test_heartbeats_hold_set_points_while_the_caller_is_idle(board, bank):
    bank.set_pressures({"s2_a": 1.5})
    time.sleep(0.8)
    assert board.watchdog_trips == 0
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
            SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.5) as bank:
        bank.set_pressures([1.0] * 7)
        raise RuntimeError("experiment failed")
    np.testing.assert_array_equal(board.setpoints_bar, np.zeros(7))
    assert board.events[-1].cause == "VENT command"


def test_lost_link_is_an_error_on_the_next_call_and_the_board_vents(board, bank):
    bank.set_pressures([1.0] * 7)
    board.cut_link()
    time.sleep(0.5)  # heartbeats go unanswered; the board hears nothing and its watchdog vents
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
    time.sleep(0.5)
    with pytest.raises(LinkLostError):
        bank.close()
    assert not bank.is_connected


@pytest.mark.parametrize("port", ["loop://", "silent"])
def test_a_board_that_does_not_answer_is_a_connection_error_with_a_hint(board, port):
    if port == "silent":
        board.cut_link()
        port = board.port
    bank = SerialValveBank(port, ARM_CHANNELS, max_pressure_bar=2.5)
    started = time.monotonic()
    with pytest.raises(ConnectionError, match=r"did not answer VER \(3 attempts, 50 ms each\): check that the board"):
        bank.connect()
    assert time.monotonic() - started < 1.0  # bounded retries
    assert not bank.is_connected


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
    ({"channels": {"a": 0, "b": 9}, "max_pressure_bar": 2.5}, "uses board channel 9"),
    ({"channels": ARM_CHANNELS, "max_pressure_bar": 2.5, "heartbeat_s": 0.2}, "too slow for the board"),
])
def test_connect_refuses_a_board_that_does_not_fit(board, kwargs, message):
    bank = SerialValveBank(board.port, **kwargs)
    with pytest.raises(DeviceError, match=message):
        bank.connect()
    assert not bank.is_connected


@pytest.mark.parametrize(("channels", "message"), [
    ({"a": 0, "b": 0}, "share a board channel"), ({"a": -1}, "non-negative"), (["a", "a"], "unique names"),
])
def test_bad_channel_maps_are_refused_at_construction(channels, message):
    with pytest.raises(ValueError, match=message):
        SerialValveBank("loop://", channels, max_pressure_bar=2.5)
