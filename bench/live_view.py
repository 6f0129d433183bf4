"""Watch a run in 3D with Rerun: the estimate, the truth, the images and the pressures as the arm moves.

    softarm run --view               # spawns the Rerun viewer (needs a display)
    softarm run --view web           # serves the web viewer here and prints its URL
    softarm run --rrd run.rrd        # saves the recording; combines with either
    softarm view RUN [--rrd FILE]    # the same recording from a run folder (twin or rig)

Everything that touches Rerun lives in this module and imports ``rerun`` only when a view is asked
for: the core install does not need rerun-sdk (``pip install 'softarm-twin[view]'``), and without it
``--view`` says how to install it.

Logging runs beside the loop: ``LiveView.submit`` only queues the frame's record and references to
its images (it never waits, so the estimator pays microseconds); one thread JPEG-encodes the images
and logs. If that thread falls ``MAX_PENDING_IMAGES`` frames behind, later frames are logged without
their images (counted in ``skipped_images``) rather than slowing the run; their 3D estimate, truth
and plots are always logged.

The recording: timelines ``frame`` (sequence: the frame's number) and ``t_s`` (seconds since the
experiment's start, simulated on the twin); metres, in the left camera's frame (OpenCV axes: x
right, y down, z forward), as the estimates are::

    world                              view coordinates RDF (static)
    world/camera/left                  Pinhole(K_left, image size): the frustum in the 3D view (static; the
                                       lens distortion is not drawn, the images and centerlines are raw)
    world/camera/left/image            the raw left image as the estimator saw it, JPEG
    world/camera/left/centerline       the 2D centerline (left_uv), cleared on an invalid frame
    world/camera/left/bridged          its points the tube fit bridged (measured False)
    world/camera/right                 its pose from the extrinsics (x_right = R x_left + T) and Pinhole(K_right)
    world/camera/right/...             as the left
    world/estimate/centerline          the 3D estimate as a line strip (cleared on an invalid frame)
    world/estimate/measured            its measured points
    world/estimate/bridged             its bridged points, apart: larger and orange
    world/estimate/invalid             on an invalid frame, the last valid estimate in red, labelled with why
    world/paper/centerline             the paper mode's estimate (``--compare``)
    world/truth/backbone               the twin's exact backbone
    plots/pressure/commanded           bar, a series per valve channel
    plots/pressure/chamber             bar, a series per channel (the twin)
    plots/error/rmse_mm, tip_mm        against the exact backbone (the twin, valid frames)
    plots/timing/<stage>               the estimator's stages, ms (``total``: the whole call)
    plots/fps/estimator                1000 / total
    log/invalid                        why a frame was invalid
    summary                            the run's summary (markdown), logged at the last frame

The default blueprint lays out the 3D view, both images and the plots. Rerun's viewer collects
anonymous usage data unless told not to: it does not when ``CI`` is set (CI runs set it; so do the
tests) or after ``rerun analytics disable``.
"""

from __future__ import annotations

import contextlib
import importlib
import math
import os
import queue
import socket
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

import cv2
import numpy as np

from bench.frame_record import SIDES, EstimateRecord, FrameRecord
from estimator import StereoCalibration

INSTALL_HINT = "pip install 'softarm-twin[view]' (from a checkout: pip install -e '.[view]')"
APPLICATION_ID = "softarm"
FRAME_TIMELINE, TIME_TIMELINE = "frame", "t_s"
VIEWERS = ("native", "web")
DEFAULT_GRPC_PORT, DEFAULT_WEB_PORT = 9876, 9090
# JPEG keeps a 1280x720 twin frame near 20 kB per eye (a 690-frame run's images: about 30 MB).
JPEG_QUALITY = 80
# Frames whose images may wait for the logging thread (each pair ~6 MB at 1280x720).
MAX_PENDING_IMAGES = 8
# How often a recording written only to a file is cut into chunks, seconds.
FILE_FLUSH_TICK_S = 3.0
# How long the end of a recording may wait for a viewer to take the last data.
FLUSH_TIMEOUT_S = 10.0
# How long a spawned viewer may take to listen before --view gives up on it.
SPAWN_WAIT_S = 5.0
# Where a frustum's image plane is drawn in the 3D view (the arm hangs about 1 m away).
IMAGE_PLANE_M = 0.25

