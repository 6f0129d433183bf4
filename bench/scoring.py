"""Scores of one frame and of a whole run, and the paper's numbers they are compared with.

Two accuracy measures, side by side:

- exact: the twin's ground-truth backbone (``estimator.metrics.score_against_backbone``):
  point-to-curve RMSE, its per-axis parts, max, tip, ...
- Q' (the paper's own, section 5.3): the depth camera's 3D points at the left centerline pixels,
  ``Q'_j = g(u_Lj, v_Lj)``, compared axis by axis with the estimate (Table 2). In the twin the
  depth is the renderer's exact depth of the left image; note that it is the depth of the arm's
  SURFACE at those pixels, so Q' sits about one tube radius in front of the axis the estimator
  reconstructs: here its z error has that offset built in (the paper's 5.5 mm z leaves no room for it;
  the paper does not say how its Q' avoided it).

Run summaries pool frames as the paper's Table 2 does ("RMSE during the entire motion"): the
root of the mean squared per-frame RMSE over the valid frames (every frame has the same number
of points). Table 3's "maximum error" is the largest per-axis RMSE of Table 2 (5.5122 mm ->
5.5/680), so ``max_axis_rmse_mm`` is the like-for-like figure; ``max_mm`` is the largest
point error of any frame, a much stricter measure.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from bench.frame_record import ROUND_M, FrameRecord
from estimator import StereoCalibration
from estimator.metrics import axis_rmse, depth_camera_points, score_against_backbone

# Zou et al., section 5: Table 2 (RMSE per axis over the whole motion, against the ZED's depth Q')
# and Table 3 (maximum error over manipulator length, frame rate).
PAPER = {
    "rmse_xyz_mm": (2.9178, 2.3287, 5.5122),
    "max_error_mm": 5.5,
    "length_mm": 680.0,
    "max_error_pct": 0.81,
    "fps": 10.0,
    "frames": 690,
    "duration_s": 58.0,
}

# Depth maps are stored and compared as 16-bit integers of this many metres (0.1 mm): 0 means no depth.
DEPTH_UNIT_M = 1e-4
_DEPTH_MAX_UNITS = 65535



def quantize_depth(depth_m: np.ndarray) -> np.ndarray:
    """(H, W) metres (inf or <= 0: none) -> uint16 in ``DEPTH_UNIT_M``, 0 where there is no depth."""
    depth = np.asarray(depth_m, dtype=np.float64)
    units = np.where(np.isfinite(depth) & (depth > 0), np.round(depth / DEPTH_UNIT_M), 0)
    return np.where(units <= _DEPTH_MAX_UNITS, units, 0).astype(np.uint16)


def dequantize_depth(units: np.ndarray, unit_m: float = DEPTH_UNIT_M) -> np.ndarray:
    """uint16 depth units -> float32 metres with ``inf`` where there is none."""
    depth = units.astype(np.float32) * np.float32(unit_m)
    depth[units == 0] = np.inf
    return depth


def score_fields(points_m: np.ndarray, left_uv: np.ndarray, gt_m: np.ndarray | None, depth_m: np.ndarray | None,
                 calibration: StereoCalibration | None) -> dict:
    """Errors of one valid estimate: ``errors`` against the exact backbone, ``qprime`` against Q'.

    Args:
        points_m: (n, 3) the estimate, metres, left camera frame.
        left_uv: (n, 2) its raw left pixels (where Q' is read).
        gt_m: (N, 3) the exact backbone, same frame, or None (no ground truth: the rig).
        depth_m: (H, W) left depth map in metres (inf: none), or None (no depth source).
        calibration: the camera's calibration (for Q'); needed with ``depth_m``.

    Returns:
        ``{"errors": {...} | None, "qprime": {...} | None, "qprime_m": [[x, y, z], ...] | None}``;
        ``qprime`` has per-axis RMSE ``x_mm``, ``y_mm``, ``z_mm``, their combination ``rmse_mm``
        and the ``count`` of points with depth.
    """
    out: dict = {"errors": None, "qprime": None, "qprime_m": None}
    if gt_m is not None:
        out["errors"] = {k: round(v, 4) for k, v in score_against_backbone(points_m, gt_m).items()}
    if depth_m is not None and calibration is not None and len(left_uv):
        q = depth_camera_points(left_uv, depth_m, calibration)
        rmse = axis_rmse(points_m, q)
        if rmse["count"]:
            rmse["rmse_mm"] = math.sqrt(rmse["x_mm"] ** 2 + rmse["y_mm"] ** 2 + rmse["z_mm"] ** 2)
            out["qprime"] = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in rmse.items()}
        out["qprime_m"] = [[None if not np.isfinite(v) else round(float(v), ROUND_M) for v in row] for row in q]
    return out


def pooled_rmse(values: Iterable[float]) -> float:
    """Root of the mean square of per-frame RMSEs (equal point counts): the whole run's RMSE."""
    values = np.asarray([v for v in values if v is not None and np.isfinite(v)], dtype=float)
    return float(np.sqrt(np.mean(values**2))) if len(values) else float("nan")


