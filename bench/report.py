"""``softarm report RUN``: plots, an overlay video and a markdown summary of a run folder.

Works on any run folder ``load_run`` can read: finished, stopped, or killed (then the summary
is recomputed from the frames). Everything goes to ``RUN/report/``:

- ``fig12_axis_error.png``: per-axis error over time, against the exact backbone (left) and
  against Q' (right, the paper's measure), for the run's estimator and for the paper mode with
  the paper's compensation, with the image-nearest crossing and without compensation (Fig 12;
  the paper mode is re-run on ``[report] compensation_frames`` recorded frames);
- ``fig13_fps.png``: estimator frame rate over time (Fig 13): the run's estimator and the re-run
  paper mode with the compiled SOM and with the numpy SOM (the paper's speed class);
- ``fig10c_centerlines_3d.png``: 3D centerlines of selected frames with the ground truth (Fig 10c);
- ``fig10ab_overlay.png``: segmentation contours and 2D centerlines of selected frames drawn on
  one camera frame, first and last in red (Fig 10a, b);
- ``fig11_qprime.png``: the estimate, Q' and the exact backbone of one pose (Fig 11);
- ``overlay.mp4``: every frame with its centerline (and the projected ground truth);
- ``summary.md``: the tables beside the paper's numbers, and what each figure shows.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np

from bench.config import ConfigError, ReportConfig, build_section
from bench.frame_record import EstimateRecord
from bench.process import Capture, process
from bench.recording import (
    CONFIG_FILE,
    EXIT_FAILED,
    EXIT_NOT_A_RUN,
    EXIT_OK,
    FRAMES_FILE,
    Run,
    RunFolderError,
    load_run,
    unreadable_frames_note,
    write_json,
)
from bench.scoring import PAPER, dequantize_depth, invalid_lines, pooled_rmse, summary_table
from estimator import CenterlineEstimator, EstimatorConfig
from estimator.metrics import axis_depth_points, axis_rmse, depth_camera_points
from estimator.segmentation import arm_mask
from hardware.interfaces import StereoFrame

REPORT_DIR = "report"
_AXES = "xyz"
_LOG_FLOOR_MM = 0.01  # errors are drawn on a log scale; an exact 0 would vanish
_COLOURS = {"main": "tab:green", "paper": "tab:purple", "paper_nearest": "tab:orange", "paper_none": "tab:red",
            "paper_nearest_image": "tab:brown", "paper_numpy": "tab:blue"}
# Fig 12's re-run: the paper preset's compensation, the image-nearest crossing, none; and the paper preset
# with the numpy SOM for Fig 13's speed (its estimates equal the compiled SOM's to rounding).
_VARIANTS = {"nearest": {"compensation": "nearest"}, "nearest_image": {"compensation": "nearest_image"},
             "none": {"compensation": "none"}, "numpy": {"compensation": "nearest", "som_compiled": False}}
_VARIANT_LABELS = {"nearest": "with compensation (crossing nearest the same place along the arm)",
                   "nearest_image": "with compensation, crossing nearest in the image",
                   "none": "no compensation", "numpy": "with compensation, numpy SOM"}
CHECKS = ("holes", "self_approach", "length", "behind_camera")


def report_command(args) -> int:
    """Entry point of ``softarm report RUN``; returns 0 written, 1 failed to write, 2 RUN is not a run folder."""
    try:
        out = write_report(Path(args.run_dir), progress=True)
    except RunFolderError as e:
        print(f"softarm report: {e}", file=sys.stderr)
        return EXIT_NOT_A_RUN
    except OSError as e:  # the run folder is read-only, the disk is full, ...
        print(f"softarm report: cannot write the report of {args.run_dir}: {e}", file=sys.stderr)
        return EXIT_FAILED
    print(f"report written to {out}")
    return EXIT_OK


def write_report(run_dir: Path, *, progress: bool = False, options: Mapping | None = None) -> Path:
    """Write the report of a run folder; returns the report folder.

    Args:
        run_dir: the run folder.
        progress: print what is being drawn.
        options: ``[report]`` options overriding those recorded with the run.

    Raises:
        RunFolderError: not a run folder, or its recorded ``[report]`` options are bad.
    """
    import matplotlib

    matplotlib.use("Agg")
    run = load_run(run_dir)
    opts = {**_recorded_report_options(run), **(options or {})}
    out = run.path / REPORT_DIR
    out.mkdir(exist_ok=True)
    say = (lambda text: print(f"report: {text}", file=sys.stderr, flush=True)) if progress else (lambda text: None)
    for note in _reading_notes(run):
        say(f"note: {note}")
    written: dict[str, str] = {}
    start = time.perf_counter()
    if not run.frames:
        (out / "summary.md").write_text(f"# Run {run.path.name}\n\nNo frames were recorded.\n", encoding="utf-8")
        return out
    say("re-running the paper mode with and without misalignment compensation (Fig 12)")
    compensation = compensation_study(run, int(opts["compensation_frames"]))
    if compensation:
        write_json(out / "compensation.json", compensation_json(compensation))
    say("plots")
    for name, draw in (("fig12_axis_error.png", lambda p: _fig12(run, compensation, p)),
                       ("fig13_fps.png", lambda p: _fig13(run, p, compensation)),
                       ("fig10c_centerlines_3d.png", lambda p: _fig10c(run, int(opts["centerline_frames"]), p)),
                       ("fig10ab_overlay.png", lambda p: _fig10ab(run, int(opts["selected_frames"]), p)),
                       ("fig11_qprime.png", lambda p: _fig11(run, p))):
        note = draw(out / name)
        written[name] = note
    if opts["video"]:
        say("overlay video")
        written["overlay.mp4"] = write_overlay_video(run, out / "overlay.mp4", float(opts["video_scale"]))
    _write_markdown(run, compensation, written, out / "summary.md", time.perf_counter() - start)
    return out


def _recorded_report_options(run: Run) -> dict:
    """The run's ``[report]`` options (config.json), checked like a config file's; defaults where left out.

    Raises:
        RunFolderError: a recorded option has a bad value (named by file and key).
    """
    known = {f.name for f in dataclasses.fields(ReportConfig)}
    table = {k: v for k, v in run.report_options().items() if k in known}  # an older run's removed keys: ignored
    try:
        return dataclasses.asdict(build_section(ReportConfig, table, run.path / CONFIG_FILE, "bench.report"))
    except ConfigError as e:
        raise RunFolderError(str(e)) from e


def _reading_notes(run: Run, limit: int = 5) -> list[str]:
    """What reading the run folder found wrong: skipped lines of frames.jsonl, a recomputed summary,
    frames whose image files are gone."""
    notes = []
    if run.skipped:
        shown = "; ".join(str(line) for line in run.skipped[:limit])
        more = f"; and {len(run.skipped) - limit} more" if len(run.skipped) > limit else ""
        notes.append(f"{len(run.skipped)} line{'s' if len(run.skipped) != 1 else ''} of {FRAMES_FILE} skipped "
                     f"({shown}{more})")
    if run.summary_note and run.complete:
        notes.append(run.summary_note)
    problems = run.image_problems()
    if problems:
        notes.append(f"left out of the images and the video: {unreadable_frames_note(problems, limit)}")
    return notes


# --- Fig 12: error compensation -------------------------------------------------------------


def compensation_study(run: Run, max_frames: int) -> dict | None:
    """Re-run the paper mode on recorded frames: compensation "nearest" (the paper preset's),
    "nearest_image" and "none", and the preset with the numpy SOM (Fig 13's paper speed).

    Frames are taken evenly over the run (at most ``max_frames``, lossless images only) and fed in
    order to one estimator per variant, so the SOM warm-starts from the previous frame as in a run;
    each goes through the run's own frame path (``bench.process.process``). Each valid estimate also
    gets Table 2 the paper's way: its unsmoothed Q (the triangulated nodes) against Q' at the left
    nodes, with the depth the depth camera sees (the tube's surface) and with the exact axis's depth
    (twin only).

    Returns:
        ``{"frames": [index, ...], "t_s": [...], <variant>: [EstimateRecord, ...], "table2": {<variant>:
        [dict | None, ...]}, "summary": {variant: {...}}}``, or None when there is nothing to re-run.
    """
    if max_frames <= 0:
        return None
    candidates = [r for r in run.frames if r.images and run.lossless(r)]
    if not candidates:
        return None
    picks = _evenly(candidates, max_frames)
    table = run.section("bench", "estimator")
    calibration = run.calibration
    estimators = {variant: CenterlineEstimator(calibration, EstimatorConfig.from_dict(
        {**table, "mode": "paper", **overrides}, source=f"{run.path} [estimator]"))
        for variant, overrides in _VARIANTS.items()}
    for estimator in estimators.values():  # compile outside the timing, then start cold as a run does
        estimator.warm_up()
    out: dict = {"frames": [], "t_s": [], **{variant: [] for variant in _VARIANTS},
                 "table2": {variant: [] for variant in _VARIANTS},
                 "variants": {variant: dict(overrides) for variant, overrides in _VARIANTS.items()}}
    for record in picks:
        left, right = run.image(record, "left"), run.image(record, "right")
        if left is None or right is None:
            continue
        depth_units, unit_m = run.depth_units(record)
        capture = Capture(index=record.index, t_s=record.t_s,
                          frame=StereoFrame(left, right, record.timestamp_s, record.camera_index),
                          commanded_bar=record.commanded_bar, gt_m=record.gt_m, depth_units=depth_units,
                          depth_unit_m=unit_m)
        depth = None if depth_units is None else dequantize_depth(depth_units, unit_m)
        out["frames"].append(record.index)
        out["t_s"].append(record.t_s)
        for variant, estimator in estimators.items():
            estimate = process(capture, {"main": estimator}, calibration).main
            out[variant].append(estimate)
            out["table2"][variant].append(table2_fields(estimate, record.gt_m, depth, calibration)
                                          if estimate.valid else None)
    if not out["frames"]:
        return None
    out["summary"] = {variant: _variant_summary(out[variant], out["table2"][variant]) for variant in _VARIANTS}
    return out


def compensation_json(compensation: dict) -> dict:
    """``compensation.json``: per variant and frame what the figures use (the Q' points left out)."""
    variants = {}
    for variant in _VARIANTS:
        rows = []
        for estimate, table2 in zip(compensation[variant], compensation["table2"][variant], strict=True):
            row = {"valid": estimate.valid, "reason": estimate.reason, "flags": list(estimate.flags),
                   "misalignment_px": estimate.misalignment_px, "timings_ms": {"total": estimate.total_ms}}
            if estimate.valid:
                row.update({"errors": estimate.errors, "qprime": estimate.qprime, "table2": table2})
            rows.append(row)
        variants[variant] = rows
    return {"frames": compensation["frames"], "t_s": compensation["t_s"], **variants,
            "variants": compensation["variants"], "summary": compensation["summary"]}


def table2_fields(estimate: EstimateRecord, gt_m: np.ndarray | None, depth_m: np.ndarray | None,
                  calibration) -> dict:
    """Table 2 per frame, the paper's way: the unsmoothed Q against Q' at the left nodes.

    Returns:
        ``{"surface": {x_mm, y_mm, z_mm, count} | None, "axis": {...} | None}``: Q' with the depth
        map's depth (what a depth camera sees: the tube's surface), and with the exact axis's depth.
    """
    q = estimate.points_unsmoothed_m if len(estimate.points_unsmoothed_m) else estimate.points_m
    out: dict = {"surface": None, "axis": None}
    seen = np.ones(len(q), dtype=bool)
    if depth_m is not None:
        surface = depth_camera_points(estimate.left_uv, depth_m, calibration)
        seen = np.all(np.isfinite(surface), axis=1)  # nodes off the arm have no depth: both columns skip them
        out["surface"] = axis_rmse(q, surface)
    if gt_m is not None:
        axis = axis_depth_points(estimate.left_uv, gt_m, calibration)
        out["axis"] = axis_rmse(q, np.where(seen[:, None], axis, np.nan))
    return out


def _variant_summary(estimates: Sequence[EstimateRecord], table2s: Sequence[dict | None]) -> dict:
    valid = [e for e in estimates if e.valid]
    exact = [e.errors for e in valid if e.errors]
    qprime = [e.qprime for e in valid if e.qprime]
    totals = [e.total_ms for e in estimates if np.isfinite(e.total_ms)]
    table2 = {kind: [t[kind] for t in table2s if t and t.get(kind) and t[kind]["count"]]
              for kind in ("surface", "axis")}
    return {
        "frames": len(estimates), "valid_frames": len(valid),
        "flagged": {check: sum(check in e.flags for e in estimates) for check in CHECKS},
        "rmse_xyz_mm": [pooled_rmse(e[f"rmse_{a}_mm"] for e in exact) for a in _AXES],
        "rmse_mm": pooled_rmse(e["rmse_mm"] for e in exact),
        "median_rmse_mm": float(np.median([e["rmse_mm"] for e in exact])) if exact else float("nan"),
        "qprime_rmse_xyz_mm": [pooled_rmse(q[f"{a}_mm"] for q in qprime) for a in _AXES],
        "table2_surface_xyz_mm": [pooled_rmse(t[f"{a}_mm"] for t in table2["surface"]) for a in _AXES],
        "table2_axis_xyz_mm": [pooled_rmse(t[f"{a}_mm"] for t in table2["axis"]) for a in _AXES],
        "misalignment_px": float(np.mean([e.misalignment_px for e in valid if e.misalignment_px is not None]))
        if any(e.misalignment_px is not None for e in valid) else float("nan"),
        "fps": 1000.0 / float(np.median(totals)) if totals else float("nan"),
    }


def _fig12(run: Run, compensation: dict | None, path: Path) -> str:
    import matplotlib.pyplot as plt

    from bench.figures import plain_log_axis

    has_exact = run.has_ground_truth
    has_q = any(f.main.qprime for f in run.frames) or bool(
        compensation and any(x.qprime for x in compensation["nearest"]))
    if not (has_exact or has_q):
        return "skipped: no ground truth and no depth source, so no error to plot"
    columns = [c for c, ok in (("exact", has_exact), ("qprime", has_q)) if ok]
    fig, axes = plt.subplots(3, len(columns), figsize=(6.5 * len(columns), 8), sharex=True, squeeze=False)
    t = [f.t_s for f in run.frames]
    series = [("main", f"{run.summary.get('mode', 'default')} mode (every frame)", [f.main for f in run.frames], t)]
    if any(f.paper is not None for f in run.frames):
        series.append(("paper", "paper mode (every frame, --compare)", [f.paper for f in run.frames], t))
    if compensation:
        for variant in ("nearest", "nearest_image", "none"):
            if variant in compensation:
                series.append((f"paper_{variant}", f"paper mode, {_VARIANT_LABELS[variant]} (re-run)",
                               compensation[variant], compensation["t_s"]))
    for col, kind in enumerate(columns):
        for row, axis in enumerate(_AXES):
            ax = axes[row][col]
            for key, label, fields, times in series:
                values = np.maximum([_axis_error(f, kind, axis) for f in fields], _LOG_FLOOR_MM)
                wide = key == "paper"  # drawn under the re-run, which repeats it on the frames they share
                ax.plot(times, values, ".-" if key.startswith("paper_") else "-", color=_COLOURS[key], label=label,
                        linewidth=3 if wide else 1.2, alpha=0.45 if wide else 1.0, markersize=3)
            if kind == "qprime":
                ax.axhline(PAPER["rmse_xyz_mm"][row], color="black", linestyle=":", linewidth=1,
                           label="paper, whole-motion RMSE (Table 2)")
            plain_log_axis(ax)
            ax.set_ylabel(f"{axis} RMSE (mm)")
            ax.grid(True, which="both", alpha=0.3)
        axes[0][col].set_title("against the exact backbone" if kind == "exact"
                               else "against Q' (depth at the left centerline pixels, the paper's measure)")
        axes[-1][col].set_xlabel(f"time (s); errors under {_LOG_FLOOR_MM:g} mm (an exact 0) are drawn at "
                                 f"{_LOG_FLOOR_MM:g} mm")
    axes[0][0].legend(fontsize=7, loc="upper left")
    if len(columns) > 1:
        axes[0][1].legend(fontsize=7, loc="upper left")
    title = "Per-axis error during the motion (Fig 12)"
    if compensation and "nearest" in compensation["summary"]:
        w, wo = compensation["summary"]["nearest"]["rmse_mm"], compensation["summary"]["none"]["rmse_mm"]
        if np.isfinite(w) and np.isfinite(wo) and wo > 0:
            title += f": paper mode {w:.1f} mm with compensation, {wo:.1f} mm without ({w / wo:.2f}x)"
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return "written"


def _axis_error(estimate: EstimateRecord | None, kind: str, axis: str) -> float:
    if estimate is None or not estimate.valid:
        return math.nan
    if kind == "exact":
        return estimate.errors[f"rmse_{axis}_mm"] if estimate.errors else math.nan
    return estimate.qprime[f"{axis}_mm"] if estimate.qprime else math.nan


# --- Fig 13: frame rate ---------------------------------------------------------------------


def _fig13(run: Run, path: Path, compensation: dict | None = None) -> str:
    import matplotlib.pyplot as plt

    from bench.figures import plain_log_axis

    fig, ax = plt.subplots(figsize=(8, 3.8))
    t = np.array([f.t_s for f in run.frames])
    for key, label in (("main", f"{run.summary.get('mode', 'default')} mode"), ("paper", "paper mode")):
        estimates = [f.estimate(key) for f in run.frames]
        if key == "paper" and not any(e is not None for e in estimates):
            continue
        totals = np.array([math.nan if e is None else e.total_ms for e in estimates], dtype=float)
        fps = 1000.0 / totals
        ax.plot(t, fps, "-", color=_COLOURS[key], linewidth=1, label=f"{label} (median {np.nanmedian(fps):.1f} fps)")
    if compensation:
        for variant, label in (("nearest", "paper mode, compiled SOM (re-run)"),
                               ("numpy", "paper mode, numpy SOM (re-run)")):
            if variant not in compensation:
                continue
            totals = np.array([e.total_ms for e in compensation[variant]], dtype=float)
            fps = 1000.0 / totals
            ax.plot(compensation["t_s"], fps, ".-", color=_COLOURS[f"paper_{variant}"], linewidth=1, markersize=3,
                    label=f"{label} (median {np.nanmedian(fps):.1f} fps)")
    if len(t) > 1 and run.backend == "rig":
        ax.plot(t[1:], 1.0 / np.maximum(np.diff(t), 1e-6), color="tab:gray", linewidth=0.8,
                label="loop rate (capture to capture)")
    ax.axhline(PAPER["fps"], color="black", linestyle=":", label=f"paper: about {PAPER['fps']:g} fps")
    plain_log_axis(ax)
    ax.set_xlabel("time (s)" + (" (simulated)" if run.backend == "sim" else ""))
    ax.set_ylabel("frames per second")
    ax.set_title("Estimator frame rate (1 / time per frame) on this machine (Fig 13)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return "written"


# --- Fig 10c, 11: 3D --------------------------------------------------------------------------


def _view(points: np.ndarray) -> np.ndarray:
    """Left-camera points (x right, y down, z forward) -> plot axes (x right, depth, up)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    return np.column_stack([points[:, 0], points[:, 2], -points[:, 1]]) * 1e3


def _fig10c(run: Run, count: int, path: Path) -> str:
    import matplotlib.pyplot as plt

    valid = [f for f in run.frames if f.main.valid]
    if not valid or count <= 0:
        return "skipped: no valid frame"
    picks = _evenly(valid, count)
    fig = plt.figure(figsize=(7.5, 7))
    ax = fig.add_subplot(projection="3d")
    cmap = plt.get_cmap("viridis")
    for k, f in enumerate(picks):
        colour = cmap(k / max(len(picks) - 1, 1))
        p = _view(f.main.points_m)
        ax.plot(p[:, 0], p[:, 1], p[:, 2], "o-", color=colour, markersize=3, linewidth=1.5,
                label=f"t = {f.t_s:.1f} s")
        if f.gt_m is not None:
            g = _view(f.gt_m)
            ax.plot(g[:, 0], g[:, 1], g[:, 2], "--", color="black", linewidth=0.8, alpha=0.7)
    if any(f.gt_m is not None for f in picks):
        ax.plot([], [], "--", color="black", linewidth=0.8, label="exact backbone")
    ax.set_xlabel("x right (mm)")
    ax.set_ylabel("depth z (mm)")
    ax.set_zlabel("up -y (mm)")
    _equal_3d(ax, np.vstack([_view(f.main.points_m) for f in picks]))
    ax.set_title("3D centerlines of selected frames (Fig 10c)")
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return "written"


def _fig11(run: Run, path: Path) -> str:
    import matplotlib.pyplot as plt

    with_q = [f for f in run.frames if f.main.valid and f.main.qprime_m is not None and len(f.main.qprime_m)]
    if not with_q:
        return "skipped: no frame with depth (Q')"
    f = with_q[len(with_q) // 2]
    q = np.asarray(f.main.qprime_m, dtype=float)
    fig = plt.figure(figsize=(7, 6.5))
    ax = fig.add_subplot(projection="3d")
    p = _view(f.main.points_m)
    ax.plot(p[:, 0], p[:, 1], p[:, 2], "o-", color=_COLOURS["main"], markersize=3, label="estimate Q")
    qv = _view(q)
    ax.plot(qv[:, 0], qv[:, 1], qv[:, 2], "s", color="tab:blue", markersize=3, label="Q' (depth at the left pixels)")
    if f.gt_m is not None:
        g = _view(f.gt_m)
        ax.plot(g[:, 0], g[:, 1], g[:, 2], "--", color="black", linewidth=1, label="exact backbone")
    ax.set_xlabel("x right (mm)")
    ax.set_ylabel("depth z (mm)")
    ax.set_zlabel("up -y (mm)")
    _equal_3d(ax, p)
    ax.set_title(f"Q against Q' at t = {f.t_s:.1f} s (Fig 11)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return "written"


def _equal_3d(ax, points: np.ndarray) -> None:
    points = points[np.all(np.isfinite(points), axis=1)]
    if not len(points):
        return
    centre = (points.max(0) + points.min(0)) / 2
    half = max(float((points.max(0) - points.min(0)).max()) / 2, 1.0) * 1.1
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)


# --- Fig 10a, b: overlays --------------------------------------------------------------------


def _fig10ab(run: Run, count: int, path: Path) -> str:
    import matplotlib.pyplot as plt

    with_images = [f for f in run.frames if f.images]
    if not with_images or count <= 0:
        return "skipped: the run recorded no images"
    background = run.image(with_images[-1], "left")
    if background is None:
        return "skipped: image files missing"
    picks = _evenly(with_images, count)
    cfg = _main_estimator_config(run)
    contours_img = background.copy()
    lines_img = background.copy()
    box = np.array([np.inf, np.inf, -np.inf, -np.inf])
    order = [k for k in range(len(picks)) if k not in (0, len(picks) - 1)] + sorted({0, len(picks) - 1})
    for k in order:  # first and last drawn last, on top
        f = picks[k]
        red = k in (0, len(picks) - 1)
        colour = (0, 0, 255) if red else (255, 160, 0)
        image = run.image(f, "left")
        if image is not None:
            mask = arm_mask(image, cfg)  # on the raw image: good enough to draw the outline
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(contours_img, contours, -1, colour, 2 if red else 1, cv2.LINE_AA)
            found = cv2.findNonZero(mask)
            if found is not None:
                x, y, w, h = cv2.boundingRect(found)
                box = np.array([min(box[0], x), min(box[1], y), max(box[2], x + w), max(box[3], y + h)])
        if f.main.valid:
            uv = np.round(np.asarray(f.main.left_uv) * 4).astype(np.int32)
            cv2.polylines(lines_img, [uv.reshape(-1, 1, 2)], False, colour, 2, cv2.LINE_AA, shift=2)
            for point in uv:
                cv2.circle(lines_img, tuple(int(v) for v in point), 4 * 3, colour, -1, cv2.LINE_AA, shift=2)
    if np.all(np.isfinite(box)):  # crop to where the arm went, with a margin
        h, w = background.shape[:2]
        m = 40
        x0, y0 = int(max(box[0] - m, 0)), int(max(box[1] - m, 0))
        x1, y1 = int(min(box[2] + m, w)), int(min(box[3] + m, h))
        contours_img, lines_img = contours_img[y0:y1, x0:x1], lines_img[y0:y1, x0:x1]
    aspect = contours_img.shape[0] / max(contours_img.shape[1], 1)
    fig, axes = plt.subplots(1, 2, figsize=(12, max(3.5, min(12.0, 6 * aspect + 0.8))))
    # The paper mode's left_uv are the SOM's nodes (W_L); the default mode's, the 3D estimate projected back.
    lines_title = ("(b) 2D centerlines W_L (left image)" if cfg.mode == "paper"
                   else "(b) the 3D centerline projected into the left image")
    for ax, image, title in ((axes[0], contours_img, "(a) segmentation contours during the motion"),
                             (axes[1], lines_img, lines_title)):
        ax.imshow(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
        ax.set_title(title)
        ax.axis("off")
    fig.suptitle(f"{len(picks)} frames at equal intervals on the last frame; first and last in red (Fig 10a, b)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return "written"


def _main_estimator_config(run: Run) -> EstimatorConfig:
    values = run.section("estimators", "main")
    if not values:
        return EstimatorConfig()
    return EstimatorConfig.from_dict({k: v for k, v in values.items()}, source=f"{run.path} estimators.main")


# --- video --------------------------------------------------------------------------------


def write_overlay_video(run: Run, path: Path, scale: float) -> str:
    """Every recorded left frame with its estimated centerline (green; paper mode purple) and the
    projected exact backbone (white), as an MP4 (mp4v) at the experiment's real pace (at least 2 fps)."""
    with_images = [f for f in run.frames if f.images]
    if not with_images:
        return "skipped: the run recorded no images"
    calibration = run.calibration
    first = run.image(with_images[0], "left")
    if first is None:
        return "skipped: image files missing"
    h, w = first.shape[:2]
    size = (max(2, int(round(w * scale / 2)) * 2), max(2, int(round(h * scale / 2)) * 2))
    span = with_images[-1].t_s - with_images[0].t_s
    fps = max(2.0, (len(with_images) - 1) / span) if span > 0 else 2.0
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    if not writer.isOpened():
        return "skipped: OpenCV cannot write MP4 (mp4v) here"
    try:
        for f in with_images:
            image = run.image(f, "left")
            if image is None:
                continue
            frame = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
            sx, sy = size[0] / w, size[1] / h

            def draw(uv, colour, thickness, frame=frame, sx=sx, sy=sy):
                uv = np.asarray(uv, dtype=float).reshape(-1, 2) * (sx, sy)
                pts = np.round(uv * 4).astype(np.int32).reshape(-1, 1, 2)
                cv2.polylines(frame, [pts], False, colour, thickness, cv2.LINE_AA, shift=2)

            if f.gt_m is not None:
                draw(calibration.project(np.asarray(f.gt_m), "left"), (255, 255, 255), 1)
            if f.paper is not None and f.paper.valid:
                draw(f.paper.left_uv, (200, 60, 160), 1)
            if f.main.valid:
                draw(f.main.left_uv, (60, 200, 60), 2)
            text = f"t {f.t_s:5.1f} s  " + " ".join(f"{k} {v:.2f}" for k, v in f.commanded_bar.items() if v)
            status = (f"rmse {f.main.errors['rmse_mm']:.1f} mm" if f.main.errors
                      else ("valid" if f.main.valid else f"invalid: {f.main.reason or ''}"[:60]))
            draw_caption(frame, (text, status))
            writer.write(frame)
    finally:
        writer.release()
    return f"written ({len(with_images)} frames at {fps:.1f} fps, {size[0]}x{size[1]})"


_CAPTION_FONT, _CAPTION_SCALE, _CAPTION_PAD = cv2.FONT_HERSHEY_SIMPLEX, 0.45, 4


def draw_caption(frame: np.ndarray, lines: Sequence[str],
                 origin: tuple[int, int] = (4, 4)) -> tuple[int, int, int, int]:
    """Write ``lines`` in white on an opaque black box in the top-left corner of a BGR frame (in place).

    One thickness, one font scale and one anchor per line, all computed once: the text cannot drift
    from its background the way an outline drawn at another thickness does (OpenCV 5 measures and
    places text differently at different thicknesses).

    Returns:
        The box (x0, y0, x1, y1), pixels, clipped to the frame.
    """
    sizes = [cv2.getTextSize(line, _CAPTION_FONT, _CAPTION_SCALE, 1) for line in lines]
    line_h = max(h + base for (_, h), base in sizes) + 2
    width = max(w for (w, _), _ in sizes)
    x0, y0 = origin
    x1 = min(x0 + width + 2 * _CAPTION_PAD, frame.shape[1] - 1)
    y1 = min(y0 + line_h * len(lines) + 2 * _CAPTION_PAD, frame.shape[0] - 1)
    cv2.rectangle(frame, (x0, y0), (x1, y1), (0, 0, 0), thickness=-1)
    for k, (line, ((_, h), _)) in enumerate(zip(lines, sizes, strict=True)):
        baseline_y = y0 + _CAPTION_PAD + k * line_h + h
        cv2.putText(frame, line, (x0 + _CAPTION_PAD, baseline_y), _CAPTION_FONT, _CAPTION_SCALE, (255, 255, 255), 1,
                    cv2.LINE_AA)
    return x0, y0, x1, y1


# --- markdown -------------------------------------------------------------------------------


def _write_markdown(run: Run, compensation: dict | None, written: Mapping[str, str], path: Path,
                    elapsed_s: float) -> None:
    s = run.summary
    lines = [f"# Run {run.path.name}", ""]
    schedule = run.section("schedule")
    lines.append(f"- backend: **{run.backend}**; estimator mode: **{s.get('mode')}**"
                 + (f", 2D centerline: **{s['centerline']}**" if s.get("centerline") else "")
                 + (" (paper mode compared on every frame)" if "paper" in s else ""))
    if s.get("replay_of"):
        lines.append(f"- a replay of the run {s['replay_of']} (its recorded frames estimated again)")
    scene = run.section("scene")
    if scene:
        lines.append(f"- twin scene: **{scene.get('preset')}** (seed {scene.get('seed')}"
                     + (f", {scene['file']}" if scene.get("file") else "") + ")"
                     + (f": {scene['description']}" if scene.get("description") else ""))
    if schedule:
        try:
            levels = np.asarray(schedule.get("levels_bar", [[0]]), dtype=float)
            channels = ", ".join(map(str, schedule.get("channels", [])))
            lines.append(f"- experiment: {schedule.get('kind')} on {channels}, "
                         f"{levels.min():g} to {levels.max():g} bar over {schedule.get('duration_s')} s, "
                         f"{len(schedule.get('capture_times_s', []))} frames scheduled")
        except (TypeError, ValueError):  # edited by hand: the frames are still reported
            lines.append("- experiment: config.json's schedule is unreadable")
    lines.append(f"- frames recorded: {len(run.frames)}, valid: {s.get('valid_frames')}")
    if not run.complete and str(s.get("stopped", "")).startswith("killed"):
        lines.append(f"- **the run was killed**: no summary.json; summary recomputed from {len(run.frames)} frames")
    elif not run.complete:
        lines.append(f"- **{s.get('stopped')}** ({len(run.frames)} frames)")
    elif s.get("stopped"):
        lines.append(f"- **stopped early**: {s['stopped']}")
    lines += [f"- **{note}**" for note in _reading_notes(run, limit=20)]
    if s.get("dropped_frames"):
        lines.append(f"- dropped frames (the loop fell behind the capture schedule): {s['dropped_frames']}")
    if s.get("depth_source"):
        lines.append(f"- depth source for Q': {s['depth_source']}")
    lines += ["", "## Accuracy and speed beside the paper (Tables 2 and 3)", ""]
    lines += summary_table(s, label=f"{s.get('mode', 'default')} mode", paper_mode=s.get("paper"), markdown=True)
    lines += ["",
              "- *exact*: point-to-curve errors against the twin's backbone (sim only). Per-axis values are the "
              "RMSE of each component of the residual to the closest backbone point.",
              "- *Q'*: the paper's measure (section 5.3): per-axis RMSE against the depth camera's 3D points at "
              "the left centerline pixels. The depth is that of the tube's surface, so Q' lies about one tube "
              f"radius in front of the axis and its z error carries that offset{_radius_words(run)}. The paper's "
              "Table 2 z (5.5 mm) leaves no room for such an offset; the paper does not say how its Q' avoided it "
              "(README, the ambiguity table). The row is the estimate as returned; for the paper mode, Table 2 "
              "the paper's way (its unsmoothed nodes) follows below.",
              "- Whole-run figures pool frames like Table 2: root of the mean squared per-frame RMSE over valid "
              "frames. Table 3's maximum error is the worst per-axis RMSE (5.5122 mm -> 5.5/680).",
              "- fps: 1 / the median estimator time per frame on this machine (the paper: about 10 fps "
              "including 3D plotting)."]
    lines += _flag_lines(run, compensation)
    if compensation:
        lines += ["", "## Misalignment compensation (Fig 12)", "",
                  f"Paper mode re-run on {len(compensation['frames'])} recorded frames (evenly spread, warm start), "
                  "with the paper's compensation (a cubic spline through the right nodes; of its crossings of left "
                  "node j's row, the one nearest node j's place along the arm; nodes whose row the spline misses "
                  "or crosses under 15 degrees placed by arc length between the nodes the rows pin), with the "
                  "crossing nearest right node j in the image, and without:", "",
                  "| paper mode | valid | RMSE exact (mm) | median (mm) | RMSE x/y/z exact (mm) | "
                  "RMSE x/y/z vs Q' (mm) |", "|---|---|---|---|---|---|"]
        for variant in ("nearest", "nearest_image", "none"):
            v = compensation["summary"].get(variant)
            if v is None:
                continue
            lines.append(f"| {_VARIANT_LABELS[variant]} | {v['valid_frames']}/{v['frames']} | {_num(v['rmse_mm'])} | "
                         f"{_num(v.get('median_rmse_mm'))} | {_xyz(v['rmse_xyz_mm'])} | "
                         f"{_xyz(v['qprime_rmse_xyz_mm'])} |")
        summary = compensation["summary"]
        before = summary.get("none", {}).get("misalignment_px")
        if before is not None and np.isfinite(before):
            # eq. (11) is read off the SOM's nodes, which every row shares: one figure, not a column
            lines += ["", f"Misalignment eq. (11) between the SOM's left and right nodes before compensation: "
                      f"{_num(before)} px (mean over the frames; the same nodes in every row). Compensation pairs "
                      "each left node with a point on its own row of the right image, so the pairs it triangulates "
                      "have none."]
        if "nearest" in summary and np.isfinite(summary["nearest"]["rmse_mm"]) and summary["none"]["rmse_mm"] > 0:
            ratio = summary["nearest"]["rmse_mm"] / summary["none"]["rmse_mm"]
            lines += ["", f"With compensation the error is {ratio:.2f}x the error without (the paper: "
                      "\"RMSE is significantly reduced in each axis\")."]
        lines += _table2_lines(compensation)
    lines += _speed_lines(compensation)
    bench_s = s.get("bench_s")
    wall_s = s.get("wall_s")
    if bench_s and isinstance(bench_s, dict) and all(isinstance(v, int | float) for v in bench_s.values()) \
            and isinstance(wall_s, int | float):
        lines += ["", "## Where the time went (wall-clock seconds)", "",
                  "| " + " | ".join(bench_s) + " | loop total |", "|" + "---|" * (len(bench_s) + 1),
                  "| " + " | ".join(f"{v:.1f}" for v in bench_s.values()) + f" | {wall_s:.1f} |",
                  "", "physics, render (or grab) and truth are the capture loop; estimate and score run beside it in "
                  "the estimating thread (estimate_wait: the loop waiting for it); record_thread is the writer thread "
                  "(record_wait: the estimating thread waiting for it)."]
    if s.get("invalid_reasons"):
        lines += ["", "## Invalid frames", "", "Grouped by reason, measurements replaced by #:", ""]
        lines += [f"- {line}" for line in invalid_lines(s)]
    lines += ["", "## Figures", ""]
    for name, note in written.items():
        if note.startswith("written"):
            lines.append(f"- [{name}]({name})" + (f": {note}" if note != "written" else ""))
            if name.endswith(".png"):
                lines += ["", f"![{name}]({name})", ""]
        else:
            lines.append(f"- {name}: {note}")
    lines += ["", f"_report written in {elapsed_s:.1f} s by `softarm report {run.path}`_", ""]
    path.write_text("\n".join(lines), encoding="utf-8")


def _flag_lines(run: Run, compensation: dict | None) -> list[str]:
    """How many frames each plausibility check flagged: dropped with the checks on (default mode),
    kept and only named with them off (paper mode, which reports every frame as the paper does)."""
    columns = [("this run's estimator", [f.main for f in run.frames])]
    if any(f.paper is not None for f in run.frames):
        columns.append(("paper mode (--compare)", [f.paper for f in run.frames]))
    if compensation and "nearest" in compensation:
        columns.append(("paper mode (re-run)", compensation["nearest"]))
    if not any(e is not None and e.flags for _, estimates in columns for e in estimates):
        return ["", "## Plausibility checks", "", "No frame failed a plausibility check "
                "(a loop in the silhouette, a centerline touching itself, an implausible length, points behind the "
                "camera)."]
    lines = ["", "## Plausibility checks", "",
             "Frames each check flagged. The default mode drops a flagged frame (invalid); the paper mode keeps it "
             "and only names the check, as the paper reports every frame.", "",
             "| check | " + " | ".join(name for name, _ in columns) + " |", "|---|" + "---|" * len(columns)]
    for check in CHECKS:
        counts = [f"{sum(e is not None and check in e.flags for e in estimates)}/{len(estimates)}"
                  for _, estimates in columns]
        lines.append(f"| {check} | " + " | ".join(counts) + " |")
    return lines


def _table2_lines(compensation: dict) -> list[str]:
    v = compensation["summary"].get("nearest")
    if v is None or not any(np.isfinite(x) for x in v["table2_surface_xyz_mm"] + v["table2_axis_xyz_mm"]):
        return []
    return ["", "## Table 2 computed the paper's way", "",
            "The paper mode's unsmoothed Q (the triangulated nodes, before the 6th-degree polynomial) against Q' "
            "at its left nodes, per axis, pooled over the re-run frames: with the depth a depth camera sees (the "
            "tube's surface, about one radius in front of the axis, as the paper's ZED saw it) and with the exact "
            "axis's depth (twin only).", "",
            "| Q' from | x (mm) | y (mm) | z (mm) |", "|---|---|---|---|",
            "| surface depth (the paper's measure) | " + " | ".join(_num(x) for x in v["table2_surface_xyz_mm"]) + " |",
            "| axis depth | " + " | ".join(_num(x) for x in v["table2_axis_xyz_mm"]) + " |",
            "| Zou et al., Table 2 | " + " | ".join(f"{x:.4f}" for x in PAPER["rmse_xyz_mm"]) + " |"]


def _speed_lines(compensation: dict | None) -> list[str]:
    if not compensation or "numpy" not in compensation["summary"]:
        return []
    s = compensation["summary"]
    return ["", "## Paper mode speed (Fig 13)", "",
            "| paper mode | fps (1 / median time per frame) |", "|---|---|",
            f"| compiled SOM | {_num(s['nearest']['fps'], 1)} |", f"| numpy SOM (the paper's speed class) | "
            f"{_num(s['numpy']['fps'], 1)} |", f"| Zou et al. | about {PAPER['fps']:g} |", "",
            "Timed on the recorded frames with the machine to itself; during the run the estimator shared the "
            "cores with the twin's physics and rendering, so the run's table above reads slower."]


def _radius_words(run: Run) -> str:
    """" (the tube's radius: 24 mm)", from the run's estimator configuration; "" where it does not say."""
    radius = run.section("estimators", "main").get("arm_radius_m")
    return f" (the tube's radius here: {1000 * radius:.0f} mm)" if isinstance(radius, int | float) else ""


def _num(value, decimals: int = 2) -> str:
    return "n/a" if value is None or not np.isfinite(value) else f"{value:.{decimals}f}"


def _xyz(values) -> str:
    return " / ".join(_num(v) for v in values)


def _evenly(items: Sequence, count: int) -> list:
    """At most ``count`` items spread evenly over the sequence, first and last included."""
    if count >= len(items):
        return list(items)
    if count == 1:
        return [items[-1]]
    return [items[i] for i in np.unique(np.round(np.linspace(0, len(items) - 1, count)).astype(int))]
