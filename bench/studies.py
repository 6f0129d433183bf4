"""``softarm study som|compare``: the paper's SOM parameter study (section 4.1) and centerline comparison (4.3).

Both run on frames the twin renders along the configured experiment (``--frames`` of them,
spread over it: by default the arm at rest, half way and fully bent), so the inputs are what
the bench sees, with a known backbone.

``som``: on the left image's arm contour (the paper's SOM input), four simulations (Fig 5):
(a) topology error (eq. 9) against the number of neurons n after sufficient training;
(b) topology error against the training length lambda for n = 15, 20, 25, 30;
(c) quantization error (eq. 10) against alpha(0) for neighbourhood radii N = 2, 4, 6, 8;
(d) quantization error against lambda for alpha(0) in (0, 0.3]; then the parameters these
curves select by the paper's criteria (Table 1), beside the paper's n = 20, N = 2, alpha(0) = 0.2,
lambda = 15.

``compare``: SOM against competitive learning (Algorithm 2), K-Means++ (Algorithm 3), thinning and
an ordered skeleton walk: their 2D nodes on the left image (Figs 7, 8), topology and ordering
errors, the 3D accuracy each gives through the whole pipeline (paper and default mode) and the
time per frame.

Each study writes PNG plots, ``<study>.md`` and ``<study>.json`` to its folder.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from bench.config import BenchConfig, ConfigError, load_bench_config
from bench.experiments import make_schedule
from bench.recording import new_run_folder, write_json
from bench.run import _stop_errors
from estimator import CalibrationFileError, CenterlineEstimator, EstimatorConfig, StereoCalibration
from estimator.centerline import centerline_nodes
from estimator.config import CENTERLINES
from estimator.metrics import closest_points_on_polyline, quantization_error, score_against_backbone, topology_error
from estimator.segmentation import arm_mask, contour_points
from estimator.som import linear_init, som_online
from hardware.errors import DeviceError

DEFAULT_FRAMES = 3
MAX_STUDY_FRAMES = 1000  # each frame is trained on hundreds of times: more is hours of work
# Table 1 of the paper.
PAPER_TABLE1 = {"n": 20, "N": 2, "alpha0": 0.2, "lambda": 15}
# The grids of Fig 5 (a-d).
N_NEURONS = (5, 10, 15, 20, 25, 30, 35, 40, 50, 60, 70)
N_CONVERGENCE = (15, 20, 25, 30)
LAMBDAS = (1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 40, 50)
RADII = (2, 4, 6, 8)
ALPHAS = (0.02, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.6, 0.8)
ALPHAS_LOW = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3)
SUFFICIENT_LAMBDA = 50  # "sufficient training times" of cases 1 and 3
TIE = 0.005  # case 3: quantization errors this close to the best count as equal
CONVERGED = 0.02  # case 4: lambda "converges" when within 2 % of the quantization error at SUFFICIENT_LAMBDA
METHOD_NAMES = {"som": "SOM", "competitive": "competitive learning", "kmeans++": "K-Means++",
                "thinning": "thinning", "skeleton": "ordered skeleton"}


@dataclass
class StudyFrame:
    """One twin frame: raw pair, exact backbone (left camera frame), time and commanded pressures."""

    left: np.ndarray
    right: np.ndarray
    gt_m: np.ndarray
    t_s: float
    commanded_bar: dict


def study_command(args) -> int:
    """Entry point of ``softarm study som|compare [--config] [--frames N] [--out DIR]``."""
    try:
        config = load_bench_config(getattr(args, "config", None))
    except ConfigError as e:
        print(f"softarm study: {e}", file=sys.stderr)
        return 2
    n = getattr(args, "frames", None)
    n = DEFAULT_FRAMES if n is None else n
    if not 1 <= n <= MAX_STUDY_FRAMES:
        print(f"softarm study: --frames {n}: expected 1 to {MAX_STUDY_FRAMES} frames (default {DEFAULT_FRAMES})",
              file=sys.stderr)
        return 2
    which = args.which
    out = Path(args.out) if getattr(args, "out", None) else new_run_folder(config.recording.root,
                                                                            f"study_{which}_{time.strftime('%Y-%m-%d_%H%M%S')}")
    print(f"softarm study {which}: rendering {n} twin frames along the experiment ...", flush=True)
    try:
        frames, calibration = twin_frames(config, n)
    except (ConfigError, CalibrationFileError, DeviceError, OSError, *_stop_errors()) as e:
        print(f"softarm study {which}: {e}; nothing written", file=sys.stderr)
        return 1
    study = som_study if which == "som" else compare_study
    try:
        out.mkdir(parents=True, exist_ok=True)
        result = study(frames, calibration, config.estimator_config(), out)
    except NoArmInFramesError as e:
        print(f"softarm study {which}: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        print(f"softarm study {which}: cannot write the study to {out}: {e}", file=sys.stderr)
        return 1
    print(f"softarm study {which}: wrote {out}")
    for line in result["headline"]:
        print(line)
    return 0


class NoArmInFramesError(ValueError):
    """None of the study's frames shows the arm (the colour range or the camera is off)."""


