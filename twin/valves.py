"""The simulated valve bank: the ``hardware.ValveBank`` contract driving an ``ArmSimulation``."""

from __future__ import annotations

import numpy as np

from hardware.errors import DeviceError
from hardware.interfaces import DEFAULT_CLAMP_TOLERANCE, ValveBank
from twin.physics import ArmSimulation


class SimValveBank(ValveBank):
    """Proportional valves of the twin: set-points become the simulation's commanded pressures.

    The base class validates every set-point exactly as for the real board (unknown channel, NaN,
    outside [0, max] -> ValueError naming the channel, clamped when ``clamp=True`` only within
    ``clamp_tolerance``; a string, a set or a boolean -> WrongTypeError); the chamber pressures then
    follow with the valve lag of the arm's parameters as the simulation advances. Closing vents all
    channels.

    Args:
        sim: the simulation to drive; its channels and maximum pressure define the bank's.
        clamp: clamp slightly out-of-range set-points (logged) instead of raising.
        clamp_tolerance: how far out of range ``clamp`` reaches, a fraction of the maximum pressure.
    """

    def __init__(self, sim: ArmSimulation, clamp: bool = False,
                 clamp_tolerance: float = DEFAULT_CLAMP_TOLERANCE) -> None:
        super().__init__(sim.channels, sim.max_pressure_bar, clamp=clamp, clamp_tolerance=clamp_tolerance)
        self._sim = sim
        self._connected = False

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        """Open the bank; the arm keeps the bank's set-points (0 bar after construction or ``close()``).

        Raises:
            DeviceError: already connected.
        """
        if self._connected:
            raise DeviceError(f"{type(self).__name__}: already connected; close() it before connecting again")
        self._sim.command(np.array([self.setpoints_bar[c] for c in self.channels]))
        self._connected = True

    def _apply(self, setpoints_bar: np.ndarray) -> None:
        self._sim.command(setpoints_bar)

    def _vent(self) -> None:
        self._sim.command(np.zeros(len(self.channels)))

    def _disconnect(self) -> None:
        self._connected = False
