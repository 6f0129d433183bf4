"""``softarm run``: drive the valves through an experiment, estimate every frame, score it, record it.

On the twin (``backend = "sim"``) the physics is advanced to each pressure change and capture
time of the schedule (simulated seconds: the run takes as long as the computer needs), every
frame is scored against the twin's exact backbone and against the paper's Q' (the rendered
left depth at the left centerline pixels). On the rig the same schedule runs in real time on a
monotonic clock: a thread commands the pressure steps on time while the main loop captures and
estimates; there is no ground truth, so it scores what it can (validity, fps, and Q' when a
depth source is configured in ``[rig.depth]``) and says so.

Safety and bookkeeping: anything that can fail without moving (config, calibration, devices,
channels and pressures of the schedule) is checked before the first set-point, and the run
folder's ``config.json`` and calibration are written before it too, so any killed run loads;
SIGINT (Ctrl-C) and SIGTERM stop the loop, vent the valves, close the devices and finish the
files (a signal before the first set-point sends none); the twin's physics runs in slices of
``SIM_SLICE_S`` simulated seconds with the stop checked between them, so a signal acts within a
fraction of a second however long a capture interval is, and a frame whose capture began after
the stop request is not recorded. A run expected to write more than ``DISK_CONFIRM_BYTES`` says
so and needs ``--yes``; its size is printed before every run. A failed estimate is recorded as an
invalid frame and the run goes on; a twin instability (``SimulationError``), a device fault,
including one the valve bank records in the background (``ValveBank.check()``, called every
frame: a lost link, an e-stop), or a failed write stops the run cleanly, keeping the frames so
far, and ``summary.json`` says why. The pressure thread is stopped and joined before the
devices are closed, so the vent is the last command the valves receive. The report is written
after the devices and files are closed and the signal handlers restored: Ctrl-C then just
stops the report.
"""

from __future__ import annotations

import math
import shutil
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from bench.config import BenchConfig, ConfigError, load_bench_config
from bench.experiments import Schedule, make_schedule
from bench.recording import (
    RunWriter,
    frame_bytes,
    human_bytes,
    jsonable,
    new_run_folder,
    point_latest,
    summarize_run,
)
from bench.scoring import (
    DEPTH_UNIT_M,
    dequantize_depth,
    estimate_fields,
    invalid_lines,
    quantize_depth,
    score_fields,
    summary_table,
)
from estimator import CalibrationFileError, CenterlineEstimator, EstimateResult, EstimatorConfig
from hardware.errors import DeviceError, EndOfStreamError, VentedBySignalError

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
# A run expected to write more than this asks for --yes first.
DISK_CONFIRM_BYTES = 2e9
_SIGNAL_EXIT = {signal.SIGINT: 130, signal.SIGTERM: 143}


class RunError(RuntimeError):
    """A run failed after the valves had moved: the devices were closed and the frames so far kept."""


@dataclass
class RunOptions:
    """What the command line adds to the config.

    Attributes:
        mode: estimator mode overriding ``[estimator] mode`` (None: the config's).
        compare: also run the paper mode on every frame.
        frames: captures spread over the experiment instead of ``[experiment] frames``.
        out: the run folder (None: a new time-stamped folder under ``[recording] root``).
        report: write the report at the end.
        progress: show a progress bar.
        argv: the command line, recorded in config.json.
        yes: go ahead with a run expected to write more than ``DISK_CONFIRM_BYTES`` (``--yes``).
    """

    mode: str | None = None
    compare: bool = False
    frames: int | None = None
    out: Path | None = None
    report: bool = True
    progress: bool = True
    argv: list[str] = field(default_factory=list)
    yes: bool = False


@dataclass
class RunOutcome:
    """How a run ended.

    Attributes:
        folder: the run folder (None when the run failed before anything moved).
        summary: ``summary.json``'s contents.
        stopped: None when the schedule ran to its end; else why it stopped (and what failed
            while closing the devices, if anything did).
        exit_code: 0 done, 1 stopped by a fault (or the report failed), 130/143 stopped by
            SIGINT/SIGTERM (during the report too).
        timings_s: wall-clock seconds per part of the loop (physics, render, estimate, ...).
        frames: frames recorded.
    """

    folder: Path | None
    summary: dict
    stopped: str | None
    exit_code: int
    timings_s: dict[str, float]
    frames: int = 0


