"""One contract suite for every StereoCamera and every ValveBank the bench may be handed.

To add an implementation (the twin's ``SimStereoCamera``/``SimValveBank``, a new board), write
a fixture below that returns it *unconnected* and append the fixture's name to
``CAMERA_FIXTURES`` or ``VALVE_FIXTURES``. A valve fixture returns a ``ValvesUnderTest`` so the
suite can see what the device itself drives, not just what the bank believes.
"""

import contextlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest

from hardware.emulator import BoardEmulator
from hardware.errors import DeviceError, NotConnectedError
from hardware.interfaces import StereoCamera, StereoFrame, ValveBank
from hardware.valves import SerialValveBank
from hardware.zed import ZedCamera
from tests.fakes import (
    ARM_CHANNELS,
    FakeStereoCamera,
    FakeValveBank,
    side_by_side_frames,
    small_calibration,
    write_side_by_side_folder,
    write_side_by_side_video,
)

# Fixture names of every implementation under contract; extend these lists.
CAMERA_FIXTURES = ["zed_video_camera", "zed_folder_camera", "fake_camera", "twin_camera"]
VALVE_FIXTURES = ["serial_valve_bank", "fake_valve_bank", "twin_valve_bank"]


@dataclass
class ValvesUnderTest:
    """A bank, and what its device actually drives (bar, in the bank's channel order)."""

    bank: ValveBank
    driven_bar: Callable[[], np.ndarray]
    tolerance_bar: float = 1e-9


# --- camera implementations ---------------------------------------------------------------


@pytest.fixture
def zed_video_camera(tmp_path):
    calibration = small_calibration()
    video = write_side_by_side_video(tmp_path / "session.mkv", side_by_side_frames(calibration, 6))
    return ZedCamera(video, calibration)


@pytest.fixture
def zed_folder_camera(tmp_path):
    calibration = small_calibration()
    return ZedCamera(write_side_by_side_folder(tmp_path / "session", side_by_side_frames(calibration, 6)), calibration)


@pytest.fixture
def fake_camera():
    return FakeStereoCamera()


@pytest.fixture(scope="module")
def twin_parts():
    """The twin's physics and camera rig, shared by the twin's devices (built once: ~4 s)."""
    from twin.params import ArmParams
    from twin.physics import ArmSimulation
    from twin.rig import StereoRig
    from twin.twin import DEFAULT_CONFIG, TwinConfig

    config = TwinConfig.load(DEFAULT_CONFIG)
    return ArmSimulation(ArmParams.load(config.arm), timestep_s=config.timestep_s), StereoRig.load(config.camera)


@pytest.fixture
def twin_camera(twin_parts):
    from twin.camera import SimStereoCamera

    sim, rig = twin_parts
    return SimStereoCamera(rig, sim.shape, lambda: sim.time_s)


# --- valve implementations ----------------------------------------------------------------


@pytest.fixture
def serial_valve_bank():
    with BoardEmulator(channels=7, max_pressure_bar=2.5) as board:
        bank = SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.5)
        yield ValvesUnderTest(bank, lambda: board.setpoints_bar, board.lsb_bar)
        bank.close()


@pytest.fixture
def fake_valve_bank():
    bank = FakeValveBank(ARM_CHANNELS, max_pressure_bar=2.5)
    return ValvesUnderTest(bank, lambda: bank.applied_bar)


@pytest.fixture
def twin_valve_bank(twin_parts):
    from twin.valves import SimValveBank

    sim, _ = twin_parts
    sim.reset()
    bank = SimValveBank(sim)
    return ValvesUnderTest(bank, lambda: sim.commanded_bar)


# --- the suite ----------------------------------------------------------------------------


@pytest.fixture(params=CAMERA_FIXTURES)
def camera(request) -> StereoCamera:
    camera = request.getfixturevalue(request.param)
    yield camera
    camera.close()


@pytest.fixture(params=VALVE_FIXTURES)
def valves(request) -> ValvesUnderTest:
    return request.getfixturevalue(request.param)


def test_camera_grabs_calibrated_frames_counting_from_zero(camera):
    camera.connect()
    frames = [camera.grab() for _ in range(3)]
    width, height = camera.calibration.image_size
    for i, frame in enumerate(frames):
        assert isinstance(frame, StereoFrame) and frame.index == i
        for image in (frame.left, frame.right):
            assert image.shape == (height, width, 3) and image.dtype == np.uint8
    # monotonic, not strictly: the twin stamps simulated time, which moves only when physics runs
    assert np.all(np.diff([f.timestamp_s for f in frames]) >= 0)


def test_camera_double_connect_is_an_error(camera):
    camera.connect()
    with pytest.raises(DeviceError):
        camera.connect()
    assert camera.is_connected


def test_camera_use_before_connect_is_an_error(camera):
    assert not camera.is_connected
    with pytest.raises(NotConnectedError):
        camera.grab()


def test_camera_close_twice_is_harmless(camera):
    camera.close()
    camera.connect()
    camera.close()
    camera.close()
    assert not camera.is_connected
    with pytest.raises(NotConnectedError):
        camera.grab()


def test_camera_context_manager_releases_even_on_error(camera):
    with pytest.raises(RuntimeError), camera:
        assert camera.is_connected
        camera.grab()
        raise RuntimeError("boom")
    assert not camera.is_connected


def test_valves_drive_what_was_set(valves):
    bank = valves.bank
    bank.connect()
    bank.set_pressures({bank.channels[0]: 1.25})
    expected = np.zeros(len(bank.channels))
    expected[0] = 1.25
    np.testing.assert_allclose(valves.driven_bar(), expected, atol=valves.tolerance_bar)
    with pytest.raises(ValueError, match=f"channel {bank.channels[1]}"):
        bank.set_pressures({bank.channels[1]: bank.max_pressure_bar + 0.1})
    np.testing.assert_allclose(valves.driven_bar(), expected, atol=valves.tolerance_bar)


def test_valves_double_connect_is_an_error(valves):
    valves.bank.connect()
    with pytest.raises(DeviceError):
        valves.bank.connect()
    assert valves.bank.is_connected


def test_valves_use_before_connect_is_an_error(valves):
    with pytest.raises(NotConnectedError):
        valves.bank.set_pressures([0.0] * len(valves.bank.channels))


def test_valves_close_twice_is_harmless_and_vents(valves):
    bank = valves.bank
    bank.close()
    bank.connect()
    bank.set_pressures([1.0] * len(bank.channels))
    bank.close()
    bank.close()
    assert not bank.is_connected
    np.testing.assert_array_equal(valves.driven_bar(), np.zeros(len(bank.channels)))


@pytest.mark.parametrize("fails", [False, True])
def test_valves_context_manager_vents(valves, fails):
    bank = valves.bank
    with pytest.raises(RuntimeError) if fails else contextlib.nullcontext(), bank:
        bank.set_pressures([2.0] * len(bank.channels))
        np.testing.assert_allclose(valves.driven_bar(), 2.0, atol=valves.tolerance_bar)
        if fails:
            raise RuntimeError("experiment failed")
    np.testing.assert_array_equal(valves.driven_bar(), np.zeros(len(bank.channels)))
    assert all(v == 0 for v in bank.setpoints_bar.values())

