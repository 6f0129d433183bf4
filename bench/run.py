"""``softarm run``: drive the valves through an experiment, estimate every frame, score it, record it.

The devices come from the factory with what differs between the backends (``bench.devices``): on
the twin (``backend = "sim"``) the clock advances the physics to each pressure change and capture
time (simulated seconds: the run takes as long as the computer needs) and every frame is scored
against the twin's exact backbone and against the paper's Q' (the rendered left depth at the left
centerline pixels); on the rig the same schedule runs in real time while a thread commands the
pressure steps on time, and there is no ground truth, so it scores what it can (validity, fps,
and Q' when ``[rig.depth]`` names a depth source) and says so. One capture loop
(``bench.capture``) and one frame path (``bench.process``) serve both.

Safety and bookkeeping: anything that can fail without moving (config, calibration, devices,
channels and pressures of the schedule) is checked before the first set-point, and the run
folder's ``config.json`` and calibration are written before it too, so any killed run loads;
SIGINT (Ctrl-C) and SIGTERM stop the loop, vent the valves, close the devices and finish the
files (a signal before the first set-point sends none); the twin's physics runs in slices of
``bench.devices.SIM_SLICE_S`` simulated seconds with the stop checked between them, so a signal
acts within a fraction of a second however long a capture interval is, and a frame whose capture
began after the stop request is not recorded. A run expected to write more than
``DISK_CONFIRM_BYTES`` says so and needs ``--yes``; its size is printed before every run. A failed
estimate is recorded as an invalid frame and the run goes on; a device fault (the twin's
``SimulationError`` too), including one the valve bank records in the background
(``ValveBank.check()``, called every frame: a lost link, an e-stop), or a failed write stops the
run cleanly, keeping the frames so far, and ``summary.json`` says why. The pressure thread is
stopped and joined before the devices are closed, so the vent is the last command the valves
receive. The report is written after the devices and files are closed and the signal handlers
restored: Ctrl-C then just stops the report.

Frames are written beside the loop by the run writer's thread (one frame in flight); the twin's
are its noise-free renders (``bench.devices.TwinArchive``), a few tens of kilobytes, so the loop
does not wait for them.
"""

from __future__ import annotations

