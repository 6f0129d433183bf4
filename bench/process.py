"""One frame, estimated and scored: the path every frame of the bench takes.

``process(capture, estimators, calibration)`` runs each estimator on the captured pair, scores each
estimate against what the capture knows (the exact backbone on the twin, a depth map for Q') and
returns the :class:`~bench.frame_record.FrameRecord`. ``softarm run`` calls it on every frame it
captures, ``softarm replay`` on every recorded frame, the report's compensation figure on the
frames it re-runs and the studies on the frames they render, so a frame's record means the same
everywhere.

    capture = Capture(index=0, t_s=0.0, frame=stereo_frame, commanded_bar={"s1_a": 0.0}, gt_m=backbone)
    record = process(capture, {"main": CenterlineEstimator(calibration)}, calibration)
    record.main.valid, record.main.errors["rmse_mm"], record.bench_ms["estimate_main"]
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping

import numpy as np

from bench.frame_record import ROUND_M, EstimateRecord, FrameRecord
from bench.scoring import dequantize_depth, score_fields
from estimator import CenterlineEstimator, EstimateResult, StereoCalibration
from hardware.interfaces import StereoFrame

# The estimates a frame records: the run's own, and the paper mode's beside it (--compare).
ESTIMATE_KEYS = ("main", "paper")


@dataclasses.dataclass(frozen=True, eq=False)
class Capture:
    """One captured stereo frame and what the devices know about it.

    Attributes:
        index: the frame's number in the run.
        t_s: seconds since the experiment's start (the schedule's time; simulated on the twin).
        frame: the raw stereo pair as the camera delivered it.
        commanded_bar: the valves' set-points at capture.
        chamber_bar: the chambers' pressures (the twin), or None.
        sim_time_s: the twin's simulated time, or None.
        gt_m: (N, 3) the exact backbone in the left camera frame (the twin), or None.
        depth_units, depth_unit_m: the left depth map (uint16, metres per unit), or None.
        timings_ms: where the time went capturing it (physics, render, truth, grab).
        started_at: ``time.monotonic()`` when the capture began (a stop requested before it drops it).
        stored: what the run keeps of the frame (``bench.devices.StoredFrame``), or None.
    """

    index: int
    t_s: float
    frame: StereoFrame
    commanded_bar: Mapping[str, float]
    chamber_bar: Mapping[str, float] | None = None
    sim_time_s: float | None = None
    gt_m: np.ndarray | None = None
    depth_units: np.ndarray | None = None
    depth_unit_m: float | None = None
    timings_ms: Mapping[str, float] = dataclasses.field(default_factory=dict)
    started_at: float = dataclasses.field(default_factory=time.monotonic)
    stored: object | None = None


def estimate(estimator: CenterlineEstimator, frame: StereoFrame) -> EstimateResult:
    """Estimate one frame; an exception inside the estimator becomes an invalid result naming it (the run
    goes on with the next frame, the estimator's warm start reset)."""
    start = time.perf_counter()
    try:
        return estimator.estimate(frame.left, frame.right)
    except Exception as e:  # noqa: BLE001 - one bad frame must not end an experiment; recorded with its reason
        estimator.reset()  # its warm start may be half-updated
        empty = np.zeros((0, 2))
        return EstimateResult(np.zeros((0, 3)), False, f"estimator error: {type(e).__name__}: {e}", empty, empty,
                              {"total": (time.perf_counter() - start) * 1e3})


def process(capture: Capture, estimators: Mapping[str, CenterlineEstimator],
            calibration: StereoCalibration | None) -> FrameRecord:
    """Estimate, score and record one capture.

    Args:
        capture: the frame and what is known about it.
        estimators: "main" (required) and optionally "paper" (the paper mode beside it), each fed
            the frames in order (their warm start carries over).
        calibration: the camera's calibration (for Q'), or None.

    Returns:
        The frame's record; its ``bench_ms`` adds ``estimate_<key>`` and ``score_<key>`` to the
        capture's timings.

    Raises:
        ValueError: no "main" estimator, or one under a key a record cannot hold.
    """
    if "main" not in estimators or set(estimators) - set(ESTIMATE_KEYS):
        raise ValueError(f"estimators: expected 'main' and optionally 'paper', got {sorted(estimators)}")
    depth_m = None
    if capture.depth_units is not None:
        depth_m = dequantize_depth(capture.depth_units, capture.depth_unit_m)
    # Scored against the truth as recorded (0.1 um), so a replay of the recorded frames reproduces every figure.
    gt_m = None if capture.gt_m is None else np.round(np.asarray(capture.gt_m, dtype=float), ROUND_M)
    bench_ms = dict(capture.timings_ms)
    estimates: dict[str, EstimateRecord] = {}
    for key, estimator in estimators.items():
        start = time.perf_counter()
        result = estimate(estimator, capture.frame)
        bench_ms[f"estimate_{key}"] = (time.perf_counter() - start) * 1e3
        start = time.perf_counter()
        scores = score_fields(result.points, result.left_uv, gt_m, depth_m, calibration) if result.valid else None
        estimates[key] = EstimateRecord.from_result(result, scores, mode=None if key == "main" else
                                                    estimator.config.mode)
        bench_ms[f"score_{key}"] = (time.perf_counter() - start) * 1e3
    frame = capture.frame
    return FrameRecord(
        index=int(capture.index), t_s=round(float(capture.t_s), 6), timestamp_s=float(frame.timestamp_s),
        camera_index=int(frame.index), commanded_bar=dict(capture.commanded_bar),
        chamber_bar=None if capture.chamber_bar is None else dict(capture.chamber_bar),
        bench_ms={k: round(float(v), 3) for k, v in bench_ms.items()}, main=estimates["main"],
        paper=estimates.get("paper"),
        sim_time_s=None if capture.sim_time_s is None else round(float(capture.sim_time_s), 6),
        gt_m=None if gt_m is None else _read_only(gt_m))


def _read_only(array: np.ndarray) -> np.ndarray:
    array = np.array(array, dtype=float)
    array.setflags(write=False)
    return array