class _Stop:
    """Set by SIGINT/SIGTERM (or a device thread); the loop checks it between steps.

    Every set-point of a run goes through ``command``, which checks the stop flag (and whether
    the devices are being closed) under ``lock`` right before sending; the devices are closed
    under the same lock once ``closed`` is set, so no set-point can follow the final vent.
    ``request`` does not take the lock: it runs in signal handlers, which interrupt the main
    thread wherever it is (inside the valve bank, too), where waiting for a lock could deadlock;
    a set-point already past its check when the signal lands is in flight, and the vent follows it.
    """

    def __init__(self) -> None:
        self.event = threading.Event()
        self.lock = threading.Lock()
        self.reason: str | None = None
        self.signum: int | None = None
        self.requested_at: float | None = None  # time.monotonic() of the request
        self.moved = False  # a set-point was sent (or started): from then on "nothing was moved" is false
        self.closed = False  # the devices are being closed: no more set-points

    def request(self, reason: str, signum: int | None = None) -> None:
        if not self.event.is_set():
            self.reason, self.signum, self.requested_at = reason, signum, time.monotonic()
            self.event.set()

    def came_before(self, started_at: float) -> bool:
        """Whether the stop was requested before ``started_at`` (time.monotonic): a capture started
        after a stop request is not part of the run."""
        return self.event.is_set() and self.requested_at is not None and self.requested_at <= started_at

    def command(self, valves, pressures, unless: threading.Event | None = None) -> bool:
        """Send set-points unless a stop was requested, the devices are closing, or ``unless`` is set.

        Returns:
            True when the set-points were sent.
        """
        with self.lock:
            if self.event.is_set() or self.closed or (unless is not None and unless.is_set()):
                return False
            self.moved = True
            valves.set_pressures(pressures)
            return True

    def close_devices(self, devices) -> None:
        """Close (vent first) the devices; no set-point of this run can follow."""
        with self.lock:
            self.closed = True
            devices.close()

    def __bool__(self) -> bool:
        return self.event.is_set()

    def wait_until(self, deadline: float) -> bool:
        """Sleep until ``deadline`` (time.monotonic) unless stopped first; True when stopped."""
        while not self.event.is_set():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self.event.wait(min(remaining, 0.05))
        return True


class _SignalGuard:
    """Turn SIGINT/SIGTERM into a stop request for the duration of a run (main thread only).

    Installed before the devices are opened, so a driver that chains its own emergency handler
    (the serial valve bank vents at once, then calls the previous handler) calls this one after.
    """

    def __init__(self, stop: _Stop) -> None:
        self._stop = stop
        self._previous: dict[int, object] = {}

    def __enter__(self) -> _SignalGuard:
        if threading.current_thread() is threading.main_thread():
            for signum in _SIGNAL_EXIT:
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def _handle(self, signum: int, frame) -> None:
        name = signal.Signals(signum).name
        if self._stop:
            print(f"\nsoftarm run: {name} again; still stopping (venting and closing the files)", file=sys.stderr)
            return
        print(f"\nsoftarm run: {name}: stopping: venting the valves, closing the devices and the files",
              file=sys.stderr, flush=True)
        self._stop.request(f"interrupted by {name}", signum)

    def __exit__(self, *exc) -> None:
        for signum, previous in self._previous.items():
            signal.signal(signum, previous if previous is not None else signal.SIG_DFL)


@dataclass
class _Capture:
    """One captured frame with what the backend knows about it."""

    index: int
    t_s: float
    frame: object  # hardware.StereoFrame
    commanded_bar: dict[str, float]
    chamber_bar: dict[str, float] | None = None
    sim_time_s: float | None = None
    gt_m: np.ndarray | None = None
    depth_units: np.ndarray | None = None  # uint16, bench.scoring.DEPTH_UNIT_M
    depth_unit_m: float | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)
    started_at: float = field(default_factory=time.monotonic)  # when the capture began (time.monotonic)


# --- the command --------------------------------------------------------------------------


def run_command(args) -> int:
    """Entry point of ``softarm run`` (see ``bench.cli``). Returns the exit code."""
    try:
        config = load_bench_config(getattr(args, "config", None), backend=getattr(args, "backend", None))
    except ConfigError as e:
        print(f"softarm run: {e}", file=sys.stderr)
        return EXIT_USAGE
    options = RunOptions(mode=getattr(args, "mode", None), compare=bool(getattr(args, "compare", False)),
                         frames=getattr(args, "frames", None),
                         out=Path(args.out) if getattr(args, "out", None) else None,
                         report=not getattr(args, "no_report", False), argv=list(sys.argv),
                         yes=bool(getattr(args, "yes", False)))
    try:
        outcome = run_experiment(config, options)
    except RunError as e:  # after the valves moved: never "nothing was moved"
        print(f"softarm run: {e}", file=sys.stderr)
        return EXIT_FAILED
    except (CalibrationFileError, DeviceError, OSError) as e:  # a device or its calibration (a ValueError too)
        print(f"softarm run: {e}", file=sys.stderr)
        print("softarm run: nothing was moved", file=sys.stderr)
        return EXIT_FAILED
    except (ConfigError, ValueError) as e:  # bad options or schedule, found before anything moved
        print(f"softarm run: {e}", file=sys.stderr)
        print("softarm run: nothing was moved", file=sys.stderr)
        return EXIT_USAGE
    return outcome.exit_code


