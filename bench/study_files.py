"""The one schema of every study's output: ``results.csv`` and ``study.json``.

``results.csv`` holds the study's table (one row per condition and mode, per episode, per method,
...), values rounded as written so that two runs of the same study compare line by line.
``study.json`` says how it was made: the study, its configuration, the software versions, the seeds,
the engine (``{"name": "local" | "ray", "workers", ...}``), the episodes (and any that failed), the
wall time and episodes per second. A local and a Ray run of the same study give the same
``results.csv`` apart from the columns that measure time (``TIMING_COLUMNS``)::

    problems = table_differences(run_a / "results.csv", run_b / "results.csv")   # [] when they agree
"""

from __future__ import annotations

import csv
import math
import platform
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from bench.engines import EngineConfig, Outcome
from bench.recording import write_json

RESULTS = "results.csv"
STUDY = "study.json"
# Columns that measure time: they differ from run to run (and engine to engine); nothing else may.
TIMING_COLUMNS = frozenset({"fps", "ms_2d", "ms_per_frame", "episode_s"})
DECIMALS = 4  # values are written to 0.1 um when in mm, 1e-4 of a fraction


def frames_from_args(args, default: int, maximum: int, unit: str = "frames") -> int:
    """``--frames``, or ``default`` when it is not given.

    Raises:
        ValueError: outside 1 .. ``maximum`` (the message names the flag, the range and the default).
    """
    frames = getattr(args, "frames", None)
    frames = default if frames is None else frames
    if not 1 <= frames <= maximum:
        raise ValueError(f"--frames {frames}: expected 1 to {maximum} {unit} (default {default})")
    return frames


def out_folder(args, config, which: str) -> Path:
    """``--out``, or a fresh ``study_<which>_<timestamp>`` under the config's runs folder."""
    import time

    from bench.recording import new_run_folder

    if getattr(args, "out", None):
        from bench.recording import writable_folder

        return writable_folder(Path(args.out), "--out")
    return new_run_folder(config.recording.runs_root(), f"study_{which}_{time.strftime('%Y-%m-%d_%H%M%S')}")


def counted(n: int, noun: str) -> str:
    """``n`` and the noun, plural unless one: "1 condition", "7 conditions"."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def cell(value: Any) -> str:
    """One value as ``results.csv`` writes it (floats to ``DECIMALS`` places, NaN and None as empty)."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if not math.isfinite(value):
            return "" if math.isnan(value) else ("inf" if value > 0 else "-inf")
        text = f"{round(value, DECIMALS):.{DECIMALS}f}".rstrip("0").rstrip(".")
        return "0" if text in ("-0", "") else text
    if isinstance(value, list | tuple):
        return " ".join(cell(v) for v in value)
    return str(value)


def write_results(out: Path, rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> Path:
    """Write ``out/results.csv``: a header of ``columns``, then one line per row (missing keys empty)."""
    path = Path(out) / RESULTS
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(columns)
        for row in rows:
            writer.writerow([cell(row.get(c)) for c in columns])
    return path


def read_results(path: Path) -> list[dict[str, str]]:
    """The rows of a ``results.csv`` (values as written)."""
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def table_differences(a: Path, b: Path, ignore: Iterable[str] = TIMING_COLUMNS) -> list[str]:
    """Where two ``results.csv`` differ, line by line, outside the ``ignore`` columns ([] when they agree)."""
    rows_a, rows_b = read_results(a), read_results(b)
    ignore = set(ignore)
    problems = []
    if len(rows_a) != len(rows_b):
        problems.append(f"{len(rows_a)} rows against {len(rows_b)}")
    for i, (ra, rb) in enumerate(zip(rows_a, rows_b, strict=False)):
        if list(ra) != list(rb):
            problems.append(f"row {i + 1}: columns {list(ra)} against {list(rb)}")
            continue
        for key in ra:
            if key not in ignore and ra[key] != rb[key]:
                problems.append(f"row {i + 1} {key}: {ra[key]!r} against {rb[key]!r}")
    return problems


def versions(*packages: str) -> dict[str, str | None]:
    """Versions of softarm-twin, Python and the packages that shape a study's numbers."""
    from importlib.metadata import PackageNotFoundError, version

    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in ("softarm-twin", "numpy", "scipy", "opencv-python-headless", "numba", "mujoco", "pyrender",
                 *packages):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def episodes_summary(outcomes: Sequence[Outcome], wall_s: float) -> dict[str, Any]:
    """Episode counts, failures, retries and rates for ``study.json``."""
    done = [o for o in outcomes if o.ok]
    seconds = [o.episode_s for o in done]
    return {
        "episodes": len(outcomes), "completed": len(done), "retried": sum(o.attempts > 1 for o in outcomes),
        "failed": [{"index": o.index, "tag": getattr(o.spec, "tag", None), "error": o.error,
                    "attempts": o.attempts} for o in outcomes if not o.ok],
        "wall_s": round(wall_s, 3),
        "episodes_per_s": round(len(outcomes) / wall_s, 5) if wall_s > 0 else None,
        "episode_s": {"sum": round(sum(seconds), 3),
                      "median": round(sorted(seconds)[len(seconds) // 2], 3) if seconds else None},
        # each episode's own time (what one core spends on it: the figure to plan a cluster with)
        "episode_list": [{"index": o.index, "tag": getattr(o.spec, "tag", None), "attempts": o.attempts,
                          "episode_s": round(o.episode_s, 3) if o.ok else None} for o in outcomes],
    }


def write_study(out: Path, *, study: str, engine: EngineConfig, workers: int | None, outcomes: Sequence[Outcome],
                wall_s: float, configuration: Mapping[str, Any], seeds: Mapping[str, Any],
                extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Write ``out/study.json`` and return what it holds (``workers`` None: what the engine used)."""
    if workers is None:
        workers = next((o.workers for o in outcomes if o.workers is not None), None)
    data: dict[str, Any] = {
        "study": study, "engine": engine.describe(workers), "configuration": dict(configuration),
        "seeds": dict(seeds), "versions": versions(*(("ray",) if engine.name == "ray" else ())),
        **episodes_summary(outcomes, wall_s), "results": RESULTS,
    }
    data.update(extra or {})
    write_json(Path(out) / STUDY, data)
    return data


def finish_study(which: str, out: Path, work: Callable[[], tuple[Sequence[str], bool]],
                 errors: tuple[type[BaseException], ...] = (), *, may_have_written: bool = False) -> int:
    """Run a study command's last step and report it as every study does; the exit status.

    ``work`` writes the study and returns its headline lines and whether every episode completed.
    An expected error (``errors``) or a failed write is one line on stderr (exit 1); otherwise the
    folder and the headline are printed (exit 1 when an episode failed, else 0).
    """
    try:
        headline, complete = work()
    except errors as e:
        print(f"softarm study {which}: {e}{'' if may_have_written else '; nothing written'}", file=sys.stderr)
        return 1
    except OSError as e:
        print(f"softarm study {which}: cannot write the study to {out}: {e}", file=sys.stderr)
        return 1
    print(f"softarm study {which}: wrote {out}")
    for line in headline:
        print(line)
    return 0 if complete else 1
