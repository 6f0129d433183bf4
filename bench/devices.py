"""What an experiment needs from its backend, each part carrying its backend's differences.

``bench.factory.make_devices`` returns :class:`Devices`: the camera and the valves (the hardware
contracts), a clock that brings the experiment to each capture time, what is known beyond the
images (``truth``: the twin's exact backbone and depth; on the rig a depth folder, or nothing) and
what of a frame the run keeps (``archive``). The capture loop (``bench.capture``) asks these parts,
never which backend it has:

- :class:`TwinClock` advances the twin's physics to each pressure change and capture time, in
  slices of ``SIM_SLICE_S`` with the stop checked between them (a signal acts within a fraction
  of a second however long a capture interval is); simulated time runs as fast as the computer.
- :class:`RealClock` waits on the monotonic clock while a :class:`PressureDriver` thread commands
  the schedule's pressure steps on time.

Every set-point goes through :meth:`Stop.command`, so none follows a stop request or the final vent.
"""

from __future__ import annotations

import dataclasses
import sys
import threading
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bench.experiments import Schedule
from bench.recording import frame_bytes
from bench.scoring import DEPTH_UNIT_M, quantize_depth
from hardware.errors import DeviceError, VentedBySignalError
from hardware.interfaces import StereoCamera, StereoFrame, ValveBank

# --- stopping -----------------------------------------------------------------------------


class Stop:
    """Set by SIGINT/SIGTERM (or a device thread); the loop checks it between steps.

    Every set-point of a run goes through ``command``, which checks the stop flag (and whether
    the devices are being closed) under ``lock`` right before sending; the devices are closed
    under the same lock once ``closed`` is set, so no set-point can follow the final vent.
    ``request`` does not take the lock: it runs in signal handlers, which interrupt the main
    thread wherever it is (inside the valve bank, too), where waiting for a lock could deadlock;
    a set-point already past its check when the signal lands is in flight, and the vent follows it.
    """

    def __init__(self) -> None:
        self.event = threading.Event()
        self.lock = threading.Lock()
        self.reason: str | None = None
        self.signum: int | None = None
        self.requested_at: float | None = None  # time.monotonic() of the request
        self.moved = False  # a set-point was sent (or started): from then on "nothing was moved" is false
        self.closed = False  # the devices are being closed: no more set-points

    def request(self, reason: str, signum: int | None = None) -> None:
        if not self.event.is_set():
            self.reason, self.signum, self.requested_at = reason, signum, time.monotonic()
            self.event.set()

    def came_before(self, started_at: float) -> bool:
        """Whether the stop was requested before ``started_at`` (time.monotonic): a capture started
        after a stop request is not part of the run."""
        return self.event.is_set() and self.requested_at is not None and self.requested_at <= started_at

    def command(self, valves: ValveBank, pressures, unless: threading.Event | None = None) -> bool:
        """Send set-points unless a stop was requested, the devices are closing, or ``unless`` is set.

        Returns:
            True when the set-points were sent.
        """
        with self.lock:
            if self.event.is_set() or self.closed or (unless is not None and unless.is_set()):
                return False
            self.moved = True
            valves.set_pressures(pressures)
            return True

    def close_devices(self, devices: Devices) -> None:
        """Close (vent first) the devices; no set-point of this run can follow."""
        with self.lock:
            self.closed = True
            devices.close()

    def __bool__(self) -> bool:
        return self.event.is_set()

    def wait_until(self, deadline: float) -> bool:
        """Sleep until ``deadline`` (time.monotonic) unless stopped first; True when stopped."""
        while not self.event.is_set():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self.event.wait(min(remaining, 0.05))
        return True


class ValveFaultError(DeviceError):
    """A fault of the valve bank that stopped the run; the message says so and names the original error."""

    def __init__(self, error: BaseException) -> None:
        super().__init__(f"valve fault: {type(error).__name__}: {error}")
        self.error = error


# --- clocks ---------------------------------------------------------------------------------


