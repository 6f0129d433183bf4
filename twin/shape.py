"""The arm's geometry at one instant: what the physics hands to the renderer and to scoring.

World frame: metres, z up (gravity along -z), origin at the arm's base (the centre of the base
mount's lower face, where arc length s = 0); at rest the arm hangs along -z.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Plate:
    """A rigid disc on the backbone: the base mount or a baseplate between two sections.

    Attributes:
        center_world: (3,) metres, the disc's centre.
        normal_world: (3,) unit vector along the backbone, base -> tip.
        radius_m, thickness_m: disc size.
    """

    center_world: np.ndarray
    normal_world: np.ndarray
    radius_m: float
    thickness_m: float


@dataclass(frozen=True, eq=False)
class ArmShape:
    """The backbone and its surface description in the world frame.

    Attributes:
        points_world: (N, 3) metres, backbone from base to tip, N >= 100, roughly even in arc length.
        s_m: (N,) metres, arc length along the current backbone (0 at the base).
        radius_m: (N,) metres, tube radius at each point.
        plates: discs drawn in the plate colour (base mount first, then section joints).
    """

    points_world: np.ndarray
    s_m: np.ndarray
    radius_m: np.ndarray
    plates: tuple[Plate, ...] = ()

    def __post_init__(self) -> None:
        points = np.asarray(self.points_world, dtype=np.float64)
        n = len(points)
        if points.ndim != 2 or points.shape[1] != 3 or n < 2:
            raise ValueError(f"points_world: expected (N, 3) with N >= 2, got {points.shape}")
        for name in ("s_m", "radius_m"):
            if np.shape(getattr(self, name)) != (n,):
                raise ValueError(f"{name}: expected ({n},), got {np.shape(getattr(self, name))}")
        if not np.all(np.isfinite(points)):
            raise ValueError("points_world: contains NaN or infinite values")

    @property
    def length_m(self) -> float:
        return float(self.s_m[-1] - self.s_m[0])