def summarize(records: Sequence[Mapping], *, key: str | None = None, arm_length_mm: float | None = None,
              wall_s: float | None = None) -> dict:
    """Summary of a run's frame records (``frames.jsonl`` lines).

    Args:
        records: frame records in order (``FrameRecord`` or their JSON objects).
        key: None for the main estimate, "paper" for the paper-mode comparison stored under it.
        arm_length_mm: for the error/length ratio; default: the first ground-truth backbone's length.
        wall_s: wall-clock duration of the loop, for ``fps_loop``.

    Returns:
        frames, valid_frames, rmse_mm, rmse_xyz_mm, max_mm, tip_mm, fps and friends (see the
        module docstring for how frames are pooled); NaN/None where nothing could be measured.
    """
    frames = [FrameRecord.coerce(r) for r in records]
    results = [r for r in (f.estimate(key) for f in frames) if r is not None]
    valid = [r for r in results if r.valid]
    scored = [r.errors for r in valid if r.errors]
    qprime = [r.qprime for r in valid if r.qprime]
    totals = [r.timings_ms["total"] for r in results if r.timings_ms.get("total")]
    stages: dict[str, list[float]] = {}
    for r in results:
        for stage, ms in r.timings_ms.items():
            stages.setdefault(stage, []).append(ms)
    if arm_length_mm is None:
        arm_length_mm = next((_length_mm(f.gt_m) for f in frames if f.gt_m is not None and len(f.gt_m)), None)
    out = {
        "frames": len(results),
        "valid_frames": len(valid),
        "valid_fraction": len(valid) / len(results) if results else float("nan"),
        "scored_frames": len(scored),
        "rmse_mm": pooled_rmse(s["rmse_mm"] for s in scored),
        "rmse_xyz_mm": [pooled_rmse(s[f"rmse_{a}_mm"] for s in scored) for a in "xyz"],
        "max_mm": max((s["max_mm"] for s in scored), default=float("nan")),
        "tip_mm": _mean(s["tip_mm"] for s in scored),
        "tip_max_mm": max((s["tip_mm"] for s in scored), default=float("nan")),
        "base_mm": _mean(s["base_mm"] for s in scored),
        "arc_rmse_mm": pooled_rmse(s["arc_rmse_mm"] for s in scored),
        "length_error_mm": _mean(s["length_error_mm"] for s in scored),
        "median_rmse_mm": float(np.median([s["rmse_mm"] for s in scored])) if scored else float("nan"),
        "qprime_frames": len(qprime),
        "qprime_rmse_xyz_mm": [pooled_rmse(q[f"{a}_mm"] for q in qprime) for a in "xyz"],
        "qprime_rmse_mm": pooled_rmse(q["rmse_mm"] for q in qprime),
        # The median frame: the first frames pay for just-in-time compilation and cold caches.
        "fps": 1000.0 / float(np.median(totals)) if totals else float("nan"),
        "fps_mean": 1000.0 / _mean(totals) if totals else float("nan"),
        "estimator_ms": {stage: float(np.median(v)) for stage, v in stages.items()},
        "arm_length_mm": arm_length_mm,
    }
    worst_axis = max(out["rmse_xyz_mm"]) if scored else float("nan")
    out["max_axis_rmse_mm"] = worst_axis
    out["max_axis_rmse_pct"] = 100 * worst_axis / arm_length_mm if arm_length_mm else float("nan")
    out["qprime_max_axis_rmse_mm"] = max(out["qprime_rmse_xyz_mm"]) if qprime else float("nan")
    out["qprime_max_axis_rmse_pct"] = (100 * out["qprime_max_axis_rmse_mm"] / arm_length_mm
                                       if qprime and arm_length_mm else float("nan"))
    out["max_pct"] = 100 * out["max_mm"] / arm_length_mm if scored and arm_length_mm else float("nan")
    if wall_s is not None and wall_s > 0:
        out["fps_loop"] = len(results) / wall_s
    reasons: dict[str, int] = {}
    examples: dict[str, str] = {}
    for r in results:
        if not r.valid:
            reason = r.reason or "?"
            template = reason_template(reason)
            reasons[template] = reasons.get(template, 0) + 1
            examples.setdefault(template, reason)
    out["invalid_reasons"] = reasons  # grouped by template: "implausible estimate: # mm long ..."
    out["invalid_examples"] = examples  # the first reason of each group, measurements included
    return out


