"""The frame record: one line of ``frames.jsonl``, typed, versioned and checked when read back.

Every part of the bench that makes or reads a frame's results goes through :class:`FrameRecord`:
``bench.process.process`` builds one per frame (run, replay, the report's re-runs, the studies),
``RunWriter`` writes ``FrameRecord.to_json()``, ``load_run`` reads ``FrameRecord.from_json`` and
the summaries, the report and replay read its attributes. A line that is not a record (a hand
edit, a partial line, another program's output) is refused by ``from_json`` with the key and the
reason, instead of raising deep inside a plot::

    FrameRecord.from_json({"index": 10})   # RecordError: missing key 't_s'

The JSON layout (version 2): the frame's bookkeeping (index, times, pressures, bench timings), the
main estimate's fields at the top level, the paper mode's (``--compare``) under ``paper``, the
exact backbone on the twin (``gt_m``) and where the frame's files are (``images``, ``depth``; on
the twin also ``clean``: the images are the noise-free render, stored as its difference from the
static scene, and the sensor noise is drawn again from ``seed`` and ``index``). Version 1
records (before the estimator's per-point fields and the twin's noise-free images) read as well.
Unknown keys are ignored (a newer writer may add some).
"""

from __future__ import annotations

import dataclasses
import math
import types
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

RECORD_VERSION = 2
# Keys of ``score_against_backbone`` that the summaries read, and of a Q' score.
ERROR_KEYS = ("rmse_mm", "rmse_x_mm", "rmse_y_mm", "rmse_z_mm", "max_mm", "tip_mm", "base_mm", "arc_rmse_mm",
              "length_error_mm")
QPRIME_KEYS = ("x_mm", "y_mm", "z_mm", "rmse_mm")
# How finely values are written: 0.1 um, 1/1000 px and ms (a replay of the recorded frames reproduces them).
ROUND_M, ROUND_PX, ROUND_MS = 7, 3, 3
SIDES = ("left", "right")


class RecordError(ValueError):
    """A JSON value is not a frame record; the message names the key and what is wrong."""


# --- checks: each returns None or what is wrong -------------------------------------------------


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


def _list_of(check_item: Callable[[Any], str | None], what: str) -> Callable[[Any], str | None]:
    def check(value: Any) -> str | None:
        if not isinstance(value, list):
            return f"expected a list of {what}, got {_kind(value)}"
        for i, item in enumerate(value):
            problem = check_item(item)
            if problem:
                return f"[{i}]: {problem}"
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


def _files(value: Any) -> str | None:
    if not isinstance(value, dict) or not all(isinstance(v, str) for v in value.values()):
        return f"expected an object of file names, got {_kind(value)}"
    return None


def _depth(value: Any) -> str | None:
    if not isinstance(value, dict) or not isinstance(value.get("path"), str):
        return f"expected an object with a path, got {_kind(value)}"
    if "unit_m" in value and not (_is_number(value["unit_m"]) and value["unit_m"] > 0):
        return f"unit_m: expected a positive number, got {_kind(value['unit_m'])}"
    if "background" in value and not isinstance(value["background"], str):
        return f"background: expected a file name, got {_kind(value['background'])}"
    if "origin" in value and not (isinstance(value["origin"], list) and len(value["origin"]) == 2
                                  and all(_check_index(v) is None for v in value["origin"])):
        return f"origin: expected [x, y] pixels >= 0, got {_kind(value['origin'])}"
    return None


def _clean(value: Any) -> str | None:
    if not isinstance(value, dict):
        return f"expected an object, got {_kind(value)}"
    for key in ("seed", "index"):
        problem = _check_index(value.get(key)) if key in value else f"missing key {key!r}"
        if problem:
            return f"{key}: {problem}" if key in value else problem
    if "background" not in value:
        return "missing key 'background'"
    problem = _files(value["background"])
    if problem:
        return f"background: {problem}"
    origin = value.get("origin", {})
    if not isinstance(origin, dict):
        return f"origin: expected an object, got {_kind(origin)}"
    for side, xy in origin.items():
        ok = isinstance(xy, list) and len(xy) == 2 and all(_check_index(v) is None for v in xy)
        if not ok:
            return f"origin: {side}: expected [x, y] pixels >= 0, got {_kind(xy)}"
    return None


