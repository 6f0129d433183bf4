"""One contract suite for every StereoCamera and every ValveBank the bench may be handed.

To add an implementation (the twin's ``SimStereoCamera``/``SimValveBank``, a new board), write
a fixture below that returns it *unconnected* and append the fixture's name to
``CAMERA_FIXTURES`` or ``VALVE_FIXTURES``. A valve fixture returns a ``ValvesUnderTest`` so the
suite can see what the device itself drives, not just what the bank believes, and how to build
the same kind of bank with clamping on.
"""

import contextlib
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest

from hardware.emulator import BoardEmulator
from hardware.errors import DeviceError, NotConnectedError, WrongTypeError
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
from tests.hardware.polling import wait_until

# Fixture names of every implementation under contract; extend these lists.
CAMERA_FIXTURES = ["zed_video_camera", "zed_folder_camera", "fake_camera", "twin_camera"]
VALVE_FIXTURES = ["serial_valve_bank", "fake_valve_bank", "twin_valve_bank"]


@dataclass
class ValvesUnderTest:
    """A bank, what its device actually drives (bar, in the bank's channel order), and a builder of
    the same kind of bank (unconnected) with ``clamp=True``, on the same device."""

    bank: ValveBank
    driven_bar: Callable[[], np.ndarray]
    tolerance_bar: float = 1e-9
    clamping: Callable[[], "ValvesUnderTest"] | None = None


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
        # a generous reply timeout: a loaded machine must not turn a slow reply into a lost link
        def build(clamp: bool) -> ValvesUnderTest:
            bank = SerialValveBank(board.port, ARM_CHANNELS, max_pressure_bar=2.5, reply_timeout_s=0.5, clamp=clamp)
            return ValvesUnderTest(bank, lambda: board.setpoints_bar, board.lsb_bar, lambda: build(True))

        valves = build(False)
        yield valves
        valves.bank.close()


@pytest.fixture
def fake_valve_bank():
    def build(clamp: bool) -> ValvesUnderTest:
        bank = FakeValveBank(ARM_CHANNELS, max_pressure_bar=2.5, clamp=clamp)
        return ValvesUnderTest(bank, lambda: bank.applied_bar, clamping=lambda: build(True))

    return build(False)


@pytest.fixture
def twin_valve_bank(twin_parts):
    from twin.valves import SimValveBank

    sim, _ = twin_parts
    sim.reset()
    return ValvesUnderTest(SimValveBank(sim), lambda: sim.commanded_bar,
                           clamping=lambda: ValvesUnderTest(SimValveBank(sim, clamp=True), lambda: sim.commanded_bar))


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



def test_valves_check_is_silent_while_all_is_well(valves):
    bank = valves.bank
    bank.check()  # before connect(): nothing recorded
    bank.connect()
    bank.set_pressures([1.0] * len(bank.channels))
    bank.check()
    bank.close()
    bank.check()


def test_valves_set_pressures_while_closing_is_refused_and_the_vent_stays_last(valves, monkeypatch):
    # close() is held between its vent and its release; a set-point arriving then must not re-pressurise.
    bank = valves.bank
    bank.connect()
    bank.set_pressures([1.0] * len(bank.channels))
    vented, resume = threading.Event(), threading.Event()
    vent = bank._vent

    def vent_then_hold():
        vent()
        vented.set()
        resume.wait(30)

    monkeypatch.setattr(bank, "_vent", vent_then_hold)
    closer = threading.Thread(target=bank.close, name="closer")
    closer.start()
    try:
        assert vented.wait(30), "close() never vented"
        with pytest.raises(NotConnectedError, match="closing"):
            bank.set_pressures([2.0] * len(bank.channels))
    finally:
        resume.set()
        closer.join(30)
    assert not closer.is_alive() and not bank.is_connected
    np.testing.assert_array_equal(valves.driven_bar(), np.zeros(len(bank.channels)))
    with pytest.raises(NotConnectedError, match="after close"):
        bank.set_pressures([2.0] * len(bank.channels))


def test_valves_close_vents_after_a_set_pressures_under_way(valves, monkeypatch):
    # A set_pressures() is inside the device call when close() starts: the vent must come after it.
    bank = valves.bank
    bank.connect()
    bank.set_pressures([1.0] * len(bank.channels))
    applying, resume = threading.Event(), threading.Event()
    apply = bank._apply

    def held_apply(setpoints_bar):
        applying.set()
        resume.wait(30)
        apply(setpoints_bar)

    monkeypatch.setattr(bank, "_apply", held_apply)
    outcome = []

    def set_pressures():
        try:
            bank.set_pressures([1.5] * len(bank.channels))
            outcome.append(None)
        except NotConnectedError as e:  # a device may refuse the command once closing has started
            outcome.append(e)

    setter = threading.Thread(target=set_pressures, name="setter")
    closer = threading.Thread(target=bank.close, name="closer")
    setter.start()
    try:
        assert applying.wait(30), "set_pressures() never reached the device"
        closer.start()
        assert wait_until(lambda: bank._is_closing), "close() never started"  # synchronisation only
    finally:
        resume.set()
        setter.join(30)
        if closer.ident is not None:
            closer.join(30)
    assert not setter.is_alive() and not closer.is_alive() and len(outcome) == 1
    np.testing.assert_array_equal(valves.driven_bar(), np.zeros(len(bank.channels)))
    assert all(v == 0 for v in bank.setpoints_bar.values())