# A measurement inside a reason: a number standing on its own ("1402 mm", "35%"), not part of a name ("s1_a").
_MEASUREMENT = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def reason_template(reason: str) -> str:
    """An invalid frame's reason with its measurements replaced by ``#``, so frames invalid for the same
    cause group together: "implausible estimate: 1402 mm long" -> "implausible estimate: # mm long"."""
    return _MEASUREMENT.sub("#", reason)


def invalid_lines(summary: Mapping, limit: int | None = None) -> list[str]:
    """The summary's invalid-frame groups, most frequent first: "5 x <template> (e.g. <first reason>)"."""
    reasons = summary.get("invalid_reasons") or {}
    examples = summary.get("invalid_examples") or {}
    lines = []
    for template, count in sorted(reasons.items(), key=lambda kv: -kv[1])[:limit]:
        example = examples.get(template)
        lines.append(f"{count} x {template}" + (f" (e.g. \"{example}\")" if example and example != template else ""))
    return lines


def summary_table(summary: Mapping, *, label: str = "this run", paper_mode: Mapping | None = None,
                  markdown: bool = False) -> list[str]:
    """The run's figures beside the paper's (Tables 2 and 3), as text or markdown lines."""
    columns = [label] + (["paper mode"] if paper_mode is not None else []) + ["Zou et al."]
    runs = [summary] + ([paper_mode] if paper_mode is not None else [])
    p = PAPER
    rows: list[tuple[str, list[str], str]] = [
        ("valid frames", [f"{s['valid_frames']}/{s['frames']}" for s in runs], f"{p['frames']} logged"),
        ("RMSE x/y/z vs exact backbone (mm)", [_xyz(s["rmse_xyz_mm"]) for s in runs], "n/a"),
        ("RMSE x/y/z vs Q' depth (mm) (Zou et al.: Table 2)", [_xyz(s["qprime_rmse_xyz_mm"]) for s in runs],
         _xyz(p["rmse_xyz_mm"], 4)),
        ("3D RMSE vs exact backbone (mm)", [_num(s["rmse_mm"]) for s in runs], "n/a"),
        ("max error / length, Table 3 (worst axis RMSE)",
         [_ratio(s.get("max_axis_rmse_mm"), s.get("arm_length_mm")) for s in runs],
         f"{p['max_error_mm']:g}/{p['length_mm']:.0f} = {p['max_error_pct']:.2f} %"),
        ("  same vs Q'", [_ratio(s.get("qprime_max_axis_rmse_mm"), s.get("arm_length_mm")) for s in runs],
         f"{p['max_error_mm']:g}/{p['length_mm']:.0f} = {p['max_error_pct']:.2f} %"),
        ("largest point error (mm)", [_num(s["max_mm"]) for s in runs], "n/a"),
        ("mean tip error (mm)", [_num(s["tip_mm"]) for s in runs], "n/a"),
        ("estimator fps (1 / median time per frame)", [_num(s["fps"], 1) for s in runs], f"{p['fps']:g}"),
    ]
    if any("fps_loop" in s for s in runs):
        rows.append(("loop fps (capture + estimate + record)", [_num(s.get("fps_loop", float("nan")), 1)
                                                                for s in runs], "n/a"))
    if markdown:
        lines = ["| | " + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]
        lines += [f"| {name} | " + " | ".join(values + [ref]) + " |" for name, values, ref in rows]
        return lines
    width = max(len(name) for name, _, _ in rows) + 2
    cells = [[name] + values + [ref] for name, values, ref in rows]
    col_w = [max(len(c[i]) for c in cells + [[""] + columns]) + 2 for i in range(1, len(columns) + 1)]
    lines = [" " * width + "".join(c.ljust(w) for c, w in zip(columns, col_w, strict=True))]
    for row in cells:
        lines.append(row[0].ljust(width) + "".join(c.ljust(w) for c, w in zip(row[1:], col_w, strict=True)))
    return lines


# --- helpers ------------------------------------------------------------------------------


def _mean(values: Iterable[float]) -> float:
    values = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(values)) if values else float("nan")


def _length_mm(points) -> float:
    points = np.asarray(points, dtype=float)
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum() * 1e3)


def _num(value, decimals: int = 2) -> str:
    return "n/a" if value is None or not np.isfinite(value) else f"{value:.{decimals}f}"


def _xyz(values, decimals: int = 2) -> str:
    return " / ".join(_num(v, decimals) for v in values)


def _ratio(error_mm, length_mm) -> str:
    if error_mm is None or length_mm is None or not np.isfinite(error_mm):
        return "n/a"
    return f"{error_mm:.1f}/{length_mm:.0f} = {100 * error_mm / length_mm:.2f} %"