# Paths (see the module docstring).
WORLD = "world"
CAMERA = "world/camera"
ESTIMATE = "world/estimate/centerline"
MEASURED = "world/estimate/measured"
BRIDGED = "world/estimate/bridged"
INVALID = "world/estimate/invalid"
PAPER = "world/paper/centerline"
TRUTH = "world/truth/backbone"
PRESSURE = "plots/pressure"
ERROR = "plots/error"
TIMING = "plots/timing"
FPS = "plots/fps/estimator"
INVALID_LOG = "log/invalid"
SUMMARY = "summary"

# Colours (RGB) and sizes (metres in 3D, pixels in the images).
ESTIMATE_RGB = (60, 150, 255)
BRIDGED_RGB = (255, 150, 0)
INVALID_RGB = (230, 50, 50)
PAPER_RGB = (200, 90, 255)
TRUTH_RGB = (70, 210, 110)
LINE_M, POINT_M, BRIDGED_M = 0.002, 0.004, 0.007
LINE_PX, POINT_PX = 2.0, 5.0


class ViewError(RuntimeError):
    """The view cannot be opened (rerun-sdk missing, no display, a recording file that cannot be written)."""


@dataclass(frozen=True)
class ViewTarget:
    """Where a recording goes.

    Attributes:
        viewer: None (no viewer), "native" (spawn the Rerun viewer) or "web" (serve the web viewer).
        rrd: the ``.rrd`` file to save the recording to, or None.
    """

    viewer: str | None = None
    rrd: Path | None = None

    def __post_init__(self) -> None:
        if self.viewer not in (None, *VIEWERS):
            raise ValueError(f"viewer: expected one of {', '.join(VIEWERS)} or None, got {self.viewer!r}")
        if self.viewer is None and self.rrd is None:
            raise ValueError("a view needs a viewer, a .rrd file or both")


def require_rerun():
    """The ``rerun`` module.

    Raises:
        ViewError: rerun-sdk is not installed; the message says how to install it.
    """
    try:
        return importlib.import_module("rerun")
    except ImportError as e:
        raise ViewError(f"the live view needs the optional Rerun viewer (rerun-sdk), which is not installed "
                        f"({e}); install it with: {INSTALL_HINT}") from e


def has_display() -> bool:
    """Whether a native window can open here (on Linux and the BSDs: an X11 or Wayland display is named)."""
    if sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def check_target(target: ViewTarget) -> None:
    """Refuse, before anything runs, a view that cannot work here.

    Raises:
        ViewError: rerun-sdk missing (with how to install it), a native viewer without a display (with
            what to use instead), or a ``.rrd`` path whose folder does not exist, that is a folder, or
            that cannot be written.
    """
    require_rerun()
    if target.viewer == "native" and not has_display():
        raise ViewError("--view needs a display to open the Rerun viewer, and there is none here (DISPLAY and "
                        "WAYLAND_DISPLAY are unset); use --view web to serve the web viewer and open its URL in a "
                        "browser, or --rrd FILE to save the recording and open it where there is a display "
                        "(rerun FILE)")
    if target.rrd is not None:
        rrd = Path(target.rrd)
        if rrd.is_dir():
            raise ViewError(f"--rrd {rrd}: is a folder; name the recording file to write (e.g. {rrd / 'run.rrd'})")
        if not rrd.parent.resolve().is_dir():
            raise ViewError(f"--rrd {rrd}: the folder {rrd.parent} does not exist")
        if rrd.is_symlink() and not rrd.exists():
            raise ViewError(f"--rrd {rrd}: a link to nothing ({os.readlink(rrd)}); name a file to write")
        if rrd.exists() and not rrd.is_file():  # a FIFO or a device: opening it to check could block
            raise ViewError(f"--rrd {rrd}: not a regular file; name a file to write")
        existed = rrd.exists()
        try:  # a folder that exists may still refuse a new file (read-only, no permission, /proc)
            with open(rrd, "ab"):
                pass
            if not existed:
                rrd.unlink()
        except OSError as e:
            raise ViewError(f"--rrd {rrd}: cannot be written ({e.strerror or e})") from e


