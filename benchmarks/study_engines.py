"""Speed of the studies' engines: workers, Ray against the local pool, and what one core adds.

    python benchmarks/study_engines.py                      # robustness study, 60 frames per condition, 3 repeats
    python benchmarks/study_engines.py --frames 12 --repeats 1   # a quicker pass

Runs ``softarm study robustness`` (every condition) side by side, alternating per repeat:
the local engine with ``--workers 1`` and ``--workers 2``, and the Ray engine (a local Ray of 2
CPUs) with ``--workers 1`` and ``2``; times are medians over the repeats (the machine is shared).
Then checks that every run's ``results.csv`` matches the first local run's line by line (outside
the timing columns) and that its ``frames.csv`` is identical.

Prints, against issue 16's targets:

- identical tables: the local and Ray engines give the same table for the same study;
- speed-up of ``--workers 2`` over ``--workers 1`` on the local engine (target >= 1.6x);
- Ray's overhead per episode (target <= 0.5 s): the Ray run's wall time, less the time inside its
  episodes, per episode (one worker: nothing overlaps), against the same for the local pool; and
  the round trip of a task that does nothing (``ray.init`` excluded from both; shown apart);
- episodes per hour per core: 3600 s over the median time inside one episode of one worker (what
  one more core of a cluster node adds), with the episode's size.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from bench.config import load_bench_config
from bench.engines import EngineConfig, run_episodes, start_ray
from bench.robustness import CONDITIONS, parse_condition, robustness_study
from bench.study_files import table_differences

TARGET_SPEEDUP = 1.6
TARGET_RAY_OVERHEAD_S = 0.5
NULL_TASKS = 40


def null_episode(spec: int) -> int:
    """An episode that does nothing: what remains of its time is the engine's."""
    return spec


def run_study(engine: EngineConfig, frames: int, out: Path) -> dict:
    config = load_bench_config()
    conditions = [parse_condition(c, 0) for c in CONDITIONS]
    start = time.perf_counter()
    result = robustness_study(config, conditions, frames, out, engine, progress=False)
    wall = time.perf_counter() - start
    study = result["study"]
    return {"engine": engine.name, "workers": engine.workers, "wall_s": wall, "study_wall_s": study["wall_s"],
            "inside_s": study["episode_s"]["sum"], "episode_median_s": study["episode_s"]["median"],
            "episodes": study["episodes"], "out": str(out)}


def null_round_trip(engine: EngineConfig) -> float:
    """Seconds per task that does nothing, the engine already up (one warm-up batch first)."""
    run_episodes(null_episode, list(range(4)), engine, progress=False)
    start = time.perf_counter()
    run_episodes(null_episode, list(range(NULL_TASKS)), engine, progress=False)
    return (time.perf_counter() - start) / NULL_TASKS


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=60, help="frames per condition (default 60: the full study)")
    parser.add_argument("--repeats", type=int, default=3, help="side-by-side repeats; medians are reported")
    parser.add_argument("--no-ray", action="store_true", help="the local engine only")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("--keep", help="keep every run's study folder under this folder (default: a temporary one)")
    args = parser.parse_args()
    engines = [EngineConfig("local", 1), EngineConfig("local", 2)]
    ray = None
    if not args.no_ray:
        ray, _ = start_ray(EngineConfig("ray", 2))  # one local Ray of 2 CPUs for every Ray run
        engines += [EngineConfig("ray", 1), EngineConfig("ray", 2)]
    runs: dict[tuple[str, int], list[dict]] = {(e.name, e.workers): [] for e in engines}
    print(f"robustness study: {len(CONDITIONS)} conditions x {args.frames} frames; {args.repeats} repeat(s) of "
          f"{', '.join(f'{e.name} x{e.workers}' for e in engines)}; {os.cpu_count()} CPUs", flush=True)
    with tempfile.TemporaryDirectory() as scratch:
        tmp = args.keep or scratch
        for repeat in range(args.repeats):
            order = engines if repeat % 2 == 0 else engines[::-1]
            for engine in order:
                out = Path(tmp) / f"{engine.name}{engine.workers}_{repeat}"
                run = run_study(engine, args.frames, out)
                runs[(engine.name, engine.workers)].append(run)
                print(f"  repeat {repeat + 1}: {engine.name} --workers {engine.workers}: {run['wall_s']:.1f} s "
                      f"({run['inside_s']:.1f} s inside episodes)", flush=True)
        reference = Path(runs[("local", 1)][0]["out"])
        differences = {}
        for key, items in runs.items():
            for run in items:
                problems = table_differences(reference / "results.csv", Path(run["out"]) / "results.csv")
                if (reference / "frames.csv").read_text() != (Path(run["out"]) / "frames.csv").read_text():
                    problems.append("frames.csv differs")
                if problems:
                    differences[f"{key[0]} x{key[1]} {run['out']}"] = problems
        null = {"local": null_round_trip(EngineConfig("local", 2))}
        if ray is not None:
            null["ray"] = null_round_trip(EngineConfig("ray", 2))
    if ray is not None:
        ray.shutdown()

    def median(key, field):
        return statistics.median(r[field] for r in runs[key])

    w1, w2 = median(("local", 1), "study_wall_s"), median(("local", 2), "study_wall_s")
    speedup = w1 / w2
    overhead = {name: statistics.median((r["study_wall_s"] - r["inside_s"]) / r["episodes"] for r in runs[(name, 1)])
                for name in ("local", "ray") if (name, 1) in runs}
    episode_s = median(("local", 1), "episode_median_s")
    per_hour = 3600.0 / episode_s
    figures = {"frames": args.frames, "conditions": len(CONDITIONS), "repeats": args.repeats,
               "runs": {f"{k[0]} x{k[1]}": v for k, v in runs.items()}, "identical_tables": not differences,
               "differences": differences, "speedup_workers_2": speedup,
               "overhead_per_episode_s": overhead, "null_task_s": null,
               "episode_s_one_core": episode_s, "episodes_per_hour_per_core": per_hour}
    print()
    print(f"identical tables (results.csv outside the timing columns, frames.csv whole), every run against the "
          f"first local run: {'yes' if not differences else 'NO'}")
    for name, problems in differences.items():
        print(f"  {name}: {problems[:3]}")
    for key in runs:
        print(f"{key[0]:5s} --workers {key[1]}: median {median(key, 'study_wall_s'):6.1f} s for {len(CONDITIONS)} "
              "episodes")
    print(f"speed-up, local --workers 2 over --workers 1: {speedup:.2f}x (target >= {TARGET_SPEEDUP}x): "
          f"{'met' if speedup >= TARGET_SPEEDUP else 'MISSED'}")
    for name, seconds in overhead.items():
        print(f"overhead per episode, {name} engine, one worker (wall less the time inside episodes): {seconds:.2f} s")
    if "ray" in overhead:
        extra = overhead["ray"] - overhead["local"]
        print(f"Ray's overhead per episode over the local pool: {extra:+.2f} s; a null task's round trip: "
              f"{1e3 * null['ray']:.1f} ms on Ray, {1e3 * null['local']:.1f} ms on the pool (target <= "
              f"{TARGET_RAY_OVERHEAD_S} s: {'met' if overhead['ray'] <= TARGET_RAY_OVERHEAD_S else 'MISSED'})")
    print(f"one episode ({args.frames} frames of the paper's ramp, both modes) on one core: {episode_s:.1f} s -> "
          f"{per_hour:.0f} episodes per hour per core")
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2, default=str) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
