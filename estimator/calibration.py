"""Stereo calibration in OpenCV conventions, its rectification, and a file a person can read.

Conventions (OpenCV): ``K`` is 3x3 in pixels, ``dist`` is (k1, k2, p1, p2, k3) or shorter,
``R``, ``T`` map left-camera points to the right camera (``x_r = R x_l + T``, metres) and
``image_size`` is (width, height). Camera axes: x right, y down, z forward. ``T`` is the left
camera's centre seen from the right camera, so a right camera to the right of the left one has
``T_x < 0`` (a 12 cm rig: ``T = (-0.12, 0, 0)``).

A calibration must also look like a real stereo rig (the limits below): a wrong sign or a typo
otherwise comes out as a confident wrong answer (a flipped T puts the arm behind the camera).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np

from estimator.config_file import ConfigFileError, TableReader, read_toml

_SIDES = ("left", "right")
_DIST_LENGTHS = (0, 1, 2, 3, 4, 5, 8, 12, 14)
# undistortPoints iterates; its default of 5 iterations leaves ~0.1 px error at ZED corners.
_INTER_BITS = 5  # OpenCV's fixed-point maps: fractions in 1/32 pixel (INTER_BITS)
_INTER_TAB = 1 << _INTER_BITS
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)


# --- what a real stereo rig looks like -----------------------------------------------------
# Each side of an image, pixels (the twin's camera.toml uses the same range).
IMAGE_SIDE_PX = (16, 16384)
# Focal length over the image side it spans: 0.05 to 6 times is a field of view of about 169 down to
# 9.5 degrees (fov = 2 atan(side / 2 f)); fx is judged against the width, fy against the height.
FOCAL_PER_SIDE = (0.05, 6.0)
# fy / fx: 1 for square pixels; anamorphic lenses squeeze up to 2.
FOCAL_ASPECT = (0.5, 2.0)
# Distance between the optical centres, metres (a ZED: 0.12).
BASELINE_M = (0.01, 1.0)
# Angle of R, degrees: the eyes of a side-by-side rig are parallel to within a few degrees; even a
# strongly converging rig turns them by less than this.
MAX_EYE_ROTATION_DEG = 30.0
# Angle between the baseline and the left camera's +x axis, degrees: beyond it the pair is not
# side by side and rectification cannot put corresponding points on the same row.
MAX_BASELINE_OFF_AXIS_DEG = 45.0
# |coefficient| limits of OpenCV's distortion model, in the order of ``dist``. Real lenses without
# a fisheye stay well inside: a factory ZED has k1 = -0.18, k2 = 0.03; calibrations of wide-angle
# webcams reach k1 ~ -0.5, k2 ~ 2.5 and, poorly constrained, k3 ~ 7; decentring (p1, p2) and thin
# prism (s1..s4) terms are below 0.01; a tilted sensor (tau_x, tau_y, radians) a few degrees. With
# the rational model (k4..k6 not all zero) numerator and denominator cancel and k1..k6 grow
# together (the ZED 2's rational terms reach 14), so they get the wider RATIONAL_K_LIMIT instead.
DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y")
DISTORTION_LIMITS = (2.0, 10.0, 0.1, 0.1, 50.0, 100.0, 100.0, 100.0, 0.1, 0.1, 0.1, 0.1, 0.5, 0.5)
RATIONAL_K_LIMIT = 100.0
_RADIAL = (0, 1, 4, 5, 6, 7)  # indices of k1..k6 in dist


class CalibrationFileError(ConfigFileError):
    """A calibration file is missing, unreadable or has a bad key; the message names both."""


class CalibrationValueError(ValueError):
    """One argument of a StereoCalibration is wrong or implausible.

    Loaders use the parts to name their own key: ``argument`` is the constructor argument
    (``K_left``, ``dist_right``, ``R``, ``T``, ``image_size``), ``entry`` the element within it
    (``fx``, ``cy``, ``k1``, ...) or None, and ``problem`` says what is wrong and the expected range
    (it follows the entry's name: ``"= 7e+307 px is outside ..."`` when there is an entry).
    """

    def __init__(self, argument: str, problem: str, entry: str | None = None) -> None:
        self.argument, self.problem, self.entry = argument, problem, entry
        super().__init__(f"{argument}: {self.detail}")

    @property
    def detail(self) -> str:
        """The message without the argument's name."""
        return self.problem if self.entry is None else f"{self.entry} {self.problem}"


def _matrix(value, shape: tuple[int, ...], name: str) -> np.ndarray:
    array = np.asarray(value, dtype=np.float64)
    if array.shape != shape:
        raise CalibrationValueError(name, f"expected shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise CalibrationValueError(name, "contains NaN or infinite values")
    return array


def _distortion(value, name: str) -> np.ndarray:
    array = np.asarray(value if value is not None else (), dtype=np.float64).ravel()
    if array.size not in _DIST_LENGTHS:
        raise CalibrationValueError(name, f"expected (k1, k2, p1, p2, k3) or shorter, got {array.size} coefficients")
    if not np.all(np.isfinite(array)):
        raise CalibrationValueError(name, "contains NaN or infinite values")
    rational = array.size >= 8 and np.any(array[5:8] != 0)
    for i, coefficient in enumerate(array):
        limit = RATIONAL_K_LIMIT if rational and i in _RADIAL else DISTORTION_LIMITS[i]
        if abs(coefficient) > limit:
            model = "the rational model" if rational else "a lens without a fisheye"
            raise CalibrationValueError(name, f"= {coefficient:g} is outside [{-limit:g}, {limit:g}] ({model}; the "
                                        "limits and why are in estimator/calibration.py)", DISTORTION_NAMES[i])
    if array.size < 5:
        array = np.concatenate([array, np.zeros(5 - array.size)])
    return array


def _image_size(value) -> tuple[int, int]:
    size = tuple(value) if isinstance(value, tuple | list | np.ndarray) else ()
    lo, hi = IMAGE_SIDE_PX
    integral = all(isinstance(v, int | np.integer) and not isinstance(v, bool | np.bool_) for v in size)
    if len(size) != 2 or not integral or not all(lo <= v <= hi for v in size):
        raise CalibrationValueError("image_size", f"expected (width, height) as two integers in [{lo}, {hi}] px, "
                                    f"got {value!r}")
    return int(size[0]), int(size[1])


def _intrinsics(K: np.ndarray, name: str, image_size: tuple[int, int]) -> None:
    """Refuse a camera matrix no real camera of this image size has."""
    if not np.allclose(K[2], (0, 0, 1)):
        raise CalibrationValueError(name, "expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    lo, hi = FOCAL_PER_SIDE
    for entry, f, side, axis in (("fx", K[0, 0], image_size[0], "width"), ("fy", K[1, 1], image_size[1], "height")):
        if not lo * side <= f <= hi * side:
            fov = [math.degrees(2 * math.atan(1 / (2 * r))) for r in (lo, hi)]
            raise CalibrationValueError(name, f"= {f:g} px is outside [{lo * side:g}, {hi * side:g}] px ({lo:g} to "
                                        f"{hi:g} times the image {axis} of {side} px, a field of view of "
                                        f"{fov[0]:.0f} to {fov[1]:.1f} degrees)", entry)
    aspect = K[1, 1] / K[0, 0]
    if not FOCAL_ASPECT[0] <= aspect <= FOCAL_ASPECT[1]:
        raise CalibrationValueError(name, f"= {K[1, 1]:g} px is {aspect:.3g} times fx = {K[0, 0]:g} px; expected "
                                    f"{FOCAL_ASPECT[0]:g} to {FOCAL_ASPECT[1]:g} times (pixels are near square)", "fy")
    for entry, c, side in (("cx", K[0, 2], image_size[0]), ("cy", K[1, 2], image_size[1])):
        if not -0.5 <= c <= side - 0.5:
            raise CalibrationValueError(name, f"= {c:g} px is outside the image: expected -0.5 to {side - 0.5:g} px "
                                        "(the principal point lies in the image)", entry)


def _eye_rotation(R: np.ndarray) -> None:
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
        raise CalibrationValueError("R", "expected a proper rotation matrix (R R^T = I, det R = +1)")
    angle = math.degrees(math.acos(float(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))
    if angle > MAX_EYE_ROTATION_DEG:
        raise CalibrationValueError("R", f"turns the right eye by {angle:.1f} degrees against the left; a stereo "
                                    f"rig's eyes differ by at most {MAX_EYE_ROTATION_DEG:g} degrees")


def _baseline(T: np.ndarray, R: np.ndarray) -> None:
    """Refuse a baseline of implausible length, or one that does not put the right eye on the right."""
    length = float(np.linalg.norm(T))
    if length <= 0:
        raise CalibrationValueError("T", "the baseline is zero")
    lo, hi = BASELINE_M
    if not lo <= length <= hi:
        raise CalibrationValueError("T", f"the baseline |T| = {length:g} m is outside [{lo:g}, {hi:g}] m (T is in "
                                    "metres)")
    centre = -R.T @ T  # the right camera's centre in the left camera frame
    off_axis = math.degrees(math.acos(float(np.clip(centre[0] / length, -1.0, 1.0))))
    if off_axis >= 180.0 - MAX_BASELINE_OFF_AXIS_DEG:
        raise CalibrationValueError(
            "T", f"({T[0]:+.4g}, {T[1]:+.4g}, {T[2]:+.4g}) m puts the right camera {-centre[0]:.4g} m to the LEFT "
            "of the left camera; with x_right = R x_left + T, T is the left camera's centre seen from the right "
            "camera, so a right camera to the right of the left one has T_x < 0 (a 12 cm rig: T = (-0.12, 0, 0)); "
            "flip the sign of T, or swap the left and right images")
    if off_axis > MAX_BASELINE_OFF_AXIS_DEG:
        raise CalibrationValueError(
            "T", f"({T[0]:+.4g}, {T[1]:+.4g}, {T[2]:+.4g}) m puts the right camera {off_axis:.0f} degrees away from "
            f"the left camera's +x axis (at most {MAX_BASELINE_OFF_AXIS_DEG:g}): the eyes must sit side by side, "
            "the right one to the right (T_x < 0 with x_right = R x_left + T)")


def _frozen(array: np.ndarray) -> np.ndarray:
    array = np.array(array, dtype=np.float64)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """Intrinsics, distortion and extrinsics of a stereo pair (OpenCV conventions, metres).

    Every argument is checked against what a real stereo rig looks like (the limits at the top of
    this module): image sides of 16 to 16384 px; fx, fy 0.05 to 6 times the image width, height;
    the principal point inside the image; bounded distortion; eyes turned by at most 30 degrees;
    a baseline of 1 cm to 1 m with the right camera to the right (``T_x < 0``).

    Raises:
        CalibrationValueError: (a ValueError) an argument has the wrong shape or type, a
            non-finite entry, or an implausible value; the message names the argument, the entry
            and the expected range.
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
        size = _image_size(self.image_size)  # first: the intrinsics are judged against it
        set_(self, "image_size", size)
        for side in _SIDES:
            K = _matrix(getattr(self, f"K_{side}"), (3, 3), f"K_{side}")
            _intrinsics(K, f"K_{side}", size)
            set_(self, f"K_{side}", _frozen(K))
            set_(self, f"dist_{side}", _frozen(_distortion(getattr(self, f"dist_{side}"), f"dist_{side}")))
        R = _matrix(self.R, (3, 3), "R")
        _eye_rotation(R)
        set_(self, "R", _frozen(R))
        T = _matrix(np.asarray(self.T, dtype=np.float64).reshape(-1), (3,), "T")
        _baseline(T, R)
        set_(self, "T", _frozen(T))

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
            CalibrationFileError: the file is missing or malformed, or a value is implausible
                (see the class); the message names the file, the key and the expected range.
        """
        path = Path(path)
        top = TableReader(path, read_toml(path, "calibration", CalibrationFileError), error=CalibrationFileError)
        # a misspelt key is an error, not a default silently used ("baseline_m" is written for people to read)
        top.only(["image_size", "baseline_m", *sorted({s for s, _ in _FILE_KEYS.values() if s is not None})])
        tables = {None: top}
        values = {}
        for name, (section, key) in _FILE_KEYS.items():
            if section not in tables:  # a missing table is named by the key it should hold
                found = top.sub(section, required=False)
                tables[section] = found or TableReader(path, {}, section, error=CalibrationFileError)
            values[name] = tables[section].take(key, _tuple if name == "image_size" else _array)
        for section, reader in tables.items():
            if section is not None:
                reader.done()
        try:
            return cls(**values)
        except CalibrationValueError as e:
            section, key = _FILE_KEYS[e.argument]
            raise tables[section].error(key, e.detail) from e


def _array(value) -> np.ndarray:
    try:
        return np.asarray(value, float)
    except (TypeError, ValueError) as e:
        raise TypeError(f"expected a numeric array ({e})") from e


def _tuple(value) -> tuple:
    if not isinstance(value, list):
        raise TypeError(f"expected a numeric array [width, height], got {value!r}")
    return tuple(value)


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
    _nearest: dict = field(default_factory=dict, repr=False)
    _view: dict = field(default_factory=dict, repr=False)

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

    def nearest_map(self, side: str, step: int = 1) -> np.ndarray:
        """A ``cv2.remap`` map (CV_16SC2, no second map) to the raw pixel nearest every ``step``-th canvas pixel.

        Nearest-pixel lookups take this rounded map rather than the fixed-point pair of ``maps``: OpenCV
        5.0 read that pair's fractions the wrong way round under ``INTER_NEAREST`` (3.1 -> 4, 3.9 -> 3;
        fixed in 5.1), so the same images gave other coarse masks on another install.
        """
        key = (side, step)
        if key in self._nearest:
            return self._nearest[key]
        m1, m2 = self.maps(side)
        m1, m2 = m1[::step, ::step], m2[::step, ::step].astype(np.int32)
        # The second map indexes OpenCV's interpolation table: the x fraction in its low bits, y above.
        frac = np.stack([m2 & (_INTER_TAB - 1), m2 >> _INTER_BITS], axis=-1)
        self._nearest[key] = np.ascontiguousarray(m1 + (2 * frac >= _INTER_TAB).astype(np.int16))
        return self._nearest[key]

    def view_margin_px(self, side: str) -> np.ndarray:
        """(H, W) float32: how far each canvas pixel lies from the edge of what the camera saw (the
        canvas pixels whose raw pixel falls outside the raw image, and the canvas's own border).
        The canvas is grown to hold every raw pixel, so its corners and rims are black, not scene."""
        side = _side(side)
        if side not in self._view:
            m = self.nearest_map(side)
            w, h = self.calibration.image_size
            seen = (m[..., 0] >= 0) & (m[..., 0] < w) & (m[..., 1] >= 0) & (m[..., 1] < h)
            seen = np.pad(seen, 1).astype(np.uint8)  # beyond the canvas nothing is seen
            self._view[side] = cv2.distanceTransform(seen, cv2.DIST_L2, 3)[1:-1, 1:-1]
        return self._view[side]

    def rectify_image(self, image: np.ndarray, side: str, roi: tuple[int, int, int, int] | None = None,
                      interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
        """Resample a raw image onto the rectified canvas, or onto ``roi = (x0, y0, x1, y1)`` of it."""
        m1, m2 = self.maps(side)
        if interpolation == cv2.INTER_NEAREST:
            m1, m2 = self.nearest_map(side), None  # see nearest_map
        if roi is not None:
            x0, y0, x1, y1 = roi
            m1, m2 = m1[y0:y1, x0:x1], None if m2 is None else m2[y0:y1, x0:x1]
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
