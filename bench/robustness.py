"""``softarm study robustness``: the estimator in the lab scenes of the twin, default and paper modes.

One episode per condition (a scene preset of ``models/scene.toml``, and its seed: ``random:3`` is
the random draw of seed 3): the configured experiment (the paper's ramp by default) with
``--frames`` captures spread over it, rendered once; the default and the paper mode estimate every
frame (each warm-started along the sequence, as in a run) and are scored against the exact backbone.

Writes ``results.csv`` (one row per condition and mode: frames, valid, false valid, RMSE of the valid
frames, tip error, fps, ...), ``frames.csv`` (every frame: valid, errors, the estimator's reason),
``study.json`` (configuration, versions, seeds, engine, wall time, the targets check) and
``robustness.png`` (each condition's image with both estimates drawn on it, beside bars of the
valid fraction and the RMSE). ``check_targets`` holds the rows to issue 10's targets.

A frame is *false valid* when it is reported valid while a point of it is more than 10 mm off: a
point more than 10 mm from the exact backbone, or the tip more than 10 mm from the true tip (an
estimate that stops short of the tip is off there, though each of its points lies on the arm).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.config import BenchConfig, ConfigError, load_bench_config
from bench.engines import EngineConfig, EngineError, engine_from_args, run_episodes, workers_used
from bench.episodes import SequenceSpec, expected_cost, sequence_episode, sequence_spec, twin_config
from bench.frame_record import FrameRecord
from bench.scoring import pooled_rmse
from bench.study_files import counted, finish_study, frames_from_args, out_folder, write_results, write_study

CONDITIONS = ("clean", "lab", "dim", "bright_warm", "blur", "occluded", "random")
DEFAULT_FRAMES = 60
MAX_FRAMES = 1000
# The modes compared, and the key each has in a frame record.
MODES = {"default": "main", "paper": "paper"}
FALSE_VALID_MM = 10.0
REFERENCE = "clean"  # the RMSE targets are ratios to this condition's RMSE
FRAMES_CSV = "frames.csv"  # every frame of every condition and mode: valid, errors, the estimator's reason
COLUMNS = ("condition", "preset", "scene_seed", "mode", "frames", "valid", "valid_fraction", "false_valid",
           "rmse_mm", "tip_mm", "max_mm", "tip_max_mm", "bridged_fraction", "fps", "error")


@dataclasses.dataclass(frozen=True)
class Target:
    """Issue 10's target for one condition (default mode): at least ``valid`` of the frames valid, the
    RMSE of the valid frames at most ``rmse_ratio`` times the clean scene's, no false valid frame."""

    valid: float
    rmse_ratio: float


TARGETS = {"lab": Target(0.95, 1.3), "dim": Target(0.95, 1.3), "bright_warm": Target(0.95, 1.3),
           "blur": Target(0.95, 1.3), "occluded": Target(0.80, 2.0)}


@dataclasses.dataclass(frozen=True)
class Condition:
    """A scene the study runs: ``preset`` drawn from ``seed``; ``name`` as the user wrote it."""

    name: str
    preset: str
    seed: int


def parse_condition(text: str, default_seed: int) -> Condition:
    """``"lab"`` (the twin's scene seed) or ``"random:3"`` (seed 3).

    Raises:
        ValueError: an empty name or a seed that is not a whole number >= 0.
    """
    preset, _, seed = text.partition(":")
    if not preset:
        raise ValueError(f"--conditions {text!r}: expected PRESET or PRESET:SEED")
    if not seed:
        return Condition(text, preset, int(default_seed))
    if not seed.isdigit():
        raise ValueError(f"--conditions {text!r}: the seed after ':' must be a whole number >= 0")
    return Condition(text, preset, int(seed))


def robustness_specs(config: BenchConfig, conditions: Sequence[Condition], frames: int) -> list[SequenceSpec]:
    """One episode per condition: both modes on the same frames, the last frame's image kept for the figure."""
    estimators = {key: config.estimator_config(mode=mode).as_dict() for mode, key in MODES.items()}
    return [sequence_spec(config, frames=frames, preset=c.preset, scene_seed=c.seed, estimators=estimators,
                          figure_frame=frames - 1, tag=c.name) for c in conditions]


def check_presets(specs: Sequence[SequenceSpec]) -> None:
    """Raise ``ConfigFileError`` (a ValueError naming the scene file's presets) for a condition whose preset
    the scene file does not define: before any episode runs."""
    for spec in {s.preset: s for s in specs}.values():
        twin_config(spec)


