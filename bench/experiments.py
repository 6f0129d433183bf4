"""Experiments as pure schedules: commanded pressures as a function of time, and capture times.

A :class:`Schedule` knows nothing about devices or clocks: ``softarm run`` advances the twin to
each change and capture time (simulated seconds) or waits for them on a monotonic clock (the
rig), and commands ``levels_at(t)``. Every kind of experiment is a staircase of levels (the
valves take set-points, not trajectories), so a schedule is the list of its change times with
the levels that hold from each one on.

    schedule = make_schedule(config.experiment)           # the paper's ramp, 690 captures
    schedule = make_schedule(config.experiment, frames=20) # the same ramp, 20 captures
    schedule.command_at(12.5)                              # {"s1_a": 0.5, "s2_a": 0.5, "s3": 0.5}
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.config import ExperimentConfig, frames_problem

# Levels are rounded to this (bar) so a staircase of 0.05 bar steps reads 0.35, not 0.35000000000000003.
_LEVEL_DECIMALS = 6


@dataclass(frozen=True, eq=False)
class Schedule:
    """A staircase of commanded pressures and the times the camera captures.

    Attributes:
        kind: the experiment kind ("ramp", "step", "sweep", "random").
        channels: the driven valves, in the column order of ``levels_bar``.
        change_times_s: (K,) increasing times (s from the start) at which the levels change;
            the first is 0.
        levels_bar: (K, C) the levels commanded from each change time on.
        capture_times_s: (N,) non-decreasing capture times within [0, duration_s].
        duration_s: length of the experiment.
    """

    kind: str
    channels: tuple[str, ...]
    change_times_s: np.ndarray
    levels_bar: np.ndarray
    capture_times_s: np.ndarray
    duration_s: float

    def __post_init__(self) -> None:
        k, c = self.levels_bar.shape
        if c != len(self.channels) or self.change_times_s.shape != (k,) or k == 0:
            raise ValueError(f"Schedule: levels {self.levels_bar.shape} do not fit {len(self.channels)} channels "
                             f"and {self.change_times_s.shape} change times")
        if self.change_times_s[0] != 0 or np.any(np.diff(self.change_times_s) <= 0):
            raise ValueError("Schedule: change times must start at 0 and increase")
        if len(self.capture_times_s) == 0 or np.any(np.diff(self.capture_times_s) < 0):
            raise ValueError("Schedule: capture times must be non-empty and non-decreasing")
        for array in (self.change_times_s, self.levels_bar, self.capture_times_s):
            array.setflags(write=False)

    @property
    def frames(self) -> int:
        return len(self.capture_times_s)

    @property
    def max_bar(self) -> float:
        return float(self.levels_bar.max())

    def step_index(self, t_s: float) -> int:
        """Index of the level that holds at ``t_s`` (the last change at or before it)."""
        return max(0, int(np.searchsorted(self.change_times_s, t_s + 1e-9, side="right")) - 1)

    def levels_at(self, t_s: float) -> np.ndarray:
        """(C,) levels commanded at ``t_s`` seconds, bar."""
        return self.levels_bar[self.step_index(t_s)].copy()

    def command_at(self, t_s: float) -> dict[str, float]:
        """The set-points at ``t_s`` by channel name (what ``ValveBank.set_pressures`` takes)."""
        return self.command(self.step_index(t_s))

    def command(self, step: int) -> dict[str, float]:
        """The set-points of change ``step`` by channel name."""
        return {name: float(v) for name, v in zip(self.channels, self.levels_bar[step], strict=True)}

    def describe(self) -> str:
        """One line for people: kind, channels, pressures, duration, frames."""
        lo, hi = float(self.levels_bar.min()), self.max_bar
        return (f"{self.kind}: {', '.join(self.channels)} between {lo:g} and {hi:g} bar, "
                f"{len(self.change_times_s)} levels over {self.duration_s:g} s, {self.frames} frames")

    def as_dict(self) -> dict:
        """JSON-ready description (for the run folder's config.json)."""
        return {"kind": self.kind, "channels": list(self.channels), "duration_s": self.duration_s,
                "change_times_s": self.change_times_s.tolist(), "levels_bar": self.levels_bar.tolist(),
                "capture_times_s": self.capture_times_s.tolist()}


def make_schedule(config: ExperimentConfig, frames: int | None = None) -> Schedule:
    """The schedule of an ``[experiment]`` section.

    Args:
        config: the experiment.
        frames: captures spread evenly over the whole experiment instead of ``config.frames``
            (first at 0 s, last at the end); ``softarm run --frames N``.

    Raises:
        ValueError: ``frames`` out of bounds (below 1, above ``bench.config.MAX_FRAMES``, or more
            captures per second than ``bench.config.MAX_CAPTURE_RATE_HZ``), before anything is allocated.
    """
    n = config.frames if frames is None else frames
    problem = frames_problem(n, config.duration_s)
    if problem:
        raise ValueError(f"--frames: {problem}")
    builders = {"ramp": _ramp, "step": _step, "sweep": _sweep, "random": _random}
    times, levels = builders[config.kind](config)
    times = np.asarray(times, dtype=float)
    levels = np.round(np.asarray(levels, dtype=float).reshape(len(times), len(config.channels)), _LEVEL_DECIMALS)
    captures = np.linspace(0.0, config.duration_s, n)
    return Schedule(config.kind, tuple(config.channels), times, levels, captures, float(config.duration_s))


def staircase(start_bar: float, max_bar: float, step_bar: float) -> np.ndarray:
    """Levels start, start + step, ... up to max (max itself included even when not on the grid)."""
    count = math.floor((max_bar - start_bar) / step_bar + 1e-9)
    levels = start_bar + step_bar * np.arange(count + 1)
    if max_bar - levels[-1] > 1e-9:
        levels = np.append(levels, max_bar)
    return levels  # bench.config.staircase_count(...) levels: the count the config's bounds were checked on


def _ramp(c: ExperimentConfig):
    """All channels together up the staircase, each level held an equal share of the duration."""
    levels = staircase(c.start_bar, c.max_bar, c.step_bar)
    times = np.arange(len(levels)) * c.duration_s / len(levels)
    return times, np.repeat(levels[:, None], len(c.channels), axis=1)


def _step(c: ExperimentConfig):
    """Start level, then the maximum from ``step_at_s`` on."""
    channels = len(c.channels)
    if c.step_at_s == 0:
        return [0.0], [[c.max_bar] * channels]
    return [0.0, c.step_at_s], [[c.start_bar] * channels, [c.max_bar] * channels]


def _sweep(c: ExperimentConfig):
    """Each channel in turn up the staircase and back down; the others hold the start level."""
    up = staircase(c.start_bar, c.max_bar, c.step_bar)
    triangle = np.concatenate([up, up[-2::-1]])
    share = c.duration_s / len(c.channels)
    times, levels = [], []
    for i in range(len(c.channels)):
        for k, level in enumerate(triangle):
            times.append(i * share + k * share / len(triangle))
            row = np.full(len(c.channels), c.start_bar)
            row[i] = level
            levels.append(row)
    return times, levels


def _random(c: ExperimentConfig):
    """Seeded random levels on the step grid, held ``hold_s`` each; the first hold is the start level
    (frame 0 shows the arm at rest, as in the other experiments)."""
    grid = staircase(c.start_bar, c.max_bar, c.step_bar)
    holds = max(1, math.ceil(c.duration_s / c.hold_s - 1e-9))
    rng = np.random.default_rng(c.seed)
    levels = grid[rng.integers(0, len(grid), size=(holds, len(c.channels)))]
    levels[0] = c.start_bar
    return np.arange(holds) * c.hold_s, levels