def _backbone(value: Any) -> str | None:
    problem = _points(3)(value)
    if problem is None and len(value) < 2:
        return f"expected at least 2 points, got {len(value)}"
    return problem


# The frame's own keys: always written.
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
    "images": _files,
    "clean": _clean,
    "depth": _depth,
    "write_ms": _check_number,
}
# An estimate's keys (the main one at the top level, the paper mode's under "paper").
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
# Newer estimate keys (version 2): a version 1 record reads without them.
_ESTIMATE_OPTIONAL: dict[str, Callable[[Any], str | None]] = {
    "flags": _list_of(_check_str, "check names"),
    "measured": _list_of(_check_bool, "true/false"),
    "point_std_m": _list_of(_check_number, "numbers"),
    "radius_m": _or_none(_check_number),
    "radius_source": _check_str,
    "points_unsmoothed_m": _points(3),
}


def _first_problem(obj: Mapping, checks: Mapping[str, Callable[[Any], str | None]], required: bool) -> str | None:
    for key, check in checks.items():
        if key not in obj:
            if required:
                return f"missing key {key!r}"
            continue
        problem = check(obj[key])
        if problem:
            return f"{key}: {problem}"
    return None


def _estimate_problem(fields: Mapping) -> str | None:
    problem = _first_problem(fields, _ESTIMATE, True) or _first_problem(fields, _ESTIMATE_OPTIONAL, False)
    if problem:
        return problem
    if fields["valid"] and not fields["points_m"]:
        return "points_m: a valid estimate has no points"
    n = len(fields["points_m"])
    for key in ("measured", "point_std_m"):
        if fields.get(key) and len(fields[key]) != n:
            return f"{key}: expected one value per point ({n}), got {len(fields[key])}"
    return None


def record_problem(record: Any) -> str | None:
    """What is wrong with one frame record (a JSON value), or None when ``FrameRecord.from_json`` reads it."""
    if not isinstance(record, dict):
        return f"expected a JSON object, got {_kind(record)}"
    problem = _first_problem(record, _RECORD, True) or _first_problem(record, _OPTIONAL, False)
    if problem:
        return problem
    problem = _estimate_problem(record)
    if problem:
        return problem
    if "paper" in record:
        paper = record["paper"]
        if not isinstance(paper, dict):
            return f"paper: expected an object, got {_kind(paper)}"
        problem = _check_str(paper.get("mode")) if "mode" in paper else "missing key 'mode'"
        problem = problem or _estimate_problem(paper)
        if problem:
            return f"paper: {problem}"
    return None


# --- the typed record -----------------------------------------------------------------------


def _array(values: Any, width: int | None = None, dtype: Any = np.float64) -> np.ndarray:
    """A read-only array of a JSON list (None -> NaN for floats)."""
    if dtype is np.float64:
        values = [[math.nan if v is None else v for v in row] for row in values] if width else \
            [math.nan if v is None else v for v in values]
    array = np.asarray(values, dtype=dtype)
    if width:
        array = array.reshape(-1, width)
    array.setflags(write=False)
    return array


def _frozen(array: Any, width: int | None = None, dtype: Any = np.float64) -> np.ndarray:
    array = np.array(array, dtype=dtype)
    if width:
        array = array.reshape(-1, width)
    array.setflags(write=False)
    return array


def _rows(array: np.ndarray) -> list:
    """JSON rows of a float array, non-finite values as null."""
    return [[float(v) if math.isfinite(v) else None for v in row] for row in array.tolist()]


def _mapping(value: Mapping | None) -> Mapping | None:
    return None if value is None else types.MappingProxyType(dict(value))


