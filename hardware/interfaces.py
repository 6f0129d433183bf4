"""Device contracts: what the bench needs from a stereo camera and a valve bank.

The real rig (``hardware.zed``, ``hardware.valves``) and the digital twin (``twin``) implement
these, so experiments run unchanged on either. Only the contract lives here: no I/O.
"""

from __future__ import annotations

import logging
import math
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

    Subclasses implement ``_apply(setpoints_bar)`` and ``_vent()``; this class owns the
    validation, so no implementation can send an unchecked set-point.
    """

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

        Raises:
            ValueError: an unknown channel, a wrong count, or a value that is NaN, negative or
                above ``max_pressure_bar`` (unless the bank clamps); the message names the channel.
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
            try:
                bar = float(value)
            except (TypeError, ValueError) as e:
                raise ValueError(f"channel {name}: pressure {value!r} is not a number") from e
            if math.isnan(bar):
                raise ValueError(f"channel {name}: pressure is NaN")
            if bar < 0 or bar > self._max_pressure_bar:
                if not self._clamp:
                    raise ValueError(f"channel {name}: {bar} bar is outside [0, {self._max_pressure_bar}] bar")
                clamped = min(max(bar, 0.0), self._max_pressure_bar)
                _log.warning("channel %s: %s bar clamped to %s bar", name, bar, clamped)
                bar = clamped
            out[self._channels.index(name)] = bar
        return out

    def set_pressures(self, pressures: Mapping[str, float] | Sequence[float]) -> None:
        """Command set-points by channel name (others keep theirs) or for all channels in order."""
        if not self.is_connected:
            raise NotConnectedError(f"{type(self).__name__}: set_pressures() before connect()")
        setpoints = self.validated(pressures)
        self._apply(setpoints)
        self._setpoints_bar = setpoints

    def vent(self) -> None:
        """Command 0 bar on every channel."""
        if self.is_connected:
            self._vent()
        self._setpoints_bar = np.zeros(len(self._channels))

    def close(self) -> None:
        """Vent, then release the device. Closing twice is harmless."""
        try:
            self.vent()
        finally:
            if self.is_connected:
                self._disconnect()

    def __enter__(self) -> ValveBank:
        if not self.is_connected:
            self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
