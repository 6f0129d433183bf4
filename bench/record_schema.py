"""What a line of ``frames.jsonl`` must hold, checked when a run is read back.

A frame record is what ``bench.run._process`` writes (``bench.scoring.estimate_fields`` and
``score_fields`` for each estimate) plus what the writer adds (images, depth, write time). The
readers (``softarm report``, ``replay``, the summaries) index these keys directly, so a record
that lacks one or holds the wrong type (a hand edit, a partial line, another program's output)
is refused here, with the key and the reason, instead of raising deep inside a plot.

    problem = record_problem(record)   # None, or e.g. "points_m: expected a list of [x, y, z], got 'x'"
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

# Keys of ``score_against_backbone`` that the summaries read, and of a Q' score.
ERROR_KEYS = ("rmse_mm", "rmse_x_mm", "rmse_y_mm", "rmse_z_mm", "max_mm", "tip_mm", "base_mm", "arc_rmse_mm",
              "length_error_mm")
QPRIME_KEYS = ("x_mm", "y_mm", "z_mm", "rmse_mm")


def record_problem(record: Any) -> str | None:
    """What is wrong with one frame record, or None when it has every key of today's records with its type.

    Unknown keys are allowed (a newer writer may add some); the main estimate's keys and, when
    present, those of the paper-mode estimate under ``paper`` are checked.
    """
    if not isinstance(record, dict):
        return f"expected a JSON object, got {_kind(record)}"
    for key, check in _RECORD.items():
        if key not in record:
            return f"missing key {key!r}"
        problem = check(record[key])
        if problem:
            return f"{key}: {problem}"
    for key, check in _OPTIONAL.items():
        if key in record:
            problem = check(record[key])
            if problem:
                return f"{key}: {problem}"
    problem = estimate_problem(record)
    if problem:
        return problem
    if "paper" in record:
        paper = record["paper"]
        if not isinstance(paper, dict):
            return f"paper: expected an object, got {_kind(paper)}"
        problem = _check_str(paper.get("mode")) if "mode" in paper else "missing key 'mode'"
        problem = problem or estimate_problem(paper)
        if problem:
            return f"paper: {problem}"
    return None


def estimate_problem(fields: Mapping) -> str | None:
    """What is wrong with the estimate fields of a record (``estimate_fields`` + ``score_fields``), or None."""
    for key, check in _ESTIMATE.items():
        if key not in fields:
            return f"missing key {key!r}"
        problem = check(fields[key])
        if problem:
            return f"{key}: {problem}"
    if fields["valid"] and not fields["points_m"]:
        return "points_m: a valid estimate has no points"
    return None


# --- checks: each returns None or what is wrong ------------------------------------------------


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _kind(value: Any) -> str:
    kinds = {bool: "a boolean", int: "an integer", float: "a number", str: "a string", list: "a list",
             dict: "an object", type(None): "null"}
    text = repr(value)
    return f"{text if len(text) <= 40 else text[:37] + '...'} ({kinds.get(type(value), type(value).__name__)})"


def _check_number(value: Any) -> str | None:
    return None if _is_number(value) else f"expected a number, got {_kind(value)}"


def _check_index(value: Any) -> str | None:
    ok = isinstance(value, int) and not isinstance(value, bool) and value >= 0
    return None if ok else f"expected an integer >= 0, got {_kind(value)}"


def _check_bool(value: Any) -> str | None:
    return None if isinstance(value, bool) else f"expected true or false, got {_kind(value)}"


def _check_str(value: Any) -> str | None:
    return None if isinstance(value, str) else f"expected a string, got {_kind(value)}"


def _or_none(check: Callable[[Any], str | None]) -> Callable[[Any], str | None]:
    return lambda value: None if value is None else check(value)


def _numbers_by_name(value: Any) -> str | None:
    if not isinstance(value, dict):
        return f"expected an object of numbers, got {_kind(value)}"
    for name, number in value.items():
        if not _is_number(number):
            return f"{name}: expected a number, got {_kind(number)}"
    return None


def _points(width: int, allow_null: bool = False) -> Callable[[Any], str | None]:
    shape = "[x, y, z]" if width == 3 else "[u, v]"

    def check(value: Any) -> str | None:
        if not isinstance(value, list):
            return f"expected a list of {shape}, got {_kind(value)}"
        for i, row in enumerate(value):
            ok = isinstance(row, list) and len(row) == width and all(
                _is_number(v) or (allow_null and v is None) for v in row)
            if not ok:
                return f"[{i}]: expected {shape} numbers, got {_kind(row)}"
        return None

    return check


def _scores(keys: tuple[str, ...]) -> Callable[[Any], str | None]:
    def check(value: Any) -> str | None:
        if not isinstance(value, dict):
            return f"expected an object, got {_kind(value)}"
        for key in keys:
            if key not in value:
                return f"missing key {key!r}"
            if not _is_number(value[key]):
                return f"{key}: expected a number, got {_kind(value[key])}"
        return None

    return check


def _images(value: Any) -> str | None:
    if not isinstance(value, dict) or not all(isinstance(v, str) for v in value.values()):
        return f"expected an object of file names, got {_kind(value)}"
    return None


def _depth(value: Any) -> str | None:
    if not isinstance(value, dict) or not isinstance(value.get("path"), str):
        return f"expected an object with a path, got {_kind(value)}"
    if "unit_m" in value and not (_is_number(value["unit_m"]) and value["unit_m"] > 0):
        return f"unit_m: expected a positive number, got {_kind(value['unit_m'])}"
    return None


def _backbone(value: Any) -> str | None:
    problem = _points(3)(value)
    if problem is None and len(value) < 2:
        return f"expected at least 2 points, got {len(value)}"
    return problem


# Written by ``_process`` for every frame.
_RECORD: dict[str, Callable[[Any], str | None]] = {
    "index": _check_index,
    "t_s": _check_number,
    "timestamp_s": _check_number,
    "camera_index": _check_index,
    "commanded_bar": _numbers_by_name,
    "chamber_bar": _or_none(_numbers_by_name),
    "bench_ms": _numbers_by_name,
}
# Written for some frames (sim, a kept depth map, recorded images, --compare) or by the writer.
_OPTIONAL: dict[str, Callable[[Any], str | None]] = {
    "sim_time_s": _check_number,
    "gt_m": _backbone,
    "images": _images,
    "depth": _depth,
    "write_ms": _check_number,
}
# ``estimate_fields`` and ``score_fields``: the main estimate, and the paper mode's under "paper".
_ESTIMATE: dict[str, Callable[[Any], str | None]] = {
    "valid": _check_bool,
    "reason": _or_none(_check_str),
    "points_m": _points(3),
    "left_uv": _points(2),
    "right_uv": _points(2),
    "timings_ms": _numbers_by_name,
    "misalignment_px": _or_none(_check_number),
    "errors": _or_none(_scores(ERROR_KEYS)),
    "qprime": _or_none(_scores(QPRIME_KEYS)),
    "qprime_m": _or_none(_points(3, allow_null=True)),
}