def _plain(value: Mapping | None) -> dict | None:
    if value is None:
        return None
    return {k: (_plain(v) if isinstance(v, Mapping) else list(v) if isinstance(v, tuple) else v)
            for k, v in value.items()}


def _round(value: float | None, digits: int) -> float | None:
    return None if value is None or not math.isfinite(value) else round(float(value), digits)


@dataclasses.dataclass(frozen=True, eq=False)
class EstimateRecord:
    """One estimator's result on a frame, with its scores, as recorded (rounded as written).

    Attributes:
        valid, reason: whether the estimate is trustworthy, and why not.
        points_m: (n, 3) metres, left camera frame, base to tip; (0, 3) when not valid.
        left_uv, right_uv: (n, 2) the 2D centerlines, raw pixels.
        timings_ms: estimator stage -> milliseconds (``total``: the whole call).
        misalignment_px: eq. (11) before compensation, or None.
        flags: plausibility checks the frame failed (kept and named in paper mode).
        measured: (n,) True where the point is measured, False where the tube fit bridged it; (0,)
            when the estimator does not say (paper mode, a version 1 record).
        point_std_m: (n,) each point's standard deviation, metres; (0,) when not known.
        radius_m: the tube's radius the fit used (None: not known), ``radius_source`` where it came from.
        points_unsmoothed_m: (k, 3) the triangulated nodes before the polynomial (the paper's Q,
            paper path); (0, 3) otherwise.
        errors: scores against the exact backbone (``ERROR_KEYS``, mm), None without ground truth.
        qprime, qprime_m: per-axis RMSE against Q' and Q' itself ((n, 3), NaN where no depth), None
            without a depth source.
        mode: the estimator mode, written for the paper-mode estimate of ``--compare``.
    """

    valid: bool
    reason: str | None
    points_m: np.ndarray
    left_uv: np.ndarray
    right_uv: np.ndarray
    timings_ms: Mapping[str, float]
    misalignment_px: float | None = None
    flags: tuple[str, ...] = ()
    measured: np.ndarray = dataclasses.field(default_factory=lambda: _frozen([], dtype=bool))
    point_std_m: np.ndarray = dataclasses.field(default_factory=lambda: _frozen([]))
    radius_m: float | None = None
    radius_source: str = ""
    points_unsmoothed_m: np.ndarray = dataclasses.field(default_factory=lambda: _frozen([], 3))
    errors: Mapping[str, float] | None = None
    qprime: Mapping[str, float] | None = None
    qprime_m: np.ndarray | None = None
    mode: str | None = None

    @classmethod
    def from_result(cls, result, scores: Mapping[str, Any] | None = None, mode: str | None = None) -> EstimateRecord:
        """The record of an ``estimator.EstimateResult`` and its ``bench.scoring.score_fields``, rounded as written.

        Args:
            result: the estimate.
            scores: ``{"errors", "qprime", "qprime_m"}`` (None or missing: not scored).
            mode: the estimator's mode, for an estimate recorded beside the main one.
        """
        scores = scores or {}
        qprime_m = scores.get("qprime_m")
        return cls(
            valid=bool(result.valid), reason=result.reason,
            points_m=_frozen(np.round(np.asarray(result.points, float), ROUND_M), 3),
            left_uv=_frozen(np.round(np.asarray(result.left_uv, float), ROUND_PX), 2),
            right_uv=_frozen(np.round(np.asarray(result.right_uv, float), ROUND_PX), 2),
            timings_ms=_mapping({k: round(float(v), ROUND_MS) for k, v in result.timings_ms.items()}),
            misalignment_px=_round(result.misalignment_px, 4),
            flags=tuple(str(f) for f in result.flags),
            measured=_frozen(getattr(result, "measured", ()), dtype=bool),
            point_std_m=_frozen(np.round(np.asarray(getattr(result, "point_std_m", ()), float), ROUND_M + 2)),
            radius_m=_round(getattr(result, "radius_m", math.nan), ROUND_M),
            radius_source=str(getattr(result, "radius_source", "") or ""),
            points_unsmoothed_m=_frozen(np.round(np.asarray(getattr(result, "points_unsmoothed", np.zeros((0, 3))),
                                                            float), ROUND_M), 3),
            errors=_mapping(scores.get("errors")), qprime=_mapping(scores.get("qprime")),
            qprime_m=None if qprime_m is None else _array(qprime_m, 3), mode=mode)

    def to_json(self) -> dict:
        out: dict[str, Any] = {} if self.mode is None else {"mode": self.mode}
        out.update({
            "valid": self.valid, "reason": self.reason, "points_m": self.points_m.tolist(),
            "left_uv": self.left_uv.tolist(), "right_uv": self.right_uv.tolist(),
            "timings_ms": dict(self.timings_ms), "misalignment_px": self.misalignment_px, "flags": list(self.flags),
            "measured": [bool(v) for v in self.measured], "point_std_m": self.point_std_m.tolist(),
            "radius_m": self.radius_m, "radius_source": self.radius_source,
        })
        if len(self.points_unsmoothed_m):
            out["points_unsmoothed_m"] = self.points_unsmoothed_m.tolist()
        out.update({"errors": _plain(self.errors), "qprime": _plain(self.qprime),
                    "qprime_m": None if self.qprime_m is None else _rows(self.qprime_m)})
        return out

    @classmethod
    def from_json(cls, obj: Mapping) -> EstimateRecord:
        """An estimate's fields as written (checked by ``FrameRecord.from_json``)."""
        return cls(
            valid=obj["valid"], reason=obj["reason"], points_m=_array(obj["points_m"], 3),
            left_uv=_array(obj["left_uv"], 2), right_uv=_array(obj["right_uv"], 2),
            timings_ms=_mapping(obj["timings_ms"]), misalignment_px=obj["misalignment_px"],
            flags=tuple(obj.get("flags", ())), measured=_array(obj.get("measured", []), dtype=bool),
            point_std_m=_array(obj.get("point_std_m", [])), radius_m=obj.get("radius_m"),
            radius_source=obj.get("radius_source", ""),
            points_unsmoothed_m=_array(obj.get("points_unsmoothed_m", []), 3),
            errors=_mapping(obj["errors"]), qprime=_mapping(obj["qprime"]),
            qprime_m=None if obj["qprime_m"] is None else _array(obj["qprime_m"], 3), mode=obj.get("mode"))

    @property
    def total_ms(self) -> float:
        """The estimator's time for the frame, ms (NaN when not recorded)."""
        return float(self.timings_ms.get("total", math.nan))