def summarize_mode(records: Sequence[FrameRecord], key: str) -> dict[str, Any]:
    """One row's metrics: one mode over one condition's frames."""
    estimates = [r.estimate(key) for r in records]
    valid = [e for e in estimates if e is not None and e.valid and e.errors]
    errors = [e.errors for e in valid]
    false_valid = sum(e["max_mm"] > FALSE_VALID_MM or e["tip_mm"] > FALSE_VALID_MM for e in errors)
    points = sum(len(e.measured) for e in valid)
    bridged = sum(int(np.count_nonzero(~np.asarray(e.measured, bool))) for e in valid)
    ms = [r.bench_ms.get(f"estimate_{key}") for r in records]
    ms = [v for v in ms if v]
    return {
        "frames": len(records), "valid": len(valid),
        "valid_fraction": len(valid) / len(records) if records else float("nan"),
        "false_valid": int(false_valid),
        "rmse_mm": pooled_rmse(e["rmse_mm"] for e in errors),
        "tip_mm": float(np.mean([e["tip_mm"] for e in errors])) if errors else float("nan"),
        "max_mm": max((e["max_mm"] for e in errors), default=float("nan")),
        "tip_max_mm": max((e["tip_mm"] for e in errors), default=float("nan")),
        "bridged_fraction": bridged / points if points else float("nan"),
        "fps": 1e3 / float(np.median(ms)) if ms else float("nan"),
    }


def check_targets(rows: Sequence[Mapping[str, Any]]) -> dict[str, list[str]]:
    """Each condition's misses of issue 10's targets (default mode): ``{condition: [problem, ...]}``, empty
    lists where every target is met. Every condition must have no false valid frame; the conditions
    of ``TARGETS`` must also reach their valid fraction and keep their RMSE within the ratio to clean."""
    default = {r["condition"]: r for r in rows if r["mode"] == "default"}
    reference = next((r for name, r in default.items() if r["preset"] == REFERENCE), None)
    clean_rmse = reference["rmse_mm"] if reference is not None else float("nan")
    out: dict[str, list[str]] = {}
    for name, row in default.items():
        problems = []
        if row.get("error"):
            problems.append(f"the episode failed: {row['error']}")
        if row["false_valid"]:
            problems.append(f"{row['false_valid']} false valid frame(s) (valid, more than {FALSE_VALID_MM:g} mm off)")
        target = TARGETS.get(row["preset"])
        if target is not None:
            if not row["valid_fraction"] >= target.valid:
                problems.append(f"{row['valid']}/{row['frames']} valid ({_pct(row['valid_fraction'])}), "
                                f"target {target.valid:.0%}")
            if not np.isfinite(clean_rmse):
                problems.append(f"no RMSE of the {REFERENCE!r} condition to compare with (run it in the same study)")
            elif not row["rmse_mm"] <= target.rmse_ratio * clean_rmse:
                problems.append(f"RMSE {row['rmse_mm']:.2f} mm = {row['rmse_mm'] / clean_rmse:.2f}x clean "
                                f"({clean_rmse:.2f} mm), target <= {target.rmse_ratio:g}x")
        out[name] = problems
    return out


def _pct(value: float) -> str:
    return f"{100 * value:.0f} %" if np.isfinite(value) else "n/a"


def robustness_study(config: BenchConfig, conditions: Sequence[Condition], frames: int, out: Path,
                     engine: EngineConfig | None = None, *, progress: bool = True) -> dict[str, Any]:
    """Run the study and write its files to ``out``; returns the rows, the targets check and a headline.

    Raises:
        ConfigFileError: a condition names no preset of the scene file (before any episode runs).
        EngineError: the engine cannot start.
    """
    engine = engine or EngineConfig()
    specs = robustness_specs(config, conditions, frames)
    check_presets(specs)
    start = time.perf_counter()
    outcomes = run_episodes(sequence_episode, specs, engine, label="robustness", progress=progress,
                            cost=expected_cost)
    wall_s = time.perf_counter() - start
    rows, figures, frame_rows = [], {}, []
    for condition, outcome in zip(conditions, outcomes, strict=True):
        records = [FrameRecord.from_json(r) for r in outcome.result["records"]] if outcome.ok else []
        frame_rows += _frame_rows(condition, records)
        if outcome.ok and outcome.result["figure"] is not None:
            figures[condition.name] = (outcome.result["figure"], records[-1] if records else None)
        for mode, key in MODES.items():
            row = {"condition": condition.name, "preset": condition.preset, "scene_seed": condition.seed,
                   "mode": mode, **summarize_mode(records, key), "error": outcome.error or ""}
            rows.append(row)
    out.mkdir(parents=True, exist_ok=True)
    write_results(out, rows, COLUMNS)
    _write_frames(out / FRAMES_CSV, frame_rows)
    targets = check_targets(rows)
    twin = twin_config(specs[0]) if specs else None
    study = write_study(
        out, study="robustness", engine=engine, workers=workers_used(engine, len(specs)), outcomes=outcomes,
        wall_s=wall_s,
        configuration={"config": str(config.path), "experiment": config.experiment, "frames": frames,
                       "conditions": [dataclasses.asdict(c) for c in conditions],
                       "estimators": {mode: config.estimator_config(mode=mode).as_dict() for mode in MODES},
                       "false_valid_mm": FALSE_VALID_MM},
        seeds={"render_noise": None if twin is None else twin.seed,
               "scenes": {c.name: c.seed for c in conditions}, "experiment": config.experiment.seed,
               "som": config.estimator_config().som_seed},
        extra={"targets": {name: {"met": not problems, "problems": problems,
                                  "target": dataclasses.asdict(TARGETS[_preset(rows, name)])
                                  if _preset(rows, name) in TARGETS else None}
                           for name, problems in targets.items()}})
    plot_robustness(rows, figures, out / "robustness.png")
    return {"rows": rows, "targets": targets, "study": study, "headline": headline(rows, targets, study)}