def blueprint():
    """The default layout: the 3D view beside both images, the plots below."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial3DView(origin=WORLD, name="3D: estimate, truth, cameras"),
                rrb.Vertical(rrb.Spatial2DView(origin=f"{CAMERA}/left", name="left image"),
                             rrb.Spatial2DView(origin=f"{CAMERA}/right", name="right image")),
                column_shares=[3, 2]),
            rrb.Horizontal(
                rrb.TimeSeriesView(origin=PRESSURE, name="pressure (bar)"),
                rrb.TimeSeriesView(origin=ERROR, name="error vs exact backbone (mm)"),
                rrb.Tabs(rrb.TimeSeriesView(origin=TIMING, name="estimator stages (ms)"),
                         rrb.TimeSeriesView(origin="plots/fps", name="estimator fps"),
                         rrb.TextDocumentView(origin=SUMMARY, name="summary"))),
            row_shares=[3, 2]),
        collapse_panels=True)


def web_url(web_port: int, grpc_port: int) -> str:
    """The web viewer's address, connected to this process's recording server (the form Rerun prints)."""
    return f"http://127.0.0.1:{web_port}?url={quote(f'rerun+http://127.0.0.1:{grpc_port}/proxy', safe='')}"


class LiveView:
    """A Rerun recording of a run, logged from its own thread.

    Open it with the target, hand it the calibration (``start``), then each frame (``submit``), and
    end it (``finish`` with the summary, or ``close``). With ``--view web`` the web viewer and the
    recording's server live in this process: ``serve_until_interrupted`` keeps them up.

    Args:
        target: the viewer and/or the ``.rrd`` file.
        max_pending_images: frames whose images may wait for the logging thread.

    Raises:
        ViewError: see ``check_target``; or the viewer did not start.
    """

    def __init__(self, target: ViewTarget, *, max_pending_images: int = MAX_PENDING_IMAGES) -> None:
        check_target(target)
        self.target = target
        self._rr = rr = require_rerun()
        self.url: str | None = None  # the web viewer's, with --view web
        self.skipped_images = 0
        self.frames = 0  # frames logged
        # What handing the frames over cost their callers (the run's estimating thread): wall-clock seconds
        # (waits for the GIL included) and the calling thread's CPU seconds.
        self.submit_s = self.submit_cpu_s = 0.0
        self.error: BaseException | None = None
        # Fewer, larger chunks when only a file is written (each chunk carries ~2 kB of schema); a viewer
        # watching gets the usual 0.2 s batches.
        batching = rr.ChunkBatcherConfig(flush_tick=FILE_FLUSH_TICK_S) if target.viewer is None else None
        self._rec = rr.RecordingStream(APPLICATION_ID, batcher_config=batching)
        sinks = []
        if target.rrd is not None:
            try:
                sinks.append(rr.FileSink(str(target.rrd)))
            except RuntimeError as e:  # Rerun's own refusal, should the file go between the check and here
                raise ViewError(f"--rrd {target.rrd}: {e}") from e
        if target.viewer == "native":
            sinks.append(self._spawn_viewer())
        elif target.viewer == "web":
            sinks.append(self._serve_web())
        self._rec.set_sinks(*sinks, default_blueprint=blueprint())
        self._rec.log(WORLD, rr.ViewCoordinates.RDF, static=True)
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        # Frames with images handed over and logged: each counter written by one thread only, so no lock
        # is shared with the logging thread.
        self._images_in = self._images_out = 0
        self._max_pending = max(1, int(max_pending_images))
        self._last_valid: np.ndarray | None = None
        self._last_time: tuple[int, float] | None = None
        self._named: set[str] = set()  # plots whose series have their names
        self._channels: tuple[str, ...] = ()  # the valves' channels, in the order of the pressure series
        self._ended = False
        self._thread = threading.Thread(target=self._run, name="live-view", daemon=True)
        self._thread.start()

    # --- sinks ----------------------------------------------------------------------------------

    def _spawn_viewer(self):
        port = DEFAULT_GRPC_PORT
        if not _listening(port):  # a viewer already listening there is reused, as rerun does
            self._rec.spawn(port=port, connect=False, hide_welcome_screen=True)
            deadline = time.monotonic() + SPAWN_WAIT_S
            while not _listening(port) and time.monotonic() < deadline:
                time.sleep(0.1)
            if not _listening(port):
                raise ViewError(f"the Rerun viewer did not start (nothing listens on port {port}; see its messages "
                                "above); use --view web, or --rrd FILE and open the file with: rerun FILE")
        return self._rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy")

    def _serve_web(self):
        rr = self._rr
        grpc_port = DEFAULT_GRPC_PORT if _bindable(DEFAULT_GRPC_PORT) else _free_port()
        web_port = DEFAULT_WEB_PORT if _bindable(DEFAULT_WEB_PORT) else _free_port()
        server = rr.GrpcServerSink(port=grpc_port)
        rr.serve_web_viewer(web_port=web_port, open_browser=False)
        self.url = web_url(web_port, grpc_port)
        return server

    # --- what the run hands over (any thread; never waits unless asked) -------------------------------

    def start(self, calibration: StereoCalibration, *, channels: Sequence[str] = (), name: str | None = None) -> None:
        """Log the cameras (static) and name the recording (the run folder's name): once, before the frames."""
        self._queue.put(("start", calibration, tuple(channels), name))

    def submit(self, record: FrameRecord, left: np.ndarray | None = None, right: np.ndarray | None = None, *,
               wait: bool = False) -> None:
        """Queue one frame: its record and its raw BGR images (referenced, not copied: do not modify them).

        Args:
            record: the frame's record.
            left, right: (H, W, 3) uint8 BGR images, or None.
            wait: wait for room for the images (a replay from disk); otherwise, when the logging
                thread is ``max_pending_images`` frames behind, the frame goes without its images.
        """
        start, start_cpu = time.perf_counter(), time.thread_time()
        images = None
        if (left is not None or right is not None) and not self._ended:
            while wait and self._images_in - self._images_out >= self._max_pending and self._thread.is_alive():
                time.sleep(0.002)
            if self._images_in - self._images_out < self._max_pending:
                images = (left, right)
                self._images_in += 1
            else:
                self.skipped_images += 1
        self._queue.put(("frame", record, images))
        self.submit_cpu_s += time.thread_time() - start_cpu
        self.submit_s += time.perf_counter() - start

    def finish(self, summary: Mapping | None = None) -> None:
        """Log the summary (if given) at the last frame, let every queued frame be logged, flush and
        complete the ``.rrd`` file; the web viewer (if any) goes on serving. Never raises: a logging
        failure is printed, and kept in ``error``."""
        if self._ended:
            return
        self._ended = True
        if summary is not None:
            self._queue.put(("summary", dict(summary)))
        self._queue.put(("end",))
        self._thread.join()
        if self.skipped_images:
            print(f"softarm: the live view fell behind and left out the images of {self.skipped_images} frames "
                  "(their estimates and plots are in)", file=sys.stderr)

    def close(self) -> None:
        """End the recording (``finish`` without a summary) and stop serving it."""
        self.finish()
        with contextlib.suppress(Exception):  # closing must not raise; finish() completed the file
            self._rec.disconnect()

    def serve_until_interrupted(self, out=sys.stdout) -> None:
        """With ``--view web``: keep the web viewer and the recording's server up until Ctrl-C (or SIGTERM)."""
        if self.url is None:
            return
        import signal

        def stop(signum, frame):
            raise KeyboardInterrupt

        previous = signal.signal(signal.SIGTERM, stop) if threading.current_thread() is threading.main_thread() \
            else None
        try:
            # Inside the try: whoever reads this line may press Ctrl-C at once, before a loaded machine
            # has run the next statement (CI saw the run die of an uncaught KeyboardInterrupt there).
            print(f"softarm: the web viewer keeps serving the recording at {self.url} ; press Ctrl-C to stop",
                  file=out, flush=True)
            while True:
                time.sleep(0.5)
        except KeyboardInterrupt:
            print("softarm: web viewer stopped", file=out, flush=True)
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)

    # --- the logging thread ----------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            kind = item[0]
            try:
                if self.error is None:
                    if kind == "start":
                        self._log_cameras(*item[1:])
                    elif kind == "frame":
                        self._log_frame(item[1], item[2])
                    elif kind == "summary":
                        self._log_summary(item[1])
            except Exception as e:  # noqa: BLE001 - the run goes on without its view
                self.error = e
                print(f"softarm: the live view stopped logging ({type(e).__name__}: {e}); the run goes on",
                      file=sys.stderr, flush=True)
            finally:
                if kind == "frame" and item[2] is not None:
                    self._images_out += 1
            if kind == "end":
                self._end()
                return

    def _end(self) -> None:
        try:
            self._rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except Exception as e:  # noqa: BLE001 - a viewer closed mid-run; the file still completes below
            print(f"softarm: the viewer did not take the last data ({e})", file=sys.stderr)
        if self.target.rrd is not None:
            # Leaving the stream's context completes file sinks (the footer) and leaves a web viewer's server up.
            with self._rec:
                pass

    def _set_time(self, index: int, t_s: float) -> None:
        self._rec.set_time(FRAME_TIMELINE, sequence=int(index))
        self._rec.set_time(TIME_TIMELINE, duration=float(t_s))
        self._last_time = (int(index), float(t_s))

    def _log_cameras(self, calibration: StereoCalibration, channels: tuple[str, ...], name: str | None) -> None:
        rr, rec = self._rr, self._rec
        if name:
            rec.send_recording_name(name)
        width, height = calibration.image_size
        # The left camera's frame is the world's; the right one's from it: x_right = R x_left + T.
        rec.log(f"{CAMERA}/right", rr.Transform3D(translation=np.asarray(calibration.T, float).ravel(),
                                                  mat3x3=np.asarray(calibration.R, float),
                                                  relation=rr.TransformRelation.ChildFromParent), static=True)
        for side in SIDES:
            rec.log(f"{CAMERA}/{side}", rr.Pinhole(image_from_camera=np.asarray(calibration.K(side), float),
                                                   resolution=[width, height], camera_xyz=rr.ViewCoordinates.RDF,
                                                   image_plane_distance=IMAGE_PLANE_M), static=True)
        self._channels = channels

    def _log_pressures(self, kind: str, pressures: Mapping[str, float]) -> None:
        """One entity per kind, one series per channel (fewer calls into Rerun than an entity per channel)."""
        rr, rec = self._rr, self._rec
        if not self._channels:  # not given: the first frame's
            self._channels = tuple(pressures)
        path = f"{PRESSURE}/{kind}"
        if path not in self._named:  # named when first logged: the rig has no chamber pressures
            self._named.add(path)
            rec.log(path, rr.SeriesLines(names=[f"{kind} {channel}" for channel in self._channels]), static=True)
        rec.log(path, rr.Scalars([float(pressures.get(channel, math.nan)) for channel in self._channels]))

    def _log_frame(self, record: FrameRecord, images) -> None:
        rr, rec = self._rr, self._rec
        self._set_time(record.index, record.t_s)
        self.frames += 1
        if images is not None:
            for side, image in zip(SIDES, images, strict=True):
                if image is not None:
                    rec.log(f"{CAMERA}/{side}/image", rr.EncodedImage(contents=_jpeg(image), media_type="image/jpeg"))
        main = record.main
        if main.valid and len(main.points_m):
            self._log_estimate(main)
        else:
            self._log_invalid(record)
        if record.paper is not None:
            paper = record.paper
            rec.log(PAPER, rr.LineStrips3D([paper.points_m], colors=[PAPER_RGB], radii=LINE_M)
                    if paper.valid and len(paper.points_m) else rr.Clear(recursive=False))
        if record.gt_m is not None and len(record.gt_m):
            rec.log(TRUTH, rr.LineStrips3D([record.gt_m], colors=[TRUTH_RGB], radii=LINE_M))
        for kind, pressures in (("commanded", record.commanded_bar), ("chamber", record.chamber_bar)):
            if pressures:
                self._log_pressures(kind, pressures)
        if main.errors is not None:
            for key in ("rmse_mm", "tip_mm"):
                if math.isfinite(main.errors.get(key, math.nan)):
                    rec.log(f"{ERROR}/{key}", rr.Scalars(float(main.errors[key])))
        for stage, ms in main.timings_ms.items():
            rec.log(f"{TIMING}/{stage}", rr.Scalars(float(ms)))
        if main.total_ms > 0:
            rec.log(FPS, rr.Scalars(1e3 / main.total_ms))

    def _log_estimate(self, main: EstimateRecord) -> None:
        rr, rec = self._rr, self._rec
        points = np.asarray(main.points_m, float)
        bridged = _bridged(main, len(points))
        rec.log(ESTIMATE, rr.LineStrips3D([points], colors=[ESTIMATE_RGB], radii=LINE_M))
        rec.log(MEASURED, rr.Points3D(points[~bridged], colors=[ESTIMATE_RGB], radii=POINT_M))
        rec.log(BRIDGED, rr.Points3D(points[bridged], colors=[BRIDGED_RGB], radii=BRIDGED_M))
        rec.log(INVALID, rr.Clear(recursive=False))
        for side, uv in (("left", main.left_uv), ("right", main.right_uv)):
            uv = np.asarray(uv, float)
            rec.log(f"{CAMERA}/{side}/centerline", rr.LineStrips2D([uv], colors=[ESTIMATE_RGB], radii=LINE_PX))
            marked = uv[bridged] if len(uv) == len(bridged) else np.zeros((0, 2))
            rec.log(f"{CAMERA}/{side}/bridged", rr.Points2D(marked, colors=[BRIDGED_RGB], radii=POINT_PX))
        self._last_valid = points

    def _log_invalid(self, record: FrameRecord) -> None:
        rr, rec = self._rr, self._rec
        main = record.main
        for path in (ESTIMATE, MEASURED, BRIDGED, *(f"{CAMERA}/{side}/{what}" for side in SIDES
                                                    for what in ("centerline", "bridged"))):
            rec.log(path, rr.Clear(recursive=False))
        why = main.reason or "no reason given"
        if self._last_valid is not None:
            rec.log(INVALID, rr.LineStrips3D([self._last_valid], colors=[INVALID_RGB], radii=LINE_M,
                                             labels=[f"frame {record.index} invalid (last valid estimate shown): "
                                                     f"{why}"]))
        else:
            rec.log(INVALID, rr.Clear(recursive=False))
        rec.log(INVALID_LOG, rr.TextLog(f"frame {record.index}: invalid: {why}", level="WARN"))

    def _log_summary(self, summary: dict) -> None:
        rr, rec = self._rr, self._rec
        if self._last_time is not None:
            self._set_time(*self._last_time)
        rec.log(SUMMARY, rr.TextDocument(summary_markdown(summary), media_type="text/markdown"),
                static=self._last_time is None)


