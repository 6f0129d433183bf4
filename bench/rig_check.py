"""``softarm rig check``: open the rig's devices, report what they are, move nothing, vent and close.

It checks the ``[rig]`` section whatever the config's backend is, so a rig can be verified
before a run is switched over to it.
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np

from bench.config import ConfigError, load_bench_config
from bench.factory import make_devices
from estimator import CalibrationFileError, StereoCalibration
from hardware.errors import DeviceError


def rig_command(args) -> int:
    """Run the check; ``args.config`` may be None (the default config). Returns the exit code."""
    try:
        config = load_bench_config(getattr(args, "config", None))
        if config.rig is None:
            raise ConfigError(f"{config.path}: no [rig] section to check")
        print(f"softarm rig check: {config.path}")
        devices = make_devices(dataclasses.replace(config, backend="rig"))
        with devices:
            for line in describe_rig(devices, config.rig.camera.calibration):
                print(line, flush=True)
    except (ConfigError, CalibrationFileError, DeviceError, ValueError, OSError) as e:
        print(f"softarm rig check: FAILED: {e}", file=sys.stderr)
        return 1
    print("valves vented, devices closed: rig OK")
    return 0


def describe_rig(devices, calibration_path) -> list[str]:
    """Report lines for the camera mode, one grabbed frame, the calibration and the valve board."""
    camera, valves = devices.camera, devices.valves
    frame = camera.grab()
    lines = [f"camera       {camera.mode}",
             f"             grabbed frame {frame.index}: 2 x {frame.left.shape[1]}x{frame.left.shape[0]}"]
    lines.append(f"calibration  {calibration_path}")
    lines += ["             " + text for text in calibration_summary(camera.calibration)]
    version, status = valves.version, valves.status()
    lines += [
        f"valve board  {valves.port} at {valves.baud} baud: firmware {version.firmware}, protocol {version.protocol}, "
        f"{version.channels} channels, limit {version.max_mbar / 1000:g} bar, step {version.lsb_umbar / 1000:g} mbar, "
        f"watchdog {version.watchdog_ms} ms",
        f"             e-stop {'LATCHED' if status.estop else 'released'}, set-points "
        + " ".join(f"{name}(ch{ch})={status.setpoints_mbar[ch]}" for name, ch in valves.board_channels.items())
        + " mbar",
        f"             host limit {valves.max_pressure_bar:g} bar",
    ]
    return lines


def calibration_summary(calib: StereoCalibration) -> list[str]:
    """Focal lengths, baseline and the rectification error on synthetic points, as report lines."""
    rms_px, max_px = rectification_error_px(calib)
    rect = calib.rectification
    return [
        f"focal left {calib.K_left[0, 0]:.1f}/{calib.K_left[1, 1]:.1f} px, right {calib.K_right[0, 0]:.1f}/"
        f"{calib.K_right[1, 1]:.1f} px, image {calib.image_size[0]}x{calib.image_size[1]}",
        f"baseline {calib.baseline_m * 1000:.2f} mm (rectified {rect.baseline_m * 1000:.2f} mm at focal "
        f"{rect.focal_px:.1f} px)",
        f"rectification error on synthetic points: {rms_px:.4f} px rms, {max_px:.4f} px max (row mismatch)",
    ]


def rectification_error_px(calib: StereoCalibration, n_points: int = 400, seed: int = 0) -> tuple[float, float]:
    """Row mismatch between the rectified left and right images of synthetic 3D points.

    Points are drawn 0.4-3 m in front of the left camera across its field of view, projected
    into both raw images with the calibration, and rectified; ideal rectification puts each
    point on the same row in both.

    Returns:
        (rms, max) of |v_left - v_right| in rectified pixels, over the points seen by both cameras.
    """
    rng = np.random.default_rng(seed)
    w, h = calib.image_size
    uv = rng.uniform((0, 0), (w, h), size=(n_points, 2))
    depth = rng.uniform(0.4, 3.0, size=n_points)
    K = calib.K_left
    points = np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(n_points)])
    points *= depth[:, None]
    uv_left, uv_right = calib.project(points, "left"), calib.project(points, "right")
    seen = np.all((uv_left >= 0) & (uv_left < (w, h)) & (uv_right >= 0) & (uv_right < (w, h)), axis=1)
    rect = calib.rectification
    rows = rect.rectify_points(uv_left[seen], "left")[:, 1] - rect.rectify_points(uv_right[seen], "right")[:, 1]
    return float(np.sqrt(np.mean(rows**2))), float(np.max(np.abs(rows)))
