"""``softarm study accuracy``: where along the arm the error is, and how it depends on the tube's
angle to the image rows, with and without the 3D tube fit.

Where the arm runs along the image rows, the rows no longer tell which left point goes with which
right one and depth has to come from elsewhere (the tube's two edges and its apparent width in
the fit; a disparity profile without it). This study shows that directly: every estimated point
of every frame is scored against the exact backbone (point to curve) and binned by its place
along the arm and by the angle its 2D centerline makes with the rows in the left image.

Writes ``accuracy.csv`` (one row per point: frame, estimator, arc fraction, angle, errors),
``accuracy_along_arm.png``, ``accuracy_vs_row_angle.png`` and ``accuracy.md``.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from estimator import CenterlineEstimator, EstimatorConfig, StereoCalibration
from estimator.metrics import closest_points_on_polyline

VARIANTS = {"tube fit": {"tube_fit": True}, "disparity profile": {"tube_fit": False}}
ARC_BINS = np.linspace(0.0, 1.0, 11)
ANGLE_BINS = np.array([0.0, 10.0, 20.0, 30.0, 45.0, 60.0, 75.0, 90.01])


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
            if not result.valid:
                rows.append({"frame": index, "variant": name, "point": -1, "valid": False, "reason": result.reason})
                continue
            closest, _ = closest_points_on_polyline(result.points, np.asarray(frame.gt_m))
            error = (result.points - closest) * 1e3
            uv = result.left_uv
            step = np.gradient(uv, axis=0)
            angle = np.degrees(np.arctan2(np.abs(step[:, 1]), np.abs(step[:, 0])))
            arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(result.points, axis=0), axis=1))])
            fraction = arc / max(arc[-1], 1e-12)
            for k in range(len(result.points)):
                rows.append({"frame": index, "variant": name, "point": k, "valid": True, "reason": "",
                             "arc_fraction": float(fraction[k]), "row_angle_deg": float(angle[k]),
                             "error_mm": float(np.linalg.norm(error[k])), "x_mm": float(error[k, 0]),
                             "y_mm": float(error[k, 1]), "z_mm": float(error[k, 2])})
    return rows


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

    out.mkdir(parents=True, exist_ok=True)
    keys = ["frame", "variant", "point", "valid", "reason", "arc_fraction", "row_angle_deg", "error_mm",
            "x_mm", "y_mm", "z_mm"]
    with open(out / "accuracy.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: row.get(k, "") for k in keys})
    headline = [f"accuracy study: {frames} frames, point-to-curve RMSE against the exact backbone"]
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