def estimator_configs(config: BenchConfig, options: RunOptions) -> dict[str, EstimatorConfig]:
    """The estimators of a run: ``main`` (the config's mode or ``--mode``) and, with ``--compare``, ``paper``.

    Raises:
        ValueError: a bad ``[estimator]`` value, or ``--compare`` when the main mode is already the paper's.
    """
    main = config.estimator_config(mode=options.mode)
    configs = {"main": main}
    if options.compare:
        if main.mode == "paper":
            raise ValueError("--compare runs the paper mode beside the main one, which already is the paper mode; "
                             "drop --compare or use --mode default")
        configs["paper"] = config.estimator_config(mode="paper")
    return configs


def run_experiment(config: BenchConfig, options: RunOptions) -> RunOutcome:
    """Run the configured experiment end to end: devices, schedule, estimates, scores, files, report.

    A fault during the run (a device, a failed write, the twin) does not raise: it stops the run
    cleanly and the outcome says why (``stopped``, ``exit_code``).

    Raises:
        ValueError: bad options, or a schedule the valves cannot take (unknown channel, too high), or
            a run expected to write more than ``DISK_CONFIRM_BYTES`` without ``options.yes``;
            before anything moves, and nothing is recorded.
        CalibrationFileError, DeviceError, OSError: a device or its calibration cannot be opened, or
            the run folder cannot be written; before anything moves.
        RunError: an error escaped the run after the valves had moved (the devices were closed).
    """
    schedule = make_schedule(config.experiment, frames=options.frames)
    est_configs = estimator_configs(config, options)
    stop = _Stop()
    with _SignalGuard(stop):
        if stop:  # a signal before we even started
            raise DeviceError(stop.reason)
        from bench.factory import make_devices

        print(f"softarm run: {config.backend} backend, {schedule.describe()}", flush=True)
        devices = make_devices(config)
        try:
            _check_schedule(schedule, devices.valves)
            _check_disk(config, options, schedule, devices.camera.calibration.image_size)
            depth_source = _rig_depth_source(config) if config.backend == "rig" else None
            folder = options.out if options.out is not None else new_run_folder(config.recording.runs_root())
            # config.json and the calibration before frames.jsonl: a run killed at any point loads
            writer = RunWriter(folder, config.recording, source=config.path, calibration=devices.camera.calibration,
                               config=_resolved_config(config, options, schedule, est_configs, devices))
            if options.out is None:
                point_latest(folder)
        except BaseException as e:
            try:
                devices.close()
            except Exception as close_error:  # noqa: BLE001 - the first error is the one to report
                e.add_note(f"closing the devices also failed: {type(close_error).__name__}: {close_error}")
            raise
        try:
            outcome = _run_loop(config, options, schedule, est_configs, devices, writer, depth_source, stop)
        except (CalibrationFileError, DeviceError, OSError, ValueError) as e:
            if not stop.moved:
                raise
            raise RunError(f"{_describe_error(e)}; the devices were closed; the frames so far are in "
                           f"{writer.folder}") from e
    # Devices and files are closed and SIGINT/SIGTERM act as usual again: Ctrl-C now only stops the report.
    _print_summary(outcome.summary, writer.folder)
    if stop.signum is not None and outcome.exit_code not in _SIGNAL_EXIT.values():
        outcome.exit_code = _SIGNAL_EXIT[stop.signum]  # the signal came after the last frame
    if outcome.exit_code in _SIGNAL_EXIT.values():
        print(f"report skipped after the interruption; write it with: softarm report {writer.folder}")
    elif options.report and config.report.enabled and outcome.frames:
        outcome.exit_code = _write_report(writer.folder, options, outcome)
    return outcome


def _write_report(folder: Path, options: RunOptions, outcome: RunOutcome) -> int:
    """Write the report of the finished run folder; returns the run's exit code, or the report's failure."""
    from bench.report import write_report

    start = time.perf_counter()
    try:
        write_report(folder, progress=options.progress)
    except KeyboardInterrupt:
        print(f"\nsoftarm run: report interrupted; the run folder is complete; write the report with: "
              f"softarm report {folder}", file=sys.stderr)
        return _SIGNAL_EXIT[signal.SIGINT]
    except Exception as e:  # noqa: BLE001 - the run is recorded; a failing report must not hide that
        print(f"softarm run: the report failed ({type(e).__name__}: {e}); the run folder is complete; "
              f"try again with: softarm report {folder}", file=sys.stderr)
        return outcome.exit_code or EXIT_FAILED
    outcome.timings_s["report"] = time.perf_counter() - start
    return outcome.exit_code