@dataclasses.dataclass(frozen=True, eq=False)
class FrameRecord:
    """One frame of a run: what was commanded and captured, the estimates and their scores, its files.

    Attributes:
        index: the frame's number in the run (0, 1, ...).
        t_s: seconds since the experiment's start (simulated on the twin).
        timestamp_s, camera_index: the camera's timestamp and frame number.
        commanded_bar: the valves' set-points when the frame was captured.
        chamber_bar: the chambers' pressures (the twin knows them), or None.
        bench_ms: where the bench's time went for this frame (physics, render, estimate_main, ...).
        main: the run's estimate; ``paper``: the paper mode's beside it (``--compare``) or None.
        sim_time_s: the twin's simulated time, or None.
        gt_m: (N, 3) the exact backbone, left camera frame (the twin), or None.
        images: side -> file of the stored images (relative to the run folder), or None.
        clean: how the stored images become the captured ones: {"seed", "index", "background":
            {side: file}, "origin": {side: [x, y]}} (the twin's noise-free images, stored as their
            difference from the background, cropped at origin), or None (the images are the frames).
        depth: {"path", "unit_m"} of the stored left depth map, or None.
        write_ms: how long the writer took for the frame.
    """

    index: int
    t_s: float
    timestamp_s: float
    camera_index: int
    commanded_bar: Mapping[str, float]
    chamber_bar: Mapping[str, float] | None
    bench_ms: Mapping[str, float]
    main: EstimateRecord
    paper: EstimateRecord | None = None
    sim_time_s: float | None = None
    gt_m: np.ndarray | None = None
    images: Mapping[str, str] | None = None
    clean: Mapping[str, Any] | None = None
    depth: Mapping[str, Any] | None = None
    write_ms: float | None = None

    def __post_init__(self) -> None:
        for name in ("commanded_bar", "chamber_bar", "bench_ms", "images", "clean", "depth"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, types.MappingProxyType):
                object.__setattr__(self, name, _mapping(value))

    # --- the estimates ----------------------------------------------------------------------------

    def estimate(self, key: str | None = None) -> EstimateRecord | None:
        """The main estimate (``key`` None or "main") or the one recorded under ``key`` ("paper")."""
        if key in (None, "main"):
            return self.main
        if key == "paper":
            return self.paper
        raise ValueError(f"key: expected None, 'main' or 'paper', got {key!r}")

    def replace(self, **changes: Any) -> FrameRecord:
        return dataclasses.replace(self, **changes)

    # --- JSON -------------------------------------------------------------------------------------

    def to_json(self) -> dict:
        """The record as one JSON object (the layout of ``frames.jsonl``)."""
        out: dict[str, Any] = {
            "index": self.index, "t_s": self.t_s, "timestamp_s": self.timestamp_s, "camera_index": self.camera_index,
            "commanded_bar": dict(self.commanded_bar),
            "chamber_bar": None if self.chamber_bar is None else dict(self.chamber_bar),
        }
        if self.sim_time_s is not None:
            out["sim_time_s"] = self.sim_time_s
        out.update(self.main.to_json())
        if self.paper is not None:
            out["paper"] = self.paper.to_json()
        if self.gt_m is not None:
            out["gt_m"] = self.gt_m.tolist()
        out["bench_ms"] = dict(self.bench_ms)
        for name in ("images", "clean", "depth"):
            value = getattr(self, name)
            if value is not None:
                out[name] = _plain(value)
        if self.write_ms is not None:
            out["write_ms"] = self.write_ms
        return out

    @classmethod
    def from_json(cls, obj: Any) -> FrameRecord:
        """Read one record of ``frames.jsonl`` (version 1 or 2).

        Raises:
            RecordError: a missing key or a value of the wrong type, named (``"points_m: expected a
                list of [x, y, z], got 'x' (a string)"``).
        """
        problem = record_problem(obj)
        if problem:
            raise RecordError(problem)
        return cls(
            index=obj["index"], t_s=obj["t_s"], timestamp_s=obj["timestamp_s"], camera_index=obj["camera_index"],
            commanded_bar=obj["commanded_bar"], chamber_bar=obj["chamber_bar"], bench_ms=obj["bench_ms"],
            main=EstimateRecord.from_json(obj),
            paper=EstimateRecord.from_json(obj["paper"]) if "paper" in obj else None,
            sim_time_s=obj.get("sim_time_s"), gt_m=_array(obj["gt_m"], 3) if "gt_m" in obj else None,
            images=obj.get("images"), clean=_frozen_json(obj.get("clean")), depth=obj.get("depth"),
            write_ms=obj.get("write_ms"))

    @classmethod
    def coerce(cls, value: FrameRecord | Mapping) -> FrameRecord:
        """``value`` itself, or the record a JSON object holds (``from_json``)."""
        return value if isinstance(value, FrameRecord) else cls.from_json(value)


def _frozen_json(value: Any) -> Any:
    """Nested JSON objects as read-only mappings, lists as tuples."""
    if isinstance(value, dict):
        return types.MappingProxyType({k: _frozen_json(v) for k, v in value.items()})
    if isinstance(value, list):
        return tuple(_frozen_json(v) for v in value)
    return value
