"""``softarm study sweep --grid FILE.toml``: estimator settings against lab scenes, a grid or a random search.

Every setting (values of ``EstimatorConfig`` fields) runs on every scene (preset and seed): one
episode each, the configured experiment with ``frames`` captures, the setting's estimator on every
frame, scored against the exact backbone. The grid file::

    [sweep]
    search = "grid"            # "grid": every combination; "random": `samples` settings drawn from `seed`
    samples = 16               # random only
    seed = 0                   # random only
    frames = 12                # captures per episode, spread over the experiment
    objective = "rmse_mm"      # what the best setting minimises: rmse_mm, tip_mm, max_mm (or maximises:
                               # valid_fraction); settings with a false valid frame, or below
    min_valid = 0.95           # this mean valid fraction, rank after every setting that meets both

    [scenes]
    presets = ["lab", "dim"]   # models/scene.toml presets
    seeds = [0, 1]             # each preset drawn from each seed

    [estimator]                # EstimatorConfig fields -> the values to try
    tube_fit = [true, false]
    som_alpha0 = [0.1, 0.2, 0.3]
    # random search only: a range instead of a list, drawn uniformly (log = true: log-uniform)
    # som_alpha0 = { min = 0.05, max = 0.5, log = true }
    # n_points = { min = 12, max = 30, integer = true }

Writes ``results.csv`` (one row per episode: the setting's values, the scene and the metrics),
``study.json`` (the grid, engine, versions, seeds, wall time, episodes per second, every setting's
scores and the best) and ``sweep.png`` (for each parameter, the best score reached at each of its
values over every other parameter, with all settings behind it).

Why no Ray Tune: the search is a plain grid or a seeded random draw run as episodes on our own
engine, so the local and Ray engines run the same episodes and give the same table, and every
episode is an independent twin run. Tune's adaptive searchers (Bayesian optimisation, HyperOpt,
Optuna) pay off on many cheap trials; here a trial is a rendered sequence, a sweep is tens to
hundreds of them, and the searchers would add packages and their own driver and result layout.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.config import BenchConfig, ConfigError, load_bench_config
from bench.engines import EngineConfig, EngineError, engine_from_args, run_episodes, workers_used
from bench.episodes import sequence_episode, sequence_spec, twin_config
from bench.frame_record import FrameRecord
from bench.robustness import summarize_mode
from bench.study_files import finish_study, out_folder, write_results, write_study
from estimator import EstimatorConfig
from estimator.config_file import ConfigFileError, TableReader, choice, integer, number, read_toml

SEARCHES = ("grid", "random")
# objective -> True when larger is better
OBJECTIVES = {"rmse_mm": False, "tip_mm": False, "max_mm": False, "valid_fraction": True}
METRICS = ("frames", "valid", "valid_fraction", "false_valid", "rmse_mm", "tip_mm", "max_mm", "tip_max_mm", "fps")
MAX_EPISODES = 100_000


@dataclasses.dataclass(frozen=True)
class Range:
    """A random search's range of one parameter."""

    lo: float
    hi: float
    log: bool = False
    integer: bool = False

    def ends(self) -> tuple:
        """The range's two ends as the draws give them (whole numbers for an integer range)."""
        return (int(self.lo), int(self.hi)) if self.integer else (self.lo, self.hi)

    def draw(self, rng: np.random.Generator):
        if self.integer:
            return int(rng.integers(int(self.lo), int(self.hi) + 1))
        if self.log:
            return float(np.exp(rng.uniform(math.log(self.lo), math.log(self.hi))))
        return float(rng.uniform(self.lo, self.hi))


@dataclasses.dataclass(frozen=True)
class Grid:
    """A sweep file, read and checked."""

    path: Path
    search: str
    samples: int
    seed: int
    frames: int
    objective: str
    min_valid: float
    presets: tuple[str, ...]
    seeds: tuple[int, ...]
    parameters: Mapping[str, tuple | Range]

    def settings(self) -> list[dict[str, Any]]:
        """Every setting to run: the grid's combinations, or ``samples`` random draws."""
        names = list(self.parameters)
        if self.search == "grid":
            return [dict(zip(names, values, strict=True))
                    for values in itertools.product(*(self.parameters[n] for n in names))]
        rng = np.random.default_rng(self.seed)
        settings = []
        for _ in range(self.samples):
            setting = {}
            for name in names:
                space = self.parameters[name]
                setting[name] = space.draw(rng) if isinstance(space, Range) else space[int(rng.integers(len(space)))]
            settings.append(setting)
        return settings


