"""Reference solutions for a clamped planar rod under a load perpendicular to its base: the test oracle.

Euler's elastica with piecewise-constant bending stiffness (rigid pieces allowed) and weight per
length, plus an optional tip load, solved by shooting on the base moment (scipy ``solve_ivp`` and
``brentq``); ``linear=True`` gives the Euler-Bernoulli small-deflection solution of the same rod.
Coordinates: u along the clamped base tangent, w along the load.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq


@dataclass(frozen=True)
class Piece:
    """A stretch of rod: length, bending stiffness (math.inf for a rigid plate), load per length in N/m."""

    length_m: float
    EI_Nm2: float
    load_per_m: float


def cantilever_tip(pieces: list[Piece], tip_load_N: float = 0.0, linear: bool = False) -> tuple[float, float]:
    """Tip position (u, w) in metres of a clamped rod loaded along +w.

    Equilibrium (Kirchhoff): theta' = m / EI, m' = -W(s) cos(theta), where W(s) is the load beyond
    s and m(L) = 0; linear=True replaces cos(theta) by 1 and (u', w') = (cos, sin) by (1, theta).
    """
    lengths = np.array([p.length_m for p in pieces])
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    loads = np.array([p.load_per_m * p.length_m for p in pieces])
    beyond = np.concatenate([np.cumsum(loads[::-1])[::-1][1:], [0.0]]) + tip_load_N  # load past each piece's end

    def shoot(m0: float) -> np.ndarray:
        y = np.array([0.0, m0, 0.0, 0.0])  # theta, m, u, w
        for piece, s0, w_end in zip(pieces, starts, beyond, strict=True):
            def rhs(s, y, piece=piece, s0=s0, w_end=w_end):
                theta, m = y[0], y[1]
                load = w_end + piece.load_per_m * (s0 + piece.length_m - s)
                dtheta = 0.0 if math.isinf(piece.EI_Nm2) else m / piece.EI_Nm2
                if linear:
                    return [dtheta, -load, 1.0, theta]
                return [dtheta, -load * math.cos(theta), math.cos(theta), math.sin(theta)]

            y = solve_ivp(rhs, (s0, s0 + piece.length_m), y, method="DOP853", rtol=1e-11, atol=1e-13).y[:, -1]
        return y

    total = float(tip_load_N * lengths.sum() + sum(p.load_per_m * p.length_m * (s0 + p.length_m / 2)
                                                  for p, s0 in zip(pieces, starts, strict=True)))
    m0 = brentq(lambda m0: shoot(m0)[1], 0.0, total * 1.000001 + 1e-12, xtol=1e-14, rtol=1e-13)
    _, _, u, w = shoot(m0)
    return float(u), float(w)
