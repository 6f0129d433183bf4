"""Device contracts: what the bench needs from a stereo camera and a valve bank.

The real rig (``hardware.zed``, ``hardware.valves``) and the digital twin (``twin``) implement
these, so experiments run unchanged on either. Only the contract lives here: no I/O.
"""

from __future__ import annotations

import logging
import math
import threading
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from estimator import StereoCalibration
from hardware.errors import NotConnectedError

_log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class StereoFrame:
    """One synchronised stereo capture.

    Attributes:
        left, right: raw (distorted, unrectified) images, (H, W, 3) uint8 BGR.
        timestamp_s: capture time in seconds on a monotonic clock (simulated time in the twin).
        index: frame counter of the camera, starting at 0.
    """

    left: np.ndarray
    right: np.ndarray
    timestamp_s: float
    index: int


class StereoCamera(ABC):
    """A calibrated stereo camera delivering raw image pairs."""

    @property
    @abstractmethod
    def calibration(self) -> StereoCalibration:
        """The calibration of the raw images this camera delivers."""

    @property
    @abstractmethod
    def is_connected(self) -> bool: ...

    @abstractmethod
    def connect(self) -> None:
        """Open the device. Raises ``DeviceError`` when already connected or when it fails."""

    @abstractmethod
    def grab(self) -> StereoFrame:
        """Return the next frame. Raises ``NotConnectedError`` before ``connect()``."""

    @abstractmethod
    def close(self) -> None:
        """Release the device; closing twice is harmless."""

    def __enter__(self) -> StereoCamera:
        if not self.is_connected:
            self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class ValveBank(ABC):
    """Proportional pressure valves, one per channel, commanded in bar (gauge).

    Subclasses implement ``_apply(setpoints_bar)``, ``_vent()`` and ``_disconnect()``; this class
    owns the validation, so no implementation can send an unchecked set-point, and the order of
    ``close()`` against ``set_pressures()`` from other threads.

    The contract:

    - ``connect()``; ``set_pressures(...)`` by name or in channel order; ``vent()``;
      ``close()`` (vents, then releases; closing twice is harmless); ``with bank:`` closes on exit,
      so the valves are vented even when the block raises.
    - ``check()`` raises the fault the device recorded in the background (a link lost between
      commands, a board watchdog vent, a latched e-stop), as a ``hardware.errors.DeviceError``
      subclass, on every call until the fault is cleared; it does nothing when all is well. A control loop
      calls it once per frame so a fault stops the experiment even while no set-point changes.
      Devices that cannot fail in the background (the twin, the fakes) inherit the no-op.
    - Once ``close()`` has started, ``set_pressures()`` in any thread raises
      ``NotConnectedError``; ``close()`` waits for a ``set_pressures()`` already under way (which
      completes, or raises ``NotConnectedError`` if the device refuses commands once closing)
      before it vents, so the vent is the last command the device receives.
    """

    # How long close() waits for a set_pressures() under way before venting regardless.
    _CLOSE_WAIT_S = 5.0

    def __init__(self, channels: Sequence[str], max_pressure_bar: float, clamp: bool = False) -> None:
        channels = tuple(channels)
        if not channels or len(set(channels)) != len(channels):
            raise ValueError(f"channels: expected unique names, got {channels!r}")
        if not (math.isfinite(max_pressure_bar) and max_pressure_bar > 0):
            raise ValueError(f"max_pressure_bar: expected a positive number, got {max_pressure_bar!r}")
        self._channels = channels
        self._max_pressure_bar = float(max_pressure_bar)
        self._clamp = bool(clamp)
        self._setpoints_bar = np.zeros(len(channels))
        # close() against set_pressures() from other threads: _state guards the two fields below;
        # _apply_lock makes validate-apply-remember one step, so concurrent partial updates compose.
        self._state = threading.Condition()
        self._closing = 0  # close() calls under way (usually 0 or 1)
        self._closed = False  # close() has run; only read while disconnected, for the error message
        self._applying: list[int] = []  # threads inside set_pressures() past the closing check
        self._apply_lock = threading.RLock()

    @property
    def channels(self) -> tuple[str, ...]:
        return self._channels

    @property
    def max_pressure_bar(self) -> float:
        return self._max_pressure_bar

    @property
    def setpoints_bar(self) -> dict[str, float]:
        """The last set-points accepted, by channel name."""
        return dict(zip(self._channels, self._setpoints_bar.tolist(), strict=True))

    @property
    @abstractmethod
    def is_connected(self) -> bool: ...

    @abstractmethod
    def connect(self) -> None: ...

    @abstractmethod
    def _apply(self, setpoints_bar: np.ndarray) -> None:
        """Send validated set-points (one per channel, in channel order)."""

    @abstractmethod
    def _vent(self) -> None:
        """Bring every channel to 0 bar as fast as the device allows."""

    @abstractmethod
    def _disconnect(self) -> None:
        """Release the link (called after venting)."""

    def validated(self, pressures: Mapping[str, float] | Sequence[float]) -> np.ndarray:
        """Check set-points and return them in channel order, unnamed channels unchanged.

        Clamping (``clamp=True``) is for slightly out-of-range numbers: a boolean, NaN or an
        infinite value is refused whatever the setting.

        Raises:
            ValueError: an unknown channel, a wrong count, a boolean, a value that is NaN or
                infinite, or one that is negative or above ``max_pressure_bar`` (unless the bank
                clamps); the message names the channel.
        """
        out = self._setpoints_bar.copy()
        if isinstance(pressures, Mapping):
            items = list(pressures.items())
            for name, _ in items:
                if name not in self._channels:
                    raise ValueError(f"unknown valve channel {name!r}; channels are {', '.join(self._channels)}")
        else:
            values = list(pressures)
            if len(values) != len(self._channels):
                raise ValueError(f"expected {len(self._channels)} pressures in channel order "
                                 f"({', '.join(self._channels)}), got {len(values)}")
            items = list(zip(self._channels, values, strict=True))
        for name, value in items:
            if isinstance(value, bool | np.bool_):  # float(True) == 1.0: a flag slipped into the command
                raise ValueError(f"channel {name}: pressure {value} is a boolean, not a number of bar")
            try:
                bar = float(value)
            except (TypeError, ValueError) as e:
                raise ValueError(f"channel {name}: pressure {value!r} is not a number") from e
            if math.isnan(bar):
                raise ValueError(f"channel {name}: pressure is NaN")
            if math.isinf(bar):
                raise ValueError(f"channel {name}: pressure {bar} is not finite")
            if bar < 0 or bar > self._max_pressure_bar:
                if not self._clamp:
                    raise ValueError(f"channel {name}: {bar} bar is outside [0, {self._max_pressure_bar}] bar")
                clamped = min(max(bar, 0.0), self._max_pressure_bar)
                _log.warning("channel %s: %s bar clamped to %s bar", name, bar, clamped)
                bar = clamped
            out[self._channels.index(name)] = bar
        return out

    def set_pressures(self, pressures: Mapping[str, float] | Sequence[float]) -> None:
        """Command set-points by channel name (others keep theirs) or for all channels in order.

        Safe to call from several threads; calls are applied one at a time.

        Raises:
            NotConnectedError: before ``connect()``, or once ``close()`` has started.
            ValueError: a set-point ``validated`` refuses (nothing is sent).
            DeviceError: the device failed or refused the command.
        """
        me = threading.get_ident()
        with self._state:
            if self._closing:
                raise NotConnectedError(f"{type(self).__name__}: set_pressures() while the bank is closing")
            if not self.is_connected:
                when = "after close()" if self._closed else "before connect()"
                raise NotConnectedError(f"{type(self).__name__}: set_pressures() {when}; the bank is not connected")
            self._applying.append(me)
        try:
            with self._apply_lock:
                setpoints = self.validated(pressures)
                self._apply(setpoints)
                self._setpoints_bar = setpoints
        finally:
            with self._state:
                self._applying.remove(me)
                self._state.notify_all()

    def check(self) -> None:
        """Raise the fault the device recorded in the background, if any; otherwise do nothing.

        Call it once per control-loop frame: a device that lost its link, was vented by its own
        watchdog or had its e-stop pressed between two commands reports it here, without waiting
        for the next ``set_pressures()``. This base implementation has nothing to report.

        Raises:
            DeviceError: a subclass naming the fault (for ``hardware.valves.SerialValveBank``:
                ``LinkLostError``, ``EStopError``, ``BoardReplyError``).
        """
        return  # not abstract on purpose: a device with no background activity has nothing to record

    def vent(self) -> None:
        """Command 0 bar on every channel.

        The remembered set-points are zeroed even when the device reports a fault while venting:
        a later partial ``set_pressures()`` (after a reconnect) must start from 0 bar on the
        channels it does not name, never from the pressures before the vent.
        """
        try:
            if self.is_connected:
                self._vent()
        finally:
            self._setpoints_bar = np.zeros(len(self._channels))

    def close(self) -> None:
        """Vent, then release the device. Closing twice is harmless.

        From the moment this starts, ``set_pressures()`` in other threads raises
        ``NotConnectedError``; one already under way is let finish (up to ``_CLOSE_WAIT_S``)
        before the vent, so the vent is the last command the device receives.
        """
        me = threading.get_ident()
        with self._state:
            self._closing += 1
        try:
            with self._state:
                # A thread that closes from inside its own set_pressures() must not wait for itself.
                drained = self._state.wait_for(lambda: all(t == me for t in self._applying),
                                               timeout=self._CLOSE_WAIT_S)
            if not drained:
                _log.error("%s: a set_pressures() did not finish within %.0f s; venting anyway",
                           type(self).__name__, self._CLOSE_WAIT_S)
        finally:  # vent and release even when the wait was interrupted (Ctrl-C)
            try:
                try:
                    self.vent()
                finally:
                    if self.is_connected:
                        self._disconnect()
            finally:
                with self._state:
                    self._closing -= 1
                    self._closed = True

    @property
    def _is_closing(self) -> bool:
        """``close()`` is under way: only the vent may still reach the device."""
        return self._closing > 0

    def __enter__(self) -> ValveBank:
        if not self.is_connected:
            self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