class Clock:
    """Brings the experiment to each capture time and commands the schedule's pressures on the way.

    ``start`` commands the start pressures and brings the arm to t = 0; ``wait_until(t)`` returns
    at schedule time t (False when stopped first); ``finish`` ends whatever runs beside the loop
    (no set-point follows it) and ``raise_fault`` raises what went wrong there.
    """

    def start(self, valves: ValveBank, schedule: Schedule, experiment, stop: Stop) -> bool:
        raise NotImplementedError

    def wait_until(self, t_s: float) -> bool:
        raise NotImplementedError

    def capture_time(self, t_s: float) -> float:
        """The experiment time of a capture scheduled at ``t_s`` (the clock's reading)."""
        return t_s

    def behind(self, next_t_s: float | None) -> bool:
        """Whether the loop is so late that the capture due now overlaps the next one's slot (it is dropped)."""
        return False

    def take_timings_ms(self) -> dict[str, float]:
        """Milliseconds the clock spent since the last call, by part ("physics" on the twin)."""
        return {}

    def finish(self) -> None:
        """Stop what runs beside the loop; no set-point of it follows."""

    def raise_fault(self) -> None:
        """Raise the fault what ran beside the loop met, if any (a ``ValveFaultError``)."""


# The twin is advanced in slices of at most this much simulated time, and the stop flag checked between
# them, so Ctrl-C or SIGTERM acts within a slice (a few ms of computing) however long the capture interval
# is; one slice is a whole number of physics steps, so the slicing does not change the simulation.
SIM_SLICE_S = 0.05
# settle() is called for at most this much simulated time at a time (the same checks, every 0.05 s),
# up to the twin's usual 30 s, for the same reason.
SETTLE_SLICE_S = 0.25
SETTLE_MAX_S = 30.0


def advance_sliced(twin, duration_s: float, stop: Stop) -> bool:
    """Advance the twin by ``duration_s`` simulated seconds (whole steps), a slice at a time.

    Returns:
        True when the whole duration was simulated, False when a stop request cut it short.

    Raises:
        SimulationError: the twin went unstable.
    """
    timestep_s = float(twin.sim.timestep_s)
    steps = round(duration_s / timestep_s) if duration_s > 0 else 0
    per_slice = max(1, int(SIM_SLICE_S / timestep_s + 1e-9))
    while steps > 0:
        if stop:
            return False
        n = min(steps, per_slice)
        twin.advance(n * timestep_s)
        steps -= n
    return not stop


def settle_sliced(twin, stop: Stop, max_time_s: float = SETTLE_MAX_S) -> bool:
    """Run the twin until the arm is at rest (``Twin.settle``), a slice at a time; False when it did
    not come to rest within ``max_time_s`` simulated seconds or a stop request came first."""
    start = twin.time_s
    while not stop:
        if twin.settle(max_time_s=min(SETTLE_SLICE_S, max_time_s)):
            return True
        if twin.time_s - start >= max_time_s - 1e-9:
            return False
    return False


class TwinClock(Clock):
    """Simulated time: the twin's physics is advanced to every pressure change and capture time.

    The schedule's clock stands still while the arm settles (``quasi_static``). A twin instability
    raises ``SimulationError`` (a ``DeviceError``) at the step where it happened.
    """

    def __init__(self, twin) -> None:
        self.twin = twin
        self._physics_s = 0.0

    def _timed(self, fn, *args, **kwargs):
        start = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            self._physics_s += time.perf_counter() - start

    def _settle(self) -> bool:
        from twin.physics import NotSettledWarning

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotSettledWarning)  # not at rest is still a true shape; said below
            return self._timed(settle_sliced, self.twin, self._stop)

    def start(self, valves: ValveBank, schedule: Schedule, experiment, stop: Stop) -> bool:
        self._valves, self._schedule, self._experiment, self._stop = valves, schedule, experiment, stop
        self._next_change = 1
        if not stop.command(valves, schedule.command(0)):  # a signal during opening or warm-up: nothing moves
            return False
        if experiment.settle and not self._settle() and not stop:
            print("softarm run: note: the arm did not come fully to rest before t = 0", file=sys.stderr)
        if experiment.lead_in_s and not self._timed(advance_sliced, self.twin, experiment.lead_in_s, stop):
            return False
        self._origin = self.twin.time_s  # simulated time of t = 0
        return not stop

    def _advance_to(self, t_s: float) -> bool:
        return self._timed(advance_sliced, self.twin, self._origin + t_s - self.twin.time_s, self._stop)

    def wait_until(self, t_s: float) -> bool:
        changes = self._schedule.change_times_s
        while self._next_change < len(changes) and changes[self._next_change] <= t_s + 1e-9:
            if not self._advance_to(changes[self._next_change]):
                return False
            if not self._stop.command(self._valves, self._schedule.command(self._next_change)):
                return False
            if self._experiment.quasi_static:
                before = self.twin.time_s
                self._settle()
                if self._stop:
                    return False
                self._origin += self.twin.time_s - before  # the schedule's clock stands still while the arm settles
            self._next_change += 1
        return self._advance_to(t_s)

    def take_timings_ms(self) -> dict[str, float]:
        physics, self._physics_s = self._physics_s, 0.0
        return {"physics": physics * 1e3}


