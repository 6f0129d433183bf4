"""One twin episode: a bending sequence in one lab scene, every frame estimated and scored.

``sequence_episode(spec)`` is a pure function of its :class:`SequenceSpec`: it makes its own twin
(the configured one, seeing ``spec.preset`` drawn from ``spec.scene_seed``), runs the experiment
with ``spec.frames`` captures spread over it through the bench's capture loop, and hands every
capture to ``bench.process.process`` with the spec's estimators (``main``, and ``paper`` beside it:
both on the same rendered frames, each warm-started along the sequence as in a run). It returns the
frame records as JSON objects (``FrameRecord.to_json``: plain, picklable, the layout of a run's
``frames.jsonl``), so the robustness study, the sweep and the accuracy study read them as a run's.

A spec holds only plain values (the experiment section, estimator tables, the twin's file), so it
travels to a worker process or a Ray node; the shipped model files are named relative to the
``models`` package and found again wherever softarm is installed there.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bench.config import BenchConfig, ExperimentConfig
from bench.devices import Devices, FrameArchive, Observation, Stop, TwinClock, TwinTruth
from models import models_dir

# A twin file inside the models package is shipped as "models:<name>" (found again on every node).
_MODELS_PREFIX = "models:"
# The image a study draws for a condition is shrunk by this (a 1280x720 eye: 640x360) before it travels.
FIGURE_SCALE = 0.5


@dataclasses.dataclass(frozen=True)
class SequenceSpec:
    """One episode: the twin's experiment in one scene, estimated by one or two estimators.

    Attributes:
        twin: the twin's parameter file (``portable_path``).
        experiment: the ``[experiment]`` section (what the valves do, when the camera captures).
        frames: captures spread evenly over the experiment.
        preset: the scene preset the camera sees (``models/scene.toml``).
        scene_seed: seed of the scene's textures and of the ``random`` preset's draw.
        estimators: "main" (and optionally "paper") -> an ``EstimatorConfig`` table (``as_dict``).
        figure_frame: the frame whose left image comes back (shrunk) for a figure, or None.
        keep_frames: return every raw stereo pair too (a study that works on the images themselves).
        cache: keep the rendered captures in this process for the next episode of the same scene
            (a sweep runs many estimator settings on each scene); the results do not change.
        tag: the study's own label for the episode (condition, parameter set); not used here.
    """

    twin: str
    experiment: ExperimentConfig
    frames: int
    preset: str
    scene_seed: int
    estimators: Mapping[str, Mapping[str, Any]]
    figure_frame: int | None = None
    keep_frames: bool = False
    cache: bool = False
    tag: Any = None

    def scene_key(self) -> tuple:
        """What the rendered frames depend on."""
        return (self.twin, self.experiment, self.frames, self.preset, self.scene_seed)


def portable_path(path: str | Path) -> str:
    """``path`` as a spec carries it: "models:<name>" for a shipped model file, else the absolute path."""
    path = Path(path).resolve()
    try:
        return _MODELS_PREFIX + path.relative_to(models_dir().resolve()).as_posix()
    except ValueError:
        return str(path)


def local_path(portable: str) -> Path:
    """The file a ``portable_path`` names, on this machine."""
    if portable.startswith(_MODELS_PREFIX):
        return models_dir() / portable[len(_MODELS_PREFIX):]
    return Path(portable)


def sequence_spec(config: BenchConfig, *, frames: int, preset: str, scene_seed: int,
                  estimators: Mapping[str, Mapping[str, Any]], **kwargs: Any) -> SequenceSpec:
    """The spec of an episode of ``config``'s twin and experiment."""
    return SequenceSpec(portable_path(config.sim.twin), config.experiment, int(frames), str(preset), int(scene_seed),
                        {k: dict(v) for k, v in estimators.items()}, **kwargs)


def twin_config(spec: SequenceSpec):
    """The twin's configuration with the spec's scene.

    Raises:
        ConfigFileError: the twin file, or the preset, is bad (names the file and the key).
    """
    from twin.twin import TwinConfig

    config = TwinConfig.load(local_path(spec.twin))
    config = dataclasses.replace(config, scene_preset=spec.preset, scene_seed=spec.scene_seed)
    config.scene()  # an unknown preset fails here, naming scene.toml's presets
    return config


