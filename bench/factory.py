"""One flag, one factory: ``make_devices(config)`` returns the twin's devices or the rig's.

The devices carry their backend's differences (``bench.devices``): the twin comes with a clock that
advances its physics, its exact truth and an archive that keeps its frames as noise-free renders;
the rig with the wall clock and its pressure thread, a depth folder when ``[rig.depth]`` names one,
and an archive that keeps the frames as captured. Everything above the factory is backend-blind.

Each branch imports its own drivers, so a rig run never loads MuJoCo, pyrender or the twin,
and a simulated run never imports pyserial or opens a port. Everything that can fail without
moving anything (the calibration file, the camera, the board's answer) is checked before the
valves are connected; a failure closes what was already opened. A missing or unusable file or
device is reported with the config file and the key that named it, e.g.
``models/bench.toml [rig.camera] calibration: models/SN00000.conf: calibration file not found``.
"""

from __future__ import annotations

from pathlib import Path

from bench.config import BenchConfig, CameraConfig, ConfigError, RigConfig, SimConfig, ValvesConfig
from bench.devices import DepthFolder, Devices, FrameArchive, RealClock, TwinArchive, TwinClock, TwinTruth
from estimator import CalibrationFileError, StereoCalibration
from hardware.errors import DeviceError
from hardware.interfaces import ValveBank


def make_devices(config: BenchConfig, *, valves: bool = True,
                 calibration: StereoCalibration | None = None) -> Devices:
    """Open the devices of ``config.backend`` ("sim" or "rig") with what the capture loop needs besides:
    the clock, the truth and the archive (``bench.devices``).

    Args:
        config: the bench config.
        valves: open the valves too; False where nothing moves (``softarm calibrate``): the rig's
            valve board is then left alone (``Devices.valves`` is None).
        calibration: the rig only: open the camera with this calibration instead of the configured
            one (a stand-in when that one is missing, to calibrate the camera).

    Raises:
        ConfigError: the twin's file (``[sim] twin``) does not exist, or the rig has no ``[rig.valves]``.
        CalibrationFileError: the rig's calibration file is missing or malformed.
        DeviceError: a device cannot be opened, or does not match its configuration.
        ValueError: the backend is not one of "sim", "rig", or a ``[rig.camera]`` value the
            camera refuses (a source that does not exist, ...).
    """
    if config.backend == "rig":
        return _make_rig(config.rig, config.path, valves=valves, calibration=calibration)
    if config.backend == "sim":
        return _make_sim(config.sim, config.path, depth=config.recording.depth,
                         noise_free=config.recording.lossless_frames)
    raise ValueError(f"backend: expected 'sim' or 'rig', got {config.backend!r}")


def load_calibration(path: Path, resolution: str) -> StereoCalibration:
    """A Stereolabs ``.conf`` (for ``resolution``) or a softarm calibration ``.toml``."""
    if Path(path).suffix.lower() == ".conf":
        from hardware.zed import load_factory_calibration

        return load_factory_calibration(path, resolution)
    return StereoCalibration.load(path)


def rig_calibration(cam: CameraConfig, config_path: Path) -> StereoCalibration:
    """The calibration ``[rig.camera] calibration`` names.

    Raises:
        CalibrationFileError: missing or malformed; the message starts with the config file and the key.
    """
    try:
        calibration = load_calibration(cam.calibration, cam.resolution)
    except CalibrationFileError as e:
        raise CalibrationFileError(f"{config_path} [rig.camera] calibration: {e}") from e
    if cam.is_device and Path(cam.calibration).suffix.lower() != ".conf":
        # a .conf holds every resolution and is read for this one; a .toml holds one: it must be this one
        from hardware.zed import ZED_RESOLUTIONS

        eye = ZED_RESOLUTIONS[cam.resolution]
        if tuple(calibration.image_size) != tuple(eye):
            raise CalibrationFileError(
                f"{config_path} [rig.camera] calibration: {cam.calibration} is for {calibration.image_size[0]}x"
                f"{calibration.image_size[1]} images, but resolution = {cam.resolution!r} gives {eye[0]}x{eye[1]} "
                "per eye: calibrate at this resolution, or set the resolution the file was made for")
    return calibration


