"""The run folder: written frame by frame so that a killed run keeps its frames, loaded tolerantly.

Layout (every file readable by a person; ``load_run`` reads it back)::

    RUN/
      config.json        the resolved configuration, the schedule, the estimator settings, argv
      bench.toml         a copy of the config file the run was started with
      calibration.toml   the camera calibration the frames were estimated with
      frames.jsonl       one JSON object per frame (``bench.frame_record.FrameRecord``), flushed as the run goes
      frames/000042_left.png, 000042_right.png   rig: the raw stereo frames (lossless PNG, or JPEG)
      frames/background_left.png, ..._right.png  sim: the noise-free static scene, once per run
      frames/000042_left.png, 000042_right.png   sim: the frame's noise-free render, as its difference
                                                 from the background, cropped to where it differs
      frames/000042_depth.png                    sim: left depth, uint16 in 0.1 mm (0 = none)
      summary.json       written at the end (a killed run has none: ``load_run`` recomputes it)
      report/            written by ``softarm report``

The twin's frames are exact functions of the noise-free render and the noise seed: the sensor
noise of frame k is drawn from (seed, k) alone (``twin.sensor.frame_generator``). So a twin run
stores the noise-free images (they compress: about 0.1 MB per frame where the noisy pair took
2.2 MB) with the seed and the camera effects (``config.json`` ``sensor``), and ``Run.image``
draws the same noise again: the images a replay or the report sees are the ones the estimator
saw, bit for bit.

``config.json`` and ``calibration.toml`` are written before ``frames.jsonl`` is created (pass
them to ``RunWriter``), so every folder holding a ``frames.jsonl`` can be loaded, even one killed
before its first frame. A frame's files are written first (each to a temporary name, then
renamed), its line in ``frames.jsonl`` last, by one background thread; ``RunWriter.submit``
waits for the previous frame to be on disk before handing over the next, so at any moment at
most one frame is in flight: a SIGKILL loses at most the frame being written, and every line in
``frames.jsonl`` has its images. A line cut short by the kill is skipped by the loader, and so is
any line that is not a frame record (``bench.frame_record``) or repeats an index; ``Run.skipped``
names each with its line number and why, and a ``summary.json`` that disagrees with the frames
read (or is not a JSON object) is recomputed from them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import time
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bench.config import RecordingConfig
from bench.frame_record import FrameRecord, RecordError
from bench.scoring import DEPTH_UNIT_M, dequantize_depth, summarize
from estimator import StereoCalibration

FRAMES_FILE = "frames.jsonl"
SUMMARY_FILE = "summary.json"
CONFIG_FILE = "config.json"
CALIBRATION_FILE = "calibration.toml"
FRAMES_DIR = "frames"
FORMAT_VERSION = 2  # 2: typed frame records, the twin's noise-free images (1 still reads)
BACKGROUND = "background"
_PNG_STRATEGIES = {"huffman": cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY, "rle": cv2.IMWRITE_PNG_STRATEGY_RLE,
                   "default": cv2.IMWRITE_PNG_STRATEGY_DEFAULT}


# What a recorded frame costs on disk, for the estimate printed (and, above 2 GB, confirmed) before a run.
# Rig frames, bytes per byte of raw BGR image, measured on noisy 1280x720 camera frames (2026-12-01,
# OpenCV 5.0): PNG at levels 1-9 with the Huffman-only or RLE strategy 0.385-0.387, the default strategy
# 0.43-0.48, level 0 (stored) 1.0; JPEG at quality 50: 0.006, 75: 0.007, 95: 0.04, 100: 0.17 (interpolated).
# A real camera's frames compress differently (less noise, more texture): the figure is an estimate.
_PNG_RATIO = {"huffman": 0.39, "rle": 0.39, "default": 0.48}
_JPEG_RATIO = ((0, 0.006), (50, 0.006), (75, 0.007), (95, 0.04), (100, 0.17))
# The twin's frames: the noise-free render's difference from the static scene, cropped to where it differs,
# as PNG (RLE), bytes per pixel of one eye; measured on the paper's ramp (2026-12-02): 12.6 kB per eye on the
# clean scene, 19 kB on the lab scene (its textured wall shows through the arm's blur and edges). The
# left depth map the same way: 11 kB. The backgrounds, once per run: 8 kB clean, 1.4 MB lab.
_TWIN_BYTES_PER_PIXEL = {"clean": 0.014, "textured": 0.021}
_TWIN_DEPTH_BYTES_PER_PIXEL = 0.012
# The left depth kept whole (a rig's, or a twin without a static scene): 12-25 kB on an empty background.
_DEPTH_BYTES_PER_PIXEL = 0.03
# One frames.jsonl line: about 9 kB on the twin (the 200-point backbone included); the paper mode adds ~5 kB.
_RECORD_BYTES, _COMPARE_RECORD_BYTES = 10_000, 5_000


def frame_bytes(recording: RecordingConfig, image_size: tuple[int, int], *, depth: bool, compare: bool,
                noise_free: bool = False, textured: bool = False) -> float:
    """Expected bytes one recorded frame takes: both eyes as the recording settings encode them, the
    depth map when one is kept, and the frame's line in frames.jsonl.

    Args:
        recording: the ``[recording]`` settings.
        image_size: (width, height) of one eye, pixels.
        depth: the twin's left depth map is kept (``[recording] depth`` on the sim backend).
        compare: the paper mode's estimate is recorded too (``--compare``).
        noise_free: the twin's frames, stored as noise-free differences from the static scene.
        textured: the twin renders a scene with a backdrop (its depth map is not empty).
    """
    width, height = image_size
    raw = 3.0 * width * height
    scene = "textured" if textured else "clean"
    if noise_free:
        images = 2 * _TWIN_BYTES_PER_PIXEL[scene] * width * height
    elif not recording.lossless_frames:
        quality, ratios = recording.jpeg_quality, _JPEG_RATIO
        images = 2 * raw * float(np.interp(quality, [q for q, _ in ratios], [r for _, r in ratios]))
    elif recording.png_compression == 0:
        images = 2 * raw
    else:
        images = 2 * raw * _PNG_RATIO[recording.png_strategy]
    total = images + _RECORD_BYTES + (_COMPARE_RECORD_BYTES if compare else 0)
    if depth:
        total += (_TWIN_DEPTH_BYTES_PER_PIXEL if noise_free else _DEPTH_BYTES_PER_PIXEL) * width * height
    return total


def human_bytes(n: float) -> str:
    """1234567 -> '1.2 MB' (decimal units, as disks are sold)."""
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n:.0f} B"


# Exit codes of the commands that read a run folder, ``softarm report`` and ``softarm replay``: 0 done;
# 1 the work failed (the report or the replay could not be written); 2 RUN is not a readable run folder.
EXIT_OK, EXIT_FAILED, EXIT_NOT_A_RUN = 0, 1, 2


class RunFolderError(ValueError):
    """A folder is not a run folder (no frames.jsonl / config.json), or cannot be written."""


def jsonable(value: Any) -> Any:
    """Dataclasses, paths, mappings, tuples, numpy values and non-finite floats as plain JSON values."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: Path, data: Any) -> None:
    """Write JSON atomically (temporary file, then rename)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(jsonable(data), indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, path)


# ``runs/latest`` names the newest run: a symbolic link to its folder, or (where links cannot be made) a
# text file holding the folder's name; ``softarm report`` and ``softarm replay`` read it by default.
LATEST = "latest"


def point_latest(folder: Path) -> None:
    """Make ``latest`` beside ``folder`` name it (a relative symlink, replaced atomically; a text file where
    symbolic links are refused). Never raises: a run does not fail over its bookmark."""
    folder = Path(folder)
    link = folder.parent / LATEST
    if link.exists() and link.is_dir() and not link.is_symlink():
        return  # a real folder of that name is somebody's; leave it
    tmp = folder.parent / f".{LATEST}.{os.getpid()}.tmp"
    try:
        tmp.unlink(missing_ok=True)
        os.symlink(folder.name, tmp, target_is_directory=True)
        os.replace(tmp, link)
        return
    except OSError:
        tmp.unlink(missing_ok=True)
    try:
        tmp.write_text(folder.name + "\n", encoding="utf-8")
        os.replace(tmp, link)
    except OSError:
        tmp.unlink(missing_ok=True)


def resolve_run_folder(path: str | Path) -> Path:
    """``path``, or the folder a ``latest`` text file names (where it could not be a symbolic link)."""
    path = Path(path)
    if path.name == LATEST and path.is_symlink():
        return path.parent / os.readlink(path)
    if path.name == LATEST and path.is_file():
        try:
            name = path.read_text(encoding="utf-8").strip()
        except (OSError, UnicodeDecodeError):
            return path
        if name and "/" not in name and (path.parent / name).is_dir():
            return path.parent / name
    return path


def writable_folder(path: Path, what: str) -> Path:
    """``path`` once it is known that a folder can be written there, before a run or a study spends its time.

    Raises:
        ValueError: a file is in the way, or the folder cannot be made or written to (with the reason).
    """
    missing: list[Path] = []
    probe = path / f".softarm-write-check-{os.getpid()}"
    try:
        existing = path
        while not existing.exists() and existing != existing.parent:
            missing.append(existing)
            existing = existing.parent
        if not existing.is_dir():
            raise ValueError(f"{what} {path}: {existing} is a file, not a folder")
        path.mkdir(parents=True, exist_ok=True)
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:  # no permission to look or to write, a read-only or special file system
        raise ValueError(f"{what} {path}: cannot be written ({e.strerror or e})") from e
    finally:
        for folder in missing:  # made only to check: the caller makes them again when it writes
            with contextlib.suppress(OSError):
                folder.rmdir()
    return path


def new_run_folder(root: Path, stamp: str | None = None) -> Path:
    """A fresh ``root/<YYYY-mm-dd_HHMMSS>`` (with ``_2``, ``_3`` ... when taken)."""
    stamp = stamp or time.strftime("%Y-%m-%d_%H%M%S")
    root = Path(root).resolve()
    folder, n = root / stamp, 1
    while folder.exists():
        n += 1
        folder = root / f"{stamp}_{n}"
    return folder


class RunWriter:
    """Writes one run folder: config and calibration at the start, frames as they come, summary at the end.

    Args:
        folder: the run folder; created, and it must not already hold a run.
        recording: image format options.
        config: the resolved configuration, written to ``config.json`` before ``frames.jsonl``
            exists (None: call ``write_config`` later).
        source: the config file the run was started with, copied beside it.
        calibration: written to ``calibration.toml``, also before ``frames.jsonl``.

    Raises:
        RunFolderError: the folder already holds a run.
        OSError: the folder or its first files cannot be written.
    """

    def __init__(self, folder: Path, recording: RecordingConfig, *, config: Mapping[str, Any] | None = None,
                 source: Path | None = None, calibration: StereoCalibration | None = None) -> None:
        self.folder = Path(folder)
        for name in (FRAMES_FILE, CONFIG_FILE):
            if (self.folder / name).exists():
                raise RunFolderError(f"{self.folder} already holds a run ({name}); choose another --out")
        (self.folder / FRAMES_DIR).mkdir(parents=True, exist_ok=True)
        self.recording = recording
        if calibration is not None:
            self.write_calibration(calibration)
        if config is not None:
            self.write_config(config, source)
        self._lines = open(self.folder / FRAMES_FILE, "a", encoding="utf-8")  # noqa: SIM115 (closed in close())
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="run-writer")
        self._pending: Future | None = None
        self.frames_written = 0
        self.write_ms_total = 0.0
        self.wait_ms_total = 0.0
        self._backgrounds: dict[str, tuple[str, np.ndarray]] = {}

    # --- start ----------------------------------------------------------------------------

    def write_config(self, config: Mapping[str, Any], source: Path | None = None) -> None:
        """``config.json`` (resolved) and a copy of the source TOML."""
        write_json(self.folder / CONFIG_FILE, {"format": FORMAT_VERSION, **config})
        if source is not None and Path(source).is_file():
            (self.folder / "bench.toml").write_text(Path(source).read_text(encoding="utf-8"), encoding="utf-8")

    def write_calibration(self, calibration: StereoCalibration) -> None:
        calibration.save(self.folder / CALIBRATION_FILE)

    # --- frames ---------------------------------------------------------------------------

    def write_backgrounds(self, images: Mapping[str, np.ndarray]) -> None:
        """The twin's noise-free static scene, once per run (``frames/background_<side>.png``, and its left
        depth ``background_depth.png``): the frames submitted with ``noise`` (and their depth maps) are
        stored as their difference from it."""
        for side, image in images.items():
            name = f"{FRAMES_DIR}/{BACKGROUND}_{side}.png"
            _write_image(self.folder / name, image, ".png", _DIFFERENCE_PNG)
            self._backgrounds[side] = (name, np.ascontiguousarray(image))

    def submit(self, record: FrameRecord | Mapping, left: np.ndarray | None = None, right: np.ndarray | None = None,
               depth_units: np.ndarray | None = None, noise: Mapping[str, int] | None = None) -> float:
        """Hand one frame to the writer thread, after the previous frame is on disk.

        Args:
            record: the frame's record (or its JSON object); the files written are added to it.
            left, right: BGR images to store, or None to store none: the frames as captured, or with
                ``noise`` the twin's noise-free images.
            depth_units: uint16 left depth (``bench.scoring.quantize_depth``), or None.
            noise: {"seed", "index"} the twin drew the frame's sensor noise from: ``left``/``right``
                are then the noise-free images, stored (losslessly) as their difference from the
                backgrounds (``write_backgrounds``), and ``Run.image`` draws the same noise again.

        Returns:
            Milliseconds spent waiting for the previous frame.

        Raises:
            OSError: writing the previous frame failed (disk full, ...).
            RecordError: ``record`` is a JSON object that is not a frame record.
            ValueError: ``noise`` without the backgrounds written first.
        """
        record = FrameRecord.coerce(record)
        if noise is not None and not {"left", "right"} <= set(self._backgrounds):
            raise ValueError("noise: the twin's frames need write_backgrounds() first")
        waited = self.flush()
        self._pending = self._pool.submit(self._write_frame, record, left, right, depth_units, noise)
        return waited

    def flush(self) -> float:
        """Wait until every submitted frame is on disk; re-raise a writer error. Returns ms waited."""
        start = time.perf_counter()
        if self._pending is not None:
            pending, self._pending = self._pending, None
            pending.result()
        waited = (time.perf_counter() - start) * 1e3
        self.wait_ms_total += waited
        return waited

    def _write_frame(self, record: FrameRecord, left, right, depth_units, noise) -> None:
        start = time.perf_counter()
        index = int(record.index)
        images, clean = {}, None
        if left is not None and right is not None:
            if noise is not None:
                clean = {"seed": int(noise["seed"]), "index": int(noise["index"]),
                         "background": {side: self._backgrounds[side][0] for side in ("left", "right")},
                         "origin": {}}
            ext = ".png" if self.recording.lossless_frames or noise is not None else ".jpg"
            params = ([cv2.IMWRITE_PNG_COMPRESSION, self.recording.png_compression,
                       cv2.IMWRITE_PNG_STRATEGY, _PNG_STRATEGIES[self.recording.png_strategy]] if ext == ".png"
                      else [cv2.IMWRITE_JPEG_QUALITY, self.recording.jpeg_quality])
            for side, image in (("left", left), ("right", right)):
                name = f"{FRAMES_DIR}/{index:06d}_{side}{ext}"
                if clean is not None:
                    patch, origin = difference_patch(image, self._backgrounds[side][1])
                    _write_image(self.folder / name, patch, ext, _DIFFERENCE_PNG)
                    clean["origin"][side] = list(origin)
                else:
                    _write_image(self.folder / name, image, ext, params)
                images[side] = name
        depth = None
        if depth_units is not None:
            name = f"{FRAMES_DIR}/{index:06d}_depth.png"
            depth = {"path": name, "unit_m": DEPTH_UNIT_M}
            if "depth" in self._backgrounds:
                patch, origin = difference_patch(depth_units, self._backgrounds["depth"][1])
                _write_image(self.folder / name, patch, ".png", _DIFFERENCE_PNG)
                depth.update(background=self._backgrounds["depth"][0], origin=list(origin))
            else:
                _write_image(self.folder / name, depth_units, ".png", [cv2.IMWRITE_PNG_COMPRESSION, 1])
        record = record.replace(images=images or record.images, clean=clean or record.clean,
                                depth=depth or record.depth,
                                write_ms=round((time.perf_counter() - start) * 1e3, 3))
        self._lines.write(json.dumps(jsonable(record.to_json()), separators=(",", ":")) + "\n")
        self._lines.flush()
        self.frames_written += 1
        self.write_ms_total += (time.perf_counter() - start) * 1e3

    # --- end ------------------------------------------------------------------------------

    def finish(self, summary: Mapping[str, Any]) -> None:
        """Wait for the last frame, write ``summary.json`` and close."""
        try:
            self.flush()
        finally:
            write_json(self.folder / SUMMARY_FILE, summary)
            self.close()

    def close(self) -> None:
        """Stop the writer thread (after the frame in flight) and close ``frames.jsonl``; idempotent."""
        self._pool.shutdown(wait=True)
        if not self._lines.closed:
            self._lines.close()


# The twin's differences from the static scene are mostly zero: run-length matching packs them best
# (19 kB for a 1280x720 eye against 360 kB with Huffman only), level 1 keeps it fast.
_DIFFERENCE_PNG = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]


def difference_patch(image: np.ndarray, background: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
    """``image - background`` (modulo 2^8 or 2^16: lossless) cropped to where they differ.

    Args:
        image, background: uint8 images (H, W, 3), or uint16 depth maps (H, W), of one shape.

    Returns:
        (the patch, its (x, y) origin in the image); a 1x1 zero patch at (0, 0) where nothing differs.
    """
    if image.shape != background.shape or image.dtype != background.dtype or image.dtype not in (np.uint8,
                                                                                                 np.uint16):
        raise ValueError(f"image: expected {background.dtype} {background.shape} like the background, got "
                         f"{image.dtype} {image.shape}")
    difference = np.subtract(image, background, dtype=image.dtype)  # wraps: (background + d) mod 2^n == image
    h = difference.shape[0]
    rows = np.flatnonzero(difference.reshape(h, -1).any(axis=1))
    if not len(rows):
        return np.zeros((1, 1) + difference.shape[2:], difference.dtype), (0, 0)
    y0, y1 = int(rows[0]), int(rows[-1]) + 1
    band = difference[y0:y1]
    cols = np.flatnonzero(band.any(axis=(0, 2)) if band.ndim == 3 else band.any(axis=0))
    x0, x1 = int(cols[0]), int(cols[-1]) + 1
    return np.ascontiguousarray(band[:, x0:x1]), (x0, y0)


def add_patch(background: np.ndarray, patch: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
    """The image ``difference_patch`` took apart: ``background`` plus ``patch`` at ``origin`` (modulo 256).

    Raises:
        ValueError: the patch does not fit the background at its origin.
    """
    x0, y0 = (int(v) for v in origin)
    h, w = patch.shape[:2]
    if patch.dtype != background.dtype or patch.shape[2:] != background.shape[2:] or y0 + h > background.shape[0] or \
            x0 + w > background.shape[1]:
        raise ValueError(f"a {w}x{h} patch at ({x0}, {y0}) does not fit a {background.shape[1]}x{background.shape[0]} "
                         "background")
    image = background.copy()
    region = image[y0:y0 + h, x0:x0 + w]
    np.add(region, patch, out=region, dtype=image.dtype)  # wraps, undoing the subtraction
    return image


def unreadable_frames_note(problems: list[str], shown: int = 5) -> str:
    """How many frames' images cannot be read back, with the first few reasons (``Run.image_problems``):
    "2 frames whose images cannot be read (frame 5: frames/000005_left.png is missing; ...)"."""
    more = f"; {len(problems) - shown} more" if len(problems) > shown else ""
    return (f"{len(problems)} frame{'s' * (len(problems) != 1)} whose images cannot be read "
            f"({'; '.join(problems[:shown])}{more})")


def _write_image(path: Path, image: np.ndarray, ext: str, params: list[int]) -> None:
    ok, data = cv2.imencode(ext, image, params)
    if not ok:
        raise OSError(f"OpenCV could not encode {path.name}")
    tmp = path.with_name(path.stem + ".tmp" + ext)
    tmp.write_bytes(data.tobytes())
    os.replace(tmp, path)


# --- loading --------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SkippedLine:
    """A line of ``frames.jsonl`` that was not read as a frame, and why."""

    line: int  # 1-based
    why: str

    def __str__(self) -> str:
        return f"line {self.line}: {self.why}"


@dataclasses.dataclass
class Run:
    """A run folder read back.

    Attributes:
        path: the folder.
        config: ``config.json`` (the resolved configuration, schedule, estimator settings).
        frames: frame records in order (``frames.jsonl``), each read by ``FrameRecord.from_json``
            (a line that is not a record is skipped and named); the first of a repeated index is kept.
        summary: ``summary.json``, recomputed from the frames where the run was killed (none), it
            is unreadable or not an object, or it disagrees with the frames read.
        complete: whether a readable ``summary.json`` was there (the run finished, or stopped cleanly).
        skipped: lines of ``frames.jsonl`` not read as frames, with why (a killed run's cut-short
            last line, a partial or malformed record, a repeated index).
        summary_note: why the summary was recomputed, or None when ``summary.json`` was used as written.
    """

    path: Path
    config: dict
    frames: list[FrameRecord]
    summary: dict
    complete: bool
    skipped: list[SkippedLine] = dataclasses.field(default_factory=list)
    summary_note: str | None = None
    _cache: dict = dataclasses.field(default_factory=dict, repr=False, compare=False)

    @property
    def skipped_lines(self) -> int:
        return len(self.skipped)

    @property
    def backend(self) -> str:
        backend = self.config.get("backend", "sim")
        return backend if isinstance(backend, str) else "sim"

    @property
    def has_ground_truth(self) -> bool:
        return any(f.gt_m is not None and len(f.gt_m) for f in self.frames)

    @property
    def calibration(self) -> StereoCalibration:
        """The calibration recorded with the run.

        Raises:
            RunFolderError: calibration.toml is missing.
        """
        path = self.path / CALIBRATION_FILE
        if not path.is_file():
            raise RunFolderError(f"{self.path}: no {CALIBRATION_FILE} in the run folder")
        return StereoCalibration.load(path)

    def section(self, *keys: str) -> dict:
        """A table of ``config.json`` (``section("bench", "report")``); {} where it is missing or not an object."""
        table: Any = self.config
        for key in keys:
            table = table.get(key) if isinstance(table, dict) else None
        return dict(table) if isinstance(table, dict) else {}

    def report_options(self) -> dict:
        return self.section("bench", "report")

    def image_problem(self, record: FrameRecord) -> str | None:
        """Why a recorded frame's images cannot be read back ("frame 5: frames/000005_left.png is
        missing"), or None when its files are all there (or it recorded no images)."""
        names = list((record.images or {}).values())
        if record.clean:
            names += list(record.clean.get("background", {}).values())
        for name in names:
            path = self.path / name
            if not path.is_file():
                return f"frame {record.index}: {name} is missing"
            if path.stat().st_size == 0:
                return f"frame {record.index}: {name} is empty"
        return None

    def image_problems(self) -> list[str]:
        """``image_problem`` of every frame that has one, in frame order."""
        return [problem for record in self.frames if (problem := self.image_problem(record)) is not None]

    def image(self, record: FrameRecord, side: str) -> np.ndarray | None:
        """The raw BGR image of one eye of a frame as the estimator saw it, or None when it was not
        recorded (or its file is missing or unreadable).

        On the twin the stored noise-free image is put back on its background and its sensor noise
        drawn again (``record.clean``): the result is the captured image, bit for bit.

        Raises:
            RunFolderError: the run's recorded camera effects (``config.json`` sensor) are unusable.
        """
        name = (record.images or {}).get(side)
        if not name:
            return None
        flags = cv2.IMREAD_UNCHANGED if record.clean else cv2.IMREAD_COLOR
        if not (self.path / name).is_file():
            return None  # said once for the whole run by image_problems, not by OpenCV for every read
        image = cv2.imread(str(self.path / name), flags)
        if image is None or not record.clean:
            return image
        background = self._background(record.clean["background"].get(side))
        origin = record.clean.get("origin", {}).get(side, (0, 0))
        if background is None or image.ndim != background.ndim:
            return None
        try:
            clean = add_patch(background, image, origin)
        except ValueError:
            return None
        return self._noise(side).noisy(clean, _frame_generator(record.clean["seed"], record.clean["index"], side))

    def clean_image(self, record: FrameRecord, side: str) -> np.ndarray | None:
        """The twin's noise-free image of one eye (before the sensor noise), or None (a rig frame, or missing)."""
        name = (record.images or {}).get(side)
        if not name or not record.clean:
            return None
        patch = cv2.imread(str(self.path / name), cv2.IMREAD_UNCHANGED) if (self.path / name).is_file() else None
        background = self._background(record.clean["background"].get(side))
        if patch is None or background is None:
            return None
        return add_patch(background, patch, record.clean.get("origin", {}).get(side, (0, 0)))

    def lossless(self, record: FrameRecord) -> bool:
        return all(str(n).endswith(".png") for n in (record.images or {}).values())

    def depth_units(self, record: FrameRecord) -> tuple[np.ndarray | None, float | None]:
        """The frame's stored left depth as (uint16 units, metres per unit), or (None, None)."""
        info = record.depth
        if not info:
            return None, None
        path = self.path / info["path"]
        units = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
        if units is None:
            return None, None
        if info.get("background"):  # the twin's: the difference from the static scene's depth
            background = self._background(info["background"])
            if background is None:
                return None, None
            try:
                units = add_patch(background, units, info.get("origin", (0, 0)))
            except ValueError:
                return None, None
        return units, float(info.get("unit_m", DEPTH_UNIT_M))

    def depth(self, record: FrameRecord) -> np.ndarray | None:
        """The frame's left depth map in metres (inf: none), or None when not recorded."""
        units, unit_m = self.depth_units(record)
        return None if units is None else dequantize_depth(units, unit_m)

    def _background(self, name: str | None) -> np.ndarray | None:
        if not name:
            return None
        key = ("background", name)
        if key not in self._cache:
            path = self.path / name
            self._cache[key] = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
        return self._cache[key]

    def _noise(self, side: str):
        """The twin's sensor model of one eye, from the run's recorded camera effects (``config.json`` sensor)."""
        key = ("noise", side)
        if key not in self._cache:
            from twin.sensor import CameraEffects, SensorSimulator

            recorded = self.config.get("sensor")
            try:
                effects = CameraEffects(**recorded)
            except (TypeError, ValueError) as e:
                raise RunFolderError(f"{self.path / CONFIG_FILE}: sensor: the twin's camera effects are unusable "
                                     f"({e}); the frames cannot be made noisy again") from e
            calibration = self.calibration
            self._cache[key] = SensorSimulator(effects, calibration.K(side), calibration.image_size,
                                               np.random.default_rng(0))
        return self._cache[key]


