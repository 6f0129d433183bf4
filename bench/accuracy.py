"""``softarm study accuracy``: where along the arm the error is, and how it depends on the tube's
angle to the image rows, with and without the 3D tube fit.

Where the arm runs along the image rows, the rows no longer tell which left point goes with which
right one and depth has to come from elsewhere (the tube's two edges and its apparent width in
the fit; a disparity profile without it). This study shows that directly: every estimated point
of every frame is scored against the exact backbone (point to curve) and binned by its place
along the arm and by the angle its 2D centerline makes with the rows in the left image.

Writes ``accuracy.csv`` (one row per point: frame, estimator, arc fraction, angle, errors),
``accuracy_along_arm.png``, ``accuracy_vs_row_angle.png`` and ``accuracy.md``; ``softarm study accuracy``
adds the studies' ``results.csv`` (one row per estimator) and ``study.json``. Each estimator runs as
an episode of its own (``bench.episodes``) on the study's engine: the configured experiment and scene
rendered by its own twin, every frame through the bench's frame path.
"""

from __future__ import annotations

import csv
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from estimator import CenterlineEstimator, EstimatorConfig, StereoCalibration
from estimator.metrics import closest_points_on_polyline

VARIANTS = {"tube fit": {"tube_fit": True}, "disparity profile": {"tube_fit": False}}
ARC_BINS = np.linspace(0.0, 1.0, 11)
ANGLE_BINS = np.array([0.0, 10.0, 20.0, 30.0, 45.0, 60.0, 75.0, 90.01])
MAX_FRAMES = 100_000  # frames per estimator variant; beyond it, a typo


def point_errors(frames: Sequence, calibration: StereoCalibration, base: EstimatorConfig) -> list[dict]:
    """Per-point errors of each variant on every frame (warm start through the sequence, as a run).

    Args:
        frames: objects with ``left``, ``right`` (raw BGR) and ``gt_m`` ((N, 3) left camera frame).
        calibration: the pair's calibration.
        base: the estimator configuration the variants start from (its mode should be "default").

    Returns:
        Rows: frame, variant, point, arc_fraction, row_angle_deg, error_mm, x/y/z_mm, valid.
    """
    rows = []
    for name, changes in VARIANTS.items():
        estimator = CenterlineEstimator(calibration, base.replace(**changes))
        for index, frame in enumerate(frames):
            result = estimator.estimate(frame.left, frame.right)
            rows += point_rows(index, name, result.valid, result.reason, result.points, result.left_uv, frame.gt_m)
    return rows


def point_rows(index: int, variant: str, valid: bool, reason: str | None, points: np.ndarray, left_uv: np.ndarray,
               gt_m: np.ndarray) -> list[dict]:
    """The rows of one estimate: one per point (a single row with point -1 when the frame is invalid)."""
    if not valid:
        return [{"frame": index, "variant": variant, "point": -1, "valid": False, "reason": reason}]
    points = np.asarray(points, float)
    closest, _ = closest_points_on_polyline(points, np.asarray(gt_m))
    error = (points - closest) * 1e3
    step = np.gradient(np.asarray(left_uv, float), axis=0)
    angle = np.degrees(np.arctan2(np.abs(step[:, 1]), np.abs(step[:, 0])))
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    fraction = arc / max(arc[-1], 1e-12)
    return [{"frame": index, "variant": variant, "point": k, "valid": True, "reason": "",
             "arc_fraction": float(fraction[k]), "row_angle_deg": float(angle[k]),
             "error_mm": float(np.linalg.norm(error[k])), "x_mm": float(error[k, 0]),
             "y_mm": float(error[k, 1]), "z_mm": float(error[k, 2])} for k in range(len(points))]


