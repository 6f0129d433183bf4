"""The bench configuration: one TOML file, a frozen dataclass per section, one generic loader.

``load_bench_config`` reads ``models/bench.toml`` (or a given file) into ``BenchConfig``. Every
section is built by ``build_section``, which needs nothing but the dataclass: the field types
say what each key may hold, ``__post_init__`` checks the values, and any unknown key, missing
key, wrong type or bad value becomes a ``ConfigError`` naming the file and the key. To add a
section, write its dataclass and add one field to ``BenchConfig``::

    @dataclass(frozen=True)
    class RecordingConfig:
        out: Path = Path("../runs")      # written in a file: against its folder; a default: against models/
        lossless: bool = True

    # in BenchConfig:
    recording: RecordingConfig = field(default_factory=RecordingConfig)
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from estimator import EstimatorConfig
from estimator.config_file import ConfigFileError, TableReader, describe, read_toml
from hardware.interfaces import DEFAULT_CLAMP_TOLERANCE, MAX_CLAMP_TOLERANCE
from hardware.protocol import DEFAULT_BAUD
from hardware.zed import ZED_FPS, resolution_name
from models import models_dir

# The shipped configs are package data (``models``), found wherever softarm is installed or run from.
MODELS = models_dir()
DEFAULT_CONFIG = MODELS / "bench.toml"
# Relative paths of the dataclass defaults (``twin.toml``) are those of models/bench.toml, so a
# default resolves against models/ whichever file left the key out.
DEFAULTS_DIR = MODELS
# Where runs go when neither --out nor [recording] root says: runs/ under the working directory.
RUNS_DIR = "runs"
BACKENDS = ("sim", "rig")
CALIBRATION_SUFFIXES = (".conf", ".toml")
EXPERIMENT_KINDS = ("ramp", "step", "sweep", "random")
# The paper's real-time bending experiment (section 5.2): the driven circuits of the three sections.
PAPER_CHANNELS = ("s1_a", "s2_a", "s3")
# The arm's valves and their board channels (models/bench.toml): what [rig.valves] channels defaults to.
ARM_VALVE_CHANNELS = {"s1_a": 0, "s1_b": 1, "s1_c": 2, "s1_d": 3, "s2_a": 4, "s2_b": 5, "s3": 6}

# Bounds of every bench config: generous, but finite, so that an absurd value is a config error
# naming the key before anything is allocated or moved, not a memory error half way into a run.
MAX_FRAMES = 1_000_000            # captures of one run (690 in the paper)
MAX_DURATION_S = 24 * 3600.0      # an experiment, or its lead-in
MAX_PRESSURE_BAR = 10.0           # any pressure (the arm's PMAs take 2.5 bar)
MIN_STEP_BAR = 0.001              # a staircase's step (the board's resolution is 1 mbar)
MAX_CHANNELS = 64                 # valves driven by one experiment
MAX_CHANGES = 100_000             # pressure changes in one schedule (the paper's ramp: 51)
MAX_CAPTURE_RATE_HZ = 10_000.0    # captures per second of the schedule (simulated seconds on the twin)
MAX_CHANGE_RATE_HZ = 1000.0       # pressure changes per second of the schedule (the board takes ~100)
MAX_FPS = 1000.0                  # a recording's assumed frame rate
MAX_BAUD = 20_000_000
MAX_BOARD_CHANNEL = 255


# A config file is missing, not TOML, or has an unknown key or a bad value; the message names file and key.
# The bench's files are read with the project's one reader, so this is the one config error of every file.
ConfigError = ConfigFileError


# --- sections -----------------------------------------------------------------------------


@dataclass(frozen=True)
class SimConfig:
    """``[sim]``: the digital twin.

    Attributes:
        twin: the twin's parameter file (written in the file: against its folder; left out:
            ``models/twin.toml``).
    """

    twin: Path = Path("twin.toml")


@dataclass(frozen=True)
class CameraConfig:
    """``[rig.camera]``: the ZED, or a recording standing in for it.

    Attributes:
        source: device index, device path (``/dev/v4l/by-id/...``), side-by-side video or image folder.
        calibration: Stereolabs ``SN<serial>.conf`` or a softarm calibration ``.toml``.
        resolution: ZED mode: "2K", "FHD", "HD" or "VGA".
        fps: frame rate to request (a device), or to assume (an image folder).
        loop: restart a video or folder at its end (trying the bench on a short recording).
    """

    source: int | Path
    calibration: Path
    resolution: str = "HD"
    fps: float = 60
    loop: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "resolution", resolution_name(self.resolution))
        if isinstance(self.source, int) and self.source < 0:
            raise ValueError(f"source: a device index must be >= 0, got {self.source}")
        if not (math.isfinite(self.fps) and 0 < self.fps <= MAX_FPS):
            raise ValueError(f"fps: expected a frame rate in (0, {MAX_FPS:g}], got {self.fps!r}")
        if self.is_device and self.fps not in ZED_FPS[self.resolution]:
            raise ValueError(f"fps: the ZED offers {', '.join(map(str, ZED_FPS[self.resolution]))} fps at "
                             f"{self.resolution}, got {self.fps:g}")
        if self.calibration.suffix.lower() not in CALIBRATION_SUFFIXES:
            raise ValueError(f"calibration: expected a Stereolabs .conf or a softarm .toml file, got "
                             f"{self.calibration.name!r}")

    @property
    def is_device(self) -> bool:
        """True for a live camera (index or /dev path), False for a recording."""
        return isinstance(self.source, int) or str(self.source).startswith("/dev/")


@dataclass(frozen=True)
class ValvesConfig:
    """``[rig.valves]``: the valve-driver board.

    Attributes:
        port: serial device (``/dev/serial/by-id/...``) or pyserial URL (``socket://host:port``).
        channels: valve name -> board channel index (0-based), in command order (left out: the
            arm's seven valves s1_a .. s3 on channels 0 .. 6, as in models/bench.toml).
        max_pressure_bar: host-side limit on every channel (the board enforces its own too).
        baud: serial rate.
        clamp: clamp set-points slightly out of range (within ``clamp_tolerance``) with a warning
            instead of raising; further out they are refused either way.
        clamp_tolerance: how far outside [0, max_pressure_bar] ``clamp`` reaches, a fraction of
            max_pressure_bar (0.1: 10 %; at most ``hardware.interfaces.MAX_CLAMP_TOLERANCE``).
        reply_timeout_s: how long to wait for each reply before a retry (two retries, then the
            link is lost); a board answers in well under a millisecond, so the default leaves
            room for a busy host, not for a slow board.
    """

    port: str
    # One assignment of valves to board channels: a file's table replaces its base's whole (merged key by
    # key, a partial map would keep the base's other valves and clash with them).
    channels: Mapping[str, int] = field(default_factory=lambda: dict(ARM_VALVE_CHANNELS), metadata={"whole": True})
    max_pressure_bar: float = 2.5
    baud: int = DEFAULT_BAUD
    clamp: bool = False
    clamp_tolerance: float = DEFAULT_CLAMP_TOLERANCE
    reply_timeout_s: float = 0.05

    def __post_init__(self) -> None:
        if not self.port.strip():
            raise ValueError("port: expected a serial device or pyserial URL, got an empty string")
        if not (math.isfinite(self.max_pressure_bar) and 0 < self.max_pressure_bar <= MAX_PRESSURE_BAR):
            raise ValueError(f"max_pressure_bar: expected a pressure in (0, {MAX_PRESSURE_BAR:g}] bar, "
                             f"got {self.max_pressure_bar!r}")
        if not 0 < self.baud <= MAX_BAUD:
            raise ValueError(f"baud: expected a rate in 1 .. {MAX_BAUD}, got {self.baud}")
        if not (math.isfinite(self.clamp_tolerance) and 0 <= self.clamp_tolerance <= MAX_CLAMP_TOLERANCE):
            raise ValueError(f"clamp_tolerance: expected a fraction of max_pressure_bar in "
                             f"[0, {MAX_CLAMP_TOLERANCE:g}], got {self.clamp_tolerance!r}")
        if not (math.isfinite(self.reply_timeout_s) and 0 < self.reply_timeout_s <= 1.0):
            raise ValueError(f"reply_timeout_s: expected 0 < seconds <= 1 (the board's watchdog vents after "
                             f"0.25 s of silence), got {self.reply_timeout_s!r}")
        if not self.channels:
            raise ValueError("channels: expected at least one 'name = board channel' entry")
        for name, index in self.channels.items():
            if not 0 <= index <= MAX_BOARD_CHANNEL:
                raise ValueError(f"channels: {name} = {index}: expected a board channel in 0 .. {MAX_BOARD_CHANNEL} "
                                 "(board channels count from 0)")
        by_index: dict[int, str] = {}
        for name, index in self.channels.items():
            if index in by_index:
                raise ValueError(f"channels: {by_index[index]} and {name} both use board channel {index}")
            by_index[index] = name
        object.__setattr__(self, "channels", types.MappingProxyType(dict(self.channels)))


@dataclass(frozen=True)
class DepthConfig:
    """``[rig.depth]``: depth maps of the left camera (e.g. exported by the ZED SDK) for the paper's Q' metric.

    The bench itself reads the ZED over UVC, which carries no depth; with this section the run
    compares its estimate with a depth map per frame as the paper did (section 5.3).

    Attributes:
        source: folder of single-channel images (16-bit PNG or TIFF, or ``.npy``), one per camera
            frame in name order (a looped recording starts over), aligned with the raw LEFT image.
        scale_m: metres per stored unit (0.001: millimetres, the ZED SDK's 16-bit export).
    """

    source: Path
    scale_m: float = 0.001

    def __post_init__(self) -> None:
        if not (math.isfinite(self.scale_m) and 0 < self.scale_m <= 1.0):
            raise ValueError(f"scale_m: expected metres per unit in (0, 1], got {self.scale_m!r}")


@dataclass(frozen=True)
class RigConfig:
    """``[rig]``: the physical devices (and, optionally, a depth source for the Q' metric).

    ``[rig.valves]`` may be left out where nothing moves (``softarm calibrate`` needs only the
    camera); ``softarm run`` on the rig then stops before opening anything and says so.
    """

    camera: CameraConfig
    valves: ValvesConfig | None = None
    depth: DepthConfig | None = None


@dataclass(frozen=True)
class ExperimentConfig:
    """``[experiment]``: what the valves are commanded and when the camera captures.

    The default is the paper's real-time bending experiment (section 5.2): s1_a, s2_a and s3
    rise together from 0 to 2.5 bar in 0.05 bar steps over 58 s while 690 frames are captured.

    Attributes:
        kind: "ramp" (staircase start -> max in ``step_bar`` steps over the whole duration),
            "step" (start, then max from ``step_at_s`` on), "sweep" (each channel in turn rises
            to max and falls back, one share of the duration each: a per-section sweep),
            "random" (every ``hold_s`` each channel takes a seeded random level on the step grid).
        channels: the valves driven (the others stay vented).
        start_bar, max_bar: lowest and highest commanded pressure.
        step_bar: pressure increment of the ramp and sweep, and the grid of random levels.
        duration_s: length of the experiment (simulated seconds in the twin, real ones on the rig).
        frames: captures spread evenly over the whole experiment, first at 0 s, last at the end
            (``softarm run --frames N`` overrides).
        step_at_s: "step": when the pressure jumps.
        hold_s: "random": how long each random set of levels is held.
        seed: "random": the sequence's seed.
        settle: sim: let the arm come to rest at the start pressures before t = 0.
        quasi_static: sim: after every pressure change run the twin until the arm is at rest
            (a static sweep; simulated time then runs ahead of the schedule's time).
        lead_in_s: hold the start pressures this long before t = 0 (rig: let the arm settle).
    """

    kind: Literal["ramp", "step", "sweep", "random"] = "ramp"
    channels: tuple[str, ...] = PAPER_CHANNELS
    start_bar: float = 0.0
    max_bar: float = 2.5
    step_bar: float = 0.05
    duration_s: float = 58.0
    frames: int = 690
    step_at_s: float = 1.0
    hold_s: float = 2.0
    seed: int = 0
    settle: bool = True
    quasi_static: bool = False
    lead_in_s: float = 0.0

    def __post_init__(self) -> None:
        if not self.channels:
            raise ValueError("channels: expected at least one valve name")
        if len(self.channels) > MAX_CHANNELS:
            raise ValueError(f"channels: expected at most {MAX_CHANNELS} valves, got {len(self.channels)}")
        if len(set(self.channels)) != len(self.channels):
            raise ValueError(f"channels: a valve is listed twice in {list(self.channels)}")
        for name in ("start_bar", "max_bar", "step_bar", "duration_s", "step_at_s", "hold_s", "lead_in_s"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"{name}: expected a finite number, got {value!r}")
        if not 0 <= self.start_bar < self.max_bar <= MAX_PRESSURE_BAR:
            raise ValueError(f"max_bar: expected 0 <= start_bar < max_bar <= {MAX_PRESSURE_BAR:g} bar, got start_bar "
                             f"{self.start_bar:g}, max_bar {self.max_bar:g}")
        if not MIN_STEP_BAR <= self.step_bar <= self.max_bar - self.start_bar:
            raise ValueError(f"step_bar: expected a step in (0, max_bar - start_bar] and at least {MIN_STEP_BAR:g} bar "
                             f"(the board's resolution), got {self.step_bar:g}")
        if not 0 < self.duration_s <= MAX_DURATION_S:
            raise ValueError(f"duration_s: expected a duration in (0, {MAX_DURATION_S:g}] s (24 h), "
                             f"got {self.duration_s:g}")
        problem = frames_problem(self.frames, self.duration_s)
        if problem:
            raise ValueError(f"frames: {problem}")
        if not 0 <= self.step_at_s < (self.duration_s if self.kind == "step" else math.inf):
            # only the step uses it: another kind keeps its default whatever its duration
            raise ValueError(f"step_at_s: expected a time in [0, duration_s), got {self.step_at_s:g}")
        if self.hold_s <= 0:
            raise ValueError(f"hold_s: expected a positive duration, got {self.hold_s:g}")
        if not 0 <= self.lead_in_s <= MAX_DURATION_S:
            raise ValueError(f"lead_in_s: expected a duration in [0, {MAX_DURATION_S:g}] s (24 h), "
                             f"got {self.lead_in_s:g}")
        if self.seed < 0:
            raise ValueError(f"seed: expected an integer >= 0, got {self.seed}")
        self._check_changes()

    def change_count(self) -> int:
        """Pressure changes of the schedule (its length), known before anything is allocated."""
        if self.kind == "step":
            return 1 if self.step_at_s == 0 else 2
        if self.kind == "random":
            return max(1, math.ceil(self.duration_s / self.hold_s - 1e-9))
        levels = staircase_count(self.start_bar, self.max_bar, self.step_bar)
        return levels if self.kind == "ramp" else len(self.channels) * (2 * levels - 1)

    def _check_changes(self) -> None:
        """The schedule's length and its rate of pressure changes, derived from several keys."""
        key = {"random": "hold_s", "step": "duration_s"}.get(self.kind, "step_bar")
        what = {"ramp": "(max_bar - start_bar) / step_bar levels",
                "sweep": "(max_bar - start_bar) / step_bar levels up and down on every channel",
                "random": "duration_s / hold_s random levels", "step": "a step"}[self.kind]
        changes = self.change_count()
        if changes > MAX_CHANGES:
            raise ValueError(f"{key}: {what} make {changes} pressure changes; expected at most {MAX_CHANGES}")
        rate = changes / self.duration_s
        if rate > MAX_CHANGE_RATE_HZ:
            raise ValueError(f"{key}: {what} over duration_s = {self.duration_s:g} s make {rate:.4g} pressure changes "
                             f"per second; expected at most {MAX_CHANGE_RATE_HZ:g}")


def staircase_count(start_bar: float, max_bar: float, step_bar: float) -> int:
    """Levels of the staircase start, start + step, ... up to max (max itself included even off the grid)."""
    on_grid = math.floor((max_bar - start_bar) / step_bar + 1e-9) + 1
    last = start_bar + step_bar * (on_grid - 1)
    return on_grid + (1 if max_bar - last > 1e-9 else 0)


def frames_problem(frames: int, duration_s: float) -> str | None:
    """What is wrong with ``frames`` captures over ``duration_s`` seconds (count and rate), or None."""
    if frames < 1:
        return f"expected at least one frame, got {frames} (allowed: 1 to {MAX_FRAMES})"
    if frames > MAX_FRAMES:
        return f"expected at most {MAX_FRAMES} frames, got {frames} (allowed: 1 to {MAX_FRAMES})"
    rate = (frames - 1) / duration_s
    if rate > MAX_CAPTURE_RATE_HZ:
        return (f"{frames} frames over duration_s = {duration_s:g} s is {rate:.4g} captures per second; "
                f"expected at most {MAX_CAPTURE_RATE_HZ:g}")
    return None


@dataclass(frozen=True)
class RecordingConfig:
    """``[recording]``: the run folder.

    Attributes:
        root: where ``softarm run`` creates its time-stamped folder (``--out`` overrides; left
            out, None: ``runs/`` under the working directory, see ``runs_root``).
        lossless_frames: raw stereo frames as PNG (lossless: the run can be replayed exactly);
            false writes JPEG (a fraction of the size; enough for the report, not for replay).
        png_compression: zlib level 0-9 of the PNGs (1: fast; the sensor noise barely compresses).
        png_strategy: zlib strategy: "huffman" (no string matching: on noisy camera images a quarter
            faster than "default" and smaller), "rle" or "default".
        jpeg_quality: JPEG quality when ``lossless_frames`` is false.
        depth: sim: keep the rendered left depth map (16-bit PNG, 0.1 mm) so a replay or the
            report can compute the paper's Q' metric again.
    """

    root: Path | None = None
    lossless_frames: bool = True
    png_compression: int = 1
    png_strategy: Literal["huffman", "rle", "default"] = "huffman"
    jpeg_quality: int = 95
    depth: bool = True

    def runs_root(self) -> Path:
        """The folder new runs go in: ``root``, or ``runs/`` under the working directory (resolved now)."""
        return Path(self.root) if self.root is not None else Path.cwd() / RUNS_DIR

    def __post_init__(self) -> None:
        if not 0 <= self.png_compression <= 9:
            raise ValueError(f"png_compression: expected a zlib level 0-9, got {self.png_compression}")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality: expected 1-100, got {self.jpeg_quality}")


@dataclass(frozen=True)
class ReportConfig:
    """``[report]``: what ``softarm report`` (and the end of ``softarm run``) draws.

    Attributes:
        enabled: write the report at the end of ``softarm run`` (``--no-report`` skips it).
        video: write the overlay video (MP4).
        video_scale: size of the video relative to the camera image.
        selected_frames: frames drawn over one image in Fig 10a, b (the paper printed 20).
        centerline_frames: frames drawn in 3D in Fig 10c.
        compensation_frames: frames on which Fig 12 re-runs the paper mode with and without
            misalignment compensation (evenly spread; 0 skips the re-run).
    """

    enabled: bool = True
    video: bool = True
    video_scale: float = 0.5
    selected_frames: int = 20
    centerline_frames: int = 6
    compensation_frames: int = 60

    def __post_init__(self) -> None:
        if not (math.isfinite(self.video_scale) and 0.05 <= self.video_scale <= 1.0):
            raise ValueError(f"video_scale: expected a factor in [0.05, 1], got {self.video_scale!r}")
        for name in ("selected_frames", "centerline_frames", "compensation_frames"):
            if not 0 <= getattr(self, name) <= MAX_FRAMES:
                raise ValueError(f"{name}: expected a count in 0 .. {MAX_FRAMES}, got {getattr(self, name)}")


@dataclass(frozen=True)
class BenchConfig:
    """The whole file. ``path`` is the file it came from (not a key)."""

    path: Path = field(default=DEFAULT_CONFIG, metadata={"from_file": False})
    backend: Literal["sim", "rig"] = "sim"
    sim: SimConfig = field(default_factory=SimConfig)
    rig: RigConfig | None = None
    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    # ``[estimator]``: keys of ``estimator.EstimatorConfig`` (mode, centerline, n_points, ...), checked on load.
    estimator: Mapping[str, Any] = field(default_factory=dict)
    recording: RecordingConfig = field(default_factory=RecordingConfig)
    report: ReportConfig = field(default_factory=ReportConfig)

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f"backend: expected one of {', '.join(map(repr, BACKENDS))}, got {self.backend!r}")
        if self.backend == "rig" and self.rig is None:
            raise ValueError("rig: backend 'rig' needs a [rig] section with [rig.camera] (and [rig.valves] to run "
                             "experiments)")
        object.__setattr__(self, "estimator", types.MappingProxyType(dict(self.estimator)))
        # unknown keys and bad values fail on load, naming [estimator] and the key
        EstimatorConfig.from_dict(dict(self.estimator), source="[estimator]")

    def estimator_config(self, mode: str | None = None, **changes: Any) -> EstimatorConfig:
        """The ``[estimator]`` table as an ``EstimatorConfig``, optionally in another mode or with changes.

        Raises:
            ValueError: an unknown key or a bad value; the message names ``[estimator]`` and the key.
        """
        table = {**self._twin_arm(), **self.estimator}
        if mode is not None:
            table["mode"] = mode  # the file's other keys stay; the new mode's presets fill the rest
        table.update(changes)
        return EstimatorConfig.from_dict(table, source="[estimator]")

    def _twin_arm(self) -> dict[str, float]:
        """On the twin, the estimator is told the twin's arm (its config is all it knows of the geometry):
        ``arm_length_m``, ``arm_radius_m`` and the rest of ``_twin_tube`` from the arm file the twin
        names, unless [estimator] sets them; nothing on the rig. Read when first asked (a config for the
        rig need not find a twin).

        Raises:
            ConfigError: the twin file or its arm file is missing or bad; names this file and [sim] twin.
        """
        if self.backend != "sim":
            return {}
        if not hasattr(self, "_arm"):
            try:
                object.__setattr__(self, "_arm", _twin_tube(self.sim.twin))
            except ConfigFileError as e:
                raise ConfigError(f"{self.path}: [sim] twin: {e}") from e
        return self._arm


def _twin_tube(twin_toml: Path) -> dict:
    """``arm_length_m`` and ``arm_radius_m`` of the arm the twin file names (``twin.params.tube_of``),
    ``base_mount`` (the twin's arm hangs from its base mount), and where it has more than one section
    ``connector_radius_m`` (its baseplates') and ``section_lengths_m`` (what its sections can reach,
    ``twin.params.section_length_ranges_m``)."""
    from twin.params import ArmParams, section_length_ranges_m, tube_of, twin_arm_file

    arm = ArmParams.load(twin_arm_file(twin_toml))
    length, radius = tube_of(arm)
    joined = ({"connector_radius_m": arm.baseplate.radius_m, "section_lengths_m": section_length_ranges_m(arm)}
              if len(arm.sections) > 1 else {})
    return {"arm_length_m": length, "arm_radius_m": radius, "base_mount": True, **joined}


# --- loading ------------------------------------------------------------------------------

# A config file may name another it changes: ``base = "bench.toml"``. The base's keys come first, this
# file's replace them (table by table); the base is a config of its own, checked on its own.
BASE_KEY = "base"
MAX_BASE_DEPTH = 8


def load_bench_config(path: str | Path | None = None, *, backend: str | None = None) -> BenchConfig:
    """Read a bench config.

    Relative paths written in a file resolve against that file's folder; keys and sections the
    file (and its ``base``) leaves out take the defaults of ``models/bench.toml``, whose paths
    resolve against ``models/`` (a file elsewhere that omits ``[sim]`` still gets the shipped
    ``twin.toml``); ``[recording] root`` left out is ``runs/`` under the working directory.

    Args:
        path: the TOML file; None for ``models/bench.toml``.
        backend: override the file's ``backend`` ("sim" or "rig").

    Raises:
        ConfigError: the file (or its base) is missing or not TOML, or a key is unknown, missing,
            of the wrong type or has a bad value; the message names the file and the key.
    """
    path = Path(path) if path is not None else DEFAULT_CONFIG
    data = _read_config(path, ())
    config = build_section(BenchConfig, data, path, context={"path": path.resolve()})
    if backend is not None:
        try:
            config = dataclasses.replace(config, backend=backend)
        except ValueError as e:
            raise ConfigError(f"{path} with the backend override: {e}") from e
    return config


def _read_config(path: Path, chain: tuple[Path, ...]) -> dict:
    """The TOML of ``path`` merged over its base's (recursively), the base's relative paths made absolute."""
    data = read_toml(path, "config", ConfigError)
    if BASE_KEY not in data:
        return data
    top = TableReader(path, data, error=ConfigError)
    base = top.take(BASE_KEY, _base_file(path.parent))
    data = {k: v for k, v in data.items() if k != BASE_KEY}
    if base.resolve() in chain or base.resolve() == path.resolve() or len(chain) >= MAX_BASE_DEPTH:
        raise top.error(BASE_KEY, f"{base} leads back to this file (a cycle: "
                                  f"{' -> '.join(str(p) for p in (*chain, path.resolve(), base.resolve()))})")
    if not base.is_file():
        raise top.error(BASE_KEY, f"{base}: config file not found")
    chain = (*chain, path.resolve())
    base_data = _read_config(base, chain)
    build_section(BenchConfig, base_data, base, context={"path": base.resolve()})  # the base's errors name it
    return _merged(_absolute_paths(BenchConfig, base_data, base.parent), data, BenchConfig)


def _base_file(folder: Path):
    def convert(value: Any) -> Path:
        if not isinstance(value, str) or not value.strip():
            raise TypeError(f"expected the config file this one changes, got {describe(value)}")
        return _resolve(Path(value), folder)

    return convert


def _merged(base: dict, changes: dict, cls: Any = None) -> dict:
    """``base`` with ``changes`` applied: tables merge key by key, every other value is replaced, and so is a
    table its field (of the dataclass ``cls``) marks ``whole`` (a complete assignment such as a channel map)."""
    fields_ = {f.name: f for f in dataclasses.fields(cls)} if dataclasses.is_dataclass(cls) else {}
    hints = typing.get_type_hints(cls) if fields_ else {}
    out = dict(base)
    for key, value in changes.items():
        f = fields_.get(key)
        if not (isinstance(value, dict) and isinstance(out.get(key), dict)) or (f and f.metadata.get("whole")):
            out[key] = value
            continue
        options = [a for a in typing.get_args(hints.get(key)) if a is not type(None)] or [hints.get(key)]
        out[key] = _merged(out[key], value, next((o for o in options if dataclasses.is_dataclass(o)), None))
    return out


def _absolute_paths(cls: Any, table: dict, folder: Path) -> dict:
    """``table`` (of the dataclass ``cls``) with its relative path strings made absolute against ``folder``,
    so a base's paths keep meaning what they meant in the base once merged into another file."""
    hints = typing.get_type_hints(cls)
    out = dict(table)
    for f in dataclasses.fields(cls):
        if f.name not in out:
            continue
        options = [a for a in typing.get_args(hints[f.name]) if a is not type(None)] or [hints[f.name]]
        value = out[f.name]
        nested = next((o for o in options if dataclasses.is_dataclass(o)), None)
        if nested is not None and isinstance(value, dict):
            out[f.name] = _absolute_paths(nested, value, folder)
        elif Path in options and isinstance(value, str) and value:
            out[f.name] = str(_resolve(Path(value), folder))
    return out


_T = typing.TypeVar("_T")


def build_section(cls: type[_T], table: Any, path: Path, section: str = "", *,
                  context: Mapping[str, Any] | None = None, defaults_dir: Path = DEFAULTS_DIR) -> _T:
    """Build the frozen dataclass ``cls`` from a TOML table, checking every key against its fields.

    Field types drive the conversion: ``bool``, ``int``, ``float`` (ints accepted), ``str``,
    ``Path`` (relative paths written in the table resolve against ``path``'s folder, those of
    the dataclass defaults against ``defaults_dir``),
    ``Literal[...]``, unions such as ``int | Path`` or ``X | None``, ``tuple[X, ...]``,
    ``Mapping[str, X]`` and nested dataclasses (sub-tables, built recursively; a missing
    sub-table takes the field's default, or is built from an empty table when there is none). Fields with
    ``metadata={"from_file": False}`` are not keys; they come from ``context``. The table is read
    with the project's one reader (``estimator.config_file.TableReader``), so messages name the
    file and the key as every config file's do.

    Args:
        cls: a dataclass whose ``__post_init__`` raises ``ValueError("<key>: <problem>")``.
        table: the parsed TOML table.
        path: the config file (for messages and relative paths).
        section: dotted name of the table ("" for the top level, "rig.camera").
        context: values of the fields that do not come from the file.
        defaults_dir: the folder the defaults' relative paths are relative to (``models/``, where
            the default config lives).

    Raises:
        ConfigError: an unknown key, a missing required key, a value of the wrong type, or a
            value ``__post_init__`` rejects; the message names the file and the key.
    """
    reader = TableReader(path, table, section or None, error=ConfigError, key_word="")
    hints = typing.get_type_hints(cls)
    keys = {f.name: f for f in dataclasses.fields(cls) if f.init and f.metadata.get("from_file", True)}
    reader.only(keys)
    values = dict(context or {})
    for name, f in keys.items():
        hint = hints[name]
        if reader.has(name):
            values[name] = reader.take(name, lambda value, hint=hint, name=name: _convert(value, hint, reader, name,
                                                                                          defaults_dir))
        elif f.default is not dataclasses.MISSING:
            values[name] = _resolve_default(f.default, defaults_dir)
        elif f.default_factory is not dataclasses.MISSING:
            values[name] = _resolve_default(f.default_factory(), defaults_dir)
        elif dataclasses.is_dataclass(hint):
            # names its missing keys
            values[name] = build_section(hint, {}, path, reader.child(name), defaults_dir=defaults_dir)
        else:
            raise reader.missing(name)
    try:
        return cls(**values)
    except ValueError as e:
        raise reader.fail(_with_section(str(e), reader.section)) from e


def _with_section(message: str, section: str | None) -> str:
    """Prefix a ``__post_init__`` message's leading key with the section, e.g. "[rig.camera] fps: ..."."""
    return f"[{section}] {message}" if section and not message.startswith("[") else message


def _convert(value: Any, hint: Any, reader: TableReader, key: str, defaults_dir: Path) -> Any:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        for option in options:  # the first option of the value's TOML type; its own errors stand
            if _fits(value, option):
                return _convert(value, option, reader, key, defaults_dir)
        raise reader.error(key, f"expected {' or '.join(map(_expected, options))}, got {describe(value)}")
    if not _fits(value, hint) or (hint is Path and not value):
        raise reader.error(key, f"expected {_expected(hint)}, got {describe(value)}")
    if dataclasses.is_dataclass(hint):
        return build_section(hint, value, reader.path, reader.child(key), defaults_dir=defaults_dir)
    if origin is tuple:
        item = args[0] if args else Any
        return tuple(_convert(v, item, reader, f"{key}[{i}]", defaults_dir) for i, v in enumerate(value))
    if _is_mapping(hint):
        item = args[1] if len(args) == 2 else Any
        return {str(k): _convert(v, item, reader, f"{key}.{k}", defaults_dir) for k, v in value.items()}
    if hint is float:
        if not math.isfinite(value):  # TOML writes inf and nan; no key of the bench takes them
            raise reader.error(key, f"expected a finite number, got {value!r}")
        return float(value)
    if hint is Path:
        return _resolve(Path(value), reader.path.resolve().parent)
    return value


# TOML value types each scalar field type accepts (float takes integers too).
_SCALARS = {bool: (bool,), int: (int,), float: (int, float), str: (str,), Path: (str,), Any: (object,)}


def _fits(value: Any, hint: Any) -> bool:
    """Whether a TOML value has the shape ``hint`` takes (before its contents are checked)."""
    origin = typing.get_origin(hint)
    if origin is Literal:
        return value in typing.get_args(hint)
    if dataclasses.is_dataclass(hint) or _is_mapping(hint):
        return isinstance(value, dict)
    if origin is tuple:
        return isinstance(value, list)
    if hint not in _SCALARS:
        raise TypeError(f"build_section: the loader does not know the field type {hint!r}")
    # Any takes booleans too: what such a field holds is checked where it is used (the estimator's table)
    return isinstance(value, _SCALARS[hint]) and (hint in (bool, Any) or not isinstance(value, bool))


def _is_mapping(hint: Any) -> bool:
    return typing.get_origin(hint) in (dict, Mapping) or hint in (dict, Mapping)


def _expected(hint: Any) -> str:
    if typing.get_origin(hint) is Literal:
        return "one of " + ", ".join(map(repr, typing.get_args(hint)))
    if dataclasses.is_dataclass(hint) or _is_mapping(hint):
        return "a table"
    if typing.get_origin(hint) is tuple:
        return "an array"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string",
            Path: "a path string", Any: "a value"}.get(hint, str(hint))


def _resolve_default(value: Any, defaults_dir: Path) -> Any:
    """A field's default with its relative paths (nested sections' too) resolved against ``defaults_dir``."""
    if isinstance(value, Path):
        return _resolve(value, defaults_dir)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        changes = {}
        for f in dataclasses.fields(value):
            if f.init and f.metadata.get("from_file", True):
                old = getattr(value, f.name)
                new = _resolve_default(old, defaults_dir)
                if new is not old:
                    changes[f.name] = new
        return dataclasses.replace(value, **changes) if changes else value
    return value


def _resolve(value: Path, folder: Path) -> Path:
    value = value.expanduser()
    return value if value.is_absolute() else (Path(folder).resolve() / value)
