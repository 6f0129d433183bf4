"""The run folder: written frame by frame so that a killed run keeps its frames, loaded tolerantly.

Layout (every file readable by a person; ``load_run`` reads it back)::

    RUN/
      config.json        the resolved configuration, the schedule, the estimator settings, argv
      bench.toml         a copy of the config file the run was started with
      calibration.toml   the camera calibration the frames were estimated with
      frames.jsonl       one JSON object per frame, appended and flushed as the run goes
      frames/000042_left.png, 000042_right.png   raw stereo frames (lossless PNG, or JPEG)
      frames/000042_depth.png                    sim: left depth, uint16 in 0.1 mm (0 = none)
      summary.json       written at the end (a killed run has none: ``load_run`` recomputes it)
      report/            written by ``softarm report``

``config.json`` and ``calibration.toml`` are written before ``frames.jsonl`` is created (pass
them to ``RunWriter``), so every folder holding a ``frames.jsonl`` can be loaded, even one killed
before its first frame. A frame's files are written first (each to a temporary name, then
renamed), its line in ``frames.jsonl`` last, by one background thread; ``RunWriter.submit``
waits for the previous frame to be on disk before handing over the next, so at any moment at
most one frame is in flight: a SIGKILL loses at most the frame being written, and every line in
``frames.jsonl`` has its images. A line cut short by the kill is skipped by the loader.
"""

from __future__ import annotations

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
from bench.scoring import DEPTH_UNIT_M, dequantize_depth, summarize
from estimator import StereoCalibration

FRAMES_FILE = "frames.jsonl"
SUMMARY_FILE = "summary.json"
CONFIG_FILE = "config.json"
CALIBRATION_FILE = "calibration.toml"
FRAMES_DIR = "frames"
FORMAT_VERSION = 1
_PNG_STRATEGIES = {"huffman": cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY, "rle": cv2.IMWRITE_PNG_STRATEGY_RLE,
                   "default": cv2.IMWRITE_PNG_STRATEGY_DEFAULT}


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

    # --- start ----------------------------------------------------------------------------

    def write_config(self, config: Mapping[str, Any], source: Path | None = None) -> None:
        """``config.json`` (resolved) and a copy of the source TOML."""
        write_json(self.folder / CONFIG_FILE, {"format": FORMAT_VERSION, **config})
        if source is not None and Path(source).is_file():
            (self.folder / "bench.toml").write_text(Path(source).read_text(encoding="utf-8"), encoding="utf-8")

    def write_calibration(self, calibration: StereoCalibration) -> None:
        calibration.save(self.folder / CALIBRATION_FILE)

    # --- frames ---------------------------------------------------------------------------

    def submit(self, record: dict, left: np.ndarray | None, right: np.ndarray | None,
               depth_units: np.ndarray | None = None) -> float:
        """Hand one frame to the writer thread, after the previous frame is on disk.

        Args:
            record: the frame's JSON record (``index`` required); image paths are added to it.
            left, right: raw BGR images, or None to store none.
            depth_units: uint16 left depth (``bench.scoring.quantize_depth``), or None.

        Returns:
            Milliseconds spent waiting for the previous frame.

        Raises:
            OSError: writing the previous frame failed (disk full, ...).
        """
        waited = self.flush()
        self._pending = self._pool.submit(self._write_frame, record, left, right, depth_units)
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

    def _write_frame(self, record: dict, left, right, depth_units) -> None:
        start = time.perf_counter()
        index = int(record["index"])
        images = {}
        if left is not None and right is not None:
            ext = ".png" if self.recording.lossless_frames else ".jpg"
            params = ([cv2.IMWRITE_PNG_COMPRESSION, self.recording.png_compression,
                       cv2.IMWRITE_PNG_STRATEGY, _PNG_STRATEGIES[self.recording.png_strategy]] if ext == ".png"
                      else [cv2.IMWRITE_JPEG_QUALITY, self.recording.jpeg_quality])
            for side, image in (("left", left), ("right", right)):
                name = f"{FRAMES_DIR}/{index:06d}_{side}{ext}"
                _write_image(self.folder / name, image, ext, params)
                images[side] = name
        if depth_units is not None:
            name = f"{FRAMES_DIR}/{index:06d}_depth.png"
            _write_image(self.folder / name, depth_units, ".png", [cv2.IMWRITE_PNG_COMPRESSION, 1])
            record["depth"] = {"path": name, "unit_m": DEPTH_UNIT_M}
        if images:
            record["images"] = images
        record["write_ms"] = round((time.perf_counter() - start) * 1e3, 3)
        self._lines.write(json.dumps(jsonable(record), separators=(",", ":")) + "\n")
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