def load_grid(path: str | Path, base: EstimatorConfig | None = None) -> Grid:
    """Read a sweep file (see the module docstring).

    Raises:
        ConfigFileError: missing file, unknown key, bad value, or a setting the estimator refuses;
            the message names the file and the key.
    """
    path = Path(path)
    top = TableReader(path, read_toml(path, "sweep"))
    sweep = top.sub("sweep")
    search = sweep.take("search", choice(SEARCHES), "grid")
    samples = sweep.take("samples", integer(1, MAX_EPISODES), 16)
    seed = sweep.take("seed", integer(0, 2**63 - 1), 0)
    frames = sweep.take("frames", integer(1, 1000), 12)
    objective = sweep.take("objective", choice(tuple(OBJECTIVES)), "rmse_mm")
    min_valid = sweep.take("min_valid", number(0.0, 1.0), 0.95)
    sweep.done()
    scenes = top.sub("scenes")
    presets = tuple(scenes.take("presets", _names))
    seeds = tuple(scenes.take("seeds", _seeds, [0]))
    scenes.done()
    table = top.sub("estimator")
    known = {f.name for f in dataclasses.fields(EstimatorConfig)}
    parameters: dict[str, tuple | Range] = {}
    fields = table.keys()  # a TableReader is not iterable
    for key in fields:
        if key not in known:
            raise table.fail(f"unknown key [estimator] {key}: not a field of EstimatorConfig (known: "
                             f"{', '.join(sorted(known))})")
        parameters[key] = table.take(key, _space(search))
    table.done()
    if not parameters:
        raise top.fail("[estimator]: no parameter to sweep (give at least one field and its values)")
    grid = Grid(path, search, samples, seed, frames, objective, min_valid, presets, seeds, parameters)
    count = len(grid.settings()) * len(presets) * len(seeds)
    if count > MAX_EPISODES:
        raise top.fail(f"{count} episodes: at most {MAX_EPISODES} (fewer values, or a random search)")
    base = base or EstimatorConfig()
    for name, space in parameters.items():  # every value the estimator would refuse, named before anything runs
        for value in space.ends() if isinstance(space, Range) else space:
            try:
                EstimatorConfig.from_dict({**base.as_dict(), name: value})
            except (TypeError, ValueError) as e:
                raise table.error(name, f"{value!r}: {e}") from e
    return grid


def _names(value: Any) -> list[str]:
    if not isinstance(value, list) or not value or not all(isinstance(v, str) and v for v in value):
        raise ValueError(f"expected a non-empty array of preset names, got {value!r}")
    return value


def _seeds(value: Any) -> list[int]:
    if (not isinstance(value, list) or not value
            or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value)):
        raise ValueError(f"expected a non-empty array of whole numbers >= 0, got {value!r}")
    return value


def _space(search: str):
    def convert(value: Any) -> tuple | Range:
        if isinstance(value, list):
            if not value:
                raise ValueError("expected at least one value")
            return tuple(tuple(v) if isinstance(v, list) else v for v in value)
        if isinstance(value, dict):
            if search != "random":
                raise ValueError("a range { min, max } needs search = \"random\" (a grid takes a list of values)")
            unknown = set(value) - {"min", "max", "log", "integer"}
            if unknown or "min" not in value or "max" not in value:
                raise ValueError(f"expected {{ min = ..., max = ... }} (optionally log, integer), got {value!r}")
            lo, hi = value["min"], value["max"]
            if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in (lo, hi)) or not lo <= hi:
                raise ValueError(f"expected numbers min <= max, got {lo!r}, {hi!r}")
            log, whole = bool(value.get("log", False)), bool(value.get("integer", False))
            if log and lo <= 0:
                raise ValueError("log = true needs min > 0")
            return Range(float(lo), float(hi), log, whole)
        raise ValueError(f"expected an array of values (or a {{ min, max }} range), got {value!r}")

    return convert


