"""The simulated valve bank honours the ValveBank contract and drives the simulation."""

import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from hardware.errors import DeviceError, NotConnectedError
from twin.params import ArmParams
from twin.physics import ArmSimulation
from twin.twin import Twin
from twin.valves import SimValveBank


@pytest.fixture(scope="module")
def sim() -> ArmSimulation:
    return ArmSimulation(ArmParams.load())


@pytest.fixture
def bank(sim) -> SimValveBank:
    sim.reset()
    return SimValveBank(sim)


def test_channels_and_range_come_from_the_simulation(bank, sim):
    assert bank.channels == sim.channels
    assert bank.max_pressure_bar == 2.5


def test_use_before_connect_raises(bank):
    assert not bank.is_connected
    with pytest.raises(NotConnectedError):
        bank.set_pressures({"s1_a": 1.0})


def test_double_connect_raises(bank):
    bank.connect()
    with pytest.raises(DeviceError, match="already connected"):
        bank.connect()


def test_set_points_reach_the_simulation_and_the_chambers_follow(bank, sim):
    with bank:
        bank.set_pressures({"s1_a": 1.5, "s3": 2.0})
        expected = np.array([1.5, 0, 0, 0, 0, 0, 2.0])
        assert np.array_equal(sim.commanded_bar, expected)
        sim.advance(1.0)
        assert np.allclose(sim.chamber_bar, expected, atol=1e-4)
        bank.set_pressures([0.5] * 7)
        assert np.array_equal(sim.commanded_bar, np.full(7, 0.5))


def test_close_vents_and_closing_twice_is_harmless(bank, sim):
    bank.connect()
    bank.set_pressures({"s2_b": 2.5})
    bank.close()
    assert not bank.is_connected
    assert np.all(sim.commanded_bar == 0)
    bank.close()
    bank.connect()  # reconnecting after close is allowed
    assert bank.is_connected


def test_context_manager_vents_on_error(bank, sim):
    with pytest.raises(RuntimeError), bank:
        bank.set_pressures({"s1_c": 2.0})
        raise RuntimeError("experiment failed")
    assert np.all(sim.commanded_bar == 0)
    assert not bank.is_connected


@pytest.mark.parametrize("pressures, message", [
    ({"s2_a": 2.6}, r"channel s2_a: 2.6 bar is outside \[0, 2.5\] bar"),
    ({"s1_d": -0.5}, r"channel s1_d: -0.5 bar is outside \[0, 2.5\] bar"),
    ({"s3": float("nan")}, "channel s3: pressure is NaN"),
    ({"s4": 1.0}, "unknown valve channel 's4'"),
    ({"s1_b": "high"}, "channel s1_b: pressure 'high' is not a number"),
])
def test_bad_set_points_are_value_errors_naming_the_channel(bank, sim, pressures, message):
    with bank:
        bank.set_pressures({"s1_a": 1.0})
        with pytest.raises(ValueError, match=message):
            bank.set_pressures(pressures)
        assert sim.commanded_bar[0] == 1.0  # nothing of the rejected command reached the arm


def test_clamping_bank_clamps_and_logs(sim, caplog):
    # within the clamping tolerance (10 % of the 2.5 bar limit); 3 bar and -1 bar are refused below
    sim.reset()
    with caplog.at_level(logging.WARNING), SimValveBank(sim, clamp=True) as bank:
        bank.set_pressures({"s2_a": 2.7, "s2_b": -0.2})
        assert sim.commanded_bar[4] == 2.5 and sim.commanded_bar[5] == 0.0
    assert any("s2_a" in r.getMessage() and "clamp" in r.getMessage() for r in caplog.records), caplog.text
    assert any("s2_b" in r.getMessage() for r in caplog.records), caplog.text


@pytest.mark.parametrize(("tolerance", "pressures", "message"), [
    (0.1, {"s2_a": 3.0}, r"channel s2_a: 3.0 bar is outside \[0, 2.5\] bar by more than the clamping tolerance "
                          r"of 0.25 bar"),
    (0.1, {"s2_b": -1.0}, r"channel s2_b: -1.0 bar is outside \[0, 2.5\] bar by more than"),
    (0.1, {"s3": 250000.0}, r"channel s3: 250000.0 bar is outside .* is it in the wrong unit\?"),
    (0.0, {"s1_a": 2.6}, r"channel s1_a: 2.6 bar is outside \[0, 2.5\] bar by more than the clamping tolerance "
                         r"of 0 bar \(0% of the limit\)"),
])
def test_clamping_bank_refuses_what_is_beyond_its_tolerance(sim, tolerance, pressures, message):
    sim.reset()
    with SimValveBank(sim, clamp=True, clamp_tolerance=tolerance) as bank:
        bank.set_pressures({"s1_b": 1.0})
        with pytest.raises(ValueError, match=message):
            bank.set_pressures(pressures)
        np.testing.assert_array_equal(sim.commanded_bar, [0, 1.0, 0, 0, 0, 0, 0])


def test_the_twin_config_turns_clamping_on(tmp_path, caplog):
    """``[valves] clamp = true`` in a twin file reaches the twin's valve bank."""
    models = Path(__file__).resolve().parents[2] / "models"
    for path in models.glob("*.toml"):  # the files twin.toml refers to, beside it
        shutil.copy(path, tmp_path)
    text = (models / "twin.toml").read_text()
    assert "clamp = false" in text
    (tmp_path / "twin.toml").write_text(text.replace("clamp = false", "clamp = true"))
    with Twin.from_config(tmp_path / "twin.toml") as tw, caplog.at_level(logging.WARNING), tw.valves as bank:
        bank.set_pressures({"s3": 2.6})  # within the clamping tolerance
        assert bank.setpoints_bar["s3"] == 2.5
    assert "s3" in caplog.text