def twin_frames(config: BenchConfig, count: int) -> tuple[list[StudyFrame], StereoCalibration]:
    """Render ``count`` frames spread over the configured experiment on the twin (whatever the backend)."""
    from bench.factory import make_devices
    from bench.run import _sim_captures, _Stop

    schedule = make_schedule(config.experiment, frames=count)
    devices = make_devices(dataclasses.replace(config, backend="sim"))
    try:
        calibration = devices.camera.calibration
        frames = [StudyFrame(c.frame.left, c.frame.right, np.asarray(c.gt_m), c.t_s, c.commanded_bar)
                  for c in _sim_captures(devices, schedule, config.experiment, _Stop())]
    finally:
        devices.close()
    return frames, calibration


def left_samples(frame: StudyFrame, calibration: StereoCalibration, cfg: EstimatorConfig):
    """The paper's SOM input: Canny contour points of the arm mask on the rectified left image.

    Returns:
        (mask, contour points (K, 2), rectified image) on the full rectified canvas.
    """
    rect = calibration.rectification.rectify_image(frame.left, "left")
    mask = arm_mask(rect, cfg)
    return mask, contour_points(mask, cfg.canny_low, cfg.canny_high, cfg.contour_step), rect


# --- section 4.1: the SOM parameters ------------------------------------------------------


def _train(samples: np.ndarray, n: int, lam: int, alpha0: float, radius: int, cfg: EstimatorConfig) -> np.ndarray:
    return som_online(samples, linear_init(samples, n), epochs=lam, alpha0=alpha0, lam=float(lam), radius=radius,
                      sigma0=cfg.som_sigma, seed=cfg.som_seed, time=cfg.som_time, compiled=True)