class PressureDriver(threading.Thread):
    """Commands the schedule's pressure steps on time (monotonic clock) while the main loop estimates.

    Each step goes through ``Stop.command``: the stop flag and ``finish()`` are checked under the
    stop's lock right before the set-point is sent, and ``finish()`` waits for that lock, so once
    it returns no set-point of this thread is under way or can follow, even if the join timed out.
    A device error is kept in ``error`` and stops the run (the clock's ``finish`` raises it).
    """

    JOIN_TIMEOUT_S = 2.0  # finish() stops waiting for the thread after this (it sends nothing more anyway)

    def __init__(self, valves: ValveBank, schedule: Schedule, t0: float, stop: Stop) -> None:
        super().__init__(name="pressure-driver", daemon=True)
        self._valves, self._schedule, self._t0, self._stop_flag = valves, schedule, t0, stop
        self._finished = threading.Event()
        self.error: BaseException | None = None
        self.sent: list[tuple[float, dict[str, float]]] = []

    def run(self) -> None:
        try:
            for k in range(1, len(self._schedule.change_times_s)):
                deadline = self._t0 + float(self._schedule.change_times_s[k])
                while not self._finished.is_set() and not self._stop_flag:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        break
                    self._finished.wait(min(remaining, 0.05))
                command = self._schedule.command(k)
                if not self._stop_flag.command(self._valves, command, unless=self._finished):
                    return
                self.sent.append((time.monotonic() - self._t0, command))
        except VentedBySignalError:
            return  # SIGINT/SIGTERM vented the valves; the signal's own handler stops the run
        except BaseException as e:  # noqa: BLE001 - handed to the main loop, which stops the run
            self.error = e
            self._stop_flag.request(f"valve fault: {e}")

    def finish(self) -> None:
        """Stop sending: waits for a set-point under way; none follows once this returns."""
        self._finished.set()  # no step starts after this: each checks it under the lock
        with self._stop_flag.lock:  # and one already under way holds the lock until it is done
            pass
        if self.is_alive():
            self.join(timeout=self.JOIN_TIMEOUT_S)


class RealClock(Clock):
    """Real time on the monotonic clock; a :class:`PressureDriver` thread commands the pressure steps.

    A capture whose slot has already passed when the loop gets to it (the loop fell behind by more
    than one capture interval) is dropped (``behind``), so frames stay aligned with the schedule.
    """

    def __init__(self) -> None:
        self._driver: PressureDriver | None = None
        self._fault: BaseException | None = None
        self._t0 = time.monotonic()

    def start(self, valves: ValveBank, schedule: Schedule, experiment, stop: Stop) -> bool:
        self._stop = stop
        if not stop.command(valves, schedule.command(0)):  # a signal during opening or warm-up: nothing moves
            return False
        if experiment.lead_in_s and stop.wait_until(time.monotonic() + experiment.lead_in_s):
            return False
        self._t0 = time.monotonic()
        self._driver = PressureDriver(valves, schedule, self._t0, stop)
        self._driver.start()
        return True

    def wait_until(self, t_s: float) -> bool:
        return not self._stop.wait_until(self._t0 + float(t_s))

    def capture_time(self, t_s: float) -> float:
        return time.monotonic() - self._t0

    def behind(self, next_t_s: float | None) -> bool:
        return next_t_s is not None and time.monotonic() - self._t0 > next_t_s

    def finish(self) -> None:
        driver, self._driver = self._driver, None
        if driver is not None:
            driver.finish()
            self._fault = driver.error

    def raise_fault(self) -> None:
        fault, self._fault = self._fault, None
        if isinstance(fault, DeviceError):
            raise ValveFaultError(fault) from fault
        if fault is not None:
            raise fault