def _check_schedule(schedule: Schedule, valves) -> None:
    """Refuse, before anything moves, a schedule naming unknown valves or exceeding their limit."""
    unknown = [c for c in schedule.channels if c not in valves.channels]
    if unknown:
        raise ValueError(f"[experiment] channels: {', '.join(unknown)} not among the valves "
                         f"({', '.join(valves.channels)})")
    if schedule.max_bar > valves.max_pressure_bar + 1e-9:
        raise ValueError(f"[experiment] max_bar: {schedule.max_bar:g} bar exceeds the valves' limit of "
                         f"{valves.max_pressure_bar:g} bar")


def _check_disk(config: BenchConfig, options: RunOptions, schedule: Schedule, image_size) -> None:
    """Print the run's expected disk use; refuse one above ``DISK_CONFIRM_BYTES`` without ``--yes``."""
    per_frame = frame_bytes(config.recording, tuple(image_size), compare=options.compare,
                            depth=config.backend == "sim" and config.recording.depth)
    total = per_frame * schedule.frames
    target = options.out if options.out is not None else config.recording.runs_root()
    free = _free_bytes(Path(target))
    room = f"; {human_bytes(free)} free there" if free is not None else ""
    print(f"softarm run: expected disk use about {human_bytes(total)} ({schedule.frames} frames x "
          f"{human_bytes(per_frame)}){room}", flush=True)
    if total > DISK_CONFIRM_BYTES and not options.yes:
        raise ValueError(f"this run would write about {human_bytes(total)} ({schedule.frames} frames x "
                         f"{human_bytes(per_frame)}), more than {human_bytes(DISK_CONFIRM_BYTES)}{room}; to go ahead, "
                         "run it again with --yes; or record fewer frames (--frames N, [experiment] frames) or "
                         "JPEG frames ([recording] lossless_frames = false)")
    if free is not None and total > free:
        print(f"softarm run: warning: the run may fill the disk ({human_bytes(total)} expected, "
              f"{human_bytes(free)} free); it stops cleanly, keeping its frames, when a write fails",
              file=sys.stderr)


def _free_bytes(folder: Path) -> float | None:
    """Free bytes on the disk that holds ``folder`` (or its nearest existing parent); None if unknown."""
    folder = folder.resolve()
    for candidate in (folder, *folder.parents):
        if candidate.exists():
            try:
                return float(shutil.disk_usage(candidate).free)
            except OSError:
                return None
    return None


def _run_loop(config, options, schedule, est_configs, devices, writer, depth_source, stop) -> RunOutcome:
    """Warm up, run the schedule, and always: stop the pressure thread, close the devices, finish the files.

    The devices are closed here, whatever happens; errors that end a run cleanly (``_stop_errors``)
    and errors while closing are recorded in ``stopped``, not raised.
    """
    calibration = devices.camera.calibration
    sim = devices.twin is not None
    records: list[dict] = []
    totals = {k: 0.0 for k in ("physics", "render", "truth", "estimate", "score", "record_wait")}
    stopped: str | None = None
    exit_code = EXIT_OK
    stats = {"dropped": 0}
    progress = None
    close_failed = False
    announced: str | None = None  # the stop reason already printed
    loop_start = time.perf_counter()
    try:
        estimators = {key: CenterlineEstimator(calibration, cfg) for key, cfg in est_configs.items()}
        for estimator in estimators.values():  # compile before the clock starts (a rig run is real time)
            if stop:
                break
            estimator.warm_up()
        progress = _progress(schedule.frames, options.progress, writer.folder)
        loop_start = time.perf_counter()
        captures = (_sim_captures(devices, schedule, config.experiment, stop) if sim
                    else _rig_captures(devices, schedule, config.experiment, stop, depth_source, stats))
        try:
            for capture in captures:
                if stop.came_before(capture.started_at):
                    break  # captured after Ctrl-C/SIGTERM or a fault: not part of the run
                # A fault the valves recorded in the background (a lost link, the board's watchdog
                # vent, an e-stop) stops the run here, before a frame taken after it is recorded.
                _check_valves(devices.valves)
                record = _process(capture, estimators, calibration, totals)
                start = time.perf_counter()
                frame = capture.frame
                # copies: the writer encodes them while the next frame is captured (a driver may reuse its buffers)
                writer.submit(record, frame.left.copy(), frame.right.copy(),
                              capture.depth_units if (sim and config.recording.depth) else None)
                totals["record_wait"] += time.perf_counter() - start
                for part in ("physics", "render", "truth"):
                    totals[part] += capture.timings_ms.get(part, 0.0) / 1e3
                records.append(record)
                _update_progress(progress, record)
        finally:
            captures.close()  # stops and joins the pressure thread, on every path, before the devices close
        if stop:
            stopped = stop.reason
            exit_code = _SIGNAL_EXIT.get(stop.signum, EXIT_FAILED)
    except _stop_errors() as e:
        stopped = f"{_describe_error(e)}"
        exit_code = EXIT_FAILED
        if progress is not None:
            progress.close()
        print(f"\nsoftarm run: stopped: {stopped}; the {len(records)} frames so far are kept", file=sys.stderr)
        announced = stopped
    except BaseException as e:
        stopped = f"unexpected error: {type(e).__name__}: {e}"
        raise
    finally:
        wall_s = time.perf_counter() - loop_start
        if progress is not None:
            progress.close()
        try:
            stop.close_devices(devices)  # vents first
        except Exception as e:  # noqa: BLE001 - whatever failed, the files are finished and the run says so
            failure = f"closing the devices failed: {_describe_error(e)}"
            stopped = f"{stopped}; {failure}" if stopped else failure
            close_failed = True
            exit_code = exit_code or EXIT_FAILED
            print(f"softarm run: {failure}", file=sys.stderr)
        summary = _finish(writer, records, config, options, schedule, stopped, wall_s, totals, stats)
    stopped = summary["stopped"]  # a failed last write is added there
    if stopped is not None and exit_code == EXIT_OK:
        exit_code = EXIT_FAILED
    if stopped is not None:
        if not stop.moved:
            what = "nothing was moved"
        elif close_failed:
            what = "check that the valves are vented"
        elif exit_code in _SIGNAL_EXIT.values():
            what = "valves vented, devices closed"
        else:
            what = "devices closed"
        reason = "" if stopped == announced else f"{stopped}; "
        print(f"softarm run: {reason}{what}; {len(records)} frames kept in {writer.folder}", file=sys.stderr)
    return RunOutcome(writer.folder, summary, stopped, exit_code, totals, frames=len(records))


