"""Whether the fitted arm's sections have lengths the arm can have.

Where a section ends at the tip and its last stretch points along a line of sight, hidden behind
the rest of it, the silhouette ends early and the fitted tube ends with it: every point it shows
fits both images, its tip looks certain, and it is 60-80 mm short (the twin's random sequences,
bright_warm). The whole arm's length cannot tell: a 685 mm arm whose sections lengthen and
shorten by a third under pressure spans 0.7-1.15 of it. One section's can, once the connectors
between the sections are located on the fitted axis: an extensile last section never gets shorter
than it is at rest.
"""

from __future__ import annotations

import itertools

import numpy as np

# How far a measured stretch may lie outside its range. A connector's band is placed along the arm
# within a few millimetres where the tube runs straight through its plate, but up to about 20 mm off
# at a sharp bend (the 6 s ramp's last frame: section 1 measured 247 mm against at most 229), and the
# tip's end adds its own. The hidden ends this is for leave 45-80 mm out.
SLACK_M = 0.03
ORDINALS = ("first", "second", "third", "fourth", "fifth", "sixth", "seventh", "eighth")


def section_length_problem(connector_arcs_m: np.ndarray, length_m: float,
                           ranges_m: tuple[tuple[float, float], ...], slack_m: float = SLACK_M) -> str | None:
    """Why the sections' lengths are impossible, or None where they are possible (or cannot be told).

    Args:
        connector_arcs_m: arc length from the base to each connector located on the fitted axis.
        length_m: the fitted axis's whole length.
        ranges_m: (min, max) length of each section, base first (``EstimatorConfig.section_lengths_m``).
        slack_m: measurement slack on each stretch between two located places.

    A stretch between two located places (the base, a connector, the tip) spans one section or more
    and must lie within the sum of their ranges. Where fewer connectors are located than the arm
    has, each is taken for the one that leaves the stretches closest to their ranges. More
    connectors than the arm has: nothing is said (a connector was mistaken, not the length).
    """
    arcs = np.sort(np.asarray(connector_arcs_m, np.float64))
    sections = len(ranges_m)
    if len(arcs) == 0 or len(arcs) > sections - 1:
        return None
    lows = np.concatenate([[0.0], np.cumsum([r[0] for r in ranges_m])])
    highs = np.concatenate([[0.0], np.cumsum([r[1] for r in ranges_m])])
    places = np.concatenate([[0.0], arcs, [length_m]])
    best = None  # (how far outside, the stretch's bounds, its length, its range)
    for chosen in itertools.combinations(range(1, sections), len(arcs)):
        bounds = (0, *chosen, sections)
        worst = None
        for k in range(len(bounds) - 1):
            a, b = bounds[k], bounds[k + 1]
            stretch = places[k + 1] - places[k]
            lo, hi = lows[b] - lows[a], highs[b] - highs[a]
            off = max(lo - stretch, stretch - hi, 0.0)
            if worst is None or off > worst[0]:
                worst = (off, (a, b), stretch, (lo, hi))
        if best is None or worst[0] < best[0]:
            best = worst
    off, (a, b), stretch, (lo, hi) = best
    if off <= slack_m:
        return None
    start = "the base" if a == 0 else f"the {_ordinal(a)} connector"
    end = "the tip" if b == sections else f"the {_ordinal(b)} connector"
    what = f"section {a + 1} measures" if b == a + 1 else f"sections {a + 1}-{b} measure"
    cause = ("its end hidden (seen end-on, or behind the arm)" if stretch < lo and b == sections else
             "a connector mistaken, or the tube fitted past the arm")
    return (f"{what} {stretch * 1e3:.0f} mm from {start} to {end}, where the arm allows "
            f"{lo * 1e3:.0f}-{hi * 1e3:.0f} mm (section_lengths_m): {cause}")


def _ordinal(n: int) -> str:
    return ORDINALS[n - 1] if n <= len(ORDINALS) else f"{n}th"