@pytest.mark.parametrize("clamp", [False, True])
@pytest.mark.parametrize("value", [True, False, np.True_, math.inf, -math.inf])
def test_valves_refuse_booleans_and_infinities_even_when_clamping(value, clamp):
    bank = FakeValveBank(ARM_CHANNELS, max_pressure_bar=2.5, clamp=clamp)
    with pytest.raises(ValueError, match="channel s1_b: pressure (True|False|inf|-inf) is (a boolean|not finite)"):
        bank.validated({"s1_b": value})
    bank.connect()
    with pytest.raises(ValueError, match="channel s1_b"):
        bank.set_pressures([0.5, value, 0.5, 0.5, 0.5, 0.5, 0.5])
    assert bank.history == [] and np.all(bank.applied_bar == 0)


def test_valves_clamping_still_clamps_finite_numbers():
    bank = FakeValveBank(ARM_CHANNELS, max_pressure_bar=2.5, clamp=True)
    np.testing.assert_array_equal(bank.validated({"s1_a": 2.6, "s1_b": -0.1, "s1_c": 1})[:3], [2.5, 0.0, 1.0])


# --- what set_pressures() accepts (issue 14): the same on every implementation -----------------


def _generator():
    yield from [1.0] * len(ARM_CHANNELS)


ACCEPTED_FORMS = {  # each sets s1_a and s3 and leaves the others at 0 bar
    "dict": lambda: {"s1_a": 0.5, "s3": 2},
    "list": lambda: [0.5, 0, 0, 0, 0, 0, 2.0],
    "tuple": lambda: (0.5, 0, 0, 0, 0, 0, 2),
    "1-D float array": lambda: np.array([0.5, 0, 0, 0, 0, 0, 2.0]),
    "1-D float32 array": lambda: np.array([0.5, 0, 0, 0, 0, 0, 2.0], dtype=np.float32),
    "numpy scalars": lambda: [np.float32(0.5), np.int64(0), 0, 0, 0, 0, np.int32(2)],
}


@pytest.mark.parametrize("form", ACCEPTED_FORMS.values(), ids=ACCEPTED_FORMS.keys())
def test_valves_take_a_mapping_or_a_sequence_in_channel_order(valves, form):
    bank = valves.bank
    bank.connect()
    bank.set_pressures(form())
    expected = np.zeros(len(bank.channels))
    expected[0], expected[6] = 0.5, 2.0
    np.testing.assert_allclose(valves.driven_bar(), expected, atol=valves.tolerance_bar)
    bank.set_pressures(np.array([1, 0, 0, 0, 0, 0, 2]))  # an integer array
    expected[0] = 1.0
    np.testing.assert_allclose(valves.driven_bar(), expected, atol=valves.tolerance_bar)


REFUSED_FORMS = {
    "a string": (lambda: "2222222", "a str is not a list of pressures"),
    "bytes": (lambda: b"2222222", "a bytes is not a list of pressures"),
    "a bytearray": (lambda: bytearray(b"2222222"), "a bytearray is not a list of pressures"),
    "a set": (lambda: {0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7}, "got a set; a set .* no channel order"),
    "a frozenset": (lambda: frozenset({0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7}), "got a frozenset"),
    "dict values": (lambda: dict.fromkeys(ARM_CHANNELS, 1.0).values(), "got a dict_values"),
    "dict keys": (lambda: dict.fromkeys(ARM_CHANNELS, 1.0).keys(), "got a dict_keys"),
    "an iterator": (lambda: iter([1.0] * len(ARM_CHANNELS)), "got a list_iterator; .* an iterator is used up"),
    "a generator": (_generator, "got a generator"),
    "a boolean": (lambda: True, r"got True \(a boolean\)"),
    "a number": (lambda: 2.0, "got a float"),
    "None": (lambda: None, "got a NoneType"),
}