class _NoArchive(FrameArchive):
    """An episode keeps no frame files: the records are its result."""

    def store(self, frame, observation):
        return None


class _BackboneTruth(TwinTruth):
    """The twin's exact backbone, chamber pressures and time, without the depth map (no Q' in a study)."""

    def observe(self, frame) -> Observation:
        start = time.perf_counter()
        gt = self.twin.frame_backbone()
        channels = self.twin.valves.channels
        chamber = {k: round(float(v), 6) for k, v in zip(channels, self.twin.sim.chamber_bar, strict=True)}
        return Observation(gt_m=gt, chamber_bar=chamber, sim_time_s=float(self.twin.time_s),
                           timings_ms={"truth": (time.perf_counter() - start) * 1e3})


def _captures(spec: SequenceSpec):
    """(calibration, the episode's captures), rendered by a twin of its own (closed when they end)."""
    from bench.capture import captures
    from bench.experiments import make_schedule
    from twin import Twin

    schedule = make_schedule(spec.experiment, frames=spec.frames)
    twin = Twin(twin_config(spec))
    devices = Devices(twin.camera, twin.valves, TwinClock(twin), _BackboneTruth(twin), _NoArchive(), twin,
                      grab_name="render")

    def run() -> Iterator:
        try:
            yield from captures(devices, schedule, spec.experiment, Stop())
        finally:
            devices.close()

    return twin.camera.calibration, run()


# One rendered sequence kept per process for ``SequenceSpec.cache`` (a sweep's next settings on the same scene).
_CACHE: dict[tuple, tuple] = {}


def _rendered(spec: SequenceSpec):
    if not spec.cache:
        return _captures(spec)
    key = spec.scene_key()
    if key not in _CACHE:
        _CACHE.clear()
        calibration, frames = _captures(spec)
        _CACHE[key] = (calibration, list(frames))
    return _CACHE[key]


def sequence_episode(spec: SequenceSpec) -> dict[str, Any]:
    """Run one episode (see the module docstring).

    Returns:
        ``{"records": [FrameRecord JSON, ...], "figure": {"index", "scale", "left"} or None,
        "frames": [(left, right), ...] or None, "image_size": [w, h]}``; ``left`` is the shrunk raw left
        image (BGR uint8) of ``figure_frame``, on which ``left_uv * scale`` draws an estimate.
    """
    from bench.process import process
    from estimator import CenterlineEstimator, EstimatorConfig

    calibration, frames = _rendered(spec)
    estimators = {key: CenterlineEstimator(calibration, EstimatorConfig.from_dict(dict(table), source=f"[{key}]"))
                  for key, table in spec.estimators.items()}
    records, figure, pairs = [], None, []
    for capture in frames:
        record = process(capture, estimators, calibration)
        records.append(record.to_json())
        if spec.keep_frames:
            pairs.append((capture.frame.left, capture.frame.right))
        if spec.figure_frame is not None and capture.index == spec.figure_frame:
            figure = {"index": capture.index, "scale": FIGURE_SCALE, "left": _shrink(capture.frame.left)}
    return {"records": records, "figure": figure, "frames": pairs if spec.keep_frames else None,
            "image_size": list(calibration.image_size)}


def expected_cost(spec: SequenceSpec) -> float:
    """What an episode is expected to cost, relative to the others of a study (which start costliest
    first): its frames times the scene draws per frame. A frame draws the arm's region and one per
    moving object (the occluded scene's cable: 62 ms a pair against 37 ms for one draw); a
    motion-blurred exposure draws more only where the arm moves over a quarter pixel within it,
    which it does not on the paper's slow ramp.
    """
    scene = twin_config(spec).scene()
    return float(spec.frames * (1 + len(scene.moving_objects)))


def calibration(spec: SequenceSpec):
    """The calibration the episode's images are rendered with (read from the twin's camera file, nothing rendered)."""
    from twin.rig import StereoRig

    return StereoRig.load(twin_config(spec).camera).calibration


def _shrink(image: np.ndarray) -> np.ndarray:
    import cv2

    h, w = image.shape[:2]
    size = (round(w * FIGURE_SCALE), round(h * FIGURE_SCALE))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)