def summary_markdown(summary: Mapping) -> str:
    """The run's summary as markdown: what ran, then the figures beside the paper's."""
    from bench.scoring import summary_table

    head = [f"# softarm {summary.get('backend', '?')} run, {summary.get('mode', 'default')} mode", "",
            f"{summary.get('valid_frames', '?')}/{summary.get('frames', '?')} valid frames"]
    if summary.get("stopped"):
        head.append(f"; stopped early: {summary['stopped']}")
    try:
        table = summary_table(summary, label=f"{summary.get('mode', 'default')} mode", paper_mode=summary.get("paper"),
                              markdown=True)
    except (KeyError, TypeError, ValueError) as e:  # a summary of a run with no scored frames
        table = [f"(no table: {type(e).__name__}: {e})"]
    return "\n".join([*head, "", *table, ""])


def record_run(run, target: ViewTarget, *, progress: bool = False) -> LiveView:
    """Turn a recorded run folder into the recording ``softarm run --rrd`` makes (same entities).

    The images are the ones the estimator saw: ``Run.image`` rebuilds the twin's from their noise-free
    renders and draws the same sensor noise again, as ``softarm replay`` does; the rig's are read as stored.

    Args:
        run: a ``bench.recording.Run``.
        target: where the recording goes.
        progress: show a progress bar.

    Returns:
        The finished view (with ``--view web`` still serving: ``serve_until_interrupted``, then ``close``).

    Raises:
        ViewError: see ``check_target``.
        RunFolderError: the run's calibration is missing, or its twin camera effects are unusable.
    """
    calibration = run.calibration
    channels = run.section("valves").get("channels") or (list(run.frames[0].commanded_bar) if run.frames else [])
    view = LiveView(target)
    try:
        view.start(calibration, channels=channels, name=run.path.name)
        frames = run.frames
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(frames), desc=f"view {run.path.name}", unit="frame", file=sys.stderr)
        try:
            for record in frames:
                view.submit(record, run.image(record, "left"), run.image(record, "right"), wait=True)
                if bar is not None:
                    bar.update(1)
        finally:
            if bar is not None:
                bar.close()
        view.finish(run.summary)
    except BaseException:
        view.close()
        raise
    return view


