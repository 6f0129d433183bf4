"""One flag, one factory: ``make_devices(config)`` returns the twin's devices or the rig's.

Each branch imports its own drivers, so a rig run never loads MuJoCo, pyrender or the twin,
and a simulated run never imports pyserial or opens a port. Everything that can fail without
moving anything (the calibration file, the camera, the board's answer) is checked before the
valves are connected; a failure closes what was already opened.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.config import BenchConfig, RigConfig, SimConfig
from estimator import StereoCalibration
from hardware.interfaces import StereoCamera, ValveBank


@dataclass
class Devices:
    """The connected camera and valves of one backend; ``close()`` vents, then releases everything.

    Attributes:
        camera: the stereo camera (connected).
        valves: the valve bank (connected, vented).
        twin: the ``twin.Twin`` in simulation (ground truth lives there), None on the rig.
    """

    camera: StereoCamera
    valves: ValveBank
    twin: Any = None

    def close(self) -> None:
        """Vent and close the valves, then close the camera and the twin, even if one step fails."""
        try:
            self.valves.close()
        finally:
            try:
                self.camera.close()
            finally:
                close_twin = getattr(self.twin, "close", None)
                if close_twin is not None:
                    close_twin()

    def __enter__(self) -> Devices:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def make_devices(config: BenchConfig) -> Devices:
    """Open the devices of ``config.backend`` ("sim" or "rig").

    Raises:
        CalibrationFileError: the rig's calibration file is missing or malformed.
        DeviceError: a device cannot be opened, or does not match its configuration.
        ValueError: the backend is not one of "sim", "rig".
    """
    if config.backend == "rig":
        return _make_rig(config.rig)
    if config.backend == "sim":
        return _make_sim(config.sim)
    raise ValueError(f"backend: expected 'sim' or 'rig', got {config.backend!r}")


def load_calibration(path: Path, resolution: str) -> StereoCalibration:
    """A Stereolabs ``.conf`` (for ``resolution``) or a softarm calibration ``.toml``."""
    if Path(path).suffix.lower() == ".conf":
        from hardware.zed import load_factory_calibration

        return load_factory_calibration(path, resolution)
    return StereoCalibration.load(path)


def _make_rig(rig: RigConfig) -> Devices:
    from hardware.valves import SerialValveBank
    from hardware.zed import ZedCamera

    cam = rig.camera
    calibration = load_calibration(cam.calibration, cam.resolution)
    camera = ZedCamera(cam.source, calibration, cam.resolution, cam.fps, loop=cam.loop)
    valves = SerialValveBank(rig.valves.port, dict(rig.valves.channels), rig.valves.max_pressure_bar,
                             baud=rig.valves.baud, clamp=rig.valves.clamp)
    camera.connect()
    try:
        valves.connect()
    except BaseException:
        camera.close()
        raise
    return Devices(camera, valves, None)


def _make_sim(sim: SimConfig) -> Devices:
    from twin import Twin

    twin = Twin.from_config(sim.twin)
    devices = Devices(twin.camera, twin.valves, twin)
    try:
        for device in (devices.camera, devices.valves):
            if not device.is_connected:
                device.connect()
    except BaseException:
        devices.close()
        raise
    return devices
