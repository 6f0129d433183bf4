"""The ``Twin`` facade: the arm's physics, its valves and its stereo camera, plus exact truth.

    from twin import Twin
    tw = Twin()                                          # models/twin.toml; Twin.from_config(path)
    tw.valves.set_pressures({"s1_a": 1.5, "s3": 2.0})    # hardware.ValveBank contract
    tw.advance(0.5); tw.settle()                         # simulated seconds; run until static
    frame = tw.camera.grab()                             # hardware.StereoFrame, raw BGR pair
    calib = tw.camera.calibration                        # the calibration used to render
    gt = tw.backbone()                                   # (N, 3) m, left-camera frame, base -> tip
    gt_world = tw.backbone(frame="world")
    truth = tw.frame_backbone()                          # what the last frame shows (its exposure's middle)
    depth = tw.camera.depth_left()                       # metres, last grabbed frame

Frames: "world" is the arm's (metres, z up, origin at the arm base); "camera" is the left
camera's (OpenCV axes: x right, y down, z forward), the frame the estimator reports in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path

import numpy as np

from estimator.config_file import ConfigFileError, TableReader, boolean, file_in, integer, number, read_toml
from estimator.skeleton import resample_polyline
from hardware.errors import DeviceError
from hardware.interfaces import DEFAULT_CLAMP_TOLERANCE, MAX_CLAMP_TOLERANCE
from twin.camera import SimStereoCamera
from twin.params import ArmParams
from twin.physics import ArmSimulation
from twin.rig import StereoRig
from twin.scene import LabScene, clean_scene, load_scene
from twin.shape import ArmShape
from twin.valves import SimValveBank

# models/ is package data (importlib.resources finds it in a checkout and in an installed wheel alike).
DEFAULT_CONFIG = Path(str(files("models") / "twin.toml"))
FRAMES = ("camera", "world")


def _name(value) -> str:
    if not isinstance(value, str) or not value.strip():
        raise TypeError(f"expected a preset name, got {value!r}")
    return value


@dataclass(frozen=True)
class TwinConfig:
    """The contents of ``twin.toml`` (paths resolved against the file's folder).

    Attributes:
        arm: the arm parameter file.
        camera: the stereo camera file.
        timestep_s: MuJoCo integration step.
        clamp_pressures: clamp slightly out-of-range set-points instead of raising.
        clamp_tolerance: how far outside [0, max] ``clamp_pressures`` reaches, a fraction of the
            maximum pressure (further out is refused, clamping or not).
        seed: sensor-noise seed.
        tube_sides: vertices around the rendered tube.
        backbone_points: points of the ground-truth backbone (>= 100).
        source: the file read, if any.
        scene_file: the lab scenes (``scene.toml``), or None for the clean scene only.
        scene_preset: which preset of ``scene_file`` the camera sees.
        scene_seed: seed of the scene's textures and of the ``random`` preset's draw.
    """

    arm: Path
    camera: Path
    timestep_s: float = 0.002
    clamp_pressures: bool = False
    seed: int = 0
    tube_sides: int = 48
    backbone_points: int = 200
    source: Path | None = None
    scene_file: Path | None = None
    scene_preset: str = "clean"
    scene_seed: int = 0
    clamp_tolerance: float = DEFAULT_CLAMP_TOLERANCE

    def scene(self) -> LabScene:
        """The lab scene this configuration renders.

        Raises:
            ConfigFileError: the scene file or the preset is bad (names the file and key).
        """
        if self.scene_file is None:
            if self.scene_preset != "clean":
                raise ConfigFileError(f"{self.source or 'twin config'}: [scene] preset {self.scene_preset!r} needs "
                                      "a scene file (key scenes)")
            return clean_scene()
        return load_scene(self.scene_file, self.scene_preset, self.scene_seed)

    @classmethod
    def load(cls, path: str | Path) -> TwinConfig:
        """Read ``twin.toml``.

        Raises:
            ConfigFileError: missing file, unknown or missing key, bad value; names file and key.
        """
        path = Path(path)
        top = TableReader(path, read_toml(path, "twin"))
        base = path.parent
        arm = top.take("arm", file_in(base))
        camera = top.take("camera", file_in(base))
        scene_file = top.take("scenes", file_in(base), None)
        physics = top.sub("physics")
        timestep_s = physics.take("timestep_s", number(1e-5, 0.02), 0.002)
        physics.done()
        valves = top.sub("valves", required=False)
        clamp = valves.take("clamp", boolean, False) if valves else False
        tolerance = (valves.take("clamp_tolerance", number(0.0, MAX_CLAMP_TOLERANCE), DEFAULT_CLAMP_TOLERANCE)
                     if valves else DEFAULT_CLAMP_TOLERANCE)
        if valves:
            valves.done()
        render = top.sub("render", required=False)
        seed = render.take("seed", integer(0, 2**63 - 1), 0) if render else 0
        sides = render.take("tube_sides", integer(8, 512), 48) if render else 48
        if render:
            render.done()
        scene = top.sub("scene", required=False)
        preset = scene.take("preset", _name, "clean") if scene else "clean"
        scene_seed = scene.take("seed", integer(0, 2**63 - 1), 0) if scene else 0
        if scene:
            scene.done()
        truth = top.sub("truth", required=False)
        points = truth.take("backbone_points", integer(100, 100_000), 200) if truth else 200
        if truth:
            truth.done()
        top.done()
        for key, file in (("arm", arm), ("camera", camera), ("scenes", scene_file)):
            if file is not None and not file.is_file():
                raise ConfigFileError(f"{path}: key {key}: file {file} not found")
        config = cls(arm, camera, timestep_s, clamp, seed, sides, points, path, scene_file, preset, scene_seed,
                     tolerance)
        try:
            config.scene()  # a bad preset is an error now, naming this file, not when the camera connects
        except ConfigFileError as e:
            raise ConfigFileError(f"{path}: key [scene] preset {preset!r}: {e}") from e
        return config


class Twin:
    """The digital twin: simulated valves and stereo camera on a MuJoCo arm, with exact truth.

    Both devices are connected on construction (``tw.valves.set_pressures`` and
    ``tw.camera.grab()`` work at once); ``close()`` (or leaving a ``with`` block) vents the
    valves and releases the renderer.

    Args:
        config: a :class:`TwinConfig`; ``None`` reads ``models/twin.toml``.

    Raises:
        ConfigFileError: twin.toml or camera.toml is malformed (names file and key).
        ParamsFileError: the arm parameter file is malformed (names file and key).
        RenderBackendError: no offscreen OpenGL (names the packages to install).
    """

    def __init__(self, config: TwinConfig | None = None) -> None:
        self.config = config if config is not None else TwinConfig.load(DEFAULT_CONFIG)
        c = self.config
        self.params = ArmParams.load(c.arm)
        self.rig = StereoRig.load(c.camera)
        self.scene = c.scene()
        self.sim = ArmSimulation(self.params, timestep_s=c.timestep_s)
        self.valves = SimValveBank(self.sim, clamp=c.clamp_pressures, clamp_tolerance=c.clamp_tolerance)
        self.camera = SimStereoCamera(self.rig, self.shape, lambda: self.sim.time_s,
                                      seed=c.seed, tube_sides=c.tube_sides, scene=self.scene)
        self.valves.connect()
        try:
            self.camera.connect()
        except BaseException:
            self.valves.close()
            raise

    @classmethod
    def from_config(cls, path: str | Path) -> Twin:
        """A twin from another ``twin.toml``."""
        return cls(TwinConfig.load(path))

    # --- time ------------------------------------------------------------------------------------

    @property
    def time_s(self) -> float:
        """Simulated time, seconds since construction (or ``reset()``)."""
        return self.sim.time_s

    def advance(self, duration_s: float) -> None:
        """Run the physics for ``duration_s`` simulated seconds.

        With an exposure time, the arm's shape as the exposure of a frame grabbed at the end would
        open is handed to the camera on the way, so the frame's motion blur follows the physics
        over its exposure (not a straight line from the previous frame, which can be a second and a
        whole swing back).

        Raises:
            ValueError: a negative or non-finite duration.
            SimulationError: the simulation went unstable (names the step).
        """
        if not (math.isfinite(duration_s) and duration_s >= 0):
            raise ValueError(f"duration_s: expected a finite number >= 0, got {duration_s!r}")
        step = self.sim.timestep_s
        steps = round(duration_s / step)
        last = round(self._exposure_s() / step)
        if last > 0 and steps > last:  # the same steps in two parts: the simulation does not change
            self.sim.advance((steps - last) * step)
            self.camera.exposure_opens(self.shape(), self.sim.time_s)
            self.sim.advance(last * step)
        else:
            self.sim.advance(duration_s)

    def settle(self, **kwargs) -> bool:
        """Run until the arm is static (see ``ArmSimulation.settle``); True if it came to rest."""
        rested = self.sim.settle(**kwargs)
        if rested and self._exposure_s() > 0:  # at rest, the arm as an exposure opens is the arm now
            self.camera.exposure_opens(self.shape(), self.sim.time_s - self._exposure_s())
        return rested

    def _points_wanted(self, frame: str, n_points: int | None) -> int:
        """How many backbone points a request asks for, after checking its frame and count."""
        if frame not in FRAMES:
            raise ValueError(f"frame: expected one of {', '.join(map(repr, FRAMES))}, got {frame!r}")
        n = self.config.backbone_points if n_points is None else int(n_points)
        if n < 2:
            raise ValueError(f"n_points: expected at least 2, got {n}")
        return n

    def _exposure_s(self) -> float:
        """The camera's exposure time where it blurs the arm's motion (0: frames are instants)."""
        if not self.camera.is_connected:
            return 0.0
        effects = self.camera.effects
        return effects.exposure_s if effects.motion_subframes >= 2 else 0.0

    def reset(self) -> None:
        """Back to rest at t = 0 with every valve vented."""
        self.valves.vent()
        self.sim.reset()

    # --- truth ---------------------------------------------------------------------------------

    def shape(self) -> ArmShape:
        """The arm's current geometry (world frame), as the camera renders it."""
        return self.sim.shape(self.config.backbone_points)

    def backbone(self, frame: str = "camera", n_points: int | None = None) -> np.ndarray:
        """The exact backbone now, base to tip, evenly spaced in arc length.

        Args:
            frame: "camera" (the left camera, OpenCV axes, as the estimator reports) or "world".
            n_points: number of points (default ``backbone_points`` of twin.toml, >= 100).

        Returns:
            (N, 3) metres.
        """
        n = self._points_wanted(frame, n_points)
        points_world = self.sim.backbone(n)
        return points_world if frame == "world" else self.rig.world_to_left_camera(points_world)

    def frame_backbone(self, frame: str = "camera", n_points: int | None = None) -> np.ndarray:
        """The exact backbone the last grabbed frame shows, base to tip, evenly spaced in arc length:
        the arm at the middle of the frame's exposure (``SimStereoCamera.exposed_shape``), the shape its
        motion blur is centred on; ``backbone()`` when the camera has no exposure time. A frame's truth.

        Raises:
            DeviceError: no frame has been grabbed since the camera connected.
        """
        n = self._points_wanted(frame, n_points)
        shape = self.camera.exposed_shape
        if shape is None:
            raise DeviceError("frame_backbone(): no frame grabbed since the camera connected")
        points_world = shape.points_world if len(shape.points_world) == n else resample_polyline(shape.points_world, n)
        return points_world if frame == "world" else self.rig.world_to_left_camera(points_world)

    # --- lifetime --------------------------------------------------------------------------------

    def close(self) -> None:
        """Vent the valves and release the camera; closing twice is harmless."""
        try:
            self.valves.close()
        finally:
            self.camera.close()

    def __enter__(self) -> Twin:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