# --- what is known beyond the images ----------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class Observation:
    """What the devices know about a captured frame besides its images.

    Attributes:
        gt_m: (N, 3) exact backbone, left camera frame (the twin), or None.
        depth_units, depth_unit_m: the left depth map (uint16, metres per unit), or None.
        chamber_bar: chamber pressures by channel (the twin), or None.
        sim_time_s: the twin's simulated time, or None.
        timings_ms: how long it took ("truth").
    """

    gt_m: np.ndarray | None = None
    depth_units: np.ndarray | None = None
    depth_unit_m: float | None = None
    chamber_bar: Mapping[str, float] | None = None
    sim_time_s: float | None = None
    timings_ms: Mapping[str, float] = dataclasses.field(default_factory=dict)


class TwinTruth:
    """The twin's exact backbone (as the frame shows it: mid-exposure), rendered left depth, chamber
    pressures and simulated time."""

    exact = True  # the frames are scored against the exact backbone

    def __init__(self, twin) -> None:
        self.twin = twin

    def describe(self) -> str:
        return "the twin's rendered left depth (exact, stored at 0.1 mm)"

    def observe(self, frame: StereoFrame) -> Observation:
        start = time.perf_counter()
        gt = self.twin.frame_backbone()
        depth = quantize_depth(self.twin.camera.depth_left())
        channels = self.twin.valves.channels
        chamber = {k: round(float(v), 6) for k, v in zip(channels, self.twin.sim.chamber_bar, strict=True)}
        return Observation(gt, depth, DEPTH_UNIT_M, chamber, float(self.twin.time_s),
                           {"truth": (time.perf_counter() - start) * 1e3})


class DepthFolder:
    """Depth maps of the rig's left camera from a folder (``[rig.depth]``), matched by camera frame index."""

    exact = False  # depth for Q' only: no backbone to score against

    def describe(self) -> str:
        return f"depth maps from {self.source}"

    def __init__(self, source: Path, scale_m: float) -> None:
        self.source = Path(source)
        if not self.source.is_dir():
            raise DeviceError(f"[rig.depth] source: {self.source} is not a folder of depth maps")
        self.files = sorted(p for p in self.source.iterdir()
                            if p.suffix.lower() in (".png", ".tif", ".tiff", ".npy"))
        if not self.files:
            raise DeviceError(f"[rig.depth] source: no depth maps (.png, .tif, .npy) in {self.source}")
        self.scale_m = scale_m

    def read(self, index: int) -> tuple[np.ndarray | None, float | None]:
        """Depth of camera frame ``index`` as (uint16 units, metres per unit); (None, None) if unreadable."""
        path = self.files[index % len(self.files)]  # a looped recording starts its depth maps over too
        depth = np.load(path) if path.suffix.lower() == ".npy" else cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if depth is None:
            return None, None
        if depth.dtype != np.uint16:  # float metres (or other units) -> our 0.1 mm integers
            return quantize_depth(np.asarray(depth, dtype=np.float64) * self.scale_m), DEPTH_UNIT_M
        return depth, self.scale_m

    def observe(self, frame: StereoFrame) -> Observation:
        units, unit_m = self.read(frame.index)
        return Observation(depth_units=units, depth_unit_m=unit_m)


# --- what a run keeps of a frame ----------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class StoredFrame:
    """What the run writes of one frame (``RunWriter.submit``'s images, depth and noise).

    Attributes:
        left, right: the images to store: the frame as captured, or the twin's noise-free render.
        depth_units: the left depth to store, or None.
        noise: {"seed", "index"} of the twin's sensor noise when ``left``/``right`` are noise-free.
    """

    left: np.ndarray
    right: np.ndarray
    depth_units: np.ndarray | None = None
    noise: Mapping[str, int] | None = None