def som_study(frames: Sequence[StudyFrame], calibration: StereoCalibration, base: EstimatorConfig,
              out: Path) -> dict:
    """Fig 5 (a-d) and Table 1 on the frames' left contours; writes plots, som.md and som.json."""
    import matplotlib

    matplotlib.use("Agg")
    cfg = base.replace(mode="paper")
    inputs = [left_samples(f, calibration, cfg) for f in frames]
    samples = [s for _, s, _ in inputs if len(s) >= 3]
    if not samples:
        raise NoArmInFramesError(f"no arm found in any of the {len(frames)} study frames; check the estimator's "
                                 "hsv_low/hsv_high against the arm's colour and that the camera sees the arm")
    start = time.perf_counter()
    n0, radius0, alpha0 = PAPER_TABLE1["n"], PAPER_TABLE1["N"], PAPER_TABLE1["alpha0"]

    def mean_over_frames(fn) -> float:
        return float(np.mean([fn(s) for s in samples]))

    # (a) topology error vs n after sufficient training
    topo_n = [mean_over_frames(lambda s, n=n: topology_error(s, _train(s, n, SUFFICIENT_LAMBDA, alpha0, radius0, cfg)))
              for n in N_NEURONS]
    # (b) topology error vs lambda for n = 15..30
    topo_lam = {n: [mean_over_frames(lambda s, n=n, lam=lam: topology_error(s, _train(s, n, lam, alpha0, radius0, cfg)))
                    for lam in LAMBDAS] for n in N_CONVERGENCE}
    # (c) quantization error vs alpha0 for N = 2..8
    quant_alpha = {r: [mean_over_frames(lambda s, a=a, r=r: quantization_error(
        s, _train(s, n0, SUFFICIENT_LAMBDA, a, r, cfg))) for a in ALPHAS] for r in RADII}
    # (d) quantization error vs lambda for alpha0 <= 0.3
    quant_lam = {a: [mean_over_frames(lambda s, a=a, lam=lam: quantization_error(
        s, _train(s, n0, lam, a, radius0, cfg))) for lam in LAMBDAS] for a in ALPHAS_LOW}
    table1 = _choose_table1(topo_n, topo_lam, quant_alpha, quant_lam)
    elapsed = time.perf_counter() - start

    _plot_fig5a(topo_n, frames[-1], inputs[-1], calibration, cfg, out / "fig5a_topology_vs_n.png")
    _plot_curves({f"n = {n}": v for n, v in topo_lam.items()}, LAMBDAS, "training times lambda",
                 "topology error (eq. 9)", "Fig 5b: topology error against lambda",
                 out / "fig5b_topology_vs_lambda.png")
    _plot_curves({f"N = {r}": v for r, v in quant_alpha.items()}, ALPHAS, "alpha(0)",
                 "quantization error (eq. 10, px)", f"Fig 5c: quantization error against alpha(0) (n = {n0}, "
                 f"lambda = {SUFFICIENT_LAMBDA})", out / "fig5c_quantization_vs_alpha.png")
    _plot_curves({f"alpha(0) = {a:g}": v for a, v in quant_lam.items()}, LAMBDAS, "training times lambda",
                 "quantization error (eq. 10, px)",
                 f"Fig 5d: quantization error against lambda (n = {n0}, N = {radius0})",
                 out / "fig5d_quantization_vs_lambda.png", highlight=f"alpha(0) = {alpha0:g}")
    result = {
        "frames": [{"t_s": f.t_s, "commanded_bar": f.commanded_bar, "samples": int(len(s))}
                   for f, (_, s, _) in zip(frames, inputs, strict=True)],
        "grids": {"n": N_NEURONS, "lambda": LAMBDAS, "N": RADII, "alpha0": ALPHAS, "alpha0_low": ALPHAS_LOW},
        "fig5a_topology_vs_n": topo_n,
        "fig5b_topology_vs_lambda": {str(k): v for k, v in topo_lam.items()},
        "fig5c_quantization_vs_alpha": {str(k): v for k, v in quant_alpha.items()},
        "fig5d_quantization_vs_lambda": {str(k): v for k, v in quant_lam.items()},
        "table1": table1, "paper_table1": PAPER_TABLE1, "seconds": elapsed,
    }
    write_json(out / "som.json", result)
    paper = PAPER_TABLE1
    headline = [
        "Table 1   n    N   alpha(0)  lambda",
        f"paper     {paper['n']:<4} {paper['N']:<3} {paper['alpha0']:<9g} {paper['lambda']}",
        f"here      {table1['n']:<4} {table1['N']:<3} {table1['alpha0']:<9g} {table1['lambda']}",
        f"largest n without topology errors after sufficient training: {table1['n_limit']} (paper: 30)",
        f"quantization error spread over the whole N x alpha(0) grid: {table1['quantization_spread_pct']:.1f} % "
        f"(ties within {100 * TIE:g} % go to the smaller N, then the smaller alpha(0))",
    ]
    _som_markdown(result, headline, out / "som.md")
    result["headline"] = headline
    return result