import math
import shutil
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.capture import captures
from bench.config import BenchConfig, ConfigError, load_bench_config
from bench.devices import Devices, Stop, ValveFaultError
from bench.experiments import Schedule, make_schedule
from bench.frame_record import FrameRecord
from bench.process import process
from bench.recording import (
    RunWriter,
    human_bytes,
    jsonable,
    new_run_folder,
    point_latest,
    summarize_run,
    writable_folder,
)
from bench.scoring import invalid_lines, summary_table
from bench.signals import Terminated, sigterm_raises, stopped_by
from bench.worker import FrameWorker
from estimator import CalibrationFileError, CenterlineEstimator, EstimatorConfig
from hardware.errors import DeviceError, EndOfStreamError, SimulationError

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
        live: a ``bench.live_view.LiveView`` (``--view``, ``--rrd``) handed the calibration and every
            frame with its images beside the loop, and the summary at the end; None: no view.
    """

    mode: str | None = None
    compare: bool = False
    frames: int | None = None
    out: Path | None = None
    report: bool = True
    progress: bool = True
    argv: list[str] = field(default_factory=list)
    yes: bool = False
    live: Any = None


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


class _SignalGuard:
    """Turn SIGINT/SIGTERM into a stop request for the duration of a run (main thread only).

    Installed before the devices are opened, so a driver that chains its own emergency handler
    (the serial valve bank vents at once, then calls the previous handler) calls this one after.
    """

    def __init__(self, stop: Stop) -> None:
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
        options.live = _open_live_view(args)
    except RuntimeError as e:  # bench.live_view.ViewError: no rerun-sdk, no display, a bad --rrd path
        print(f"softarm run: {e}", file=sys.stderr)
        print("softarm run: nothing was moved", file=sys.stderr)
        return EXIT_USAGE
    try:
        outcome = run_experiment(config, options)
        if options.live is not None:
            if getattr(args, "rrd", None):
                print(f"recording: {args.rrd}; open it with: rerun {args.rrd}")
            if outcome.exit_code not in _SIGNAL_EXIT.values():
                options.live.serve_until_interrupted()  # --view web: the viewer stays up until Ctrl-C
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
    finally:
        if options.live is not None:
            options.live.close()  # completes the .rrd file whatever happened
    return outcome.exit_code


def _open_live_view(args):
    """The live view ``--view [web]`` and ``--rrd FILE`` ask for, or None (``bench.live_view``: Rerun is optional).

    Raises:
        bench.live_view.ViewError: rerun-sdk is not installed, no display for the native viewer, a bad ``--rrd``.
    """
    viewer, rrd = getattr(args, "view", None), getattr(args, "rrd", None)
    if viewer is None and rrd is None:
        return None
    from bench.live_view import LiveView, ViewTarget

    view = LiveView(ViewTarget(viewer=viewer, rrd=Path(rrd) if rrd else None))
    if view.url is not None:
        print(f"softarm run: the web viewer is at {view.url}", flush=True)
    return view


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
    if options.out is not None:
        writable_folder(options.out, "--out")  # a folder that takes no file is said before the devices open
    stop = Stop()
    with _SignalGuard(stop):
        if stop:  # a signal before we even started
            raise DeviceError(stop.reason)
        from bench.factory import make_devices

        print(f"softarm run: {config.backend} backend, {schedule.describe()}", flush=True)
        devices = make_devices(config)
        try:
            _check_schedule(schedule, devices.valves, config.path)
            check_disk(config, options, schedule, devices.archive.expected_bytes(
                config.recording, tuple(devices.camera.calibration.image_size), compare=options.compare))
            folder = options.out if options.out is not None else new_run_folder(config.recording.runs_root())
            # config.json and the calibration before frames.jsonl: a run killed at any point loads
            writer = RunWriter(folder, config.recording, source=config.path, calibration=devices.camera.calibration,
                               config=_resolved_config(config, options, schedule, est_configs, devices))
            writer.write_backgrounds(devices.archive.backgrounds())
            if options.out is None:
                point_latest(folder)
        except BaseException as e:
            try:
                devices.close()
            except Exception as close_error:  # noqa: BLE001 - the first error is the one to report
                e.add_note(f"closing the devices also failed: {type(close_error).__name__}: {close_error}")
            raise
        try:
            outcome = _run_loop(config, options, schedule, est_configs, devices, writer, stop)
        except (CalibrationFileError, DeviceError, OSError, ValueError) as e:
            if not stop.moved:
                raise
            raise RunError(f"{_describe_error(e)}; the devices were closed; the frames so far are in "
                           f"{writer.folder}") from e
    # Devices and files are closed and SIGINT/SIGTERM act as usual again: Ctrl-C now only stops the report.
    _print_summary(outcome.summary, writer.folder)
    if options.live is not None:
        options.live.finish(outcome.summary)  # the viewer shows the summary while the report is written
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
        with sigterm_raises():
            write_report(folder, progress=options.progress)
    except (KeyboardInterrupt, Terminated) as e:
        name, code = stopped_by(e)
        print(f"\nsoftarm run: report stopped by {name}; the run folder is complete; write the report with: "
              f"softarm report {folder}", file=sys.stderr)
        return code
    except Exception as e:  # noqa: BLE001 - the run is recorded; a failing report must not hide that
        print(f"softarm run: the report failed ({type(e).__name__}: {e}); the run folder is complete; "
              f"try again with: softarm report {folder}", file=sys.stderr)
        return outcome.exit_code or EXIT_FAILED
    outcome.timings_s["report"] = time.perf_counter() - start
    return outcome.exit_code


def _check_schedule(schedule: Schedule, valves, source: Path) -> None:
    """Refuse, before anything moves, a schedule naming unknown valves or exceeding their limit
    (``source``: the bench config the schedule came from, named in the message)."""
    unknown = [c for c in schedule.channels if c not in valves.channels]
    if unknown:
        raise ValueError(f"{source}: [experiment] channels: {', '.join(unknown)} not among the valves "
                         f"({', '.join(valves.channels)})")
    if schedule.max_bar > valves.max_pressure_bar + 1e-9:
        raise ValueError(f"{source}: [experiment] max_bar: {schedule.max_bar:g} bar exceeds the valves' limit of "
                         f"{valves.max_pressure_bar:g} bar")


def check_disk(config: BenchConfig, options: RunOptions, schedule: Schedule, per_frame: float) -> None:
    """Print the run's expected disk use (``per_frame`` bytes a frame: the devices' archive says how many,
    ``FrameArchive.expected_bytes``); refuse a run above ``DISK_CONFIRM_BYTES`` without ``--yes``.

    Raises:
        ValueError: the run needs more than ``DISK_CONFIRM_BYTES`` and ``options.yes`` is not set.
    """
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


def _run_loop(config, options, schedule, est_configs, devices: Devices, writer: RunWriter, stop: Stop) -> RunOutcome:
    """Warm up, run the schedule, and always: stop the pressure thread, close the devices, finish the files.

    The devices are closed here, whatever happens; errors that end a run cleanly (``STOP_ERRORS``)
    and errors while closing are recorded in ``stopped``, not raised.
    """
    calibration = devices.camera.calibration
    records: list[FrameRecord] = []
    totals: dict[str, float] = {"estimate": 0.0, "score": 0.0, "record_wait": 0.0, "estimate_wait": 0.0}
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
        live = options.live
        if live is not None:
            live.start(calibration, channels=devices.valves.channels, name=writer.folder.name)

        def record_frame(capture) -> None:  # in the worker thread, frame after frame
            record = process(capture, estimators, calibration)
            if live is not None:  # queued for the view's own thread: never waits
                live.submit(record, capture.frame.left, capture.frame.right)
            stored = capture.stored
            start = time.perf_counter()
            writer.submit(record, stored.left, stored.right, stored.depth_units, stored.noise)
            totals["record_wait"] += time.perf_counter() - start
            _add_timings(totals, record.bench_ms)
            records.append(record)
            _update_progress(progress, record)

        loop_start = time.perf_counter()
        frames = captures(devices, schedule, config.experiment, stop, stats)
        worker = FrameWorker(record_frame, depth=WORKER_DEPTH, name="estimate-record")
        try:
            for capture in frames:
                if stop.came_before(capture.started_at):
                    break  # captured after Ctrl-C/SIGTERM or a fault: not part of the run
                # A fault the valves recorded in the background (a lost link, the board's watchdog
                # vent, an e-stop) stops the run here, before a frame taken after it is recorded.
                _check_valves(devices.valves)
                start = time.perf_counter()
                worker.put(capture)  # estimated and recorded beside the next capture
                totals["estimate_wait"] += time.perf_counter() - start
        except BaseException:
            frames.close()  # stops and joins the pressure thread, on every path, before the devices close
            worker.close()  # the frames captured so far are still estimated and recorded
            raise
        frames.close()
        worker.finish()
        if stop:
            stopped = stop.reason
            exit_code = _SIGNAL_EXIT.get(stop.signum, EXIT_FAILED)
    except STOP_ERRORS as e:
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
        summary = _finish(writer, records, config, options, schedule, stopped, wall_s, totals, stats, devices)
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


def _add_timings(totals: dict[str, float], bench_ms) -> None:
    """Add a frame's ``bench_ms`` to the run's seconds: its capture parts as they are named (physics,
    render, truth on the twin; grab on the rig), its estimates and scores summed over the estimators."""
    for part, ms in bench_ms.items():
        key = part.split("_", 1)[0] if part.startswith(("estimate_", "score_")) else part
        totals[key] = totals.get(key, 0.0) + ms / 1e3


def _check_valves(valves) -> None:
    """Raise, as a valve fault, what the valve bank recorded in the background since the last frame."""
    try:
        valves.check()
    except DeviceError as e:
        raise ValveFaultError(e) from e


# Captured frames that may wait for the estimator (each a stereo pair: ~6 MB at 1280x720).
WORKER_DEPTH = 2
# Errors that end a run cleanly (the frames so far are kept): device faults (the twin's instability is
# one), failed writes (a full disk).
STOP_ERRORS: tuple[type[BaseException], ...] = (DeviceError, OSError)


def _describe_error(e: BaseException) -> str:
    if isinstance(e, EndOfStreamError):
        return f"the camera's recording ended ({e})"
    if isinstance(e, ValveFaultError):
        return str(e)
    kind = "twin instability" if isinstance(e, SimulationError) else type(e).__name__
    return f"{kind}: {e}"


def _finish(writer, records, config, options, schedule, stopped, wall_s, totals, stats, devices: Devices) -> dict:
    summary = summarize_run(records, {"backend": config.backend,
                                      "estimators": {"main": {"mode": config.estimator_config(options.mode).mode}}},
                            wall_s=wall_s)
    try:
        writer.flush()  # the last frame on disk, so the writer's time is complete
    except OSError as e:
        stopped = f"{stopped + '; ' if stopped else ''}recording failed: {e}"
    totals = {**totals, "record_thread": writer.write_ms_total / 1e3}
    truth = devices.truth
    summary.update({
        "stopped": stopped,
        "scheduled_frames": schedule.frames,
        "dropped_frames": stats["dropped"],
        "wall_s": wall_s,
        "bench_s": {k: round(v, 3) for k, v in totals.items()},
        "ground_truth": bool(truth is not None and truth.exact),
        "depth_source": truth.describe() if truth is not None else
        "none: the rig has no ground truth and no [rig.depth] source, so only validity and fps are scored",
    })
    writer.finish(summary)
    return summary


def _resolved_config(config, options, schedule, est_configs, devices: Devices) -> dict:
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
        **devices.archive.describe(),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


# --- output -------------------------------------------------------------------------------


def _progress(total: int, enabled: bool, folder: Path):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=f"run {folder.name}", unit="frame", file=sys.stderr, dynamic_ncols=True)


def _update_progress(progress, record: FrameRecord) -> None:
    if progress is None:
        return
    main = record.main
    postfix = {"valid": "yes" if main.valid else "NO"}
    if main.errors:
        postfix["rmse_mm"] = f"{main.errors['rmse_mm']:.2f}"
    postfix["est_ms"] = f"{main.timings_ms.get('total', math.nan):.0f}"
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
