"""Speed and size of ``softarm run``: where the wall-clock time of a run goes, and what it writes.

    python benchmarks/run_speed.py                    # the default run: the paper's ramp, 690 frames, report included
    python benchmarks/run_speed.py --frames 60        # a quicker run of the same experiment
    python benchmarks/run_speed.py --run runs/<dir>   # the split of a run already recorded (no new run)
    python benchmarks/run_speed.py --logging          # the Rerun recording (--rrd) off and on, side by side

Prints the split between start-up (twin, renderer, first settle), the capture loop (physics,
rendering, ground truth), what runs beside it (estimation and scoring in the estimating thread, the
writer thread encoding the frames; the loop only waits when they fall behind) and the report, then
the bytes written per frame and for the whole run folder. Targets (issue 13): the default run, 690
frames, report included, within 60 s on this 2-core machine; at most 0.25 MB per twin frame and
150 MB for the default run folder with its report.

``--logging`` measures the live view's recording (``softarm run --rrd``), without the report: one run
with it on (the file's size, ``rerun rrd verify``, what handing a frame over costs the estimating
thread), then two runs with it on in alternate blocks of frames, the blocks swapped in the second, so
every frame is estimated once with the recording and once without, side by side in time: the
estimator's fps (1 / median time per frame, as a run's summary gives it) off and on. Targets (issue
15): fps lower by less than 3 % with the recording on; handing a frame over under 1 ms; the default
run's recording at most 200 MB, accepted by ``rerun rrd verify``.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
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
TARGET_FPS_DROP = 0.03
TARGET_SUBMIT_MS = 1.0
TARGET_RRD_MB = 200.0


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


class _Blocks:
    """A live view that is handed only the frames of every other block of ``block`` frames (``phase`` 0: the
    first block, 1: the second), so one run estimates half its frames with the recording on, half off."""

    def __init__(self, live, block: int, phase: int) -> None:
        self.live, self.block, self.phase = live, block, phase
        # A control: the wall-clock of a bare queue put at the same place, on the frames the view is not handed.
        self.control_s, self.control_n = 0.0, 0
        self._queue: queue.SimpleQueue = queue.SimpleQueue()

    def on(self, index: int) -> bool:
        return (index // self.block) % 2 == self.phase

    def start(self, *args, **kwargs) -> None:
        self.live.start(*args, **kwargs)

    def submit(self, record, left=None, right=None) -> None:
        if self.on(record.index):
            self.live.submit(record, left, right)
        else:
            start = time.perf_counter()
            self._queue.put(("frame", record.index, None))
            self.control_s += time.perf_counter() - start
            self.control_n += 1
            self._queue.get_nowait()

    def finish(self, summary=None) -> None:
        self.live.finish(summary)

    def close(self) -> None:
        self.live.close()


def logging_comparison(config, frames: int | None, block: int, keep: Path | None) -> bool:
    """The Rerun recording's cost: one run with it on (its file and what handing frames over costs), then
    the estimator's time per frame with it off and on, side by side; returns whether the targets are met.

    Side by side: two runs with the recording on in alternate blocks of ``block`` frames, the blocks
    swapped in the second, so every frame is estimated once with the recording on and once off, minutes
    apart at most; the machine's load drifting over a run weighs on both alike.
    """
    import statistics
    import subprocess

    from bench.live_view import LiveView, ViewTarget
    from bench.recording import load_run

    os.environ.setdefault("CI", "true")  # Rerun's viewer tools send no usage data where CI is set
    ok = True
    with tempfile.TemporaryDirectory(prefix="softarm-bench-") as tmp:
        root = keep if keep is not None else Path(tmp)
        root.mkdir(parents=True, exist_ok=True)

        def run(name: str, live) -> dict:
            try:
                outcome = run_experiment(config, RunOptions(frames=frames, out=root / name, report=False,
                                                            progress=False, live=live))
            finally:
                live.close()
            return outcome.summary

        rrd = root / "full.rrd"
        live = LiveView(ViewTarget(rrd=rrd))
        summary = run("full", live)
        verify = subprocess.run([sys.executable, "-m", "rerun_cli", "rrd", "verify", str(rrd)], capture_output=True,
                                text=True)  # the rerun-sdk wheel's CLI, whatever PATH says
        size_mb = rrd.stat().st_size / 1e6
        count = max(summary["frames"], 1)
        submit_ms, submit_cpu_ms = 1e3 * live.submit_s / count, 1e3 * live.submit_cpu_s / count
        print(f"recording on, {summary['frames']} frames: {rrd.name} {size_mb:.1f} MB (target <= {TARGET_RRD_MB:.0f} "
              f"MB: {'met' if size_mb <= TARGET_RRD_MB else 'NOT met'}); rerun rrd verify: "
              f"{'ok' if verify.returncode == 0 else 'FAILED ' + verify.stderr.strip()[-300:]}; {live.frames} frames "
              f"logged, {live.skipped_images} without their images")
        print(f"  handing a frame to the view: {submit_ms:.3f} ms wall-clock (waits for the GIL and the CPU "
              f"included), {submit_cpu_ms:.3f} ms of the estimating thread's CPU (target < {TARGET_SUBMIT_MS:g} ms: "
              f"{'met' if submit_cpu_ms < TARGET_SUBMIT_MS else 'NOT met'})")
        ok = verify.returncode == 0 and size_mb <= TARGET_RRD_MB and submit_cpu_ms < TARGET_SUBMIT_MS

        times: dict[str, dict[int, float]] = {"on": {}, "off": {}}
        hand_over = {"view": [0.0, 0], "control": [0.0, 0]}
        for phase in (0, 1):
            blocks = _Blocks(LiveView(ViewTarget(rrd=root / f"blocks{phase}.rrd")), block, phase)
            run(f"blocks{phase}", blocks)
            for record in load_run(root / f"blocks{phase}").frames:
                times["on" if blocks.on(record.index) else "off"][record.index] = record.main.total_ms
            hand_over["view"][0] += blocks.live.submit_s
            hand_over["view"][1] += blocks.live.frames
            hand_over["control"][0] += blocks.control_s
            hand_over["control"][1] += blocks.control_n
        view_ms, control_ms = (1e3 * total / max(n, 1) for total, n in hand_over.values())
        print(f"  in the side-by-side runs, handing a frame over: {view_ms:.3f} ms wall-clock; a bare queue put at "
              f"the same place (the frames the view was not handed): {control_ms:.3f} ms")
    both = sorted(set(times["on"]) & set(times["off"]))
    on_ms = [times["on"][i] for i in both]
    off_ms = [times["off"][i] for i in both]
    fps_on, fps_off = 1e3 / statistics.median(on_ms), 1e3 / statistics.median(off_ms)
    drop = 1.0 - fps_on / fps_off
    ratio = statistics.median(a / b for a, b in zip(on_ms, off_ms, strict=True))
    verdict = "met" if drop < TARGET_FPS_DROP else "NOT met"
    print(f"estimator, {len(both)} frames each estimated with the recording off and on (alternate blocks of {block}): "
          f"{fps_off:.2f} fps off, {fps_on:.2f} fps on: {100 * drop:+.1f} % lower with it on (target < "
          f"{100 * TARGET_FPS_DROP:.0f} %: {verdict}); median per-frame time ratio on/off {ratio:.3f}")
    return ok and drop < TARGET_FPS_DROP


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, help="frames over the experiment (default: the config's, 690)")
    parser.add_argument("--config", help="bench config (default models/bench.toml)")
    parser.add_argument("--compare", action="store_true", help="also run the paper mode on every frame")
    parser.add_argument("--no-report", action="store_true", help="time the run without its report")
    parser.add_argument("--out", help="run folder to keep (default: a temporary folder, deleted)")
    parser.add_argument("--run", help="print the split of an existing run folder instead of running")
    parser.add_argument("--logging", action="store_true",
                        help="compare the estimator's fps with the Rerun recording off and on (needs the [view] extra)")
    parser.add_argument("--block", type=int, default=30,
                        help="with --logging: frames per block with the recording on, then off (default 30)")
    args = parser.parse_args(argv)
    print(f"machine: {os.cpu_count()} CPUs")
    if args.logging:
        ok = logging_comparison(load_bench_config(args.config), args.frames, args.block,
                                Path(args.out) if args.out else None)
        return 0 if ok else 1
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