def _check_valves(valves) -> None:
    """Raise, as a valve fault, what the valve bank recorded in the background since the last frame."""
    try:
        valves.check()
    except DeviceError as e:
        raise _ValveFaultError(e) from e


class _ValveFaultError(DeviceError):
    """A fault of the valve bank that stopped the run; the message says so and names the original error."""

    def __init__(self, error: BaseException) -> None:
        super().__init__(f"valve fault: {type(error).__name__}: {error}")
        self.error = error


def _stop_errors() -> tuple[type[BaseException], ...]:
    """Errors that end a run cleanly (the frames so far are kept): device faults, failed writes (a full
    disk), and in sim the twin's instability."""
    errors: list[type[BaseException]] = [DeviceError, OSError]
    twin_physics = sys.modules.get("twin.physics")  # loaded only on the sim backend
    if twin_physics is not None:
        errors.append(twin_physics.SimulationError)
    return tuple(errors)


def _describe_error(e: BaseException) -> str:
    if isinstance(e, EndOfStreamError):
        return f"the camera's recording ended ({e})"
    if isinstance(e, _ValveFaultError):
        return str(e)
    kind = "twin instability" if type(e).__name__ == "SimulationError" else type(e).__name__
    return f"{kind}: {e}"


def _finish(writer, records, config, options, schedule, stopped, wall_s, totals, stats) -> dict:
    summary = summarize_run(records, {"backend": config.backend,
                                      "estimators": {"main": {"mode": config.estimator_config(options.mode).mode}}},
                            wall_s=wall_s)
    try:
        writer.flush()  # the last frame on disk, so the writer's time is complete
    except OSError as e:
        stopped = f"{stopped + '; ' if stopped else ''}recording failed: {e}"
    totals = {**totals, "record_thread": writer.write_ms_total / 1e3}
    summary.update({
        "stopped": stopped,
        "scheduled_frames": schedule.frames,
        "dropped_frames": stats["dropped"],
        "wall_s": wall_s,
        "bench_s": {k: round(v, 3) for k, v in totals.items()},
        "ground_truth": config.backend == "sim",
        "depth_source": _depth_note(config),
    })
    writer.finish(summary)
    return summary


def _depth_note(config: BenchConfig) -> str:
    if config.backend == "sim":
        return "the twin's rendered left depth (exact, stored at 0.1 mm)"
    if config.rig is not None and config.rig.depth is not None:
        return f"depth maps from {config.rig.depth.source}"
    return "none: the rig has no ground truth and no [rig.depth] source, so only validity and fps are scored"


