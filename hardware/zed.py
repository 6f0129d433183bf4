"""The ZED stereo camera without the vendor SDK: UVC capture and the factory calibration file.

Over UVC the ZED streams one side-by-side YUYV frame (left eye, then right), hardware
synchronised. ``ZedCamera`` opens it by device index or path, or opens a side-by-side video
file or image folder instead (how sessions are replayed and how the driver is tested).
``load_factory_calibration`` reads Stereolabs' ``SN<serial>.conf`` into OpenCV conventions.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from estimator import CalibrationFileError, StereoCalibration
from estimator.calibration import BASELINE_M, MAX_EYE_ROTATION_DEG, CalibrationValueError
from hardware.errors import DeviceError, EndOfStreamError, NotConnectedError
from hardware.interfaces import StereoCamera, StereoFrame

_log = logging.getLogger(__name__)

# Per-eye image size (width, height) of each ZED resolution, and the frame rates it offers.
ZED_RESOLUTIONS = {"2K": (2208, 1242), "FHD": (1920, 1080), "HD": (1280, 720), "VGA": (672, 376)}
ZED_FPS = {"2K": (15,), "FHD": (15, 30), "HD": (15, 30, 60), "VGA": (15, 30, 60, 100)}
_ALIASES = {"HD2K": "2K", "HD1080": "FHD", "1080": "FHD", "HD720": "HD", "720": "HD"}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")
# What a factory file may say: the calibration's plausible baseline in the file's millimetres, and
# its largest eye rotation for each rotation key (radians in the file).
_BASELINE_MM = (1000.0 * BASELINE_M[0], 1000.0 * BASELINE_M[1])
_MAX_ROTATION_RAD = math.radians(MAX_EYE_ROTATION_DEG)


def resolution_name(resolution: str) -> str:
    """Normalise a ZED resolution name ("HD", "hd720", "FHD", ...) to a key of ``ZED_RESOLUTIONS``.

    Raises:
        ValueError: not a ZED resolution; the message lists the allowed names.
    """
    key = str(resolution).strip().upper()
    key = _ALIASES.get(key, key)
    if key not in ZED_RESOLUTIONS:
        raise ValueError(f"resolution: expected one of {', '.join(ZED_RESOLUTIONS)} (or HD2K, HD1080, HD720), "
                         f"got {resolution!r}")
    return key


# --- factory calibration ------------------------------------------------------------------


def load_factory_calibration(path: str | Path, resolution: str = "HD") -> StereoCalibration:
    """Read a Stereolabs factory calibration file (``SN<serial>.conf``) for one resolution.

    Intrinsics come from ``[LEFT_CAM_<R>]``/``[RIGHT_CAM_<R>]`` (fx, fy, cx, cy required; k1, k2,
    p1, p2, k3 default to 0; newer ``[*_DISTO]`` sections are ignored). The stereo pose comes
    from ``[STEREO]``: ``R = Rodrigues(RX_<R>, CV_<R>, RZ_<R>)`` and
    ``T = -(Baseline, TY, TZ) / 1000`` metres, TY/TZ read with or without the ``_<R>`` suffix
    and 0 when absent. Keys are case-insensitive; a UTF-8 BOM and spaces around ``=`` are fine.
    Stereolabs store ``Baseline`` as a positive distance in millimetres and the rotations in
    radians: a Baseline outside [10, 1000] mm or a rotation key beyond 30 degrees is refused, and so
    is anything ``StereoCalibration`` finds implausible (a focal length, principal point or
    distortion no real lens has), each naming the section and key.

    Args:
        path: the ``.conf`` file.
        resolution: "2K", "FHD", "HD" or "VGA" (aliases HD2K, HD1080, HD720).

    Returns:
        The calibration of the raw per-eye images, ``image_size`` the per-eye size.

    Raises:
        CalibrationFileError: the file is missing or malformed, or a section or key needed for
            this resolution is missing, not a number or implausible; the message names file,
            section and key (and the expected range).
    """
    # Sign conventions, checked against Stereolabs' own OpenCV samples (stereolabs/zed-opencv-native
    # cpp/include/calibration.hpp and python/zed_opencv_native.py; stereolabs/zed-open-capture
    # examples/include/calibration.hpp): all build R with cv::Rodrigues on the vector
    # (RX, CV, RZ) in that order and pass it to cv::stereoRectify as the left-to-right R, so
    # RX is the x component (tilt), CV the y component (convergence), RZ the z component (roll).
    # For T the samples disagree on the sign (C++: +Baseline; Python: -Baseline with TY, TZ
    # unchanged); they only use |T| for depth. Geometry settles it: Baseline, TY, TZ (mm) place the
    # right eye in the left camera frame (the right eye sits at +x), and OpenCV's T (x_r = R x_l + T)
    # is the left optical centre seen from the right camera, which is -(Baseline, TY, TZ) for the
    # sub-milliradian R of a ZED. The test that the rectified baseline comes out positive
    # (right eye to the right) guards this sign.
    path = Path(path)
    res = resolution_name(resolution)
    sections = _read_ini(path)

    def section(name: str) -> dict[str, str]:
        if name not in sections:
            raise CalibrationFileError(f"{path}: missing section [{name}] (needed for resolution {res})")
        return sections[name]

    def number(name: str, key: str, default: float | None = None, alternatives: tuple[str, ...] = ()) -> float:
        table = section(name)
        for candidate in (key, *alternatives):
            if candidate.lower() in table:
                text = table[candidate.lower()]
                if not text.strip() and default is not None:
                    return default  # "k3=" written without a value: the term is absent
                try:
                    value = float(text)
                except ValueError:
                    value = math.nan
                if not math.isfinite(value):
                    raise CalibrationFileError(f"{path}: [{name}] {candidate}: {text!r} is not a finite number")
                return value
        if default is None:
            raise CalibrationFileError(f"{path}: missing key [{name}] {key} (needed for resolution {res})")
        return default

    def used_key(name: str, key: str, alternatives: tuple[str, ...]) -> str:
        """Which of the candidate keys the file has (the one ``number`` read), for error messages."""
        present = [k for k in (key, *alternatives) if k.lower() in sections.get(name, {})]
        return present[0] if present else key

    cameras = {}
    for side in ("LEFT", "RIGHT"):
        name = f"{side}_CAM_{res}"
        fx, fy, cx, cy = (number(name, key) for key in ("fx", "fy", "cx", "cy"))
        dist = [number(name, key, 0.0) for key in ("k1", "k2", "p1", "p2", "k3")]
        cameras[side] = (np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), np.array(dist))
    baseline_mm = number("STEREO", "Baseline")
    if not _BASELINE_MM[0] <= baseline_mm <= _BASELINE_MM[1]:
        raise CalibrationFileError(
            f"{path}: [STEREO] Baseline = {baseline_mm:g} is outside [{_BASELINE_MM[0]:g}, {_BASELINE_MM[1]:g}] "
            "mm: Stereolabs files store the baseline as a positive distance in millimetres (120 for a ZED)")
    ty_mm = number("STEREO", f"TY_{res}", 0.0, ("TY",))
    tz_mm = number("STEREO", f"TZ_{res}", 0.0, ("TZ",))
    rotation_keys = (f"RX_{res}", f"CV_{res}", f"RZ_{res}")
    rotation = np.array([number("STEREO", key) for key in rotation_keys])
    for key, angle in zip(rotation_keys, rotation, strict=True):
        if abs(angle) > _MAX_ROTATION_RAD:
            raise CalibrationFileError(
                f"{path}: [STEREO] {key} = {angle:g} rad is outside [{-_MAX_ROTATION_RAD:.4g}, "
                f"{_MAX_ROTATION_RAD:.4g}] rad: Stereolabs store the eye rotation in radians, and a stereo rig's "
                f"eyes differ by at most {MAX_EYE_ROTATION_DEG:g} degrees")
    R = cv2.Rodrigues(rotation)[0]
    # Baseline, TY, TZ place the right eye in the left frame; OpenCV's T is minus that (see above).
    T = -np.array([baseline_mm, ty_mm, tz_mm]) / 1000.0 + 0.0  # + 0.0 turns -0.0 into 0.0
    try:
        return StereoCalibration(cameras["LEFT"][0], cameras["LEFT"][1], cameras["RIGHT"][0], cameras["RIGHT"][1],
                                 R, T, ZED_RESOLUTIONS[res])
    except CalibrationValueError as e:
        if e.argument in ("K_left", "K_right", "dist_left", "dist_right") and e.entry is not None:
            side = "LEFT" if e.argument.endswith("left") else "RIGHT"
            where = f"[{side}_CAM_{res}] {e.entry}"
        elif e.argument == "R":
            where = f"[STEREO] {', '.join(rotation_keys)}"
        elif e.argument == "T":
            ty_key, tz_key = used_key("STEREO", f"TY_{res}", ("TY",)), used_key("STEREO", f"TZ_{res}", ("TZ",))
            where = (f"[STEREO] Baseline, {ty_key}, {tz_key} (the right eye at ({baseline_mm:g}, {ty_mm:g}, "
                     f"{tz_mm:g}) mm from the left one)")
        else:
            where = f"resolution {res}: {e.argument}"
        separator = " " if e.entry else ": "  # "[LEFT_CAM_HD] fx = ..." but "[STEREO] RX_HD, ...: turns ..."
        raise CalibrationFileError(f"{path}: {where}{separator}{e.problem}") from e


def _read_ini(path: Path) -> dict[str, dict[str, str]]:
    """Sections (upper-cased names) of key -> value (lower-cased keys); the last duplicate wins."""
    try:
        text = path.read_text(encoding="utf-8-sig")  # strips a UTF-8 BOM
    except FileNotFoundError as e:
        raise CalibrationFileError(f"{path}: calibration file not found") from e
    except (OSError, UnicodeDecodeError) as e:
        raise CalibrationFileError(f"{path}: cannot read the calibration file ({e})") from e
    sections: dict[str, dict[str, str]] = {}
    current: dict[str, str] | None = None
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1].strip().upper(), {})
        elif "=" in line and current is not None:
            key, _, value = line.partition("=")
            current[key.strip().lower()] = value.strip()
        else:
            raise CalibrationFileError(f"{path}: line {number}: expected '[SECTION]' or 'key = value' inside a "
                                       f"section, got {raw.strip()[:40]!r}")
    if not sections:
        raise CalibrationFileError(f"{path}: no [SECTION] found; not a Stereolabs .conf file")
    return sections


# --- capture ------------------------------------------------------------------------------


@dataclass(frozen=True)
class CaptureMode:
    """What the source actually delivers.

    Attributes:
        source: the device or file opened.
        kind: "device", "video" or "images".
        frame_size: side-by-side frame (width, height) in pixels; each eye is half as wide.
        fps: frame rate (reported by the device or the container; the requested rate for images).
        pixel_format: FOURCC of the stream ("YUYV" for the ZED), or the image format.
        backend: OpenCV capture backend in use.
    """

    source: str
    kind: str
    frame_size: tuple[int, int]
    fps: float
    pixel_format: str
    backend: str

    def __str__(self) -> str:
        w, h = self.frame_size
        return (f"{self.source} ({self.kind}): {w}x{h} side-by-side = 2 x {w // 2}x{h} at {self.fps:g} fps, "
                f"{self.pixel_format}, {self.backend}")


class ZedCamera(StereoCamera):
    """A ZED over UVC, or a recorded side-by-side video or image folder, as a ``StereoCamera``.

    Args:
        source: a device index (``0``), a device path (prefer ``/dev/v4l/by-id/...``), a
            side-by-side video file, or a folder of side-by-side images (sorted by name).
        calibration: calibration of the per-eye images (``load_factory_calibration``).
        resolution: ZED mode to request from a device ("2K", "FHD", "HD", "VGA").
        fps: frame rate to request from a device; for an image folder, the rate timestamps
            assume.
        loop: restart a video or folder at its end instead of raising ``EndOfStreamError``.

    Raises:
        ValueError: unknown resolution, a rate the ZED does not offer at it, or (for a device)
            a calibration whose image size is not the resolution's.

    Frames carry ``time.monotonic()`` timestamps from a device, and the recording's own time
    (frame index / fps) from a video or folder, so a replay keeps its original timing.
    """

    def __init__(self, source: int | str | os.PathLike, calibration: StereoCalibration, resolution: str = "HD",
                 fps: float = 60, *, loop: bool = False) -> None:
        self._resolution = resolution_name(resolution)
        self._kind, self._source = _classify(source)
        if not isinstance(calibration, StereoCalibration):
            raise TypeError(f"calibration: expected an estimator.StereoCalibration, got {type(calibration).__name__}")
        if self._kind == "device":
            if fps not in ZED_FPS[self._resolution]:
                raise ValueError(f"fps: the ZED offers {', '.join(map(str, ZED_FPS[self._resolution]))} fps at "
                                 f"{self._resolution}, got {fps!r}")
            if tuple(calibration.image_size) != ZED_RESOLUTIONS[self._resolution]:
                raise ValueError(f"calibration image_size {calibration.image_size} does not match the ZED "
                                 f"{self._resolution} eye size {ZED_RESOLUTIONS[self._resolution]}; load the "
                                 f"calibration for resolution {self._resolution!r}")
        elif not (isinstance(fps, (int, float)) and fps > 0):
            raise ValueError(f"fps: expected a positive rate, got {fps!r}")
        self._calibration = calibration
        self._fps = float(fps)
        self._loop = bool(loop)
        self._capture: cv2.VideoCapture | None = None
        self._images: list[Path] | None = None
        self._mode: CaptureMode | None = None
        self._position = 0  # next image of a folder
        self._index = 0

    def __repr__(self) -> str:
        return f"ZedCamera({self._source!r}, resolution={self._resolution!r})"

    @property
    def calibration(self) -> StereoCalibration:
        return self._calibration

    @property
    def is_connected(self) -> bool:
        return self._mode is not None

    @property
    def mode(self) -> CaptureMode:
        """The mode in use. Raises ``NotConnectedError`` before ``connect()``."""
        if self._mode is None:
            raise NotConnectedError(f"{self!r}: mode before connect()")
        return self._mode

    def connect(self) -> None:
        """Open the source and check its frame size against the calibration.

        Raises:
            DeviceError: already connected; the source cannot be opened; a device fell back to
                another mode than requested; or the frames are not twice the calibration's width
                by its height.
        """
        if self.is_connected:
            raise DeviceError(f"{self!r}: connect() while already connected")
        try:
            opener = {"device": self._open_device, "video": self._open_video, "images": self._open_images}
            mode = opener[self._kind]()
            width, height = self._calibration.image_size
            if mode.frame_size != (2 * width, height):
                raise DeviceError(f"{self._source}: frames are {mode.frame_size[0]}x{mode.frame_size[1]} but the "
                                  f"calibration's image_size {width}x{height} needs side-by-side "
                                  f"{2 * width}x{height} frames")
        except BaseException:
            self._release()
            raise
        self._mode, self._position, self._index = mode, 0, 0

    def grab(self) -> StereoFrame:
        """Return the next stereo pair.

        Raises:
            NotConnectedError: before ``connect()`` or after ``close()``.
            EndOfStreamError: a video or folder ran out of frames (and ``loop`` is off).
            DeviceError: the device stopped delivering frames, or a frame has the wrong size.
        """
        if self._mode is None:
            raise NotConnectedError(f"{self!r}: grab() before connect()")
        frame = self._read()
        timestamp_s = time.monotonic() if self._kind == "device" else self._index / self._mode.fps
        if frame.shape[:2] != (self._mode.frame_size[1], self._mode.frame_size[0]):
            where = (self._images[self._position - 1] if self._kind == "images"  # the file, as an unreadable one is
                     else f"{self._source}: frame {self._index} (counted from 0)")
            raise DeviceError(f"{where} is {frame.shape[1]}x{frame.shape[0]}, "
                              f"expected {self._mode.frame_size[0]}x{self._mode.frame_size[1]}")
        half = frame.shape[1] // 2
        stereo = StereoFrame(np.ascontiguousarray(frame[:, :half]), np.ascontiguousarray(frame[:, half:]),
                             float(timestamp_s), self._index)
        self._index += 1
        return stereo

    def close(self) -> None:
        """Release the device or file; closing twice is harmless."""
        self._release()
        self._mode = None

    # --- sources --------------------------------------------------------------------------

    def _open_device(self) -> CaptureMode:
        target = self._source
        if isinstance(target, str):
            if not os.path.exists(target):
                raise DeviceError(f"camera {target}: no such device; list cameras with `ls -l /dev/v4l/by-id/`")
            target = os.path.realpath(target)  # by-id links point at /dev/videoN
        backend = cv2.CAP_V4L2 if sys.platform.startswith("linux") else cv2.CAP_ANY
        capture = cv2.VideoCapture(target, backend)
        self._capture = capture
        if not capture.isOpened():
            raise DeviceError(f"could not open camera {self._source!r}; check that the ZED is plugged into a USB 3 "
                              "port, that no other program uses it, and the index or path "
                              "(`ls -l /dev/v4l/by-id/`)")
        width, height = ZED_RESOLUTIONS[self._resolution]
        capture.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*"YUYV"))
        capture.set(cv2.CAP_PROP_FRAME_WIDTH, 2 * width)
        capture.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        capture.set(cv2.CAP_PROP_FPS, self._fps)
        capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # hand out the newest frame, not one queued 4 frames ago
        got = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        got_fps = float(capture.get(cv2.CAP_PROP_FPS))
        fourcc = _fourcc_text(capture.get(cv2.CAP_PROP_FOURCC))
        requested = f"{2 * width}x{height} at {self._fps:g} fps (ZED {self._resolution})"
        if got != (2 * width, height):
            raise DeviceError(f"camera {self._source!r} fell back to {got[0]}x{got[1]} instead of {requested}; "
                              "a ZED on USB 2 only offers small modes: use a USB 3 port and cable")
        if got_fps > 0 and abs(got_fps - self._fps) > 0.5:
            raise DeviceError(f"camera {self._source!r} fell back to {got_fps:g} fps instead of {requested}")
        if fourcc.isalnum() and fourcc != "YUYV":  # a readable code that is not the ZED's only format
            raise DeviceError(f"camera {self._source!r} streams {fourcc} instead of YUYV: not a ZED, or a "
                              "driver that converts; check the device with `v4l2-ctl --list-formats-ext`")
        if got_fps <= 0:
            _log.warning("camera %r does not report its frame rate; assuming %g fps", self._source, self._fps)
        return CaptureMode(str(self._source), "device", got, got_fps if got_fps > 0 else self._fps, fourcc,
                           capture.getBackendName())

    def _open_video(self) -> CaptureMode:
        capture = cv2.VideoCapture(str(self._source))
        self._capture = capture
        if not capture.isOpened():
            raise DeviceError(f"could not open video {self._source}: not a video OpenCV can decode")
        size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        fps = float(capture.get(cv2.CAP_PROP_FPS))
        return CaptureMode(str(self._source), "video", size, fps if fps > 0 else self._fps,
                           _fourcc_text(capture.get(cv2.CAP_PROP_FOURCC)), capture.getBackendName())

    def _open_images(self) -> CaptureMode:
        images = sorted(p for p in Path(self._source).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not images:
            raise DeviceError(f"image folder {self._source} has no images ({', '.join(IMAGE_SUFFIXES)})")
        first = _read_image(images[0])
        self._images = images
        return CaptureMode(str(self._source), "images", (first.shape[1], first.shape[0]), self._fps,
                           images[0].suffix.lstrip(".").upper(), "imread")

    def _read(self) -> np.ndarray:
        if self._kind == "images":
            if self._position >= len(self._images):
                if not self._loop:
                    raise EndOfStreamError(f"{self._source}: end of the image folder after {self._index} frames")
                self._position = 0
            self._position += 1
            return _read_image(self._images[self._position - 1])
        ok, frame = self._capture.read()
        if not ok and self._kind == "video" and self._loop and self._index > 0:
            self._capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, frame = self._capture.read()
        if not ok:
            if self._kind == "video":
                raise EndOfStreamError(f"{self._source}: end of the video after {self._index} frames")
            raise DeviceError(f"camera {self._source!r} stopped delivering frames (unplugged?)")
        return frame

    def _release(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None
        self._images = None


def _classify(source: int | str | os.PathLike) -> tuple[str, int | str]:
    """Tell a device (index or /dev path) from a video file or an image folder."""
    if isinstance(source, bool):
        raise TypeError(f"source: expected a device index or a path, got {source!r}")
    if isinstance(source, int):
        if source < 0:
            raise ValueError(f"source: a device index must be >= 0, got {source}")
        return "device", source
    text = os.fspath(source)
    if text.isdigit():
        return "device", int(text)
    if text.startswith("/dev/"):
        return "device", text
    path = Path(text)
    if path.is_dir():
        return "images", str(path)
    if path.is_file():
        return "video", str(path)
    raise ValueError(f"source: {text!r} does not exist (expected a device index, a /dev path, a side-by-side "
                     "video file or an image folder)")


def _read_image(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise DeviceError(f"{path}: not an image OpenCV can read")
    return image


def _fourcc_text(value: float) -> str:
    code = int(value)
    text = "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4))
    return text if text.isprintable() and text.strip() else f"0x{code:08X}"
