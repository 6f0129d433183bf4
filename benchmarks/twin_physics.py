"""Physics real-time factor of the arm at the model's default resolution.

    python benchmarks/twin_physics.py [--runs 5] [--seconds 10]

Each run simulates the paper's ramp (s1_a, s2_a and s3 from 0 to 2.5 bar) for ``--seconds`` of
simulated time, commanding a new pressure every 50 ms as the bench does between frames, and the
real-time factor is simulated seconds per wall-clock second. Prints the median over the runs (and
the spread); also the per-step cost and the rate of one long ``advance`` (no command changes).
Target (issue 3): >= 10x real time on a 2-core machine. Run it on an idle machine.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from twin.params import ArmParams
from twin.physics import ArmSimulation

RAMP = ("s1_a", "s2_a", "s3")


def ramp_rtf(sim: ArmSimulation, seconds: float, chunk_s: float = 0.05) -> float:
    sim.reset()
    chunks = int(round(seconds / chunk_s))
    mask = np.array([c in RAMP for c in sim.channels], dtype=float)
    start = time.perf_counter()
    for k in range(chunks):
        sim.command(mask * sim.max_pressure_bar * (k + 1) / chunks)
        sim.advance(chunk_s)
    return seconds / (time.perf_counter() - start)


def long_advance_rtf(sim: ArmSimulation, seconds: float) -> float:
    sim.reset()
    sim.command(np.full(len(sim.channels), 1.0))
    start = time.perf_counter()
    sim.advance(seconds)
    return seconds / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5, help="timed runs; the median is quoted (default 5)")
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per run")
    parser.add_argument("--params", type=Path, default=None, help="arm parameter file (default models/arm.toml)")
    args = parser.parse_args()

    params = ArmParams.load(args.params)
    sim = ArmSimulation(params)
    links = [s.n_links for s in params.sections]
    print(f"model: {len(params.sections)} sections x {links} links, nv = {sim.model.nv}, nu = {sim.model.nu}, "
          f"timestep {sim.timestep_s * 1e3:g} ms, integrator implicitfast")
    ramp_rtf(sim, 1.0)  # warm-up
    rtf = [ramp_rtf(sim, args.seconds) for _ in range(args.runs)]
    long = [long_advance_rtf(sim, args.seconds) for _ in range(args.runs)]
    median = statistics.median(rtf)
    print(f"ramp with a command every 50 ms: real-time factor {median:.1f}x "
          f"(median of {args.runs} runs of {args.seconds:g} s; min {min(rtf):.1f}x, max {max(rtf):.1f}x)")
    print(f"one long advance:                real-time factor {statistics.median(long):.1f}x")
    print(f"cost per {sim.timestep_s * 1e3:g} ms step: {sim.timestep_s / median * 1e6:.0f} us")
    print(f"target >= 10x: {'met' if median >= 10 else 'NOT met'}")


if __name__ == "__main__":
    main()
