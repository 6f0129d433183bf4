"""Devices without hardware for tests: in-memory camera and valves, a stand-in twin, recorded sources.

The fakes implement the same contracts as the real drivers (``tests/hardware/test_contracts.py``
runs them through the same suite), so a test that passes with them exercises the contract,
not a shortcut. Nothing here imports pyserial or the twin.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from estimator import StereoCalibration
from hardware.errors import DeviceError, NotConnectedError
from hardware.interfaces import StereoCamera, StereoFrame, ValveBank

ARM_CHANNELS = ("s1_a", "s1_b", "s1_c", "s1_d", "s2_a", "s2_b", "s3")


def small_calibration(width: int = 64, height: int = 48) -> StereoCalibration:
    """A small, mildly distorted ZED-like pair (12 cm baseline) for fast image tests."""
    f = 0.55 * width
    K = np.array([[f, 0.0, width / 2 - 0.5], [0.0, f, height / 2 - 0.5], [0.0, 0.0, 1.0]])
    R = cv2.Rodrigues(np.array([0.002, -0.003, 0.001]))[0]
    return StereoCalibration(K, [-0.05, 0.01, 0, 0, 0], K, [-0.04, 0.008, 0, 0, 0], R, [-0.12, 0.0, 0.0],
                             (width, height))


def side_by_side_frames(calibration: StereoCalibration, count: int) -> list[np.ndarray]:
    """Distinct side-by-side BGR frames: the left eye's colour encodes the frame number, the right eye's differs.

    Returns:
        ``count`` arrays of shape (H, 2W, 3) uint8, W x H the calibration's image size.
    """
    width, height = calibration.image_size
    frames = []
    for i in range(count):
        frame = np.zeros((height, 2 * width, 3), np.uint8)
        frame[:, :width] = (10 * i % 256, 200, 50)
        frame[:, width:] = (50, 100, 255 - 10 * i % 256)
        frames.append(frame)
    return frames


def write_side_by_side_video(path: Path, frames: list[np.ndarray], fps: float = 30.0) -> Path:
    """Write frames losslessly (FFV1 in Matroska) so a reader gets the exact pixels back."""
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), fps, (width, height))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write FFV1 video to {path}")
    for frame in frames:
        writer.write(frame)
    writer.release()
    return path


def write_side_by_side_folder(folder: Path, frames: list[np.ndarray]) -> Path:
    """Write frames as numbered PNGs (lossless)."""
    folder.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(frames):
        cv2.imwrite(str(folder / f"frame_{i:05d}.png"), frame)
    return folder


class FakeStereoCamera(StereoCamera):
    """An in-memory stereo camera: grey frames whose brightness is the frame index, 30 fps time."""

    def __init__(self, calibration: StereoCalibration | None = None) -> None:
        self._calibration = calibration or small_calibration()
        self._connected = False
        self._index = 0
        self.closed_count = 0

    @property
    def calibration(self) -> StereoCalibration:
        return self._calibration

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        if self._connected:
            raise DeviceError("FakeStereoCamera: connect() while already connected")
        self._connected, self._index = True, 0

    def grab(self) -> StereoFrame:
        if not self._connected:
            raise NotConnectedError("FakeStereoCamera: grab() before connect()")
        width, height = self._calibration.image_size
        image = np.full((height, width, 3), self._index % 256, np.uint8)
        frame = StereoFrame(image, image.copy(), self._index / 30.0, self._index)
        self._index += 1
        return frame

    def close(self) -> None:
        if self._connected:
            self.closed_count += 1
        self._connected = False


class FakeValveBank(ValveBank):
    """An in-memory valve bank; ``applied_bar`` is what the valves are driven to, ``history`` every command."""

    def __init__(self, channels=ARM_CHANNELS, max_pressure_bar: float = 2.5, clamp: bool = False) -> None:
        super().__init__(channels, max_pressure_bar, clamp)
        self._connected = False
        self.applied_bar = np.zeros(len(self.channels))
        self.history: list[np.ndarray] = []

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        if self._connected:
            raise DeviceError("FakeValveBank: connect() while already connected")
        self._connected = True

    def _apply(self, setpoints_bar: np.ndarray) -> None:
        self.applied_bar = np.array(setpoints_bar, dtype=float)
        self.history.append(self.applied_bar.copy())

    def _vent(self) -> None:
        self._apply(np.zeros(len(self.channels)))

    def _disconnect(self) -> None:
        self._connected = False


class FakeTwin:
    """Stands in for ``twin.Twin`` in factory tests: same construction and attributes, no physics."""

    def __init__(self, config_path: Path) -> None:
        self.config_path = Path(config_path)
        self.camera = FakeStereoCamera()
        self.valves = FakeValveBank()
        self.closed = False

    @classmethod
    def from_config(cls, path: Path) -> FakeTwin:
        return cls(path)

    def close(self) -> None:
        self.closed = True