def _write_image(path: Path, image: np.ndarray, ext: str, params: list[int]) -> None:
    ok, data = cv2.imencode(ext, image, params)
    if not ok:
        raise OSError(f"OpenCV could not encode {path.name}")
    tmp = path.with_name(path.stem + ".tmp" + ext)
    tmp.write_bytes(data.tobytes())
    os.replace(tmp, path)


# --- loading --------------------------------------------------------------------------------


@dataclasses.dataclass
class Run:
    """A run folder read back.

    Attributes:
        path: the folder.
        config: ``config.json`` (the resolved configuration, schedule, estimator settings).
        frames: frame records in order (``frames.jsonl``), a cut-short last line skipped.
        summary: ``summary.json``, or one recomputed from the frames when the run was killed.
        complete: whether ``summary.json`` was there (the run finished, or stopped cleanly).
        skipped_lines: lines of ``frames.jsonl`` that could not be read (a killed run's last one).
    """

    path: Path
    config: dict
    frames: list[dict]
    summary: dict
    complete: bool
    skipped_lines: int = 0

    @property
    def backend(self) -> str:
        return self.config.get("backend", "sim")

    @property
    def has_ground_truth(self) -> bool:
        return any(f.get("gt_m") for f in self.frames)

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

    def report_options(self) -> dict:
        return dict(self.config.get("bench", {}).get("report", {}))

    def image(self, record: Mapping, side: str) -> np.ndarray | None:
        """The raw BGR image of one eye of a frame, or None when it was not recorded (or is missing)."""
        name = record.get("images", {}).get(side)
        if not name:
            return None
        image = cv2.imread(str(self.path / name), cv2.IMREAD_COLOR)
        return image

    def lossless(self, record: Mapping) -> bool:
        return all(str(n).endswith(".png") for n in record.get("images", {}).values())

    def depth(self, record: Mapping) -> np.ndarray | None:
        """The frame's left depth map in metres (inf: none), or None when not recorded."""
        info = record.get("depth")
        if not info:
            return None
        units = cv2.imread(str(self.path / info["path"]), cv2.IMREAD_UNCHANGED)
        return None if units is None else dequantize_depth(units, info.get("unit_m", DEPTH_UNIT_M))


def read_frames(path: Path) -> tuple[list[dict], int]:
    """Frame records of a ``frames.jsonl``; lines that are not complete JSON objects are skipped.

    Returns:
        (records, number of skipped lines).
    """
    records, skipped = [], 0
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                skipped += 1
                continue
            if isinstance(record, dict) and "index" in record:
                records.append(record)
            else:
                skipped += 1
    return records, skipped


def load_run(path: str | Path) -> Run:
    """Read a run folder, finished or killed.

    A killed run has no ``summary.json``; the summary is then recomputed from the frames (and
    marked ``"stopped": "killed (no summary.json)"``); so is an unreadable one.

    Raises:
        RunFolderError: not a run folder.
    """
    path = Path(path)
    frames_path = path / FRAMES_FILE
    if not frames_path.is_file():
        raise RunFolderError(f"{path}: not a run folder (no {FRAMES_FILE})")
    try:
        config = json.loads((path / CONFIG_FILE).read_text(encoding="utf-8"))
    except FileNotFoundError as e:
        raise RunFolderError(f"{path}: not a run folder (no {CONFIG_FILE})") from e
    except json.JSONDecodeError as e:
        raise RunFolderError(f"{path / CONFIG_FILE}: not valid JSON ({e})") from e
    frames, skipped = read_frames(frames_path)
    summary_path = path / SUMMARY_FILE
    complete = summary_path.is_file()
    summary = None
    if complete:
        try:
            summary = json.loads(summary_path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as e:  # cut short or edited by hand: the frames still hold everything
            complete = False
            reason = f"{SUMMARY_FILE} unreadable ({e}); recomputed from the frames"
    else:
        reason = f"killed (no {SUMMARY_FILE})"
    if summary is None:
        summary = summarize_run(frames, config)
        summary["stopped"] = reason
    return Run(path, config, frames, summary, complete, skipped)


def summarize_run(frames: list[dict], config: Mapping, *, wall_s: float | None = None) -> dict:
    """The ``summary.json`` of a run's frames: the main estimate, and the paper mode if compared."""
    main_mode = config.get("estimators", {}).get("main", {}).get("mode", "default")
    summary = {"backend": config.get("backend"), "mode": main_mode,
               **summarize(frames, wall_s=wall_s)}
    if any("paper" in f for f in frames):
        summary["paper"] = summarize(frames, key="paper", wall_s=wall_s)
    return summary