def _frame_generator(seed: int, index: int, side: str) -> np.random.Generator:
    from twin.sensor import frame_generator

    return frame_generator(seed, index, side)


def read_frames(path: Path) -> tuple[list[FrameRecord], list[SkippedLine]]:
    """Frame records of a ``frames.jsonl``; every line that is not one is skipped and named.

    A line is skipped when it is not JSON (the last one without its end of line: cut short by a
    kill), when ``FrameRecord.from_json`` finds a missing key or a wrong type, or when its index
    repeats an earlier record's (the first is kept). Blank lines are ignored.

    Returns:
        (records in file order, skipped lines with why).
    """
    records: list[FrameRecord] = []
    skipped: list[SkippedLine] = []
    first_line: dict[int, int] = {}
    with open(path, encoding="utf-8", errors="replace") as f:
        lines = f.read().split("\n")
    # split leaves "" after a final newline; a last line that is not "" had no end of line
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as e:
            cut = number == len(lines)
            why = "cut short (no end of line: the run was killed while writing it)" if cut else f"not JSON ({e})"
            skipped.append(SkippedLine(number, why))
            continue
        try:
            record = FrameRecord.from_json(record)
        except RecordError as e:
            skipped.append(SkippedLine(number, f"not a frame record: {e}"))
            continue
        index = record.index
        if index in first_line:
            skipped.append(SkippedLine(number, f"index {index} again (first on line {first_line[index]}); "
                                               "the first is kept"))
            continue
        first_line[index] = number
        records.append(record)
    return records, skipped


