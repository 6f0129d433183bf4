"""``softarm replay RUN``: re-run an estimator configuration on a recorded run's frames and score it again.

The recorded raw frames are fed in order to one estimator (so its warm start behaves as in the
run), each through the same frame path as the run (``bench.process.process``): scored against the
recorded ground truth (``gt_m``) and, where the run kept depth maps, against Q'; the result is a
new run-like folder (``frames.jsonl``, ``summary.json``, ``config.json``, the calibration) whose
records point at the original frames, so ``softarm report`` works on it too. With the run's own
configuration (no ``--mode`` or ``--centerline``) and lossless frames the estimates are those
recorded, bit for bit: the pipeline is deterministic and the twin's frames are rebuilt exactly
(their noise-free render with the same sensor noise drawn again, ``Run.image``).
"""

from __future__ import annotations

import os
import shutil
import sys
import time
from pathlib import Path

from bench.config import RecordingConfig
from bench.frame_record import FrameRecord
from bench.process import Capture, process
from bench.recording import (
    CALIBRATION_FILE,
    EXIT_FAILED,
    EXIT_NOT_A_RUN,
    EXIT_OK,
    Run,
    RunFolderError,
    RunWriter,
    load_run,
    new_run_folder,
    point_latest,
    summarize_run,
    unreadable_frames_note,
)
from bench.scoring import summary_table
from estimator import CenterlineEstimator, EstimatorConfig
from hardware.interfaces import StereoFrame


def replay_command(args) -> int:
    """Entry point of ``softarm replay RUN [--mode ...] [--centerline ...] [--out DIR]``.

    Returns:
        0 replayed; 1 the replay failed (nothing to replay, the output folder is taken or cannot be
        written); 2 RUN is not a readable run folder (or its recorded estimator settings are bad),
        as ``softarm report`` answers.
    """
    try:
        run = load_run(Path(args.run_dir))
        config = replay_estimator_config(run, getattr(args, "mode", None), getattr(args, "centerline", None))
    except (RunFolderError, ValueError) as e:
        print(f"softarm replay: {e}", file=sys.stderr)
        return EXIT_NOT_A_RUN
    given = getattr(args, "out", None)
    out = Path(given) if given else new_run_folder(RecordingConfig().runs_root(),
                                                   f"replay_{time.strftime('%Y-%m-%d_%H%M%S')}")
    try:
        summary = replay(run, config, out, progress=True)
    except (RunFolderError, OSError) as e:
        print(f"softarm replay: {e}", file=sys.stderr)
        return EXIT_FAILED
    if not given:
        point_latest(out)
    label = f"replay ({config.mode}, {config.centerline})"
    print(f"replayed {summary['frames']} frames of {run.path} into {out}")
    if summary.get("skipped"):
        print(f"softarm replay: left out {unreadable_frames_note(summary['skipped'])}", file=sys.stderr)
    print("recorded:")
    for line in summary_table(run.summary, label=f"recorded ({run.summary.get('mode')})"):
        print("  " + line)
    print("replayed:")
    for line in summary_table(summary, label=label):
        print("  " + line)
    print(f"write its report with: softarm report {out}")
    return EXIT_OK


def replay_estimator_config(run: Run, mode: str | None = None, centerline: str | None = None) -> EstimatorConfig:
    """The run's main estimator configuration, or the run's ``[estimator]`` table in another mode/centerline.

    Raises:
        ValueError: a bad recorded configuration.
    """
    recorded = run.section("estimators", "main")
    if recorded and mode is None and centerline is None:
        return EstimatorConfig.from_dict(recorded, source=f"{run.path} estimators.main")
    table = run.section("bench", "estimator")
    if recorded:
        table["mode"] = recorded.get("mode", table.get("mode", "default"))
    if mode is not None:
        table["mode"] = mode
    if centerline is not None:
        table["centerline"] = centerline
    return EstimatorConfig.from_dict(table, source=f"{run.path} [estimator]")


def replay(run: Run, config: EstimatorConfig, out: Path, *, progress: bool = False) -> dict:
    """Estimate every recorded frame of ``run`` with ``config`` into the run-like folder ``out``.

    Returns:
        The new ``summary.json`` contents.

    Raises:
        RunFolderError: the run has no recorded frames to replay, or ``out`` already holds a run.
    """
    usable = [r for r in run.frames if r.images]
    if not usable:
        raise RunFolderError(f"{run.path}: no recorded images to replay (the run kept no frames)")
    lossy = sum(1 for r in usable if not run.lossless(r))
    if lossy:
        print(f"softarm replay: note: {lossy} frames were recorded as JPEG (lossy): scores will differ from the run's",
              file=sys.stderr)
    calibration = run.calibration
    out = Path(out)
    writer = RunWriter(out, RecordingConfig())
    shutil.copyfile(run.path / CALIBRATION_FILE, out / CALIBRATION_FILE)
    writer.write_config({**run.config, "replay_of": str(run.path.resolve()), "argv": list(sys.argv),
                         "estimators": {"main": config.as_dict()}})
    estimator = CenterlineEstimator(calibration, config)
    records: list[FrameRecord] = []
    skipped: list[str] = []  # frames whose images could not be read back, and why
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(usable), desc=f"replay {run.path.name}", unit="frame", file=sys.stderr)
    start = time.perf_counter()
    try:
        for original in usable:
            left, right = run.image(original, "left"), run.image(original, "right")
            if left is None or right is None:
                skipped.append(run.image_problem(original) or f"frame {original.index}: an image file is unreadable")
                continue
            depth_units, unit = run.depth_units(original)
            capture = Capture(index=original.index, t_s=original.t_s,
                              frame=StereoFrame(left, right, original.timestamp_s, original.camera_index),
                              commanded_bar=original.commanded_bar, chamber_bar=original.chamber_bar,
                              sim_time_s=original.sim_time_s, gt_m=original.gt_m, depth_units=depth_units,
                              depth_unit_m=unit)
            record = process(capture, {"main": estimator}, calibration)
            record = record.replace(**_pointing_at(run, original, out))
            writer.submit(record)
            records.append(record)
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
        summary = summarize_run(records, {"backend": run.backend, "estimators": {"main": config.as_dict()}},
                                wall_s=time.perf_counter() - start)
        summary.pop("fps_loop", None)  # nothing was captured: the loop's rate means nothing here
        summary.update({"replay_of": str(run.path.resolve()), "skipped_frames": len(skipped), "skipped": skipped,
                        "ground_truth": run.has_ground_truth, "depth_source": run.summary.get("depth_source")})
        writer.finish(summary)
    return summary


def _pointing_at(run: Run, original: FrameRecord, out: Path) -> dict:
    """The original frame's files, as paths relative to the replay's folder ``out``."""
    changes: dict = {"images": {side: _relative(run.path / name, out) for side, name in original.images.items()}}
    if original.clean:
        changes["clean"] = {**original.clean, "background": {side: _relative(run.path / name, out)
                                                           for side, name in original.clean["background"].items()}}
    if original.depth:
        depth = original.depth
        changes["depth"] = {**depth, "path": _relative(run.path / depth["path"], out)}
        if depth.get("background"):
            changes["depth"]["background"] = _relative(run.path / depth["background"], out)
    return changes


def _relative(target: Path, folder: Path) -> str:
    return os.path.relpath(Path(target).resolve(), Path(folder).resolve())