def _frame_rows(condition: Condition, records: Sequence[FrameRecord]) -> list[dict]:
    rows = []
    for record in records:
        for mode, key in MODES.items():
            e = record.estimate(key)
            errors = e.errors or {}
            rows.append({"condition": condition.name, "mode": mode, "frame": record.index, "t_s": record.t_s,
                         "valid": e.valid, "max_mm": errors.get("max_mm"), "tip_mm": errors.get("tip_mm"),
                         "rmse_mm": errors.get("rmse_mm"), "reason": e.reason or ""})
    return rows


def _write_frames(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    import csv

    from bench.study_files import cell

    columns = ("condition", "mode", "frame", "t_s", "valid", "rmse_mm", "max_mm", "tip_mm", "reason")
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(columns)
        writer.writerows([cell(r.get(c)) for c in columns] for r in rows)


def _preset(rows, name: str) -> str:
    return next(r["preset"] for r in rows if r["condition"] == name)



def headline(rows: Sequence[Mapping[str, Any]], targets: Mapping[str, list[str]], study: Mapping) -> list[str]:
    lines = [f"{'condition':14s} {'mode':8s} {'valid':>9s} {'false':>5s} {'RMSE mm':>8s} {'tip mm':>7s} "
             f"{'fps':>6s}  targets"]
    for r in rows:
        note = ""
        if r["mode"] == "default":
            problems = targets.get(r["condition"])
            held = "" if r["preset"] in TARGETS else " (no false valid; no other target)"
            note = ("met" + held) if not problems else "MISSED: " + "; ".join(problems)
        lines.append(f"{r['condition']:14s} {r['mode']:8s} {r['valid']:>4d}/{r['frames']:<4d} {r['false_valid']:>5d} "
                     f"{r['rmse_mm']:8.2f} {r['tip_mm']:7.2f} {r['fps']:6.1f}  {note}")
    lines.append(f"{counted(study['episodes'], 'episode')} in {study['wall_s']:.1f} s on the {study['engine']['name']} "
                 f"engine ({counted(study['engine']['workers'], 'worker')})")
    return lines


def plot_robustness(rows: Sequence[Mapping[str, Any]], figures: Mapping[str, tuple], path: Path) -> None:
    """Each condition's image with both modes' estimates, beside bars of valid fraction and RMSE."""
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bench.figures import plain_log_axis

    names = list(dict.fromkeys(r["condition"] for r in rows))
    columns = min(4, max(1, len(names)))
    image_rows = -(-len(names) // columns)
    fig = plt.figure(figsize=(max(10.0, 4.2 * columns), 2.6 * image_rows + 3.4))
    grid = fig.add_gridspec(image_rows + 1, columns * 2, height_ratios=[2.4] * image_rows + [3.0])
    colours = {"default": "lime", "paper": "magenta"}
    for i, name in enumerate(names):
        ax = fig.add_subplot(grid[i // columns, 2 * (i % columns): 2 * (i % columns) + 2])
        ax.axis("off")
        figure, record = figures.get(name, (None, None))
        if figure is None:
            ax.set_title(f"{name}: no image (episode failed)", fontsize=9)
            continue
        image = cv2.cvtColor(figure["left"], cv2.COLOR_BGR2RGB)
        x0, y0 = _crop_origin(image, record, figure["scale"])
        crop = image[y0:, x0:][: image.shape[0] * 3 // 4, : image.shape[1] * 3 // 4]
        ax.imshow(crop)
        parts = []
        for mode, key in MODES.items():
            estimate = record.estimate(key) if record is not None else None
            if estimate is None:
                continue
            uv = np.asarray(estimate.left_uv, float) * figure["scale"] - (x0, y0)
            if len(uv):
                ax.plot(uv[:, 0], uv[:, 1], "-", color=colours[mode], linewidth=1.2,
                        alpha=1.0 if estimate.valid else 0.4, label=mode)
            parts.append(f"{mode} {'valid' if estimate.valid else 'invalid'}")
        ax.set_xlim(-0.5, crop.shape[1] - 0.5)  # an estimate far off stays inside the picture's frame
        ax.set_ylim(crop.shape[0] - 0.5, -0.5)
        ax.set_title(f"{name} (frame {figure['index']}): " + ", ".join(parts), fontsize=8)
    x = np.arange(len(names))
    by = {(r["condition"], r["mode"]): r for r in rows}
    for j, (key, label) in enumerate((("valid_fraction", "valid fraction"), ("rmse_mm", "RMSE of valid frames (mm)"))):
        ax = fig.add_subplot(grid[image_rows, j * columns: (j + 1) * columns])
        for offset, mode in ((-0.2, "default"), (0.2, "paper")):
            values = [by[(n, mode)][key] for n in names]
            ax.bar(x + offset, np.nan_to_num(values, nan=0.0), 0.4, label=f"{mode} mode",
                   color="tab:green" if mode == "default" else "tab:purple")
        if key == "rmse_mm":
            plain_log_axis(ax)
        if key == "valid_fraction":
            ax.set_ylim(0, 1.05)
            for n_i, n in enumerate(names):
                target = TARGETS.get(by[(n, "default")]["preset"])
                if target is not None:
                    ax.hlines(target.valid, n_i - 0.4, n_i + 0.4, colors="k", linestyles="--", linewidth=1)
        ax.set_xticks(x, names, rotation=20, fontsize=8)
        ax.set_ylabel(label)
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("Robustness: each condition's last frame with the estimates (green: default mode, magenta: "
                 "paper mode, faint: invalid)\ndashed: the valid-fraction target", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _crop_origin(image: np.ndarray, record: FrameRecord | None, scale: float) -> tuple[int, int]:
    """Top-left corner of a window of 3/4 the image's size centred on the default estimate (or the middle)."""
    h, w = image.shape[:2]
    estimate = record.estimate("main") if record is not None else None
    centre = (w / 2, h / 2)
    if estimate is not None and len(estimate.left_uv):
        uv = np.asarray(estimate.left_uv, float) * scale
        centre = tuple(0.5 * (uv.min(axis=0) + uv.max(axis=0)))
    x0 = int(np.clip(centre[0] - 3 * w / 8, 0, w - 3 * w // 4))
    y0 = int(np.clip(centre[1] - 3 * h / 8, 0, h - 3 * h // 4))
    return x0, y0


def robustness_command(args) -> int:
    """``softarm study robustness [--conditions ...] [--frames N] [--out DIR] [--engine ...] [--workers N]``."""
    try:
        config = load_bench_config(getattr(args, "config", None))
        engine = engine_from_args(args)
        twin_seed = twin_config(sequence_spec(config, frames=1, preset="clean", scene_seed=0, estimators={})).scene_seed
        conditions = [parse_condition(c, twin_seed) for c in (getattr(args, "conditions", None) or CONDITIONS)]
        names = [c.name for c in conditions]
        twice = sorted({name for name in names if names.count(name) > 1})
        if twice:  # the study's rows and study.json are keyed by condition: a second run would hide the first
            raise ValueError(f"--conditions: {', '.join(twice)} given more than once")
        frames = frames_from_args(args, DEFAULT_FRAMES, MAX_FRAMES, "frames per condition")
        check_presets(robustness_specs(config, conditions, 1))  # a bad --conditions, like any bad option
        out = out_folder(args, config, "robustness")
    except (ConfigError, ValueError) as e:
        print(f"softarm study robustness: {e}", file=sys.stderr)
        return 2
    print(f"softarm study robustness: {counted(len(conditions), 'condition')} x {counted(frames, 'frame')} on the "
          f"{engine.name} engine ...", flush=True)

    def work():
        result = robustness_study(config, conditions, frames, out, engine,
                                  progress=not getattr(args, "no_progress", False))
        return result["headline"], not result["study"]["failed"]

    return finish_study("robustness", out, work, (ConfigError, EngineError))