def _choose_table1(topo_n, topo_lam, quant_alpha, quant_lam) -> dict:
    """Table 1 by the paper's criteria, applied to the measured curves.

    N and alpha(0): the smallest quantization error after sufficient training (case 3).
    lambda: the smallest lambda from which on the error at the chosen alpha(0) stays within 2 % of
    its sufficiently trained value (case 4: "converges ... the increase of lambda prolongs the time").
    n: among 15..30, the most neurons whose topology error is 0 after lambda epochs (cases 1, 2:
    more neurons follow the shape more finely; the real-time budget lambda limits how many train
    without topology errors). n_limit: the largest n of case 1 with no topology error.
    """
    grid = np.array([quant_alpha[r] for r in RADII])
    best = float(grid.min())
    # Ties (within TIE of the best) go to the smaller N (fewer neurons moved: the paper's reason for N = 2),
    # then the smaller alpha(0) (gentler learning).
    r_index, alpha_index = min(zip(*np.nonzero(grid <= best * (1 + TIE)), strict=True))
    radius, alpha0 = RADII[int(r_index)], ALPHAS[int(alpha_index)]
    curve = quant_lam.get(alpha0) or quant_lam[min(quant_lam, key=lambda a: abs(a - alpha0))]
    final = curve[-1]
    within = [abs(q - final) <= CONVERGED * final for q in curve]
    # converged: this lambda and every longer training stay within CONVERGED of the sufficiently trained error
    lam = next(lam for k, lam in enumerate(LAMBDAS) if all(within[k:]))
    lam_index = LAMBDAS.index(lam)
    trained = [n for n in N_CONVERGENCE if topo_lam[n][lam_index] == 0]
    n = max(trained) if trained else min(N_CONVERGENCE)
    limit = 0
    for count, error in zip(N_NEURONS, topo_n, strict=True):
        if error > 0:
            break
        limit = count
    return {"n": n, "N": radius, "alpha0": alpha0, "lambda": lam, "n_limit": limit,
            "quantization_spread_pct": 100 * float(grid.max() - best) / best}


def _plot_curves(curves: dict, x, xlabel: str, ylabel: str, title: str, path: Path, highlight: str | None = None):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for label, values in curves.items():
        ax.plot(x, values, "o-", markersize=3, linewidth=2.5 if label == highlight else 1.2, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_fig5a(topo_n, frame, inputs, calibration, cfg, path: Path) -> None:
    import matplotlib.pyplot as plt

    mask, samples, rect = inputs
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), gridspec_kw={"width_ratios": [1.2, 1]})
    axes[0].plot(N_NEURONS, topo_n, "o-")
    axes[0].set_xlabel("neurons n")
    axes[0].set_ylabel("topology error (eq. 9)")
    axes[0].set_title(f"Fig 5a: topology error against n (lambda = {SUFFICIENT_LAMBDA})", fontsize=10)
    axes[0].grid(True, alpha=0.3)
    crop, (x0, y0) = _crop(rect, mask)
    axes[1].imshow(cv2.cvtColor(crop, cv2.COLOR_BGR2RGB))
    if len(samples) >= 3:
        for n, colour in ((20, "tab:green"), (50, "tab:orange"), (70, "tab:red")):
            nodes = _train(samples, n, SUFFICIENT_LAMBDA, PAPER_TABLE1["alpha0"], PAPER_TABLE1["N"], cfg)
            axes[1].plot(nodes[:, 0] - x0, nodes[:, 1] - y0, "o-", color=colour, markersize=2.5, linewidth=1,
                         label=f"n = {n}")
    axes[1].set_title(f"nodes on the contour at t = {frame.t_s:.1f} s", fontsize=10)
    axes[1].legend(fontsize=8)
    axes[1].axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _som_markdown(result: dict, headline: list[str], path: Path) -> None:
    t = result["table1"]
    lines = ["# SOM parameter study (section 4.1, Fig 5, Table 1)", "",
             f"On the left contour of {len(result['frames'])} twin frames (t = "
             + ", ".join(f"{f['t_s']:.1f} s" for f in result["frames"]) + "); errors are means over the frames.", "",
             "| Table 1 | n | N | alpha(0) | lambda |", "|---|---|---|---|---|",
             "| paper | {n} | {N} | {alpha0} | {lambda} |".format(**PAPER_TABLE1),
             f"| chosen here | {t['n']} | {t['N']} | {t['alpha0']} | {t['lambda']} |", "",
             f"Largest n with no topology error after {SUFFICIENT_LAMBDA} epochs: {t['n_limit']} (paper: 30).", "",
             f"The quantization error varies by {t['quantization_spread_pct']:.1f} % over the whole N x alpha(0) grid: "
             "on contour input it is dominated by the tube's half width (the contour lies that far from the nodes), "
             f"so differences below {100 * TIE:g} % are treated as ties.", "",
             "Criteria (the paper's, applied to these curves): N and alpha(0) minimise the quantization error after "
             "sufficient training (Fig 5c); lambda is the shortest training from which on the quantization error at "
             f"that alpha(0) stays within {CONVERGED:.0%} of the sufficiently trained one (Fig 5d); "
             "n is the most neurons among 15-30 that reach zero topology error within lambda epochs (Fig 5b).", "",
             "## Fig 5a: topology error against n", "", "| n | " + " | ".join(map(str, N_NEURONS)) + " |",
             "|---|" + "---|" * len(N_NEURONS),
             "| error | " + " | ".join(f"{v:.3f}" for v in result["fig5a_topology_vs_n"]) + " |", ""]
    for name, key, grid in (("Fig 5b: topology error against lambda (rows: n)", "fig5b_topology_vs_lambda", LAMBDAS),
                            ("Fig 5c: quantization error (px) against alpha(0) (rows: N)",
                             "fig5c_quantization_vs_alpha", ALPHAS),
                            ("Fig 5d: quantization error (px) against lambda (rows: alpha(0))",
                             "fig5d_quantization_vs_lambda", LAMBDAS)):
        lines += [f"## {name}", "", "| | " + " | ".join(f"{g:g}" for g in grid) + " |", "|---|" + "---|" * len(grid)]
        for row, values in result[key].items():
            lines.append(f"| {row} | " + " | ".join(f"{v:.3f}" for v in values) + " |")
        lines.append("")
    for png in ("fig5a_topology_vs_n", "fig5b_topology_vs_lambda", "fig5c_quantization_vs_alpha",
                "fig5d_quantization_vs_lambda"):
        lines += [f"![{png}]({png}.png)", ""]
    lines += ["```", *headline, "```", ""]
    path.write_text("\n".join(lines), encoding="utf-8")