def _resolved_config(config, options, schedule, est_configs, devices) -> dict:
    valves = devices.valves
    return {
        "backend": config.backend,
        "argv": options.argv,
        "source": str(config.path),
        "options": {"mode": options.mode, "compare": options.compare, "frames": options.frames},
        "bench": jsonable(config),
        "estimators": {key: jsonable(cfg.as_dict()) for key, cfg in est_configs.items()},
        "schedule": schedule.as_dict(),
        "valves": {"channels": list(valves.channels), "max_pressure_bar": valves.max_pressure_bar},
        "camera": {"image_size": list(devices.camera.calibration.image_size), "type": type(devices.camera).__name__},
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


# --- one frame ----------------------------------------------------------------------------


def _estimate(estimator: CenterlineEstimator, frame) -> EstimateResult:
    """Estimate one frame; an exception inside the estimator becomes an invalid result (the run goes on)."""
    start = time.perf_counter()
    try:
        return estimator.estimate(frame.left, frame.right)
    except Exception as e:  # noqa: BLE001 - one bad frame must not end an experiment; recorded with its reason
        estimator.reset()  # its warm start may be half-updated
        empty = np.zeros((0, 2))
        return EstimateResult(np.zeros((0, 3)), False, f"estimator error: {type(e).__name__}: {e}", empty, empty,
                              {"total": (time.perf_counter() - start) * 1e3})


def _process(capture: _Capture, estimators, calibration, totals) -> dict:
    """Estimate, score and build the JSON record of one capture."""
    record: dict = {
        "index": capture.index,
        "t_s": round(capture.t_s, 6),
        "timestamp_s": capture.frame.timestamp_s,
        "camera_index": capture.frame.index,
        "commanded_bar": capture.commanded_bar,
        "chamber_bar": capture.chamber_bar,
    }
    if capture.sim_time_s is not None:
        record["sim_time_s"] = round(capture.sim_time_s, 6)
    depth_m = None
    if capture.depth_units is not None:
        depth_m = dequantize_depth(capture.depth_units, capture.depth_unit_m)
    bench_ms = dict(capture.timings_ms)
    # Scored against the truth as recorded (0.1 um), so a replay of the recorded frames reproduces every figure.
    gt_m = None if capture.gt_m is None else np.round(np.asarray(capture.gt_m, dtype=float), 7)
    for key, estimator in estimators.items():
        start = time.perf_counter()
        result = _estimate(estimator, capture.frame)
        elapsed = time.perf_counter() - start
        totals["estimate"] += elapsed
        bench_ms[f"estimate_{key}"] = elapsed * 1e3
        start = time.perf_counter()
        fields = estimate_fields(result)
        if result.valid:
            fields.update(score_fields(result.points, result.left_uv, gt_m, depth_m, calibration))
        else:
            fields.update({"errors": None, "qprime": None, "qprime_m": None})
        score_s = time.perf_counter() - start
        totals["score"] += score_s
        bench_ms[f"score_{key}"] = score_s * 1e3
        if key == "main":
            record.update(fields)
        else:
            record[key] = {"mode": estimator.config.mode, **fields}
    if gt_m is not None:
        record["gt_m"] = gt_m.tolist()
    record["bench_ms"] = {k: round(v, 3) for k, v in bench_ms.items()}
    return record


# --- the twin -----------------------------------------------------------------------------


# The twin is advanced in slices of at most this much simulated time, and the stop flag checked between
# them, so Ctrl-C or SIGTERM acts within a slice (a few ms of computing) however long the capture interval
# is; one slice is a whole number of physics steps, so the slicing does not change the simulation.
SIM_SLICE_S = 0.05
# settle() is called for at most this much simulated time at a time (the same checks, every 0.05 s),
# up to the twin's usual 30 s, for the same reason.
SETTLE_SLICE_S = 0.25
SETTLE_MAX_S = 30.0


def advance_sliced(twin, duration_s: float, stop: _Stop) -> bool:
    """Advance the twin by ``duration_s`` simulated seconds (whole steps), a slice at a time.

    Returns:
        True when the whole duration was simulated, False when a stop request cut it short.

    Raises:
        SimulationError: the twin went unstable.
    """
    timestep_s = float(twin.sim.timestep_s)
    steps = round(duration_s / timestep_s) if duration_s > 0 else 0
    per_slice = max(1, int(SIM_SLICE_S / timestep_s + 1e-9))
    while steps > 0:
        if stop:
            return False
        n = min(steps, per_slice)
        twin.advance(n * timestep_s)
        steps -= n
    return not stop


def settle_sliced(twin, stop: _Stop, max_time_s: float = SETTLE_MAX_S) -> bool:
    """Run the twin until the arm is at rest (``Twin.settle``), a slice at a time; False when it did
    not come to rest within ``max_time_s`` simulated seconds or a stop request came first."""
    start = twin.time_s
    while not stop:
        if twin.settle(max_time_s=min(SETTLE_SLICE_S, max_time_s)):
            return True
        if twin.time_s - start >= max_time_s - 1e-9:
            return False
    return False


def _sim_captures(devices, schedule: Schedule, experiment, stop: _Stop) -> Iterator[_Capture]:
    """Advance the twin through the schedule and capture at each capture time (simulated seconds).

    The physics runs in slices (``advance_sliced``), checking ``stop`` between them; a stop ends the
    captures at once, and a capture that a stop request overtook is not handed out.

    Raises:
        SimulationError: the twin went unstable (the caller keeps the frames so far).
    """
    import warnings

    from twin.physics import NotSettledWarning

    twin, valves, camera = devices.twin, devices.valves, devices.camera
    phys = {"s": 0.0}

    def timed_physics(fn, *a, **kw):
        start = time.perf_counter()
        try:
            return fn(*a, **kw)
        finally:
            phys["s"] += time.perf_counter() - start

    if not stop.command(valves, schedule.command(0)):  # a signal during opening or warm-up: nothing moves
        return
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotSettledWarning)  # not at rest is still a true shape; said below
        if experiment.settle and not timed_physics(settle_sliced, twin, stop) and not stop:
            print("softarm run: note: the arm did not come fully to rest before t = 0", file=sys.stderr)
    if experiment.lead_in_s and not timed_physics(advance_sliced, twin, experiment.lead_in_s, stop):
        return
    origin = twin.time_s  # simulated time of t = 0
    changes = schedule.change_times_s
    next_change = 1

    def advance_to(t_s: float) -> bool:
        return timed_physics(advance_sliced, twin, origin + t_s - twin.time_s, stop)

    for i, t_capture in enumerate(schedule.capture_times_s):
        if stop:
            return
        phys["s"] = 0.0
        while next_change < len(changes) and changes[next_change] <= t_capture + 1e-9:
            if not advance_to(changes[next_change]):
                return
            if not stop.command(valves, schedule.command(next_change)):
                return
            if experiment.quasi_static:
                before = twin.time_s
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", NotSettledWarning)
                    timed_physics(settle_sliced, twin, stop)
                if stop:
                    return
                origin += twin.time_s - before  # the schedule's clock stands still while the arm settles
            next_change += 1
        if not advance_to(t_capture):
            return
        started_at = time.monotonic()
        start = time.perf_counter()
        frame = camera.grab()
        depth_units = quantize_depth(camera.depth_left())
        render_s = time.perf_counter() - start
        start = time.perf_counter()
        gt = twin.backbone()
        truth_s = time.perf_counter() - start
        if stop.came_before(started_at):
            return
        sim = twin.sim
        yield _Capture(
            index=i, t_s=float(t_capture), frame=frame,
            commanded_bar={k: round(float(v), 6) for k, v in valves.setpoints_bar.items()},
            chamber_bar={k: round(float(v), 6) for k, v in zip(valves.channels, sim.chamber_bar, strict=True)},
            sim_time_s=twin.time_s, gt_m=gt, depth_units=depth_units, depth_unit_m=DEPTH_UNIT_M,
            timings_ms={"physics": phys["s"] * 1e3, "render": render_s * 1e3, "truth": truth_s * 1e3},
            started_at=started_at)


