"""The twin's stereo rig: intrinsics, distortion, extrinsics, pose in the world and appearance.

One file (``models/camera.toml``) feeds both the renderer and the calibration the twin exposes,
so the calibration a user gets is exactly the one the images were rendered with.

Frames: the world is the arm's (metres, z up, origin at the arm base). Camera frames follow
OpenCV (x right, y down, z forward). ``T_world_cam_left`` maps left-camera points to the world:
``p_world = T[:3, :3] @ p_cam + T[:3, 3]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from estimator import StereoCalibration
from estimator.calibration import CalibrationValueError
from estimator.config_file import ConfigFileError, TableReader, integer, number, read_toml, vector

# The twin's files are read with the project's one TOML reader (``estimator.config_file``); its
# ConfigFileError, TableReader and converters stay importable from here, as before.


def load_toml(path: str | Path, what: str) -> dict[str, Any]:
    """Read a TOML file of the twin or raise ConfigFileError naming it."""
    return read_toml(path, what)


# --- the rig ---------------------------------------------------------------------------------

_GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV camera axes -> OpenGL camera axes


@dataclass(frozen=True)
class Appearance:
    """Colours (display RGB in 0..1) and lighting of the rendered scene."""

    background_rgb: tuple[float, float, float]
    arm_rgb: tuple[float, float, float]
    plate_rgb: tuple[float, float, float]
    ambient: float
    directional: float
    light_direction_world: tuple[float, float, float]


@dataclass(frozen=True)
class SensorModel:
    """What the sensor adds to the optical image: noise (8-bit DN), blur (px) and exposure gain."""

    noise_std_dn: float = 0.0
    blur_sigma_px: float = 0.0
    exposure_gain: float = 1.0

    def __post_init__(self) -> None:
        for name, lo in (("noise_std_dn", 0.0), ("blur_sigma_px", 0.0), ("exposure_gain", 1e-6)):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= lo):
                raise ValueError(f"{name}: expected a finite number >= {lo}, got {value!r}")


def look_at(position: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """4x4 pose of an OpenCV camera (z forward, y down) at ``position`` looking at ``target``.

    Raises:
        ValueError: the camera and the target coincide or the view direction is parallel to ``up``.
    """
    forward = np.asarray(target, float) - np.asarray(position, float)
    if np.linalg.norm(forward) < 1e-9:
        raise ValueError("the camera position and the look-at point coincide")
    z = forward / np.linalg.norm(forward)
    x = np.cross(z, np.asarray(up, float))
    if np.linalg.norm(x) < 1e-6:
        raise ValueError("the viewing direction is parallel to the up vector")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = position
    return T


@dataclass(frozen=True, eq=False)
class StereoRig:
    """The simulated stereo camera: its calibration, its pose in the world, what it sees.

    Attributes:
        calibration: the exact calibration the renderer uses (OpenCV conventions).
        T_world_cam_left: (4, 4) pose of the left camera (OpenCV axes) in the world, metres.
        appearance: colours and lights.
        sensor: noise, blur and exposure of the raw images.
        source: the file it was loaded from, if any.
    """

    calibration: StereoCalibration
    T_world_cam_left: np.ndarray
    appearance: Appearance
    sensor: SensorModel
    source: Path | None = None

    def __post_init__(self) -> None:
        T = np.array(self.T_world_cam_left, dtype=np.float64)
        if T.shape != (4, 4) or not np.allclose(T[3], (0, 0, 0, 1)):
            raise ValueError(f"T_world_cam_left: expected a 4x4 rigid transform, got shape {T.shape}")
        R = T[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ValueError("T_world_cam_left: the rotation part is not a proper rotation")
        T.setflags(write=False)
        object.__setattr__(self, "T_world_cam_left", T)

    # --- loading -----------------------------------------------------------------------------

    @classmethod
    def load(cls, path: str | Path) -> StereoRig:
        """Read ``camera.toml``.

        Raises:
            ConfigFileError: the file is missing, a key is missing, unknown or has a bad value;
                the message names the file and the key.
        """
        path = Path(path)
        data = load_toml(path, "camera")
        top = TableReader(path, data)

        image = top.sub("image")
        size = (image.take("width_px", integer(16, 16384)), image.take("height_px", integer(16, 16384)))
        image.done()

        eyes = {}
        for side in ("left", "right"):
            t = top.sub(side)
            fx, fy = t.take("fx_px", number(0, lo_open=True)), t.take("fy_px", number(0, lo_open=True))
            cx, cy = t.take("cx_px", number()), t.take("cy_px", number())
            dist = t.take("dist", vector((4, 5), -10, 10))
            t.done()
            eyes[side] = (np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), dist)

        ext = top.sub("extrinsics")
        rvec = ext.take("rotation_mrad", vector(3, -1000, 1000)) * 1e-3
        T_m = ext.take("T_m", vector(3, -10, 10))
        if np.linalg.norm(T_m) <= 0:
            raise ext.error("T_m", "the baseline is zero")
        ext.done()

        pose = top.sub("pose")
        position = pose.take("position_m", vector(3))
        target = pose.take("look_at_m", vector(3))
        up = pose.take("up_world", vector(3))
        try:
            T_world_cam = look_at(position, target, up)
        except ValueError as e:
            raise pose.error("look_at_m", str(e)) from e
        pose.done()

        look = top.sub("appearance")
        colour = vector(3, 0.0, 1.0)
        appearance = Appearance(
            background_rgb=tuple(look.take("background_rgb", colour)),
            arm_rgb=tuple(look.take("arm_rgb", colour)),
            plate_rgb=tuple(look.take("plate_rgb", colour)),
            ambient=look.take("ambient", number(0.0, 1.0)),
            directional=look.take("directional", number(0.0, 4.0)),
            light_direction_world=tuple(look.take("light_direction_world", vector(3))),
        )
        if np.linalg.norm(appearance.light_direction_world) < 1e-9:
            raise look.error("light_direction_world", "must not be the zero vector")
        look.done()

        sens = top.sub("sensor")
        sensor = SensorModel(
            noise_std_dn=sens.take("noise_std_dn", number(0.0, 64.0)),
            blur_sigma_px=sens.take("blur_sigma_px", number(0.0, 20.0)),
            exposure_gain=sens.take("exposure_gain", number(0.0, 16.0, lo_open=True)),
        )
        sens.done()
        top.done()

        try:
            R = cv2.Rodrigues(rvec)[0]
            calibration = StereoCalibration(eyes["left"][0], eyes["left"][1], eyes["right"][0], eyes["right"][1],
                                            R, T_m, size)
        except CalibrationValueError as e:  # name this file's key, not the constructor's argument
            raise _camera_error(path, e) from e
        return cls(calibration, T_world_cam, appearance, sensor, path)

    # --- frames ------------------------------------------------------------------------------

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of each raw image, pixels."""
        return self.calibration.image_size

    def T_world_cam(self, side: str = "left") -> np.ndarray:
        """(4, 4) pose of one camera (OpenCV axes) in the world."""
        if side == "left":
            return self.T_world_cam_left.copy()
        if side != "right":
            raise ValueError(f"side: expected 'left' or 'right', got {side!r}")
        T_left_right = np.eye(4)  # x_r = R x_l + T  =>  x_l = R^T x_r - R^T T
        T_left_right[:3, :3] = self.calibration.R.T
        T_left_right[:3, 3] = -self.calibration.R.T @ self.calibration.T
        return self.T_world_cam_left @ T_left_right

    def T_world_cam_gl(self, side: str = "left") -> np.ndarray:
        """(4, 4) pose of one camera with OpenGL axes (x right, y up, looking down -z)."""
        return self.T_world_cam(side) @ _GL_FROM_CV

    def world_to_left_camera(self, points_world: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (N, 3) left-camera points, metres."""
        points = _points(points_world, "points_world")
        T = self.T_world_cam_left
        return (points - T[:3, 3]) @ T[:3, :3]

    def left_camera_to_world(self, points_cam: np.ndarray) -> np.ndarray:
        """(N, 3) left-camera points -> (N, 3) world points, metres."""
        points = _points(points_cam, "points_cam")
        T = self.T_world_cam_left
        return points @ T[:3, :3].T + T[:3, 3]

    def project_world(self, points_world: np.ndarray, side: str = "left") -> np.ndarray:
        """(N, 3) world points -> (N, 2) raw pixels of one camera (distortion included)."""
        return self.calibration.project(self.world_to_left_camera(points_world), side)


def _camera_error(path: Path, error: CalibrationValueError) -> ConfigFileError:
    """Name the camera.toml key behind a StereoCalibration argument, not the argument."""
    side = error.argument.rpartition("_")[2]
    if error.argument.startswith("K_") and error.entry in ("fx", "fy", "cx", "cy"):
        return ConfigFileError(f"{path}: key [{side}] {error.entry}_px {error.problem}")
    keys = {"R": "[extrinsics] rotation_mrad", "T": "[extrinsics] T_m", "image_size": "[image] width_px, height_px"}
    key = f"[{side}] dist" if error.argument.startswith("dist_") else keys.get(error.argument, error.argument)
    return ConfigFileError(f"{path}: key {key}: {error.detail}")


def _points(points: np.ndarray, name: str) -> np.ndarray:
    array = np.asarray(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f"{name}: expected (N, 3), got {array.shape}")
    return array