def sweep_specs(config: BenchConfig, grid: Grid) -> tuple[list[dict], list]:
    """(settings, specs): scene-major, so a worker's consecutive episodes share a rendered scene (cached)."""
    settings = grid.settings()
    specs = []
    for preset in grid.presets:
        for seed in grid.seeds:
            for index, setting in enumerate(settings):
                table = config.estimator_config(**setting).as_dict()
                specs.append(sequence_spec(config, frames=grid.frames, preset=preset, scene_seed=seed,
                                           estimators={"main": table}, cache=True,
                                           tag={"setting": index, "preset": preset, "scene_seed": seed}))
    return settings, specs


def score_settings(rows: Sequence[Mapping[str, Any]], settings: Sequence[Mapping], grid: Grid) -> list[dict]:
    """Each setting's scores over its scenes: mean valid fraction, false valid frames, the objective (mean over
    scenes; NaN when a scene failed or had no valid frame) and whether it meets ``min_valid`` with no false valid."""
    out = []
    for index, setting in enumerate(settings):
        mine = [r for r in rows if r["setting"] == index]
        failed = any(r["error"] for r in mine)
        valid = float(np.mean([r["valid_fraction"] for r in mine])) if mine else float("nan")
        values = [r[grid.objective] for r in mine]
        objective = float(np.mean(values)) if values and all(np.isfinite(values)) and not failed else float("nan")
        false_valid = int(sum(r["false_valid"] for r in mine))
        eligible = bool(not failed and valid >= grid.min_valid and false_valid == 0)
        out.append({"setting": index, "parameters": dict(setting), "valid_fraction": valid,
                    "false_valid": false_valid, grid.objective: objective, "eligible": eligible})
    return out


def rank(scores: Sequence[Mapping], grid: Grid) -> list[Mapping]:
    """Settings best first: those that meet ``min_valid`` with no false valid, then by the objective."""
    sign = -1.0 if OBJECTIVES[grid.objective] else 1.0

    def key(s):
        value = s[grid.objective]
        return (not s["eligible"], not np.isfinite(value), sign * value if np.isfinite(value) else 0.0, s["setting"])

    return sorted(scores, key=key)


def check_grid_presets(grid: Grid, specs: list) -> None:
    """Raise ``ConfigFileError`` naming the grid file's ``[scenes] presets`` (and the scene file's presets)
    for a preset the scene file does not define: before any episode runs."""
    for preset in grid.presets:
        try:
            twin_config(dataclasses.replace(specs[0], preset=preset))
        except ConfigFileError as e:
            raise ConfigFileError(f"{grid.path} [scenes] presets: {preset!r}: {e}") from e


def sweep_study(config: BenchConfig, grid: Grid, out: Path, engine: EngineConfig | None = None, *,
                progress: bool = True) -> dict[str, Any]:
    """Run the sweep and write its files; returns the settings' scores (best first) and a headline."""
    engine = engine or EngineConfig()
    settings, specs = sweep_specs(config, grid)
    check_grid_presets(grid, specs)
    start = time.perf_counter()
    outcomes = run_episodes(sequence_episode, specs, engine, label="sweep", progress=progress)
    wall_s = time.perf_counter() - start
    names = list(grid.parameters)
    rows = []
    for episode, outcome in enumerate(outcomes):
        tag = outcome.spec.tag
        records = [FrameRecord.from_json(r) for r in outcome.result["records"]] if outcome.ok else []
        rows.append({"episode": episode, "setting": tag["setting"], **settings[tag["setting"]],
                     "preset": tag["preset"], "scene_seed": tag["scene_seed"], **summarize_mode(records, "main"),
                     "error": outcome.error or ""})
    out.mkdir(parents=True, exist_ok=True)
    write_results(out, rows, ["episode", "setting", *names, "preset", "scene_seed", *METRICS, "error"])
    ranked = rank(score_settings(rows, settings, grid), grid)
    best = ranked[0] if ranked else None
    twin = twin_config(specs[0])
    study = write_study(
        out, study="sweep", engine=engine, workers=workers_used(engine, len(specs)), outcomes=outcomes, wall_s=wall_s,
        configuration={"config": str(config.path), "grid": str(grid.path), "search": grid.search,
                       "samples": grid.samples if grid.search == "random" else None, "frames": grid.frames,
                       "objective": grid.objective, "min_valid": grid.min_valid, "presets": grid.presets,
                       "parameters": {n: dataclasses.asdict(s) if isinstance(s, Range) else s
                                      for n, s in grid.parameters.items()},
                       "experiment": config.experiment, "estimator": dict(config.estimator),
                       "settings": len(settings)},
        seeds={"search": grid.seed if grid.search == "random" else None, "scenes": grid.seeds,
               "render_noise": twin.seed, "experiment": config.experiment.seed},
        extra={"best": best, "ranking": ranked})
    plot_sweep(ranked, rows, grid, out / "sweep.png")
    lines = [f"{len(settings)} settings x {len(grid.presets) * len(grid.seeds)} scenes = {len(specs)} episodes in "
             f"{wall_s:.1f} s ({study['episodes_per_s']:.3f} episodes/s) on the {engine.name} engine"]
    for s in ranked[:5]:
        lines.append(f"  {grid.objective} {s[grid.objective]:.3f}, valid {s['valid_fraction']:.0%}, false valid "
                     f"{s['false_valid']}{'' if s['eligible'] else ' (below min_valid or false valid)'}: "
                     + ", ".join(f"{k} = {v}" for k, v in s["parameters"].items()))
    return {"rows": rows, "ranking": ranked, "best": best, "study": study, "headline": lines}