# --- section 4.3: centerline methods ------------------------------------------------------


def nodes_2d(method: str, mask: np.ndarray, samples: np.ndarray, cfg: EstimatorConfig) -> np.ndarray:
    """The 2D centerline of one method on a (rectified, full-frame) mask, cold, as the pipeline computes it."""
    if method not in CENTERLINES:
        raise ValueError(f"method: expected one of {CENTERLINES}, got {method!r}")
    return centerline_nodes(mask, samples, cfg.replace(centerline=method))


def order_error(nodes: np.ndarray, reference: np.ndarray) -> float:
    """Fraction of consecutive node pairs that step backwards along the reference curve (an ordering failure)."""
    if len(nodes) < 2:
        return float("nan")
    _, arc = closest_points_on_polyline(np.asarray(nodes, dtype=float), np.asarray(reference, dtype=float))
    return float(np.mean(np.diff(arc) < 0))


def compare_study(frames: Sequence[StudyFrame], calibration: StereoCalibration, base: EstimatorConfig,
                  out: Path) -> dict:
    """Figs 7, 8 and the accuracy/topology/time table; writes plots, compare.md and compare.json."""
    import matplotlib

    matplotlib.use("Agg")
    paper_cfg = base.replace(mode="paper")
    rect = calibration.rectification
    per_method: dict[str, dict] = {}
    drawn: dict[str, np.ndarray] = {}
    inputs = [left_samples(f, calibration, paper_cfg) for f in frames]
    for method in CENTERLINES:
        topo, order, times_2d = [], [], []
        pipeline: dict[str, dict] = {}
        for f, (mask, samples, _) in zip(frames, inputs, strict=True):
            if len(samples) < 3:
                continue
            start = time.perf_counter()
            nodes = nodes_2d(method, mask, samples, paper_cfg)
            times_2d.append((time.perf_counter() - start) * 1e3)
            gt_rect = _project_rect(rect, f.gt_m)
            topo.append(topology_error(samples, nodes) if len(nodes) >= 2 else float("nan"))
            order.append(order_error(nodes, gt_rect))
            drawn[method] = nodes
        for mode in ("paper", "default"):
            scores, totals, valid = [], [], 0
            for f in frames:
                est = CenterlineEstimator(calibration, base.replace(mode=mode, centerline=method))  # cold, per frame
                result = est.estimate(f.left, f.right)
                totals.append(result.timings_ms.get("total", float("nan")))
                if result.valid:
                    valid += 1
                    scores.append(score_against_backbone(result.points, f.gt_m))
            pipeline[mode] = {
                "valid": valid, "frames": len(frames),
                "rmse_mm": _pooled([s["rmse_mm"] for s in scores]),
                "max_mm": max((s["max_mm"] for s in scores), default=float("nan")),
                "tip_mm": float(np.mean([s["tip_mm"] for s in scores])) if scores else float("nan"),
                "ms_per_frame": float(np.median(totals)),
            }
        per_method[method] = {"topology_error": _nanmean(topo), "order_error": _nanmean(order),
                              "ms_2d": float(np.median(times_2d)) if times_2d else float("nan"), "pipeline": pipeline}
    last_mask, last_samples, last_rect = inputs[-1]
    _plot_fig7(drawn, last_rect, last_mask, frames[-1], out / "fig7_centerlines.png")
    _plot_fig8(drawn, last_rect, last_mask, out / "fig8_thinning_vs_som.png")
    _plot_compare_bars(per_method, out / "compare_accuracy_time.png")
    result = {"frames": [{"t_s": f.t_s, "commanded_bar": f.commanded_bar} for f in frames], "methods": per_method}
    write_json(out / "compare.json", result)
    headline = [f"{'method':22s} {'topology':>9s} {'order':>7s} {'paper-mode RMSE':>16s} {'default RMSE':>13s} "
                f"{'2D ms':>7s}"]
    for method, m in per_method.items():
        headline.append(f"{METHOD_NAMES[method]:22s} {m['topology_error']:9.3f} {m['order_error']:7.3f} "
                        f"{_mm(m['pipeline']['paper']):>16s} {_mm(m['pipeline']['default']):>13s} {m['ms_2d']:7.1f}")
    _compare_markdown(result, out / "compare.md")
    result["headline"] = headline
    return result


