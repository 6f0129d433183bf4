"""Stereo calibration in OpenCV conventions, its rectification, and a file a person can read.

Conventions (OpenCV): ``K`` is 3x3 in pixels, ``dist`` is (k1, k2, p1, p2, k3) or shorter,
``R``, ``T`` map left-camera points to the right camera (``x_r = R x_l + T``, metres) and
``image_size`` is (width, height). Camera axes: x right, y down, z forward.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np

_SIDES = ("left", "right")
_DIST_LENGTHS = (0, 1, 2, 3, 4, 5, 8, 12, 14)
# undistortPoints iterates; its default of 5 iterations leaves ~0.1 px error at ZED corners.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)


class CalibrationFileError(ValueError):
    """A calibration file is missing, unreadable or has a bad key; the message names both."""


def _matrix(value, shape: tuple[int, ...], name: str) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return array


def _distortion(value, name: str) -> np.ndarray:
    array = np.asarray(value if value is not None else (), dtype=np.float64).ravel()
    if array.size not in _DIST_LENGTHS:
        raise ValueError(f"{name}: expected (k1, k2, p1, p2, k3) or shorter, got {array.size} coefficients")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    if array.size < 5:
        array = np.concatenate([array, np.zeros(5 - array.size)])
    return array


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.array(array, dtype=np.float64)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """Intrinsics, distortion and extrinsics of a stereo pair (OpenCV conventions, metres).

    Raises:
        ValueError: a matrix has the wrong shape, a non-finite entry, R is not a rotation,
            the baseline is zero or the image size is not two positive integers.
    """

    K_left: np.ndarray
    dist_left: np.ndarray
    K_right: np.ndarray
    dist_right: np.ndarray
    R: np.ndarray
    T: np.ndarray
    image_size: tuple[int, int]

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for side in _SIDES:
            K = _matrix(getattr(self, f"K_{side}"), (3, 3), f"K_{side}")
            if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], (0, 0, 1)):
                raise ValueError(f"K_{side}: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
            set_(self, f"K_{side}", _frozen(K))
            set_(self, f"dist_{side}", _frozen(_distortion(getattr(self, f"dist_{side}"), f"dist_{side}")))
        R = _matrix(self.R, (3, 3), "R")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
            raise ValueError("R: expected a proper rotation matrix (R R^T = I, det R = +1)")
        set_(self, "R", _frozen(R))
        T = _matrix(np.asarray(self.T, dtype=np.float64).reshape(-1), (3,), "T")
        if np.linalg.norm(T) <= 0:
            raise ValueError("T: the baseline is zero")
        set_(self, "T", _frozen(T))
        size = tuple(self.image_size) if isinstance(self.image_size, tuple | list | np.ndarray) else ()
        integral = all(isinstance(v, int | float | np.integer | np.floating) and float(v).is_integer() for v in size)
        if len(size) != 2 or not integral or min(size) <= 0:
            raise ValueError(f"image_size: expected (width, height) in pixels, got {self.image_size!r}")
        set_(self, "image_size", (int(size[0]), int(size[1])))

    # --- derived quantities -------------------------------------------------------------

    @property
    def baseline_m(self) -> float:
        """Distance between the two optical centres, metres."""
        return float(np.linalg.norm(self.T))

    def K(self, side: str) -> np.ndarray:
        return self.K_left if _side(side) == "left" else self.K_right

    def dist(self, side: str) -> np.ndarray:
        return self.dist_left if _side(side) == "left" else self.dist_right

    @cached_property
    def rectification(self) -> Rectification:
        """The rectified geometry the estimator works in (computed once per calibration)."""
        return Rectification.from_calibration(self)

    def project(self, points_left_cam: np.ndarray, side: str = "left") -> np.ndarray:
        """Project 3D points into a raw (distorted) image.

        Args:
            points_left_cam: (N, 3) metres in the left camera frame.
            side: "left" or "right".

        Returns:
            (N, 2) raw pixel coordinates (OpenCV: pixel centres at integers).
        """
        points = np.ascontiguousarray(points_left_cam, dtype=np.float64).reshape(-1, 3)
        if _side(side) == "left":
            rvec, tvec = np.zeros(3), np.zeros(3)
        else:
            rvec, tvec = cv2.Rodrigues(self.R)[0].ravel(), self.T
        if len(points) == 0:
            return np.zeros((0, 2))
        uv, _ = cv2.projectPoints(points, rvec, tvec, self.K(side), self.dist(side).reshape(1, -1))
        return uv.reshape(-1, 2)

    # --- construction and files ---------------------------------------------------------

    @classmethod
    def from_projection_matrices(
        cls, P_left: np.ndarray, P_right: np.ndarray, image_size: tuple[int, int]
    ) -> StereoCalibration:
        """Build a calibration for an already rectified (undistorted) pair.

        Args:
            P_left, P_right: 3x4 projection matrices ``K [R | t]`` of both cameras in a common
                frame (for a rectified pair usually ``K [I | 0]`` and ``K [I | (-f B, 0, 0)]``).
            image_size: (width, height).

        Returns:
            A calibration with zero distortion whose left camera frame is the left camera's.
        """
        cams = []
        for name, P in (("P_left", P_left), ("P_right", P_right)):
            P = _matrix(P, (3, 4), name)
            K, R_cam, c_h = cv2.decomposeProjectionMatrix(P)[:3]
            K = K / K[2, 2]
            if K[0, 0] < 0:  # decomposition may flip signs; keep fx, fy positive
                flip = np.diag(np.sign(np.diag(K)))
                K, R_cam = K @ flip, flip @ R_cam
            centre = (c_h[:3] / c_h[3]).ravel()
            cams.append((K, R_cam, -R_cam @ centre))
        (K1, R1, t1), (K2, R2, t2) = cams
        R = R2 @ R1.T
        return cls(K1, np.zeros(5), K2, np.zeros(5), R, t2 - R @ t1, image_size)

    def save(self, path: str | Path) -> None:
        """Write the calibration as commented TOML (OpenCV conventions, metres)."""
        path = Path(path)

        def row(values) -> str:
            return "[" + ", ".join(repr(float(v)) for v in values) + "]"

        def mat(m) -> str:
            return "[\n  " + ",\n  ".join(row(r) for r in np.asarray(m)) + ",\n]"

        text = "\n".join(
            [
                "# softarm-twin stereo calibration, OpenCV conventions:",
                "# K in pixels, dist = (k1, k2, p1, p2, k3), x_right = R x_left + T with T in metres,",
                "# image_size = [width, height]; camera axes x right, y down, z forward.",
                f"image_size = [{self.image_size[0]}, {self.image_size[1]}]",
                f"baseline_m = {self.baseline_m!r}  # informative; T is authoritative",
                "",
                "[left]",
                f"K = {mat(self.K_left)}",
                f"dist = {row(self.dist_left)}",
                "",
                "[right]",
                f"K = {mat(self.K_right)}",
                f"dist = {row(self.dist_right)}",
                "",
                "[extrinsics]",
                f"R = {mat(self.R)}",
                f"T_m = {row(self.T)}",
                "",
            ]
        )
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)

    @classmethod
    def load(cls, path: str | Path) -> StereoCalibration:
        """Read a file written by :meth:`save`.

        Raises:
            CalibrationFileError: the file is missing or malformed; the message names the
                file and the key.
        """
        path = Path(path)
        try:
            data = tomllib.loads(path.read_text())
        except FileNotFoundError as e:
            raise CalibrationFileError(f"{path}: calibration file not found") from e
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise CalibrationFileError(f"{path}: not a TOML calibration file ({e})") from e

        values = {}
        for name, (section, key) in _FILE_KEYS.items():
            table = data if section is None else data.get(section)
            if not isinstance(table, dict) or key not in table:
                raise CalibrationFileError(f"{path}: missing key {_where(section, key)}")
            try:
                values[name] = tuple(table[key]) if name == "image_size" else np.asarray(table[key], float)
            except (TypeError, ValueError) as e:
                raise CalibrationFileError(f"{path}: key {_where(section, key)} is not a numeric array ({e})") from e
        try:
            return cls(**values)
        except ValueError as e:
            name, _, reason = str(e).partition(":")
            section, key = _FILE_KEYS.get(name, (None, name))
            raise CalibrationFileError(f"{path}: key {_where(section, key)}: {reason.strip()}") from e


# Constructor field -> (TOML section, key) of the calibration file.
_FILE_KEYS = {
    "image_size": (None, "image_size"),
    "K_left": ("left", "K"),
    "dist_left": ("left", "dist"),
    "K_right": ("right", "K"),
    "dist_right": ("right", "dist"),
    "R": ("extrinsics", "R"),
    "T": ("extrinsics", "T_m"),
}


def _where(section: str | None, key: str) -> str:
    return key if section is None else f"[{section}] {key}"


def _side(side: str) -> str:
    if side not in _SIDES:
        raise ValueError(f"side: expected 'left' or 'right', got {side!r}")
    return side


@dataclass(frozen=True, eq=False)
class Rectification:
    """Rectified stereo geometry: rows agree between the two images.

    The rectified cameras keep the original focal length (no zoom) and the canvas is grown so
    every raw pixel of both cameras lands inside it, so nothing the camera saw is cropped.
    """

    calibration: StereoCalibration
    R_rect: dict  # side -> 3x3 rotation from the raw camera frame to the rectified frame
    P: dict  # side -> 3x4 rectified projection matrix (P["right"][0, 3] = -f B)
    size: tuple[int, int]  # rectified canvas (width, height)
    _maps: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_calibration(cls, calib: StereoCalibration) -> Rectification:
        c = calib
        R1, R2, P1, P2 = cv2.stereoRectify(
            c.K_left, c.dist_left.reshape(1, -1), c.K_right, c.dist_right.reshape(1, -1),
            c.image_size, c.R, c.T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1,
        )[:4]
        f = float(P1[0, 0])
        # Footprint of both raw images on the rectified plane (with focal f, centre at 0).
        w, h = c.image_size
        border = np.concatenate(
            [
                np.stack([np.linspace(0, w - 1, 64), np.zeros(64)], 1),
                np.stack([np.linspace(0, w - 1, 64), np.full(64, h - 1.0)], 1),
                np.stack([np.zeros(36), np.linspace(0, h - 1, 36)], 1),
                np.stack([np.full(36, w - 1.0), np.linspace(0, h - 1, 36)], 1),
            ]
        )
        P0 = np.array([[f, 0, 0], [0, f, 0], [0, 0, 1.0]])
        pts = np.concatenate(
            [
                cv2.undistortPoints(border.reshape(-1, 1, 2), c.K(s), c.dist(s).reshape(1, -1),
                                    R=Rs, P=P0, criteria=_UNDISTORT_CRITERIA).reshape(-1, 2)
                for s, Rs in (("left", R1), ("right", R2))
            ]
        )
        lo, hi = np.floor(pts.min(0)) - 2, np.ceil(pts.max(0)) + 2
        cx, cy = -lo
        size = (int(hi[0] - lo[0]) + 1, int(hi[1] - lo[1]) + 1)
        Pl = np.array([[f, 0, cx, 0], [0, f, cy, 0], [0, 0, 1, 0]], dtype=np.float64)
        Pr = Pl.copy()
        Pr[0, 3] = P2[0, 3]  # -f * baseline
        return cls(c, {"left": R1, "right": R2}, {"left": Pl, "right": Pr}, size)

    @property
    def focal_px(self) -> float:
        return float(self.P["left"][0, 0])

    @property
    def baseline_m(self) -> float:
        return float(-self.P["right"][0, 3] / self.P["right"][0, 0])

    def maps(self, side: str) -> tuple[np.ndarray, np.ndarray]:
        """Fixed-point ``cv2.remap`` maps from the rectified canvas into the raw image."""
        side = _side(side)
        if side not in self._maps:
            c = self.calibration
            self._maps[side] = cv2.initUndistortRectifyMap(
                c.K(side), c.dist(side).reshape(1, -1), self.R_rect[side], self.P[side][:, :3],
                self.size, cv2.CV_16SC2,
            )
        return self._maps[side]

    def rectify_image(self, image: np.ndarray, side: str, roi: tuple[int, int, int, int] | None = None,
                      interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
        """Resample a raw image onto the rectified canvas, or onto ``roi = (x0, y0, x1, y1)`` of it."""
        m1, m2 = self.maps(side)
        if roi is not None:
            x0, y0, x1, y1 = roi
            m1, m2 = m1[y0:y1, x0:x1], m2[y0:y1, x0:x1]
        return cv2.remap(image, m1, m2, interpolation, borderMode=cv2.BORDER_CONSTANT)

    def rectify_points(self, uv_raw: np.ndarray, side: str) -> np.ndarray:
        """(N, 2) raw pixels -> (N, 2) rectified pixels."""
        uv = np.asarray(uv_raw, dtype=np.float64).reshape(-1, 1, 2)
        if len(uv) == 0:
            return np.zeros((0, 2))
        c = self.calibration
        out = cv2.undistortPoints(uv, c.K(side), c.dist(side).reshape(1, -1), R=self.R_rect[side],
                                  P=self.P[side][:, :3], criteria=_UNDISTORT_CRITERIA)
        return out.reshape(-1, 2)

    def unrectify_points(self, uv_rect: np.ndarray, side: str) -> np.ndarray:
        """(N, 2) rectified pixels -> (N, 2) raw pixels (exact forward distortion model)."""
        uv = np.asarray(uv_rect, dtype=np.float64).reshape(-1, 2)
        if len(uv) == 0:
            return np.zeros((0, 2))
        P = self.P[side]
        rays = np.column_stack([(uv[:, 0] - P[0, 2]) / P[0, 0], (uv[:, 1] - P[1, 2]) / P[1, 1], np.ones(len(uv))])
        rays_cam = rays @ self.R_rect[side]  # rotate back: R_rect^T applied to each row
        c = self.calibration
        out, _ = cv2.projectPoints(rays_cam, np.zeros(3), np.zeros(3), c.K(side), c.dist(side).reshape(1, -1))
        return out.reshape(-1, 2)

    def to_left_camera(self, points_rect: np.ndarray) -> np.ndarray:
        """(N, 3) points in the rectified left frame -> the raw left camera frame."""
        return np.asarray(points_rect, dtype=np.float64) @ self.R_rect["left"]

    def from_left_camera(self, points_cam: np.ndarray) -> np.ndarray:
        """(N, 3) points in the raw left camera frame -> the rectified left frame."""
        return np.asarray(points_cam, dtype=np.float64) @ self.R_rect["left"].T

    def disparity_to_depth_m(self, disparity_px: float) -> float:
        return math.inf if disparity_px <= 0 else self.focal_px * self.baseline_m / disparity_px