def binned_rmse(rows: list[dict], variant: str, key: str, bins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(RMSE per bin in mm, point count per bin) of one variant's valid points by ``key``."""
    points = [r for r in rows if r["variant"] == variant and r["valid"]]
    values = np.array([r[key] for r in points])
    errors = np.array([r["error_mm"] for r in points])
    rmse, counts = np.full(len(bins) - 1, np.nan), np.zeros(len(bins) - 1, int)
    if len(values) == 0:
        return rmse, counts
    which = np.clip(np.digitize(values, bins) - 1, 0, len(bins) - 2)
    for b in range(len(bins) - 1):
        mask = which == b
        counts[b] = int(mask.sum())
        if counts[b]:
            rmse[b] = float(np.sqrt(np.mean(errors[mask] ** 2)))
    return rmse, counts


def write_accuracy_study(rows: list[dict], out: Path, frames: int) -> list[str]:
    """Write the CSV, both figures and the markdown summary; returns the headline lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bench.study_files import counted

    out.mkdir(parents=True, exist_ok=True)
    keys = ["frame", "variant", "point", "valid", "reason", "arc_fraction", "row_angle_deg", "error_mm",
            "x_mm", "y_mm", "z_mm"]
    with open(out / "accuracy.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: row.get(k, "") for k in keys})
    headline = [f"accuracy study: {counted(frames, 'frame')}, point-to-curve RMSE against the exact backbone"]
    lines = ["# Accuracy along the arm and against the angle to the image rows", "",
             f"{frames} twin frames, every estimated point scored against the exact backbone (point to curve).", "",
             "| estimator | valid frames | RMSE | x / y / z RMSE | largest |", "|---|---|---|---|---|"]
    for variant in VARIANTS:
        points = [r for r in rows if r["variant"] == variant and r["valid"]]
        valid_frames = len({r["frame"] for r in points})
        if not points:
            lines.append(f"| {variant} | 0 | - | - | - |")
            continue
        e = np.array([r["error_mm"] for r in points])
        xyz = [float(np.sqrt(np.mean(np.square([r[k] for r in points])))) for k in ("x_mm", "y_mm", "z_mm")]
        rmse = float(np.sqrt(np.mean(e**2)))
        lines.append(f"| {variant} | {valid_frames}/{frames} | {rmse:.2f} mm | "
                     f"{xyz[0]:.2f} / {xyz[1]:.2f} / {xyz[2]:.2f} mm | {e.max():.1f} mm |")
        headline.append(f"  {variant}: {valid_frames}/{frames} valid, RMSE {rmse:.2f} mm (z {xyz[2]:.2f}), "
                        f"largest {e.max():.1f} mm")
    for key, bins, xlabel, name, title in (
            ("arc_fraction", ARC_BINS, "place along the arm (0 base, 1 tip)", "accuracy_along_arm.png",
             "Error along the arm"),
            ("row_angle_deg", ANGLE_BINS, "angle of the 2D centerline to the image rows (degrees)",
             "accuracy_vs_row_angle.png", "Error against the angle to the rows")):
        fig, ax = plt.subplots(figsize=(7, 4))
        centres = 0.5 * (bins[:-1] + bins[1:])
        lines += ["", f"## {title}", "", "| bin | " + " | ".join(VARIANTS) + " |",
                  "|---|" + "---|" * len(VARIANTS)]
        table = {}
        for variant in VARIANTS:
            rmse, counts = binned_rmse(rows, variant, key, bins)
            ax.plot(centres, rmse, "o-", label=variant)
            table[variant] = (rmse, counts)
        for b in range(len(centres)):
            cells = [f"{table[v][0][b]:.2f} mm (n={table[v][1][b]})" if table[v][1][b] else "-" for v in VARIANTS]
            lines.append(f"| {bins[b]:.2f}-{bins[b + 1]:.2f} | " + " | ".join(cells) + " |")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("RMSE (mm)")
        ax.set_title(title)
        ax.grid(True, alpha=0.3)
        ax.legend()
        fig.tight_layout()
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        lines += ["", f"![{title}]({name})"]
    (out / "accuracy.md").write_text("\n".join(lines) + "\n")
    return headline


# --- softarm study accuracy ----------------------------------------------------------------------


def variant_summary(rows: list[dict], variant: str, frames: int) -> dict:
    """One ``results.csv`` row: a variant's valid frames and pooled point errors."""
    points = [r for r in rows if r["variant"] == variant and r["valid"]]
    e = np.array([r["error_mm"] for r in points])
    axes = [float(np.sqrt(np.mean(np.square([r[k] for r in points])))) if points else float("nan")
            for k in ("x_mm", "y_mm", "z_mm")]
    return {"variant": variant, "frames": frames, "valid": len({r["frame"] for r in points}),
            "rmse_mm": float(np.sqrt(np.mean(e**2))) if len(e) else float("nan"), "rmse_x_mm": axes[0],
            "rmse_y_mm": axes[1], "rmse_z_mm": axes[2], "max_mm": float(e.max()) if len(e) else float("nan")}


def accuracy_command(args) -> int:
    """``softarm study accuracy [--frames N] [--out DIR] [--engine local|ray] [--workers N]``: each variant an
    episode of the configured experiment (all its frames unless --frames), in the configured scene."""
    from bench.config import ConfigError, load_bench_config
    from bench.engines import EngineError, engine_from_args, run_episodes, workers_used
    from bench.episodes import sequence_episode, sequence_spec
    from bench.frame_record import FrameRecord
    from bench.study_files import counted, finish_study, frames_from_args, out_folder, write_results, write_study
    from twin.twin import TwinConfig

    try:
        config = load_bench_config(getattr(args, "config", None))
        engine = engine_from_args(args)
        twin = TwinConfig.load(config.sim.twin)
        frames = frames_from_args(args, config.experiment.frames, MAX_FRAMES)
        out = out_folder(args, config, "accuracy")
    except (ConfigError, ValueError) as e:
        print(f"softarm study accuracy: {e}", file=sys.stderr)
        return 2
    base = config.estimator_config(mode="default")
    specs = [sequence_spec(config, frames=frames, preset=twin.scene_preset, scene_seed=twin.scene_seed,
                           estimators={"main": base.replace(**changes).as_dict()}, tag=name)
             for name, changes in VARIANTS.items()]
    print(f"softarm study accuracy: {counted(len(specs), 'estimator')} x {counted(frames, 'frame')} on the "
          f"{engine.name} engine ...", flush=True)
    start = time.perf_counter()
    try:
        outcomes = run_episodes(sequence_episode, specs, engine, label="accuracy",
                                progress=not getattr(args, "no_progress", False))
    except EngineError as e:
        print(f"softarm study accuracy: {e}; nothing written", file=sys.stderr)
        return 1
    wall_s = time.perf_counter() - start
    rows = []
    for outcome in outcomes:
        if not outcome.ok:
            print(f"softarm study accuracy: {outcome.spec.tag}: the episode failed twice: {outcome.error}",
                  file=sys.stderr)
            continue
        for index, record_json in enumerate(outcome.result["records"]):
            record = FrameRecord.from_json(record_json)
            m = record.main
            rows += point_rows(index, outcome.spec.tag, m.valid, m.reason, m.points_m, m.left_uv, record.gt_m)

    def work():
        headline = write_accuracy_study(rows, out, frames)
        write_results(out, [variant_summary(rows, name, frames) for name in VARIANTS],
                      ("variant", "frames", "valid", "rmse_mm", "rmse_x_mm", "rmse_y_mm", "rmse_z_mm", "max_mm"))
        write_study(out, study="accuracy", engine=engine, workers=workers_used(engine, len(specs)), outcomes=outcomes,
                    wall_s=wall_s, configuration={"config": str(config.path), "experiment": config.experiment,
                                                  "frames": frames, "scene": twin.scene_preset,
                                                  "variants": VARIANTS, "estimator": base.as_dict()},
                    seeds={"render_noise": twin.seed, "scene": twin.scene_seed, "som": base.som_seed})
        return headline, all(o.ok for o in outcomes)

    return finish_study("accuracy", out, work)