class FrameArchive:
    """Keeps the frames as the camera delivered them (the rig): lossless PNG, or JPEG as configured."""

    def backgrounds(self) -> dict[str, np.ndarray]:
        """Images written once per run, that frames refer to (none here)."""
        return {}

    def describe(self) -> dict[str, Any]:
        """What ``config.json`` needs to turn stored frames back into captured ones (nothing here)."""
        return {}

    def expected_bytes(self, recording, image_size: tuple[int, int], *, compare: bool) -> float:
        """Bytes a recorded frame is expected to take (``bench.recording.frame_bytes``)."""
        return frame_bytes(recording, image_size, depth=False, compare=compare)

    def store(self, frame: StereoFrame, observation: Observation | None) -> StoredFrame:
        # copies: the writer encodes them while the next frame is captured (a driver may reuse its buffers)
        return StoredFrame(frame.left.copy(), frame.right.copy())


class TwinArchive(FrameArchive):
    """Keeps the twin's frames as what reproduces them exactly: the noise-free render and the noise seed.

    The sensor noise of frame k is drawn from (seed, k) alone, so the noisy images need not be
    stored: the noise-free ones compress about twentyfold, and ``Run.image`` draws the same noise
    again. The left depth map is kept too when ``depth`` is set (the paper's Q' on replay).
    """

    def __init__(self, camera, depth: bool, noise_free: bool = True) -> None:
        self.camera = camera
        self.depth = depth
        self.noise_free = noise_free  # False ([recording] lossless_frames = false): the noisy frames, as JPEG

    def backgrounds(self) -> dict[str, np.ndarray]:
        if not self.noise_free:
            return {}
        images = {side: self.camera.background(side) for side in ("left", "right")}
        if any(v is None for v in images.values()):
            return {}
        depth = self.camera.background_depth() if self.depth else None
        return images if depth is None else {**images, "depth": quantize_depth(depth)}

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {"sensor": self.camera.effects.as_dict()}
        scene = getattr(self.camera, "scene", None)
        if scene is not None:  # which lab the twin rendered: a run folder says what it was measured in
            out["scene"] = {"preset": scene.preset, "seed": int(scene.seed), "description": scene.description,
                            "file": None if scene.source is None else str(scene.source)}
        return out

    def expected_bytes(self, recording, image_size: tuple[int, int], *, compare: bool) -> float:
        scene = getattr(self.camera, "scene", None)
        textured = scene is not None and scene.backdrop is not None
        return frame_bytes(recording, image_size, depth=self.depth, compare=compare, noise_free=self.noise_free,
                           textured=textured)

    def store(self, frame: StereoFrame, observation: Observation | None) -> StoredFrame:
        images = self.camera.last_images
        depth = observation.depth_units if (self.depth and observation is not None) else None
        if images is None or images.clean_left is None or not self.backgrounds():
            return StoredFrame(frame.left.copy(), frame.right.copy(), depth)
        return StoredFrame(images.clean_left, images.clean_right, depth,
                           {"seed": int(self.camera.noise_seed), "index": int(images.frame_index)})


# --- the devices --------------------------------------------------------------------------------


@dataclasses.dataclass
class Devices:
    """The connected devices of one backend and what the loop needs besides; ``close()`` vents, then
    releases everything.

    Attributes:
        camera: the stereo camera (connected).
        valves: the valve bank (connected, vented), or None where nothing moves (calibration).
        clock: brings the experiment to each capture time (``TwinClock`` or ``RealClock``).
        truth: what is known beyond the images (``TwinTruth``, ``DepthFolder``), or None.
        archive: what a run keeps of each frame.
        twin: the ``twin.Twin`` in simulation, None on the rig.
        grab_name: what a grab is, in the run's timings: "render" on the twin, "grab" on a camera.
    """

    camera: StereoCamera
    valves: ValveBank | None
    clock: Clock = dataclasses.field(default_factory=RealClock)
    truth: TwinTruth | DepthFolder | None = None
    archive: FrameArchive = dataclasses.field(default_factory=FrameArchive)
    twin: Any = None
    grab_name: str = "grab"

    def close(self) -> None:
        """Vent and close the valves, then close the camera and the twin, even if one step fails."""
        try:
            if self.valves is not None:
                self.valves.close()
        finally:
            try:
                self.camera.close()
            finally:
                close_twin = getattr(self.twin, "close", None)
                if close_twin is not None:
                    close_twin()

    def __enter__(self) -> Devices:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