def load_run(path: str | Path) -> Run:
    """Read a run folder, finished or killed.

    A killed run has no ``summary.json``; the summary is then recomputed from the frames (and
    marked ``"stopped": "killed (no summary.json)"``); so is an unreadable one, or one that is
    not a JSON object. A ``summary.json`` whose figures disagree with the frames read (a line
    cut or edited after the run) is recomputed too, keeping what only the run knew (why it
    stopped, its timings); ``Run.summary_note`` says so.

    Raises:
        RunFolderError: not a run folder (no frames.jsonl or config.json), or a config.json that is
            not a JSON object.
    """
    given = Path(path)
    path = resolve_run_folder(path)
    frames_path = path / FRAMES_FILE
    if not path.exists():
        if given.name == LATEST:  # the default RUN: no run has pointed it anywhere yet
            raise RunFolderError(f"{given}: no run yet under {given.parent} (run softarm run first, or name a "
                                 "run folder)")
        raise RunFolderError(f"{path}: no such folder")
    if not path.is_dir():
        raise RunFolderError(f"{path}: a file, not a run folder")
    if not frames_path.is_file():
        raise RunFolderError(f"{path}: not a run folder (no {FRAMES_FILE})")
    config_path = path / CONFIG_FILE
    try:
        config = json.loads(config_path.read_text(encoding="utf-8"))
    except FileNotFoundError as e:
        raise RunFolderError(f"{path}: not a run folder (no {CONFIG_FILE})") from e
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise RunFolderError(f"{config_path}: not valid JSON ({e})") from e
    except OSError as e:
        raise RunFolderError(f"{config_path}: cannot be read ({e})") from e
    if not isinstance(config, dict):
        raise RunFolderError(f"{config_path}: expected a JSON object (the run's configuration), got "
                             f"{_json_kind(config)}")
    frames, skipped = read_frames(frames_path)
    stored, note = _read_summary(path / SUMMARY_FILE)
    if stored is None:
        summary = summarize_run(frames, config)
        summary["stopped"] = note
        return Run(path, config, frames, summary, False, skipped, note)
    wall_s = stored.get("wall_s")
    fresh = summarize_run(frames, config, wall_s=wall_s if isinstance(wall_s, int | float) else None)
    summary = {**stored, **fresh}  # keys the stored summary lacks are filled in from the frames
    differences = [key for key, value in fresh.items() if key in stored and not _same(stored[key], value)]
    if "paper" in stored and "paper" not in fresh:  # a paper-mode summary without paper-mode frames
        differences.append("paper")
        del summary["paper"]
    if not differences:
        return Run(path, config, frames, summary, True, skipped)
    shown = ", ".join(_difference(key, stored[key], fresh[key]) for key in differences[:3])
    more = f" and {len(differences) - 3} more" if len(differences) > 3 else ""
    note = f"{SUMMARY_FILE} disagreed with the {len(frames)} frames read ({shown}{more}); recomputed from the frames"
    return Run(path, config, frames, summary, True, skipped, note)