def view_command(args) -> int:
    """Entry point of ``softarm view RUN [--rrd FILE] [--web]``: 0 done, 1 the view failed, 2 RUN is not a run."""
    from bench.recording import EXIT_FAILED, EXIT_NOT_A_RUN, EXIT_OK, RunFolderError, load_run, unreadable_frames_note

    try:
        run = load_run(Path(args.run_dir))
    except RunFolderError as e:
        print(f"softarm view: {e}", file=sys.stderr)
        return EXIT_NOT_A_RUN
    problems = run.image_problems()
    if problems:  # those frames are recorded without their images
        print(f"softarm view: note: recorded without images: {unreadable_frames_note(problems)}", file=sys.stderr)
    rrd = Path(args.rrd) if getattr(args, "rrd", None) else None
    web = bool(getattr(args, "web", False))
    target = ViewTarget(viewer="web" if web else (None if rrd is not None else "native"), rrd=rrd)
    try:
        view = record_run(run, target, progress=True)
    except (ViewError, RunFolderError, OSError) as e:
        print(f"softarm view: {e}", file=sys.stderr)
        return EXIT_FAILED
    try:
        if rrd is not None:
            print(f"softarm view: {view.frames} frames of {run.path} recorded in {rrd} ({_size(rrd)}); open it "
                  f"with: rerun {rrd}")
        if view.url is not None:
            view.serve_until_interrupted()
    finally:
        view.close()
    return EXIT_FAILED if view.error is not None else EXIT_OK


def _size(path: Path) -> str:
    try:
        return f"{Path(path).stat().st_size / 1e6:.1f} MB"
    except OSError:
        return "size unknown"


def _bridged(estimate: EstimateRecord, n: int) -> np.ndarray:
    """(n,) True where the tube fit bridged the point; all False where the estimator does not say."""
    measured = np.asarray(estimate.measured, bool)
    return ~measured if len(measured) == n else np.zeros(n, bool)


def _jpeg(image: np.ndarray) -> bytes:
    ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError(f"could not JPEG-encode an image of shape {image.shape} and dtype {image.dtype}")
    return encoded.tobytes()


def _listening(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False


def _bindable(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("", port))
            return True
        except OSError:
            return False


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("", 0))
        return int(s.getsockname()[1])