def nominal_calibration(cam: CameraConfig) -> StereoCalibration:
    """A stand-in calibration, only to open a camera whose calibration is missing or broken (the raw
    frames do not depend on it): a ZED-like pinhole pair of the per-eye size the source delivers,
    the resolution's for a device, the recording's own for a video or image folder."""
    import numpy as np

    from hardware.zed import ZED_RESOLUTIONS

    size = None if cam.is_device else _recording_eye_size(cam.source)
    w, h = size or ZED_RESOLUTIONS[cam.resolution]
    K = np.array([[w * 0.55, 0, (w - 1) / 2], [0, w * 0.55, (h - 1) / 2], [0, 0, 1.0]])
    return StereoCalibration(K, np.zeros(5), K, np.zeros(5), np.eye(3), np.array([-0.12, 0.0, 0.0]), (w, h))


def _recording_eye_size(source: Path) -> tuple[int, int] | None:
    """(width, height) of one eye of a side-by-side video or image folder, or None when it cannot be read."""
    import cv2

    from hardware.zed import IMAGE_SUFFIXES

    source = Path(source)
    if source.is_dir():
        images = sorted(p for p in source.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        image = cv2.imread(str(images[0]), cv2.IMREAD_COLOR) if images else None
        size = None if image is None else (image.shape[1], image.shape[0])
    else:
        capture = cv2.VideoCapture(str(source))
        size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))) \
            if capture.isOpened() else None
        capture.release()
    if size is None or size[0] < 2 or size[1] < 1:
        return None
    return size[0] // 2, size[1]


def rig_camera(cam: CameraConfig, config_path: Path, calibration: StereoCalibration):
    """The ``hardware.zed.ZedCamera`` of ``[rig.camera]``, connected.

    Raises:
        ValueError: the camera refuses a ``[rig.camera]`` value (a source that does not exist, ...).
        DeviceError: the source cannot be opened or does not fit the calibration.
        Both messages start with the config file and ``[rig.camera]`` and the key.
    """
    from hardware.zed import ZedCamera

    try:
        camera = ZedCamera(cam.source, calibration, cam.resolution, cam.fps, loop=cam.loop)
    except ValueError as e:  # the driver's messages start with the key ("source: ...", "fps: ...")
        raise ValueError(f"{config_path} [rig.camera] {e}") from e
    try:
        camera.connect()
    except DeviceError as e:
        raise DeviceError(f"{config_path} [rig.camera] source: {e}") from e
    return camera


def serial_valves(valves: ValvesConfig) -> ValveBank:
    """The valve board of ``[rig.valves]`` (``hardware.valves.SerialValveBank``), not yet connected."""
    from hardware.valves import SerialValveBank

    return SerialValveBank(valves.port, dict(valves.channels), valves.max_pressure_bar, baud=valves.baud,
                           clamp=valves.clamp, clamp_tolerance=valves.clamp_tolerance,
                           reply_timeout_s=valves.reply_timeout_s)


def _make_rig(rig: RigConfig, config_path: Path, *, valves: bool,
              calibration: StereoCalibration | None) -> Devices:
    if valves and rig.valves is None:
        raise ConfigError(f"{config_path} [rig.valves]: the rig backend drives the valve board; add a [rig.valves] "
                          "section with its port (only `softarm calibrate` works without one)")
    cam = rig.camera
    calibration = calibration if calibration is not None else rig_calibration(cam, config_path)
    depth = None if rig.depth is None else DepthFolder(rig.depth.source, rig.depth.scale_m)
    bank = serial_valves(rig.valves) if valves else None
    camera = rig_camera(cam, config_path, calibration)
    try:
        if bank is not None:
            try:
                bank.connect()
            except DeviceError as e:  # the board, its port or its limits against this file's [rig.valves]
                raise type(e)(f"{config_path} [rig.valves]: {e}") from e
    except BaseException:
        camera.close()
        raise
    return Devices(camera, bank, RealClock(), depth, FrameArchive())


def _make_sim(sim: SimConfig, config_path: Path, *, depth: bool, noise_free: bool) -> Devices:
    if not Path(sim.twin).is_file():
        raise ConfigError(f"{config_path} [sim] twin: {sim.twin}: twin file not found")
    from twin import Twin

    twin = Twin.from_config(sim.twin)
    devices = Devices(twin.camera, twin.valves, TwinClock(twin), TwinTruth(twin),
                      TwinArchive(twin.camera, depth, noise_free), twin, grab_name="render")
    try:
        for device in (devices.camera, devices.valves):
            if not device.is_connected:
                device.connect()
    except BaseException:
        devices.close()
        raise
    return devices