def _read_summary(path: Path) -> tuple[dict | None, str]:
    """``summary.json`` as an object, or (None, why it cannot be used)."""
    if not path.is_file():
        return None, f"killed (no {SUMMARY_FILE})"
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:  # cut short or edited by hand: the frames hold everything
        return None, f"{SUMMARY_FILE} unreadable ({e}); recomputed from the frames"
    except OSError as e:
        return None, f"{SUMMARY_FILE} cannot be read ({e}); recomputed from the frames"
    if not isinstance(summary, dict):
        return None, f"{SUMMARY_FILE} is not a JSON object ({_json_kind(summary)}); recomputed from the frames"
    return summary, ""


def _json_kind(value: Any) -> str:
    return {list: "a list", str: "a string", int: "a number", float: "a number", bool: "a boolean",
            type(None): "null"}.get(type(value), type(value).__name__)


def _same(stored: Any, fresh: Any) -> bool:
    """Whether a stored summary value is the recomputed one (NaN is stored as null; floats to 1e-9)."""
    fresh = jsonable(fresh)
    if isinstance(fresh, dict):
        return isinstance(stored, dict) and stored.keys() == fresh.keys() and all(
            _same(stored[k], v) for k, v in fresh.items())
    if isinstance(fresh, list):
        return isinstance(stored, list) and len(stored) == len(fresh) and all(
            _same(a, b) for a, b in zip(stored, fresh, strict=True))
    if isinstance(fresh, float) and isinstance(stored, int | float) and not isinstance(stored, bool):
        return math.isclose(stored, fresh, rel_tol=1e-9, abs_tol=1e-12)
    return type(stored) is type(fresh) and stored == fresh


def _difference(key: str, stored: Any, fresh: Any) -> str:
    if isinstance(fresh, int) and isinstance(stored, int | float):
        return f"{key} {stored} there, {fresh} in the frames"
    return key


def summarize_run(frames: list[FrameRecord] | list[Mapping], config: Mapping, *, wall_s: float | None = None) -> dict:
    """The ``summary.json`` of a run's frames (records or their JSON objects): the main estimate, and the
    paper mode if compared."""
    frames = [FrameRecord.coerce(f) for f in frames]
    estimators = config.get("estimators")
    main = estimators.get("main") if isinstance(estimators, Mapping) else None
    main_mode = main.get("mode", "default") if isinstance(main, Mapping) else "default"
    summary = {"backend": config.get("backend"), "mode": main_mode,
               **summarize(frames, wall_s=wall_s)}
    if isinstance(main, Mapping) and main.get("centerline"):
        summary["centerline"] = main["centerline"]  # the 2D stage (a replay may swap the mode's own)
    if any(f.paper is not None for f in frames):
        summary["paper"] = summarize(frames, key="paper", wall_s=wall_s)
    return summary