@pytest.mark.parametrize(("form", "message"), REFUSED_FORMS.values(), ids=REFUSED_FORMS.keys())
def test_valves_refuse_containers_whose_meaning_or_order_is_a_guess(valves, form, message):
    bank = valves.bank
    bank.connect()
    bank.set_pressures({"s1_a": 1.0})
    before = valves.driven_bar().copy()
    with pytest.raises(TypeError, match=f"pressures: expected a mapping channel -> bar, or 7 numbers in channel "
                                        f"order .*{message}") as error:
        bank.set_pressures(form())
    assert isinstance(error.value, WrongTypeError) and isinstance(error.value, ValueError)
    np.testing.assert_array_equal(valves.driven_bar(), before)
    assert bank.setpoints_bar["s1_a"] == 1.0 and bank.setpoints_bar["s1_b"] == 0.0


@pytest.mark.parametrize(("form", "message"), [
    (lambda: np.full((1, 7), 1.0), r"an array of shape \(1, 7\)"),
    (lambda: np.array(1.0), r"an array of shape \(\)"),
    (lambda: [1.0] * 6, "expected 7 pressures in channel order"),
])
def test_valves_refuse_arrays_that_are_not_one_row_of_pressures(valves, form, message):
    valves.bank.connect()
    with pytest.raises(ValueError, match=message):
        valves.bank.set_pressures(form())
    assert not valves.driven_bar().any()


@pytest.mark.parametrize(("value", "message"), [
    ("2", r"channel s1_b: pressure '2' is not a number of bar \(a str\)"),
    (b"2", r"channel s1_b: pressure b'2' is not a number of bar \(a bytes\)"),
    (None, r"channel s1_b: pressure None is not a number of bar"),
    (1 + 0j, r"channel s1_b: pressure \(1\+0j\) is not a number of bar \(a complex\)"),
    (np.True_, "channel s1_b: pressure True is a boolean"),
])
def test_valves_refuse_values_that_are_not_numbers_naming_the_channel(valves, value, message):
    bank = valves.bank
    bank.connect()
    for command in ({"s1_b": value}, [0.5, value, 0.5, 0.5, 0.5, 0.5, 0.5]):
        with pytest.raises(TypeError, match=message):
            bank.set_pressures(command)
    assert not valves.driven_bar().any()


def test_valves_refuse_a_boolean_array():
    bank = FakeValveBank(ARM_CHANNELS, max_pressure_bar=2.5)
    bank.connect()
    with pytest.raises(TypeError, match="channel s1_a: pressure True is a boolean"):
        bank.set_pressures(np.ones(7, dtype=bool))
    assert bank.history == []


def test_valves_clamp_only_within_the_tolerance(valves):
    """clamp=True is for rounding slips: within 10 % of the 2.5 bar limit. Pascals typed as bar are refused."""
    clamping = valves.clamping()
    bank = clamping.bank
    with bank:
        bank.set_pressures({"s1_a": 2.7, "s1_b": -0.2, "s1_c": 1.0})
        np.testing.assert_allclose(clamping.driven_bar()[:3], [2.5, 0.0, 1.0], atol=clamping.tolerance_bar)
        assert bank.setpoints_bar["s1_a"] == 2.5 and bank.setpoints_bar["s1_b"] == 0.0
        for value in (250000.0, 2.76, -0.26, -1.0):
            with pytest.raises(ValueError, match=rf"channel s3: {value} bar is outside \[0, 2.5\] bar by more than "
                                                 r"the clamping tolerance of 0.25 bar \(10% of the limit\)"):
                bank.set_pressures({"s3": value, "s1_c": 2.0})
        for value in (math.nan, math.inf, 10**400):  # the last: an int no float holds (OverflowError before)
            with pytest.raises(ValueError, match="channel s3: pressure"):
                bank.set_pressures({"s3": value})
        np.testing.assert_allclose(clamping.driven_bar()[:3], [2.5, 0.0, 1.0], atol=clamping.tolerance_bar)
        assert clamping.driven_bar()[6] == 0.0


# --- the base class's constructor --------------------------------------------------------------


@pytest.mark.parametrize(("kwargs", "error", "message"), [
    ({"max_pressure_bar": True}, TypeError, r"max_pressure_bar: expected a number in \(0, inf\) bar, got True"),
    ({"max_pressure_bar": math.nan}, ValueError, "max_pressure_bar: expected a finite number"),
    ({"max_pressure_bar": math.inf}, ValueError, "max_pressure_bar: expected a finite number"),
    ({"max_pressure_bar": 0}, ValueError, "max_pressure_bar: expected a finite number"),
    ({"max_pressure_bar": "2.5"}, TypeError, r"max_pressure_bar: .* \(a str\)"),
    ({"clamp": 1}, TypeError, "clamp: expected True or False, got 1"),
    ({"channels": "s1_a"}, TypeError, "channels: expected a list of valve names"),
    ({"channels": ["a", ""]}, ValueError, "channels: expected unique names"),
])
def test_a_bank_checks_its_constructor_arguments(kwargs, error, message):
    arguments = {"channels": ARM_CHANNELS, "max_pressure_bar": 2.5, **kwargs}
    with pytest.raises(error, match=message):
        FakeValveBank(**arguments)