def _mm(p: dict) -> str:
    rmse = p["rmse_mm"]
    return f"{rmse:.1f} mm ({p['valid']}/{p['frames']})" if np.isfinite(rmse) else f"n/a (0/{p['frames']})"


def _project_rect(rect, points_cam: np.ndarray) -> np.ndarray:
    points = rect.from_left_camera(points_cam)
    P = rect.P["left"]
    h = points @ P[:, :3].T + P[:, 3]
    return h[:, :2] / h[:, 2:3]


def _pooled(values) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else float("nan")


def _nanmean(values) -> float:
    values = [v for v in values if np.isfinite(v)]
    return float(np.mean(values)) if values else float("nan")


def _crop(image: np.ndarray, mask: np.ndarray, margin: int = 30):
    found = cv2.findNonZero(mask)
    if found is None:
        return image, (0, 0)
    x, y, w, h = cv2.boundingRect(found)
    x0, y0 = max(x - margin, 0), max(y - margin, 0)
    return image[y0:y + h + margin, x0:x + w + margin], (x0, y0)


def _plot_fig7(drawn: dict, rect_image: np.ndarray, mask: np.ndarray, frame: StudyFrame, path: Path) -> None:
    import matplotlib.pyplot as plt

    crop, (x0, y0) = _crop(rect_image, mask)
    methods = list(drawn)
    fig, axes = plt.subplots(1, len(methods), figsize=(3.2 * len(methods), 4.2), squeeze=False)
    for ax, method in zip(axes[0], methods, strict=True):
        nodes = drawn[method]
        ax.imshow(cv2.cvtColor(crop, cv2.COLOR_BGR2RGB))
        ax.plot(nodes[:, 0] - x0, nodes[:, 1] - y0, "-", color="tab:blue", linewidth=1)
        ax.scatter(nodes[:, 0] - x0, nodes[:, 1] - y0, c=np.arange(len(nodes)), cmap="viridis", s=14, zorder=3)
        ax.set_title(METHOD_NAMES[method], fontsize=10)
        ax.axis("off")
    fig.suptitle(f"Fig 7: 2D centerlines, nodes connected in output order (t = {frame.t_s:.1f} s)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_fig8(drawn: dict, rect_image: np.ndarray, mask: np.ndarray, path: Path) -> None:
    import matplotlib.pyplot as plt

    from estimator.skeleton import thin

    crop, (x0, y0) = _crop(rect_image, mask)
    mask_crop, _ = _crop(mask, mask)
    skeleton = thin(mask_crop)
    fig, axes = plt.subplots(1, 3, figsize=(11, 4.5))
    axes[0].imshow(mask_crop, cmap="gray")
    # the paper's Fig 8: (a) the steps of thinning, (b) the order of the points; a1, a2 are the steps
    axes[0].set_title("(a1) thinning: the binary mask", fontsize=10)
    axes[1].imshow(skeleton, cmap="gray")
    axes[1].set_title("(a2) thinning: one pixel wide", fontsize=10)
    axes[2].imshow(cv2.cvtColor(crop, cv2.COLOR_BGR2RGB))
    for method, colour in (("thinning", "tab:red"), ("som", "tab:green")):
        if method in drawn:
            nodes = drawn[method]
            axes[2].plot(nodes[:, 0] - x0, nodes[:, 1] - y0, "o-", color=colour, markersize=3, linewidth=1,
                         label=METHOD_NAMES[method])
    axes[2].legend(fontsize=8)
    axes[2].set_title("(b) points connected in output order", fontsize=10)
    for ax in axes:
        ax.axis("off")
    fig.suptitle("Fig 8: thinning against SOM", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_compare_bars(per_method: dict, path: Path) -> None:
    import matplotlib.pyplot as plt

    from bench.figures import plain_log_axis

    names = [METHOD_NAMES[m] for m in per_method]
    x = np.arange(len(names))
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for offset, mode in ((-0.2, "paper"), (0.2, "default")):
        values = [per_method[m]["pipeline"][mode]["rmse_mm"] for m in per_method]
        axes[0].bar(x + offset, np.nan_to_num(values, nan=0.0), 0.4, label=f"{mode} mode pipeline")
        times = [per_method[m]["pipeline"][mode]["ms_per_frame"] for m in per_method]
        axes[2].bar(x + offset, times, 0.4, label=f"{mode} mode pipeline")
    plain_log_axis(axes[0])
    axes[0].set_ylabel("3D RMSE vs exact backbone (mm)")
    axes[1].bar(x - 0.2, [per_method[m]["topology_error"] for m in per_method], 0.4, label="topology error (eq. 9)")
    axes[1].bar(x + 0.2, [per_method[m]["order_error"] for m in per_method], 0.4, label="order error")
    axes[1].set_ylabel("fraction")
    axes[2].set_ylabel("ms per frame")
    for ax in axes:
        ax.set_xticks(x, names, rotation=20, fontsize=8)
        ax.legend(fontsize=7)
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].set_title("3D accuracy (missing bar: no valid frame)", fontsize=10)
    axes[1].set_title("2D topology and ordering", fontsize=10)
    axes[2].set_title("time per frame", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _compare_markdown(result: dict, path: Path) -> None:
    lines = ["# Centerline extraction comparison (section 4.3, Figs 7, 8)", "",
             f"{len(result['frames'])} twin frames (t = " + ", ".join(f"{f['t_s']:.1f} s" for f in result["frames"])
             + "). 2D nodes on the rectified left image as the paper-mode pipeline computes them; 3D accuracy "
             "through the whole pipeline with that centerline stage (cold start on every frame).", "",
             "- topology error: eq. (9) on the contour samples; order error: fraction of consecutive nodes that step "
             "backwards along the projected exact backbone (the ordering failure of Fig 8b).", "",
             "| method | topology error | order error | 2D ms | paper-mode RMSE (valid) | paper-mode ms | "
             "default-mode RMSE (valid) | default-mode ms |", "|---|---|---|---|---|---|---|---|"]
    for method, m in result["methods"].items():
        p, d = m["pipeline"]["paper"], m["pipeline"]["default"]
        lines.append(f"| {METHOD_NAMES[method]} | {m['topology_error']:.3f} | {m['order_error']:.3f} | "
                     f"{m['ms_2d']:.1f} | {_mm(p)} | {p['ms_per_frame']:.0f} | {_mm(d)} | {d['ms_per_frame']:.0f} |")
    lines += ["", "![fig7](fig7_centerlines.png)", "", "![fig8](fig8_thinning_vs_som.png)", "",
              "![accuracy and time](compare_accuracy_time.png)", ""]
    path.write_text("\n".join(lines), encoding="utf-8")
