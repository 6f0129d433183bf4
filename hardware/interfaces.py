"""Device contracts: what the bench needs from a stereo camera and a valve bank.

The real rig (``hardware.zed``, ``hardware.valves``) and the digital twin (``twin``) implement
these, so experiments run unchanged on either. Only the contract lives here: no I/O.
"""

from __future__ import annotations

import logging
import math
import numbers
import threading
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from estimator import StereoCalibration
from hardware.errors import NotConnectedError, WrongTypeError

_log = logging.getLogger(__name__)

# clamp=True clamps a set-point at most this fraction of the limit outside [0, limit]: a rounding
# slip past the limit is clamped, a value in the wrong unit (250000 "bar" meant as pascals) is refused.
DEFAULT_CLAMP_TOLERANCE = 0.1
MAX_CLAMP_TOLERANCE = 0.5


# --- checks of devices' numeric constructor arguments ----------------------------------------
# A boolean is refused where a number belongs (float(True) is 1.0: a flag slipped into the wrong
# argument), and so is anything float() would have to guess at (a string); NaN and infinity are
# refused before they reach a library that fails on them in its own words (pyserial raises
# OverflowError for an infinite timeout).


def is_real_number(value: object) -> bool:
    """An int, float or numpy number (not a boolean, not a string, not complex)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


def check_number(name: str, value: object, low: float, high: float, unit: str = "", *,
                 low_open: bool = False) -> float:
    """Return ``value`` as a float after checking it is a finite real number in range.

    Args:
        name: the argument's name, for the message.
        value: what the caller passed.
        low, high: the allowed range; ``high`` is inclusive, ``low`` too unless ``low_open``.
        unit: appended to the range in the message ("bar", "s").
        low_open: exclude ``low`` itself (a duration or a limit that must be positive).

    Raises:
        WrongTypeError: ``value`` is a boolean or not a real number.
        ValueError: NaN, infinite, or outside the range; the message names the argument and the range.
    """
    opening, closing = "(" if low_open else "[", ")" if math.isinf(high) else "]"
    allowed = f"{opening}{low:g}, {high:g}{closing}{' ' + unit if unit else ''}"
    if not is_real_number(value):
        kind = "a boolean" if isinstance(value, bool | np.bool_) else f"a {type(value).__name__}"
        raise WrongTypeError(f"{name}: expected a number in {allowed}, got {value!r} ({kind})")
    try:
        number = float(value)
    except OverflowError:  # an int beyond a double
        raise ValueError(f"{name}: expected a finite number in {allowed}, got {value!r:.40}") from None
    if not math.isfinite(number) or number < low or number > high or (low_open and number == low):
        raise ValueError(f"{name}: expected a finite number in {allowed}, got {value!r}")
    return number


def check_integer(name: str, value: object, low: int, high: int) -> int:
    """Return ``value`` as an int after checking it is an integer (not a boolean) in ``[low, high]``.

    Raises:
        WrongTypeError: a boolean, a float (even a whole one: ``retries=2.0`` is a slip), or not a number.
        ValueError: outside the range; the message names the argument and the range.
    """
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Integral):
        raise WrongTypeError(f"{name}: expected an integer in [{low}, {high}], got {value!r} "
                             f"(a {'boolean' if isinstance(value, bool | np.bool_) else type(value).__name__})")
    if not low <= int(value) <= high:
        raise ValueError(f"{name}: expected an integer in [{low}, {high}], got {value!r}")
    return int(value)


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

    - ``connect()``; ``set_pressures(...)`` by name (a mapping) or in channel order (a list, a
      tuple or a 1-D array; never a string, a set or an iterator); ``vent()``;
      ``close()`` (vents, then releases; closing twice is harmless); ``with bank:`` closes on exit,
      so the valves are vented even when the block raises.
    - ``check()`` raises the fault the device recorded in the background (a link lost between
      commands, a board watchdog vent, a latched e-stop), as a ``hardware.errors.DeviceError``
      subclass, on every call until the fault is cleared; it does nothing when all is well. A control loop
      calls it once per frame so a fault stops the experiment even while no set-point changes.
      Devices that cannot fail in the background (the twin, the fakes) inherit the no-op.
    - Set-points outside [0, ``max_pressure_bar``] raise ``ValueError`` naming the channel; with
      ``clamp=True`` those within ``clamp_tolerance`` of the range (a fraction of the limit,
      default 10 %) are clamped with a warning instead. NaN, infinity and booleans are refused
      whatever the setting.
    - Once ``close()`` has started, ``set_pressures()`` in any thread raises
      ``NotConnectedError``; ``close()`` waits for a ``set_pressures()`` already under way (which
      completes, or raises ``NotConnectedError`` if the device refuses commands once closing)
      before it vents, so the vent is the last command the device receives.
    """

    # How long close() waits for a set_pressures() under way before venting regardless.
    _CLOSE_WAIT_S = 5.0

    def __init__(self, channels: Sequence[str], max_pressure_bar: float, clamp: bool = False,
                 clamp_tolerance: float = DEFAULT_CLAMP_TOLERANCE) -> None:
        """
        Args:
            channels: unique valve names, in command order.
            max_pressure_bar: the host-side limit on every channel, bar, finite and above 0.
            clamp: clamp slightly out-of-range set-points (with a warning) instead of raising.
            clamp_tolerance: how far outside [0, max_pressure_bar] ``clamp`` reaches, as a
                fraction of max_pressure_bar in [0, 0.5].

        Raises:
            WrongTypeError (a ``TypeError`` and a ``ValueError``): an argument of the wrong type
                (``max_pressure_bar=True``, ``clamp=1``).
            ValueError: duplicate or empty channel names, or a number outside its range; the
                message names the argument and the range.
        """
        if isinstance(channels, str | bytes) or not isinstance(channels, Sequence):
            raise WrongTypeError(f"channels: expected a list of valve names, got {channels!r}")
        channels = tuple(channels)
        if not channels or not all(isinstance(c, str) and c for c in channels) or len(set(channels)) != len(channels):
            raise ValueError(f"channels: expected unique names, got {channels!r}")
        self._max_pressure_bar = check_number("max_pressure_bar", max_pressure_bar, 0.0, math.inf, "bar",
                                              low_open=True)
        if not isinstance(clamp, bool | np.bool_):
            raise WrongTypeError(f"clamp: expected True or False, got {clamp!r}")
        self._clamp_tolerance = check_number("clamp_tolerance", clamp_tolerance, 0.0, MAX_CLAMP_TOLERANCE,
                                             "(a fraction of max_pressure_bar)")
        self._channels = channels
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

    @property
    def clamp_tolerance_bar(self) -> float:
        """How far outside [0, max_pressure_bar] a set-point may be and still be clamped (``clamp=True``)."""
        return self._clamp_tolerance * self._max_pressure_bar

    def validated(self, pressures: Mapping[str, float] | Sequence[float]) -> np.ndarray:
        """Check set-points and return them in channel order, unnamed channels unchanged.

        ``pressures`` is a mapping channel name -> bar, or one number per channel in channel
        order as a list, a tuple or a 1-D numpy array. Anything whose order is arbitrary (a set,
        a dict's keys or values), anything consumed by reading it (an iterator, a generator) and a
        string (``"2222222"`` is seven characters, not seven pressures) is refused.

        Clamping (``clamp=True``) is for slightly out-of-range numbers: within ``clamp_tolerance``
        (a fraction of ``max_pressure_bar``) of the range. A value further out is a mistake, not a
        rounding slip (pascals typed as bar), and is refused whatever the setting, as is a NaN or
        an infinite value.

        Raises:
            WrongTypeError (a ``TypeError`` and a ``ValueError``): ``pressures`` is not a mapping or
                a sequence in channel order, or a value is a boolean, a string or not a number; the
                message names the channel.
            ValueError: an unknown channel, a wrong count, an array that is not 1-D, a value that is
                NaN or infinite, or one that is negative or above ``max_pressure_bar`` (beyond the
                clamping tolerance, when the bank clamps); the message names the channel.
        """
        out = self._setpoints_bar.copy()
        for name, value in self._named_values(pressures):
            out[self._channels.index(name)] = self._checked_bar(name, value)
        return out

    def _named_values(self, pressures: object) -> list[tuple[str, object]]:
        """Pair each value with its channel name; refuse containers whose meaning or order is a guess."""
        names = ", ".join(self._channels)
        order = f"a mapping channel -> bar, or {len(self._channels)} numbers in channel order ({names})"
        if isinstance(pressures, Mapping):
            items = list(pressures.items())
            for name, _ in items:
                if name not in self._channels:
                    raise ValueError(f"unknown valve channel {name!r}; channels are {', '.join(self._channels)}")
            return items
        if isinstance(pressures, np.ndarray):
            if pressures.ndim != 1:
                raise ValueError(f"pressures: expected {order}, got an array of shape {pressures.shape}")
            values = pressures.tolist()  # numpy scalars become Python numbers (np.bool_ becomes bool)
        elif isinstance(pressures, str | bytes | bytearray | memoryview):
            raise WrongTypeError(f"pressures: expected {order}, got {pressures!r}: a {type(pressures).__name__} "
                                 "is not a list of pressures")
        elif isinstance(pressures, bool | np.bool_):
            raise WrongTypeError(f"pressures: expected {order}, got {pressures!r} (a boolean)")
        elif isinstance(pressures, Sequence):
            values = list(pressures)
        else:  # a set (arbitrary order), a dict view, an iterator or generator, a single number, None ...
            raise WrongTypeError(f"pressures: expected {order}, got a {type(pressures).__name__}; a set or a "
                                 "dict's keys/values have no channel order and an iterator is used up by "
                                 "reading it: pass a dict, a list, a tuple or a 1-D array")
        if len(values) != len(self._channels):
            raise ValueError(f"expected {len(self._channels)} pressures in channel order ({names}), got {len(values)}")
        return list(zip(self._channels, values, strict=True))

    def _checked_bar(self, name: str, value: object) -> float:
        """One set-point as a float in [0, max_pressure_bar], clamped within the tolerance if the bank clamps."""
        if isinstance(value, bool | np.bool_):  # float(True) == 1.0: a flag slipped into the command
            raise WrongTypeError(f"channel {name}: pressure {value} is a boolean, not a number of bar")
        if not is_real_number(value):
            raise WrongTypeError(f"channel {name}: pressure {value!r} is not a number of bar "
                                 f"(a {type(value).__name__})")
        try:
            bar = float(value)
        except OverflowError:  # an int beyond a double (10**400): no pressure any valve could take
            raise ValueError(f"channel {name}: pressure {value!r:.40} is too large for a number of bar") from None
        if math.isnan(bar):
            raise ValueError(f"channel {name}: pressure is NaN")
        if math.isinf(bar):
            raise ValueError(f"channel {name}: pressure {bar} is not finite")
        limit = self._max_pressure_bar
        if 0.0 <= bar <= limit:
            return bar
        if not self._clamp:
            raise ValueError(f"channel {name}: {bar} bar is outside [0, {limit}] bar")
        margin = self.clamp_tolerance_bar
        if not -margin <= bar <= limit + margin:
            raise ValueError(f"channel {name}: {bar} bar is outside [0, {limit}] bar by more than the clamping "
                             f"tolerance of {margin:g} bar ({self._clamp_tolerance:.0%} of the limit): refused, not "
                             "clamped; is it in the wrong unit?")
        clamped = min(max(bar, 0.0), limit)
        _log.warning("channel %s: %s bar clamped to %s bar", name, bar, clamped)
        return clamped

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
