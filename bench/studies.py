"""``softarm study som|compare``: the paper's SOM parameter study (section 4.1) and centerline comparison (4.3).

Both run on frames the twin renders along the configured experiment (``--frames`` of them,
spread over it: by default the arm at rest, half way and fully bent), so the inputs are what
the bench sees, with a known backbone.

``som``: on the left image's arm contour (the paper's SOM input), four simulations (Fig 5):
(a) topology error (eq. 9) against the number of neurons n after sufficient training;
(b) topology error against the training length lambda for n = 15, 20, 25, 30;
(c) quantization error (eq. 10) against alpha(0) for neighbourhood radii N = 2, 4, 6, 8;
(d) quantization error against lambda for alpha(0) in (0, 0.3] (and the chosen alpha(0) if it lies
outside); then the parameters these curves select by the paper's criteria (Table 1), beside the
paper's n = 20, N = 2, alpha(0) = 0.2, lambda = 15. The SOM is trained as the paper preset trains it
(contour order, Gaussian width N / 2) under both readings of the learning-rate clock t of eq. (3):
counting presented samples (the preset) and counting epochs; the figures show the preset's
reading, som.md and som.json both.

``compare``: SOM against competitive learning (Algorithm 2), K-Means++ (Algorithm 3), thinning and
an ordered skeleton walk: their 2D nodes on the left image (Figs 7, 8), topology and ordering
errors, the 3D accuracy each gives through the whole pipeline (paper and default mode) and the
time per frame.

Each study writes PNG plots, ``<study>.md`` and ``<study>.json`` to its folder, and the schema every
study shares (``bench.study_files``): ``results.csv`` (som: one row per point of each Fig 5 curve under
each clock; compare: one row per method and mode) and ``study.json`` (engine, versions, wall time).

Both run as episodes on an engine (``--engine local|ray --workers N``, ``bench.engines``): the frames
are rendered by one twin episode, then ``som`` trains under each learning-rate clock and ``compare``
runs each method in an episode of its own. ``softarm study robustness``, ``sweep`` and ``accuracy``
are dispatched to ``bench.robustness``, ``bench.sweep`` and ``bench.accuracy``.
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
from bench.engines import EngineConfig, EngineError, engine_from_args, run_episodes, workers_used
from bench.episodes import calibration as episode_calibration
from bench.episodes import sequence_episode, sequence_spec
from bench.frame_record import FrameRecord
from bench.process import Capture, process
from bench.recording import write_json
from bench.signals import Terminated, sigterm_raises, stopped_by
from bench.study_files import (
    counted,
    finish_study,
    frames_from_args,
    out_folder,
    write_results,
    write_study,
)
from estimator import CalibrationFileError, CenterlineEstimator, EstimatorConfig, StereoCalibration
from estimator.centerline import centerline_nodes
from estimator.config import CENTERLINES
from estimator.metrics import closest_points_on_polyline, quantization_error, topology_error
from estimator.segmentation import arm_mask, contour_points
from estimator.som import linear_init, som_online
from hardware.errors import DeviceError
from hardware.interfaces import StereoFrame

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
# case 4: lambda "converges" once the quantization error has come within this fraction of its whole fall
# (from lambda = 1 to SUFFICIENT_LAMBDA) of its sufficiently trained value, and stays there
CONVERGED = 0.05
# a curve whose whole fall is below this fraction of its final value is flat: it does not pick lambda
FLAT = 0.01
# case 2: the topology error has converged once it stays within this fraction of the samples of its
# sufficiently trained value (on a strongly bent arm it need not reach 0)
TOPOLOGY_TOLERANCE = 0.01
CLOCKS = ("sample", "epoch")  # what t counts in alpha(t) = alpha0 / (1 + t / lambda); the first is the preset
METHOD_NAMES = {"som": "SOM", "competitive": "competitive learning", "kmeans++": "K-Means++",
                "thinning": "thinning", "skeleton": "ordered skeleton"}


@dataclass
class StudyFrame:
    """One twin frame: raw pair, exact backbone (left camera frame), time and commanded pressures, and
    the frame as the run would record it (the configured estimator's result, scored)."""

    left: np.ndarray
    right: np.ndarray
    gt_m: np.ndarray
    t_s: float
    commanded_bar: dict
    capture: Capture | None = None
    record: FrameRecord | None = None


# subcommands run by a module of their own: which -> (module, function)
_OTHER_STUDIES = {"robustness": ("bench.robustness", "robustness_command"), "sweep": ("bench.sweep", "sweep_command"),
                  "accuracy": ("bench.accuracy", "accuracy_command")}


def study_command(args) -> int:
    """Entry point of ``softarm study som|compare|robustness|sweep|accuracy [--config] [--frames N] [--out DIR]
    [--engine local|ray] [--workers N] [--ray-address HOST:PORT]``.

    Ctrl-C or SIGTERM stops the study where it is (its worker processes with it) with one line and
    the shell's exit code (130, 143); the files of a study are written at its end, so none are.
    """
    with sigterm_raises():
        try:
            return _study(args)
        except (KeyboardInterrupt, Terminated) as e:
            name, code = stopped_by(e)
            print(f"\nsoftarm study {args.which}: stopped by {name}; the study was not finished (its files, "
                  "written at its end, are missing or incomplete)", file=sys.stderr)
            return code


def _study(args) -> int:
    which = args.which
    if which in _OTHER_STUDIES:
        import importlib

        module, function = _OTHER_STUDIES[which]
        return int(getattr(importlib.import_module(module), function)(args) or 0)
    try:
        config = load_bench_config(getattr(args, "config", None))
        engine = engine_from_args(args)
        n = frames_from_args(args, DEFAULT_FRAMES, MAX_STUDY_FRAMES)
        out = out_folder(args, config, which)
    except (ConfigError, ValueError) as e:
        print(f"softarm study: {e}", file=sys.stderr)
        return 2
    progress = not getattr(args, "no_progress", False)
    print(f"softarm study {which}: rendering {counted(n, 'twin frame')} along the experiment ...", flush=True)
    start = time.perf_counter()
    try:
        frames, calibration = twin_frames(config, n, engine, progress=progress)
    except (ConfigError, CalibrationFileError, DeviceError, OSError, EngineError, StudyEpisodeError) as e:
        print(f"softarm study {which}: {e}; nothing written", file=sys.stderr)
        return 1
    study = som_study if which == "som" else compare_study

    def work():
        out.mkdir(parents=True, exist_ok=True)
        result = study(frames, calibration, config.estimator_config(), out, engine, progress=progress)
        write_study(out, study=which, engine=engine, workers=workers_used(engine, result["episodes"]),
                    outcomes=result["outcomes"], wall_s=time.perf_counter() - start,
                    configuration={"config": str(config.path), "experiment": config.experiment, "frames": n,
                                   "estimator": config.estimator_config().as_dict()},
                    seeds={"som": config.estimator_config().som_seed, "experiment": config.experiment.seed})
        return result["headline"], True

    return finish_study(which, out, work, (NoArmInFramesError, StudyEpisodeError, EngineError), may_have_written=True)


class NoArmInFramesError(ValueError):
    """None of the study's frames shows the arm (the colour range or the camera is off)."""


class StudyEpisodeError(RuntimeError):
    """An episode of the study failed twice; the study cannot be completed without it."""


def _results(outcomes, what: str) -> list:
    failed = [o for o in outcomes if not o.ok]
    if failed:
        raise StudyEpisodeError(f"{what}: episode {failed[0].index} failed twice: {failed[0].error}")
    return [o.result for o in outcomes]


def twin_frames(config: BenchConfig, count: int, engine: EngineConfig | None = None, *,
                progress: bool = False) -> tuple[list[StudyFrame], StereoCalibration]:
    """Render ``count`` frames spread over the configured experiment on the twin (whatever the backend),
    in one episode on ``engine``, through the run's own capture loop and frame path (the configured
    estimator's record of each).

    Raises:
        ConfigError: the twin file is missing (names the config file and ``[sim] twin``).
        StudyEpisodeError: the episode failed twice (its error).
    """
    if not Path(config.sim.twin).is_file():
        raise ConfigError(f"{config.path} [sim] twin: {config.sim.twin}: twin file not found")
    spec = sequence_spec(config, frames=count, preset=_twin_preset(config), scene_seed=_twin_scene_seed(config),
                         estimators={"main": config.estimator_config().as_dict()}, keep_frames=True, tag="render")
    (result,) = _results(run_episodes(sequence_episode, [spec], engine, label="render", progress=progress),
                         "rendering the frames")
    frames = []
    for record_json, (left, right) in zip(result["records"], result["frames"], strict=True):
        record = FrameRecord.from_json(record_json)
        frames.append(StudyFrame(left, right, np.asarray(record.gt_m), record.t_s, dict(record.commanded_bar),
                                 None, record))
    return frames, episode_calibration(spec)


def _twin_preset(config: BenchConfig) -> str:
    from twin.twin import TwinConfig

    return TwinConfig.load(config.sim.twin).scene_preset


def _twin_scene_seed(config: BenchConfig) -> int:
    from twin.twin import TwinConfig

    return TwinConfig.load(config.sim.twin).scene_seed


def left_samples(frame: StudyFrame, calibration: StereoCalibration, cfg: EstimatorConfig):
    """The paper's SOM input: Canny contour points of the arm mask on the rectified left image.

    Returns:
        (mask, contour points (K, 2), rectified image) on the full rectified canvas.
    """
    rect = calibration.rectification.rectify_image(frame.left, "left")
    mask = arm_mask(rect, cfg)
    return mask, contour_points(mask, cfg.canny_low, cfg.canny_high, cfg.contour_step), rect


# --- section 4.1: the SOM parameters ------------------------------------------------------


def _train(samples: np.ndarray, n: int, lam: int, alpha0: float, radius: int, cfg: EstimatorConfig,
           clock: str | None = None) -> np.ndarray:
    return som_online(samples, linear_init(samples, n), epochs=lam, alpha0=alpha0, lam=float(lam), radius=radius,
                      sigma0=cfg.som_sigma, seed=cfg.som_seed, time=clock or cfg.som_time, compiled=True,
                      order=cfg.som_order, shrink=cfg.som_shrink)


def fig5_curves(samples: Sequence[np.ndarray], cfg: EstimatorConfig, clock: str) -> dict:
    """The four simulations of Fig 5 under one learning-rate clock, errors averaged over the frames."""
    n0, radius0, alpha0 = PAPER_TABLE1["n"], PAPER_TABLE1["N"], PAPER_TABLE1["alpha0"]

    def mean(error, n, lam, alpha, radius) -> float:
        return float(np.mean([error(s, _train(s, n, lam, alpha, radius, cfg, clock)) for s in samples]))

    curves = {
        # (a) topology error against n after sufficient training
        "topology_vs_n": [mean(topology_error, n, SUFFICIENT_LAMBDA, alpha0, radius0) for n in N_NEURONS],
        # (b) topology error against lambda for n = 15..30
        "topology_vs_lambda": {n: [mean(topology_error, n, lam, alpha0, radius0) for lam in LAMBDAS]
                               for n in N_CONVERGENCE},
        # (c) quantization error against alpha0 for N = 2..8, sufficient training
        "quantization_vs_alpha": {r: [mean(quantization_error, n0, SUFFICIENT_LAMBDA, a, r) for a in ALPHAS]
                                  for r in RADII},
        # (d) quantization error against lambda for alpha0 <= 0.3
        "quantization_vs_lambda": {a: [mean(quantization_error, n0, lam, a, radius0) for lam in LAMBDAS]
                                   for a in ALPHAS_LOW},
    }
    table1 = _choose_table1(curves["topology_vs_n"], curves["topology_vs_lambda"], curves["quantization_vs_alpha"],
                            curves["quantization_vs_lambda"])
    if table1["alpha0"] not in curves["quantization_vs_lambda"]:  # Fig 5d must show the chosen alpha(0)
        a = table1["alpha0"]
        curves["quantization_vs_lambda"][a] = [mean(quantization_error, n0, lam, a, radius0) for lam in LAMBDAS]
        table1 = _choose_table1(curves["topology_vs_n"], curves["topology_vs_lambda"],
                                curves["quantization_vs_alpha"], curves["quantization_vs_lambda"])
    curves["table1"] = table1
    return curves


@dataclass(frozen=True)
class SomSpec:
    """An episode of the SOM study: the Fig 5 curves under one learning-rate clock."""

    samples: tuple
    config: dict
    clock: str


def som_episode(spec: SomSpec) -> dict:
    return fig5_curves(list(spec.samples), EstimatorConfig.from_dict(spec.config), spec.clock)


def som_study(frames: Sequence[StudyFrame], calibration: StereoCalibration, base: EstimatorConfig,
              out: Path, engine: EngineConfig | None = None, *, progress: bool = False) -> dict:
    """Fig 5 (a-d) and Table 1 on the frames' left contours, one episode per clock on ``engine``; writes plots,
    som.md, som.json and results.csv."""
    import matplotlib

    matplotlib.use("Agg")
    cfg = base.replace(mode="paper")
    inputs = [left_samples(f, calibration, cfg) for f in frames]
    samples = [s for _, s, _ in inputs if len(s) >= 3]
    if not samples:
        raise NoArmInFramesError(f"no arm found in any of the {len(frames)} study frames; check the estimator's "
                                 "hsv_low/hsv_high against the arm's colour and that the camera sees the arm")
    start = time.perf_counter()
    clocks = (cfg.som_time, *(c for c in CLOCKS if c != cfg.som_time))
    outcomes = run_episodes(som_episode, [SomSpec(tuple(samples), cfg.as_dict(), c) for c in clocks], engine,
                            label="som", progress=progress)
    by_clock = dict(zip(clocks, _results(outcomes, "the SOM study"), strict=True))
    elapsed = time.perf_counter() - start
    shown = by_clock[cfg.som_time]
    table1 = shown["table1"]
    n0, radius0, alpha0 = PAPER_TABLE1["n"], PAPER_TABLE1["N"], PAPER_TABLE1["alpha0"]
    clock_note = f"t counts {'presented samples' if cfg.som_time == 'sample' else 'epochs'}"

    _plot_fig5a(shown["topology_vs_n"], frames[-1], inputs[-1], calibration, cfg, out / "fig5a_topology_vs_n.png")
    _plot_curves({f"n = {n}": v for n, v in shown["topology_vs_lambda"].items()}, LAMBDAS, "training times lambda",
                 "topology error (eq. 9)", f"Fig 5b: topology error against lambda ({clock_note})",
                 out / "fig5b_topology_vs_lambda.png")
    _plot_curves({f"N = {r}": v for r, v in shown["quantization_vs_alpha"].items()}, ALPHAS, "alpha(0)",
                 "quantization error (eq. 10, px)", f"Fig 5c: quantization error against alpha(0) (n = {n0}, "
                 f"lambda = {SUFFICIENT_LAMBDA}, sigma = N / 2, {clock_note})", out / "fig5c_quantization_vs_alpha.png")
    _plot_curves({f"alpha(0) = {a:g}": v for a, v in sorted(shown["quantization_vs_lambda"].items())}, LAMBDAS,
                 "training times lambda", "quantization error (eq. 10, px)",
                 f"Fig 5d: quantization error against lambda (n = {n0}, N = {radius0}, {clock_note})",
                 out / "fig5d_quantization_vs_lambda.png", highlight=f"alpha(0) = {alpha0:g}")
    result = {
        "frames": [{"t_s": f.t_s, "commanded_bar": f.commanded_bar, "samples": int(len(s))}
                   for f, (_, s, _) in zip(frames, inputs, strict=True)],
        "clock": cfg.som_time, "order": cfg.som_order,
        "grids": {"n": N_NEURONS, "lambda": LAMBDAS, "N": RADII, "alpha0": ALPHAS, "alpha0_low": ALPHAS_LOW},
        "fig5a_topology_vs_n": shown["topology_vs_n"],
        "fig5b_topology_vs_lambda": {str(k): v for k, v in shown["topology_vs_lambda"].items()},
        "fig5c_quantization_vs_alpha": {str(k): v for k, v in shown["quantization_vs_alpha"].items()},
        "fig5d_quantization_vs_lambda": {f"{k:g}": v for k, v in sorted(shown["quantization_vs_lambda"].items())},
        "table1": table1, "paper_table1": PAPER_TABLE1, "seconds": elapsed,
        "clocks": {clock: {"table1": c["table1"],
                           "fig5a_topology_vs_n": c["topology_vs_n"],
                           "fig5b_topology_vs_lambda": {str(k): v for k, v in c["topology_vs_lambda"].items()},
                           "fig5c_quantization_vs_alpha": {str(k): v for k, v in c["quantization_vs_alpha"].items()},
                           "fig5d_quantization_vs_lambda": {f"{k:g}": v for k, v in
                                                            sorted(c["quantization_vs_lambda"].items())}}
                   for clock, c in by_clock.items()},
    }
    write_json(out / "som.json", result)
    paper = PAPER_TABLE1
    headline = ["Table 1            n    N   alpha(0)  lambda",
                f"paper              {paper['n']:<4} {paper['N']:<3} {paper['alpha0']:<9g} {paper['lambda']}"]
    for clock, c in by_clock.items():
        t = c["table1"]
        label = f"here, t = {clock}" + (" *" if clock == cfg.som_time else "")
        headline.append(f"{label:<18} {t['n']:<4} {t['N']:<3} {t['alpha0']:<9g} {t['lambda']}")
    headline += [f"(* the paper preset's clock; figures drawn for it) largest n without topology errors after "
                 f"sufficient training: {table1['n_limit']} (paper: 30)"]
    headline += [f"differs from the paper: {d}" for d in table1["differences"]]
    _som_markdown(result, headline, out / "som.md")
    write_results(out, _som_rows(by_clock), ("clock", "figure", "series", "x", "value"))
    result.update(headline=headline, outcomes=outcomes, episodes=len(outcomes))
    return result


def _som_rows(by_clock: dict) -> list[dict]:
    """The Fig 5 curves of each clock, one row per point (the figure's x and its error)."""
    rows = []
    for clock, c in by_clock.items():
        rows += [{"clock": clock, "figure": "5a", "series": "", "x": n, "value": v}
                 for n, v in zip(N_NEURONS, c["topology_vs_n"], strict=True)]
        for figure, key, grid, name in (("5b", "topology_vs_lambda", LAMBDAS, "n"),
                                        ("5c", "quantization_vs_alpha", ALPHAS, "N"),
                                        ("5d", "quantization_vs_lambda", LAMBDAS, "alpha0")):
            for series, values in sorted(c[key].items()):
                rows += [{"clock": clock, "figure": figure, "series": f"{name}={series:g}", "x": x, "value": v}
                         for x, v in zip(grid, values, strict=True)]
    return rows


def _choose_table1(topo_n, topo_lam, quant_alpha, quant_lam) -> dict:
    """Table 1 by the paper's criteria, applied to the measured curves.

    N and alpha(0) (case 3): the smallest quantization error after sufficient training. Errors
    within ``TIE`` of the best are equal: the smallest such N (fewer neurons moved, the paper's
    reason for N = 2), and the middle of that N's near-best alpha(0) plateau (a flat curve does
    not push the choice to an end of the grid).
    lambda (cases 4 and 2): the quantization error at the chosen alpha(0) has converged when it
    has come within ``CONVERGED`` of its whole fall of the sufficiently trained value and stays
    there; a curve that falls by less than ``FLAT`` of its value is flat and picks nothing. The
    topology error for n = 20 must have reached 0 and stay there too; lambda is the longer of
    the two (the shortest training after which both errors have converged). "Reached 0" is
    read as "stays within ``TOPOLOGY_TOLERANCE`` of its sufficiently trained value": on a
    strongly bent, foreshortened arm the contour's topology error need not reach 0.
    n (cases 1, 2): among 15..30, the most neurons whose topology error is 0 after lambda epochs.
    n_limit: the largest n of case 1 with no topology error.

    Returns:
        n, N, alpha0, lambda, n_limit, quantization_spread_pct, lambda_by ("quantization",
        "topology" or both), flat (which curves were flat), differences (sentences, where the
        choice differs from the paper's Table 1 and why).
    """
    grid = np.array([quant_alpha[r] for r in RADII])
    alphas = ALPHAS if grid.shape[1] == len(ALPHAS) else tuple(range(grid.shape[1]))
    best = float(grid.min())
    near = grid <= best * (1 + TIE)
    r_index = int(np.flatnonzero(near.any(axis=1))[0])
    plateau = np.flatnonzero(near[r_index])
    alpha_index = int(plateau[(len(plateau) - 1) // 2])
    radius, alpha0 = RADII[r_index], alphas[alpha_index]
    flat = []
    alpha_row = grid[r_index]
    if float(alpha_row.max() - alpha_row.min()) <= TIE * best:
        flat.append("alpha0")
    key = min(quant_lam, key=lambda a: abs(a - alpha0))
    curve = np.asarray(quant_lam[key], dtype=float)
    final = float(curve[-1])
    fall = float(curve.max() - final)
    lam_q = None
    if fall > FLAT * final:
        within = np.abs(curve - final) <= CONVERGED * fall
        lam_q = next(lam for k, lam in enumerate(LAMBDAS) if within[k:].all())
    else:
        flat.append("lambda")
    topo = np.asarray(topo_lam[PAPER_TABLE1["n"]] if PAPER_TABLE1["n"] in topo_lam else topo_lam[min(topo_lam)])
    settled = np.abs(topo - topo[-1]) <= TOPOLOGY_TOLERANCE
    lam_t = next(lam for k, lam in enumerate(LAMBDAS) if settled[k:].all())
    lam = max(lam_q or LAMBDAS[0], lam_t)
    lambda_by = [name for name, value in (("quantization", lam_q), ("topology", lam_t)) if value == lam]
    lam_index = LAMBDAS.index(lam)
    trained = [n for n in N_CONVERGENCE if topo_lam[n][lam_index] == 0]
    n = max(trained) if trained else min(N_CONVERGENCE)
    limit = 0
    for count, error in zip(N_NEURONS, topo_n, strict=True):
        if error > 0:
            break
        limit = count
    choice = {"n": n, "N": radius, "alpha0": alpha0, "lambda": lam, "n_limit": limit,
              "quantization_spread_pct": 100 * float(grid.max() - best) / best, "lambda_by": lambda_by,
              "lambda_quantization": lam_q, "lambda_topology": lam_t, "flat": flat}
    choice["differences"] = _differences(choice)
    return choice


def _differences(choice: dict) -> list[str]:
    """Where the chosen Table 1 differs from the paper's, and why (from the curves' own evidence)."""
    paper = PAPER_TABLE1
    out = []
    if choice["n"] != paper["n"]:
        out.append(f"n = {choice['n']}: the most neurons among 15-30 whose topology error is 0 after "
                   f"lambda = {choice['lambda']} epochs (the paper's n = 20 is a trade-off with real-time speed "
                   "that the errors alone do not make)")
    if choice["N"] != paper["N"]:
        out.append(f"N = {choice['N']}: its quantization error is within {100 * TIE:g} % of the best")
    if choice["alpha0"] != paper["alpha0"]:
        why = ("the quantization error is flat in alpha(0) (within "
               f"{100 * TIE:g} %), so the middle of the plateau is taken" if "alpha0" in choice["flat"]
               else "it has the smallest quantization error after sufficient training")
        out.append(f"alpha(0) = {choice['alpha0']:g}: {why}")
    if choice["lambda"] != paper["lambda"]:
        if "lambda" in choice["flat"]:
            why = (f"the quantization error hardly changes with lambda (it falls by less than {100 * FLAT:g} %), so "
                   f"lambda is where the topology error of n = 20 reaches 0 ({choice['lambda_topology']})")
        else:
            why = (f"the quantization error has converged from lambda = {choice['lambda_quantization']} and the "
                   f"topology error of n = 20 from lambda = {choice['lambda_topology']}")
        out.append(f"lambda = {choice['lambda']}: {why}")
    return out


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
    clock_words = {"sample": "presented samples (the paper preset)", "epoch": "epochs (passes over the contour)"}
    lines = ["# SOM parameter study (section 4.1, Fig 5, Table 1)", "",
             f"On the left contour of {len(result['frames'])} twin frames (t = "
             + ", ".join(f"{f['t_s']:.1f} s" for f in result["frames"]) + "); errors are means over the frames. "
             f"Points presented in {result['order']} order, Gaussian neighbourhood of width N / 2.", "",
             "| Table 1 | t in alpha(t) counts | n | N | alpha(0) | lambda | lambda set by |",
             "|---|---|---|---|---|---|---|",
             "| paper | (not said) | {n} | {N} | {alpha0} | {lambda} | |".format(**PAPER_TABLE1)]
    for clock, c in result["clocks"].items():
        ct = c["table1"]
        lines.append(f"| chosen here | {clock_words[clock]} | {ct['n']} | {ct['N']} | {ct['alpha0']:g} | "
                     f"{ct['lambda']} | {' and '.join(ct['lambda_by'])} error |")
    lines += ["", f"Largest n with no topology error after {SUFFICIENT_LAMBDA} epochs: {t['n_limit']} (paper: 30).",
              "",
              f"The quantization error varies by {t['quantization_spread_pct']:.1f} % over the whole N x alpha(0) grid "
              "(on contour input it is dominated by the tube's half width: the contour lies that far from the "
              f"nodes); differences below {100 * TIE:g} % are treated as ties.", ""]
    if t["differences"]:
        lines += ["Where the choice differs from the paper's Table 1 (preset clock), and why:", ""]
        lines += [f"- {d}" for d in t["differences"]] + [""]
    else:
        lines += ["The preset clock's curves select the paper's Table 1.", ""]
    lines += ["Criteria (the paper's, applied to these curves): N and alpha(0) minimise the quantization error after "
              "sufficient training (Fig 5c; ties: the smallest N, the middle of the near-best alpha(0) plateau); "
              "lambda is the shortest training after which the quantization error at that alpha(0) has come within "
              f"{CONVERGED:.0%} of its whole fall of the sufficiently trained value (Fig 5d; a curve falling by less "
              f"than {FLAT:.0%} is flat and does not decide) and the topology error of n = 20 stays 0 (Fig 5b); "
              "n is the most neurons among 15-30 that reach zero topology error within lambda epochs (Fig 5b).", "",
              f"Figures and the tables below: t counts {clock_words[result['clock']]}. som.json holds both clocks.", "",
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


@dataclass(frozen=True)
class CompareSpec:
    """An episode of the comparison: one centerline method on every frame, 2D and through the pipeline."""

    method: str
    frames: tuple
    calibration: StereoCalibration
    config: dict


def compare_episode(spec: CompareSpec) -> tuple[dict, np.ndarray | None]:
    """(the method's scores, its 2D nodes on the last frame with an arm, or None)."""
    base = EstimatorConfig.from_dict(spec.config)
    return compare_method(spec.method, list(spec.frames), spec.calibration, base)


def compare_method(method: str, frames: Sequence[StudyFrame], calibration: StereoCalibration,
                   base: EstimatorConfig) -> tuple[dict, np.ndarray | None]:
    """One method's topology and order errors, 2D time and whole-pipeline accuracy in both modes."""
    paper_cfg = base.replace(mode="paper")
    rect = calibration.rectification
    inputs = [left_samples(f, calibration, paper_cfg) for f in frames]
    topo, order, times_2d = [], [], []
    drawn = None
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
        drawn = nodes
    for mode in ("paper", "default"):
        scores, totals, valid, flagged = [], [], 0, 0
        for f in frames:
            est = CenterlineEstimator(calibration, base.replace(mode=mode, centerline=method))  # cold, per frame
            result = process(_capture(f), {"main": est}, calibration).main
            totals.append(result.total_ms)
            flagged += bool(result.flags)
            if result.valid:
                valid += 1
                scores.append(result.errors)
        pipeline[mode] = {
            "valid": valid, "frames": len(frames), "flagged": flagged,
            "rmse_mm": _pooled([s["rmse_mm"] for s in scores]),
            "max_mm": max((s["max_mm"] for s in scores), default=float("nan")),
            "tip_mm": float(np.mean([s["tip_mm"] for s in scores])) if scores else float("nan"),
            "ms_per_frame": float(np.median(totals)),
        }
    entry = {"topology_error": _nanmean(topo), "order_error": _nanmean(order),
             "ms_2d": float(np.median(times_2d)) if times_2d else float("nan"), "pipeline": pipeline}
    return entry, drawn


def compare_study(frames: Sequence[StudyFrame], calibration: StereoCalibration, base: EstimatorConfig,
                  out: Path, engine: EngineConfig | None = None, *, progress: bool = False) -> dict:
    """Figs 7, 8 and the accuracy/topology/time table, one episode per method on ``engine``; writes plots,
    compare.md, compare.json and results.csv."""
    import matplotlib

    matplotlib.use("Agg")
    paper_cfg = base.replace(mode="paper")
    study_frames = tuple(dataclasses.replace(f, capture=None, record=None) for f in frames)  # what travels
    specs = [CompareSpec(method, study_frames, calibration, base.as_dict()) for method in CENTERLINES]
    outcomes = run_episodes(compare_episode, specs, engine, label="compare", progress=progress)
    per_method: dict[str, dict] = {}
    drawn: dict[str, np.ndarray] = {}
    for method, (entry, nodes) in zip(CENTERLINES, _results(outcomes, "the comparison"), strict=True):
        per_method[method] = entry
        if nodes is not None:
            drawn[method] = nodes
    inputs = [left_samples(frames[-1], calibration, paper_cfg)]
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
    write_results(out, [{"method": method, "mode": mode, "topology_error": m["topology_error"],
                         "order_error": m["order_error"], "ms_2d": m["ms_2d"], **m["pipeline"][mode]}
                        for method, m in per_method.items() for mode in ("paper", "default")],
                  ("method", "mode", "topology_error", "order_error", "valid", "frames", "flagged", "rmse_mm",
                   "max_mm", "tip_mm", "ms_2d", "ms_per_frame"))
    result.update(headline=headline, outcomes=outcomes, episodes=len(outcomes))
    return result


def _capture(frame: StudyFrame) -> Capture:
    """The frame as captured (its exact backbone; depth kept where the capture had it)."""
    if frame.capture is not None:
        return frame.capture
    return Capture(index=0, t_s=frame.t_s, frame=StereoFrame(frame.left, frame.right, frame.t_s, 0),
                   commanded_bar=frame.commanded_bar, gt_m=frame.gt_m)


def _mm(p: dict) -> str:
    rmse = p["rmse_mm"]
    flagged = f", {p['flagged']} flagged" if p.get("flagged") else ""
    return (f"{rmse:.1f} mm ({p['valid']}/{p['frames']}{flagged})" if np.isfinite(rmse)
            else f"n/a (0/{p['frames']}{flagged})")


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
             "backwards along the projected exact backbone (the ordering failure of Fig 8b).",
             "- valid: frames with an estimate (the paper mode reports every frame, as the paper does); flagged: "
             "frames failing a plausibility check (dropped in default mode, kept and named in paper mode).", "",
             "| method | topology error | order error | 2D ms | paper-mode RMSE (valid) | paper-mode ms | "
             "default-mode RMSE (valid) | default-mode ms |", "|---|---|---|---|---|---|---|---|"]
    for method, m in result["methods"].items():
        p, d = m["pipeline"]["paper"], m["pipeline"]["default"]
        lines.append(f"| {METHOD_NAMES[method]} | {m['topology_error']:.3f} | {m['order_error']:.3f} | "
                     f"{m['ms_2d']:.1f} | {_mm(p)} | {p['ms_per_frame']:.0f} | {_mm(d)} | {d['ms_per_frame']:.0f} |")
    lines += ["", "![fig7](fig7_centerlines.png)", "", "![fig8](fig8_thinning_vs_som.png)", "",
              "![accuracy and time](compare_accuracy_time.png)", ""]
    path.write_text("\n".join(lines), encoding="utf-8")
