"""``softarm rig check``: open the rig's devices, report what they are, move nothing, vent and close.

Each device is checked on its own (the calibration file, the camera, the valve board), so one that
fails does not hide the state of the others: every device is reported, then the failures.

The calibration is checked against the camera itself: one grabbed frame is rectified with it
and the rows of features matched between the two eyes are compared (``rectified_row_mismatch``).

It checks the ``[rig]`` section whatever the config's backend is, so a rig can be verified
before a run is switched over to it.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import cv2
import numpy as np

from bench.config import ConfigError, load_bench_config
from bench.factory import nominal_calibration, rig_calibration, rig_camera, serial_valves
from estimator import CalibrationFileError, StereoCalibration
from hardware.errors import DeviceError


def rig_command(args) -> int:
    """Run the check; ``args.config`` may be None (the default config). Returns the exit code: 0 when
    every device is fine, 1 when the config is unusable or any device failed (the others are still
    checked and reported)."""
    try:
        config = load_bench_config(getattr(args, "config", None))
        if config.rig is None:
            raise ConfigError(f"{config.path}: no [rig] section to check")
    except ConfigError as e:
        print(f"softarm rig check: FAILED: {e}", file=sys.stderr)
        return 1
    print(f"softarm rig check: {config.path}")
    failed = []
    for name, check in (("calibration", _check_calibration), ("camera", _check_camera), ("valves", _check_valves)):
        lines, error = check(config)
        for line in lines:
            print(line, flush=True)
        if error is not None:
            failed.append(name)
            print(f"{_LABELS[name]} FAILED: {error}", file=sys.stderr, flush=True)
    if failed:
        print(f"softarm rig check: FAILED: {', '.join(failed)} (the other devices are reported above); nothing was "
              "moved", file=sys.stderr)
        return 1
    print("valves vented, devices closed: rig OK")
    return 0


_LABELS = {"calibration": "calibration ", "camera": "camera      ", "valves": "valve board "}
_INDENT = " " * 13
_ERRORS = (ConfigError, CalibrationFileError, DeviceError, ValueError, OSError)


def _check_calibration(config) -> tuple[list[str], BaseException | None]:
    cam = config.rig.camera
    try:
        calibration = rig_calibration(cam, config.path)
    except _ERRORS as e:
        return [], e
    return [f"calibration  {cam.calibration}"] + [_INDENT + line for line in calibration_summary(calibration)], None


def _check_camera(config) -> tuple[list[str], BaseException | None]:
    """Open the camera, grab one frame, and (with a usable calibration) measure the calibration against it."""
    cam = config.rig.camera
    try:
        calibration = rig_calibration(cam, config.path)
    except _ERRORS:
        calibration = None  # reported by _check_calibration; the camera is still opened and read
    try:
        camera = rig_camera(cam, config.path, calibration or nominal_calibration(cam))
    except _ERRORS as e:
        return [], e
    try:
        frame = camera.grab()
        lines = [f"camera       {camera.mode}",
                 f"{_INDENT}grabbed frame {frame.index}: 2 x {frame.left.shape[1]}x{frame.left.shape[0]}"]
        if calibration is not None:
            lines.append(_INDENT + row_mismatch_line(calibration, frame))
        else:
            lines.append(f"{_INDENT}(the calibration is not measured against the camera: it could not be loaded)")
        if _grey(frame.left):  # the estimator finds the arm by its colour
            lines.append(f"{_INDENT}warning: the frame has no colour (grey: its three channels are equal); the "
                         "estimator segments the arm by its colour and will find none")
    except _ERRORS as e:
        return [f"camera       {camera.mode}"], e
    finally:
        camera.close()
    return lines, None


def _grey(image: np.ndarray) -> bool:
    """Whether a BGR image carries no colour: its three channels equal at every pixel."""
    return bool(image.ndim == 3 and np.array_equal(image[..., 0], image[..., 1])
                and np.array_equal(image[..., 1], image[..., 2]))


def _check_valves(config) -> tuple[list[str], BaseException | None]:
    """Connect to the valve board (which vents), report what it says, close (vents again); no set-point."""
    valves_config = config.rig.valves
    if valves_config is None:
        return [], ConfigError(f"{config.path}: no [rig.valves] section (the valve board's port and channels)")
    try:
        valves = serial_valves(valves_config)
        with valves:  # connects (and vents); closing vents again
            return describe_valves(valves), None
    except _ERRORS as e:
        return [], e


def describe_valves(valves) -> list[str]:
    """Report lines of a connected valve board: firmware, limits, e-stop, set-points."""
    version, status = valves.version, valves.status()
    return [
        f"valve board  {valves.port} at {valves.baud} baud: firmware {version.firmware}, protocol {version.protocol}, "
        f"{version.channels} channels, limit {version.max_mbar / 1000:g} bar, step {version.lsb_umbar / 1000:g} mbar, "
        f"watchdog {version.watchdog_ms} ms",
        f"{_INDENT}e-stop {'LATCHED' if status.estop else 'released'}, set-points "
        + " ".join(f"{name}(ch{ch})={status.setpoints_mbar[ch]}" for name, ch in valves.board_channels.items())
        + " mbar",
        f"{_INDENT}host limit {valves.max_pressure_bar:g} bar",
        f"{_INDENT}unreadable frames (line noise) since the board started: {status.unreadable_frames}",
    ]


def calibration_summary(calib: StereoCalibration, frame=None) -> list[str]:
    """Focal lengths, baseline and, given a grabbed frame, how well the calibration rectifies it, as report lines."""
    rect = calib.rectification
    lines = [
        f"focal left {calib.K_left[0, 0]:.1f}/{calib.K_left[1, 1]:.1f} px, right {calib.K_right[0, 0]:.1f}/"
        f"{calib.K_right[1, 1]:.1f} px, image {calib.image_size[0]}x{calib.image_size[1]}",
        f"baseline {calib.baseline_m * 1000:.2f} mm (rectified {rect.baseline_m * 1000:.2f} mm at focal "
        f"{rect.focal_px:.1f} px)",
    ]
    return lines if frame is None else [*lines, row_mismatch_line(calib, frame)]


def row_mismatch_line(calib: StereoCalibration, frame) -> str:
    """How well ``calib`` rectifies a grabbed frame, as one report line (``rectified_row_mismatch``)."""
    mismatch = rectified_row_mismatch(calib, frame.left, frame.right)
    if mismatch.matches < MIN_MATCHES:
        return (f"row mismatch after rectification: not measured (only {mismatch.matches} features matched "
                f"between the eyes in the grabbed frame; point the camera at a textured, well-lit scene)")
    return (f"row mismatch after rectification: median {mismatch.median_px:.2f} px, 90 % under "
            f"{mismatch.p90_px:.2f} px ({mismatch.matches} features matched between the eyes in the "
            f"grabbed frame; under ~0.5 px: the file fits this camera; a few px: the wrong file, or a "
            f"knocked camera)")


# Fewer matches than this and the median says more about false matches than about the calibration.
MIN_MATCHES = 20


@dataclass(frozen=True)
class RowMismatch:
    """Vertical disparity of features matched between the rectified eyes of one frame.

    Attributes:
        matches: features matched (after the ratio test, with non-negative disparity).
        median_px, p90_px: median and 90th percentile of |v_left - v_right|, rectified pixels
            (NaN without matches).
    """

    matches: int
    median_px: float
    p90_px: float


def rectified_row_mismatch(calib: StereoCalibration, left: np.ndarray, right: np.ndarray) -> RowMismatch:
    """How far apart the rows of the same scene points are after rectifying a real frame with ``calib``.

    A calibration that fits the camera puts every point on the same row in both rectified images
    (the epipolar constraint); the wrong file, or a camera whose eyes moved since it was
    calibrated, leaves a vertical disparity. Unlike points projected with the calibration itself
    (which agree by construction), this measures the file against the camera. ORB features are
    detected inside the valid area of both rectified images and matched with Lowe's ratio test;
    matches with a negative disparity (a point behind the cameras) are dropped as false.

    Args:
        calib: the calibration under test.
        left, right: raw (H, W, 3) uint8 BGR images of one stereo frame, W x H the calibration's size.

    Returns:
        The match count and the median and 90th percentile of the row differences, pixels.
    """
    rect = calib.rectification
    grey, masks = [], []
    for side, image in (("left", left), ("right", right)):
        grey.append(cv2.cvtColor(rect.rectify_image(image, side), cv2.COLOR_BGR2GRAY))
        # the rectified canvas is larger than the raw image; no features on the edge of the valid area
        valid = rect.rectify_image(np.full(image.shape[:2], 255, np.uint8), side, interpolation=cv2.INTER_NEAREST)
        masks.append(cv2.erode(valid, np.ones((15, 15), np.uint8)))
    orb = cv2.ORB_create(nfeatures=4000)
    (kp_l, des_l), (kp_r, des_r) = (orb.detectAndCompute(g, m) for g, m in zip(grey, masks, strict=True))
    if des_l is None or des_r is None or len(kp_r) < 2:
        return RowMismatch(0, math.nan, math.nan)
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(des_l, des_r, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.75 * p[1].distance]
    if not good:
        return RowMismatch(0, math.nan, math.nan)
    good = sorted(good, key=lambda m: m.distance)[:MAX_REFINED]
    uv_l = np.array([kp_l[m.queryIdx].pt for m in good])
    uv_r = np.array([kp_r[m.trainIdx].pt for m in good])
    plausible = uv_l[:, 0] - uv_r[:, 0] >= -1.0  # a point in front of the cameras has disparity >= 0
    dv = [d for a, b in zip(uv_l[plausible], uv_r[plausible], strict=True)
          if (d := _row_offset_px(grey[0], grey[1], a, b)) is not None]
    if not dv:
        return RowMismatch(0, math.nan, math.nan)
    dv = np.abs(np.array(dv))
    return RowMismatch(int(dv.size), float(np.median(dv)), float(np.percentile(dv, 90)))


MAX_REFINED = 500  # best matches refined to sub-pixel rows (ORB's keypoints sit on whole pixels)
_HALF_PATCH, _SEARCH = 7, 4


def _row_offset_px(left: np.ndarray, right: np.ndarray, uv_left: np.ndarray, uv_right: np.ndarray) -> float | None:
    """Sub-pixel row of the left patch around ``uv_left`` found near ``uv_right``, minus the left row.

    Normalised cross-correlation over a +-4 px window, refined by a parabola through the peak;
    None near the border, or when the peak is weak or on the window's edge (no reliable match).
    """
    (xl, yl), (xr, yr) = np.round(uv_left).astype(int), np.round(uv_right).astype(int)
    h, w = left.shape
    r, s = _HALF_PATCH, _HALF_PATCH + _SEARCH
    if not (s <= xl < w - s and s <= yl < h - s and s <= xr < w - s and s <= yr < h - s):
        return None
    patch = left[yl - r:yl + r + 1, xl - r:xl + r + 1]
    window = right[yr - s:yr + s + 1, xr - s:xr + s + 1]
    if patch.std() < 2.0:
        return None
    score = cv2.matchTemplate(window, patch, cv2.TM_CCOEFF_NORMED)
    iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
    if score[iy, ix] < 0.8 or not (0 < iy < score.shape[0] - 1):
        return None
    above, peak, below = score[iy - 1, ix], score[iy, ix], score[iy + 1, ix]
    curvature = above - 2 * peak + below
    sub = 0.0 if curvature >= 0 else 0.5 * (above - below) / curvature
    return float(yr - _SEARCH + iy + sub - yl)