# --- the rig ------------------------------------------------------------------------------


class _PressureDriver(threading.Thread):
    """Commands the schedule's pressure steps on time (monotonic clock) while the main loop estimates.

    Each step goes through ``_Stop.command``: the stop flag and ``finish()`` are checked under the
    stop's lock right before the set-point is sent, and ``finish()`` waits for that lock, so once
    it returns no set-point of this thread is under way or can follow, even if the join timed out.
    A device error is kept in ``error`` and stops the run (the main loop re-raises it).
    """

    JOIN_TIMEOUT_S = 2.0  # finish() stops waiting for the thread after this (it sends nothing more anyway)

    def __init__(self, valves, schedule: Schedule, t0: float, stop: _Stop) -> None:
        super().__init__(name="pressure-driver", daemon=True)
        self._valves, self._schedule, self._t0, self._stop_flag = valves, schedule, t0, stop
        self._finished = threading.Event()
        self.error: BaseException | None = None
        self.sent: list[tuple[float, dict[str, float]]] = []

    def run(self) -> None:
        try:
            for k in range(1, len(self._schedule.change_times_s)):
                deadline = self._t0 + float(self._schedule.change_times_s[k])
                while not self._finished.is_set() and not self._stop_flag:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        break
                    self._finished.wait(min(remaining, 0.05))
                command = self._schedule.command(k)
                if not self._stop_flag.command(self._valves, command, unless=self._finished):
                    return
                self.sent.append((time.monotonic() - self._t0, command))
        except VentedBySignalError:
            return  # SIGINT/SIGTERM vented the valves; the signal's own handler stops the run
        except BaseException as e:  # noqa: BLE001 - handed to the main loop, which stops the run
            self.error = e
            self._stop_flag.request(f"valve fault: {e}")

    def finish(self) -> None:
        """Stop sending: waits for a set-point under way; none follows once this returns."""
        self._finished.set()  # no step starts after this: each checks it under the lock
        with self._stop_flag.lock:  # and one already under way holds the lock until it is done
            pass
        if self.is_alive():
            self.join(timeout=self.JOIN_TIMEOUT_S)