def plot_sweep(ranked: Sequence[Mapping], rows: Sequence[Mapping], grid: Grid, path: Path) -> None:
    """For each parameter: every setting's score against its value (faint) and the best reached at each value."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(grid.parameters)
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.8), squeeze=False)
    best = ranked[0] if ranked else None
    for ax, name in zip(axes[0], names, strict=True):
        values = [s["parameters"][name] for s in ranked]
        numeric = all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)
        labels = list(dict.fromkeys(str(v) for v in values))

        def position(v, numeric=numeric, labels=labels) -> float:
            return float(v) if numeric else float(labels.index(str(v)))

        for s in ranked:
            ax.plot(position(s["parameters"][name]), s[grid.objective], "o", alpha=0.35,
                    color="tab:blue" if s["eligible"] else "tab:red", markersize=4)
        per_value: dict[Any, float] = {}
        for s in ranked:  # ranked best first: the first eligible score of each value is its best
            v = position(s["parameters"][name])
            if s["eligible"] and np.isfinite(s[grid.objective]) and v not in per_value:
                per_value[v] = s[grid.objective]
        xs = sorted(per_value)
        ax.plot(xs, [per_value[x] for x in xs], "-", color="tab:green", label="best at this value")
        if best is not None and np.isfinite(best[grid.objective]):
            ax.plot(position(best["parameters"][name]), best[grid.objective], "*", color="gold", markersize=14,
                    markeredgecolor="k", label="best setting")
        if not numeric:
            ax.set_xticks(range(len(labels)), labels, rotation=20, fontsize=8)
        ax.set_xlabel(name)
        ax.set_ylabel(f"{grid.objective} (mean over scenes)")
        ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.suptitle(f"Sweep: {len(ranked)} settings on {len(grid.presets) * len(grid.seeds)} scenes (red: below "
                 f"min_valid {grid.min_valid:g} or a false valid frame)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def sweep_command(args) -> int:
    """``softarm study sweep --grid FILE.toml [--out DIR] [--engine local|ray] [--workers N]``."""
    grid_path = getattr(args, "grid", None)
    if not grid_path:
        print("softarm study sweep: --grid FILE.toml is required (the parameters and scenes to sweep)", file=sys.stderr)
        return 2
    try:
        config = load_bench_config(getattr(args, "config", None))
        engine = engine_from_args(args)
        grid = load_grid(grid_path, config.estimator_config())
        if getattr(args, "frames", None) is not None:
            if not 1 <= args.frames <= 1000:
                raise ValueError(f"--frames {args.frames}: expected 1 to 1000 frames per episode")
            grid = dataclasses.replace(grid, frames=int(args.frames))
        check_grid_presets(grid, sweep_specs(config, grid)[1])  # a typo in the grid, like any bad option
        out = out_folder(args, config, "sweep")
    except (ConfigError, ConfigFileError, ValueError) as e:
        print(f"softarm study sweep: {e}", file=sys.stderr)
        return 2

    def work():
        result = sweep_study(config, grid, out, engine, progress=not getattr(args, "no_progress", False))
        return result["headline"], not result["study"]["failed"]

    return finish_study("sweep", out, work, (ConfigFileError, EngineError))
