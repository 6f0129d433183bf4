"""Speed and size of ``softarm run``: where the wall-clock time of a run goes, and what it writes.

    python benchmarks/run_speed.py                    # the default run: the paper's ramp, 690 frames, report included
    python benchmarks/run_speed.py --frames 60        # a quicker run of the same experiment
    python benchmarks/run_speed.py --run runs/<dir>   # the split of a run already recorded (no new run)

Prints the split between start-up (twin, renderer, first settle), the capture loop (physics,
rendering, ground truth), what runs beside it (estimation and scoring in the estimating thread, the
writer thread encoding the frames; the loop only waits when they fall behind) and the report, then
the bytes written per frame and for the whole run folder. Targets (issue 13): the default run, 690
frames, report included, within 60 s on this 2-core machine; at most 0.25 MB per twin frame and
150 MB for the default run folder with its report.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from bench.config import load_bench_config
from bench.run import RunOptions, run_experiment

TARGET_S = 60.0
TARGET_FRAME_MB = 0.25
TARGET_RUN_MB = 150.0


def print_split(summary: dict, folder: Path, total_s: float | None, report_s: float | None) -> None:
    bench_s = summary.get("bench_s", {})
    loop_s = summary.get("wall_s", float("nan"))
    frames = summary.get("frames", 0)
    print(f"frames: {frames} ({summary.get('valid_frames')} valid)")
    if total_s is not None:
        verdict = "met" if total_s <= TARGET_S else "NOT met"
        print(f"total wall time: {total_s:.1f} s   target <= {TARGET_S:.0f} s: {verdict}")
        startup = total_s - loop_s - (report_s or 0.0)
        print(f"  start-up (twin, renderer, settle, folder, warm-up): {startup:6.1f} s")
    print(f"  loop:                                       {loop_s:6.1f} s ({frames / loop_s:.1f} frames/s)")

    def row(label: str, key: str) -> float:
        value = bench_s.get(key, float("nan"))
        print(f"    {label:40s} {value:6.1f} s  {1000 * value / max(frames, 1):6.1f} ms/frame")
        return value if value == value else 0.0

    accounted = sum(row(label, key) for label, key in (
        ("physics (MuJoCo)", "physics"), ("rendering (stereo pair + depth)", "render"), ("camera grab", "grab"),
        ("ground truth (backbone, depth)", "truth"), ("waiting for the estimating thread", "estimate_wait"))
        if key in bench_s or key != "grab")
    print(f"    {'other (queueing, progress, bookkeeping)':40s} {loop_s - accounted:6.1f} s")
    print("  beside the loop (the estimating thread):")
    for label, key in (("estimation", "estimate"), ("scoring (exact + Q')", "score"),
                       ("waiting for the writer", "record_wait")):
        row(label, key)
    writer = bench_s.get("record_thread", float("nan"))
    print(f"  writer thread (PNG + depth + JSON): {writer:.1f} s ({1000 * writer / max(frames, 1):.1f} ms/frame)")
    if report_s is not None:
        print(f"  report (plots, Fig 12 re-runs, video):      {report_s:6.1f} s")
    est = summary.get("estimator_ms", {})
    if est:
        print("  estimator stages, median ms per frame: " + ", ".join(f"{k} {v:.1f}" for k, v in est.items()))
    frames_dir = folder / "frames"
    if frames_dir.is_dir():
        stored = sum(p.stat().st_size for p in frames_dir.iterdir()) + (folder / "frames.jsonl").stat().st_size
        whole = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
        report = sum(p.stat().st_size for p in (folder / "report").rglob("*") if p.is_file()) \
            if (folder / "report").is_dir() else 0
        per_frame = stored / max(frames, 1) / 1e6
        print(f"  recorded frames (images, depth, frames.jsonl): {stored / 1e6:.1f} MB, {per_frame:.3f} MB per frame "
              f"(target <= {TARGET_FRAME_MB} MB: {'met' if per_frame <= TARGET_FRAME_MB else 'NOT met'})")
        print(f"  run folder with its report: {whole / 1e6:.1f} MB (report {report / 1e6:.1f} MB; target <= "
              f"{TARGET_RUN_MB:.0f} MB for the default run: {'met' if whole / 1e6 <= TARGET_RUN_MB else 'NOT met'})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, help="frames over the experiment (default: the config's, 690)")
    parser.add_argument("--config", help="bench config (default models/bench.toml)")
    parser.add_argument("--compare", action="store_true", help="also run the paper mode on every frame")
    parser.add_argument("--no-report", action="store_true", help="time the run without its report")
    parser.add_argument("--out", help="run folder to keep (default: a temporary folder, deleted)")
    parser.add_argument("--run", help="print the split of an existing run folder instead of running")
    args = parser.parse_args(argv)
    print(f"machine: {os.cpu_count()} CPUs")
    if args.run:
        summary = json.loads((Path(args.run) / "summary.json").read_text())
        print_split(summary, Path(args.run), None, None)
        return 0
    config = load_bench_config(args.config)
    with tempfile.TemporaryDirectory(prefix="softarm-bench-") as tmp:
        out = Path(args.out) if args.out else Path(tmp) / "run"
        start = time.perf_counter()
        outcome = run_experiment(config, RunOptions(frames=args.frames, compare=args.compare, out=out,
                                                    report=not args.no_report, progress=True))
        total = time.perf_counter() - start
        print()
        print_split(outcome.summary, out, total, outcome.timings_s.get("report"))
    return 0 if outcome.exit_code == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