def _rig_captures(devices, schedule: Schedule, experiment, stop: _Stop, depth_source,
                  stats: dict) -> Iterator[_Capture]:
    """Run the schedule in real time: pressure steps from a thread, captures at their times.

    A capture whose slot has already passed when the loop gets to it (the loop fell behind
    by more than one capture interval) is dropped, so frames stay aligned with the schedule;
    the summary counts them.
    """
    valves, camera = devices.valves, devices.camera
    if not stop.command(valves, schedule.command(0)):  # a signal during opening or warm-up: nothing moves
        return
    if experiment.lead_in_s and stop.wait_until(time.monotonic() + experiment.lead_in_s):
        return
    t0 = time.monotonic()
    driver = _PressureDriver(valves, schedule, t0, stop)
    driver.start()
    captures = schedule.capture_times_s
    try:
        index = 0
        for i, t_capture in enumerate(captures):
            if stop.wait_until(t0 + float(t_capture)):
                break
            late = i + 1 < len(captures) and time.monotonic() - t0 > captures[i + 1]
            if late:
                stats["dropped"] += 1
                continue
            started_at = time.monotonic()
            start = time.perf_counter()
            frame = camera.grab()
            grab_ms = (time.perf_counter() - start) * 1e3
            t_s = time.monotonic() - t0
            if stop.came_before(started_at):
                break
            depth_units, unit = (None, None)
            if depth_source is not None:
                depth_units, unit = depth_source.read(frame.index)
            yield _Capture(index=index, t_s=t_s, frame=frame,
                           commanded_bar={k: round(float(v), 6) for k, v in valves.setpoints_bar.items()},
                           depth_units=depth_units, depth_unit_m=unit, timings_ms={"grab": grab_ms},
                           started_at=started_at)
            index += 1
    finally:
        driver.finish()
    if isinstance(driver.error, DeviceError):
        raise _ValveFaultError(driver.error) from driver.error
    if driver.error is not None:
        raise driver.error


class _DepthFolder:
    """Depth maps of the rig's left camera from a folder (``[rig.depth]``), matched by camera frame index."""

    def __init__(self, source: Path, scale_m: float) -> None:
        self.source = Path(source)
        if not self.source.is_dir():
            raise DeviceError(f"[rig.depth] source: {self.source} is not a folder of depth maps")
        self.files = sorted(p for p in self.source.iterdir()
                            if p.suffix.lower() in (".png", ".tif", ".tiff", ".npy"))
        if not self.files:
            raise DeviceError(f"[rig.depth] source: no depth maps (.png, .tif, .npy) in {self.source}")
        self.scale_m = scale_m

    def read(self, index: int) -> tuple[np.ndarray | None, float | None]:
        """Depth of camera frame ``index`` as (uint16 units, metres per unit); (None, None) if unreadable."""
        path = self.files[index % len(self.files)]  # a looped recording starts its depth maps over too
        depth = np.load(path) if path.suffix.lower() == ".npy" else cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if depth is None:
            return None, None
        if depth.dtype != np.uint16:  # float metres (or other units) -> our 0.1 mm integers
            return quantize_depth(np.asarray(depth, dtype=np.float64) * self.scale_m), DEPTH_UNIT_M
        return depth, self.scale_m


def _rig_depth_source(config: BenchConfig) -> _DepthFolder | None:
    depth = config.rig.depth if config.rig is not None else None
    return None if depth is None else _DepthFolder(depth.source, depth.scale_m)


# --- output -------------------------------------------------------------------------------


def _progress(total: int, enabled: bool, folder: Path):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=f"run {folder.name}", unit="frame", file=sys.stderr, dynamic_ncols=True)


def _update_progress(progress, record: dict) -> None:
    if progress is None:
        return
    postfix = {"valid": "yes" if record["valid"] else "NO"}
    if record.get("errors"):
        postfix["rmse_mm"] = f"{record['errors']['rmse_mm']:.2f}"
    postfix["est_ms"] = f"{record['timings_ms'].get('total', math.nan):.0f}"
    progress.set_postfix(postfix, refresh=False)
    progress.update(1)


def _print_summary(summary: dict, folder: Path) -> None:
    print()
    print(f"run folder: {folder}")
    if summary.get("stopped"):
        print(f"stopped early: {summary['stopped']}")
    label = f"{summary.get('mode', 'default')} mode"
    for line in summary_table(summary, label=label, paper_mode=summary.get("paper")):
        print(line)
    if not summary.get("ground_truth"):
        print(f"no ground truth on the rig: accuracy is not scored. Depth source: {summary.get('depth_source')}")
    else:
        print("exact: against the twin's backbone; Q': against the rendered depth at the left centerline pixels "
              "(the paper's measure; it sees the tube's surface, about one radius in front of the axis)")
    for line in invalid_lines(summary, limit=5):
        print(f"invalid: {line}")
