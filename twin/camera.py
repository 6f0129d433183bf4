"""The twin's stereo camera: the ``hardware.StereoCamera`` contract, rendering the simulated arm.

``grab()`` renders the arm's current shape into a raw (distorted, noisy) stereo pair, stamped
with the simulated time; ``depth_left()`` gives the left depth map of that same frame (the
paper's Q' metric compares against it). The calibration is the one the renderer uses.

Frame k's sensor noise is drawn from (seed, k) alone, so ``last_images`` (the frame before its
noise, and k) with ``noise_seed`` and ``effects`` reproduce the grabbed images exactly: a run
stores that, losslessly compressible, instead of the noise.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from estimator import StereoCalibration
from hardware.errors import DeviceError, NotConnectedError
from hardware.interfaces import StereoCamera, StereoFrame
from twin.render import StereoImages, StereoRenderer
from twin.rig import StereoRig
from twin.scene import LabScene
from twin.sensor import CameraEffects
from twin.shape import ArmShape


class SimStereoCamera(StereoCamera):
    """A simulated ZED: raw BGR pairs of whatever ``shape_source`` returns at each grab.

    Args:
        rig: the cameras (calibration, pose, appearance, sensor).
        shape_source: returns the arm's current :class:`ArmShape` (world frame).
        clock_s: returns the current simulated time, seconds (the frames' timestamps).
        seed: sensor-noise seed; frames are reproducible for a seed and a sequence of shapes.
        tube_sides: vertices around the rendered tube.
        scene: what surrounds the arm (backdrop, objects, lights, camera effects); None: the clean scene.

    The OpenGL context is created by ``connect()`` and released by ``close()``.
    """

    def __init__(self, rig: StereoRig, shape_source: Callable[[], ArmShape], clock_s: Callable[[], float], *,
                 seed: int = 0, tube_sides: int = 48, scene: LabScene | None = None) -> None:
        self._rig = rig
        self._scene = scene
        self._shape_source = shape_source
        self._clock_s = clock_s
        self._seed = int(seed)
        self._tube_sides = int(tube_sides)
        self._renderer: StereoRenderer | None = None
        self._connections = 0
        self._index = 0
        self._last_depth: np.ndarray | None = None
        self._last_shape: ArmShape | None = None
        self._exposed_shape: ArmShape | None = None
        self._opening: tuple[ArmShape, float] | None = None
        self._last_time_s: float | None = None
        self._last_images: StereoImages | None = None

    @property
    def scene(self) -> LabScene | None:
        """The lab scene the camera sees (None: the clean scene)."""
        return self._scene

    @property
    def calibration(self) -> StereoCalibration:
        """The exact calibration the images are rendered with (OpenCV conventions)."""
        return self._rig.calibration

    @property
    def rig(self) -> StereoRig:
        return self._rig

    @property
    def is_connected(self) -> bool:
        return self._renderer is not None

    @property
    def renderer(self) -> StereoRenderer:
        """The connected renderer (e.g. to render calibration-board views through this camera).

        Raises:
            NotConnectedError: before ``connect()`` or after ``close()``.
        """
        if self._renderer is None:
            raise NotConnectedError(f"{type(self).__name__}: renderer used before connect()")
        return self._renderer

    def connect(self) -> None:
        """Create the offscreen renderer; frame indices restart at 0.

        Raises:
            DeviceError: already connected.
            RenderBackendError: no offscreen OpenGL (EGL); the message names the packages to install.
        """
        if self._renderer is not None:
            raise DeviceError(f"{type(self).__name__}: already connected; close() it before connecting again")
        # A new connection continues the noise sequence rather than repeating the first one's.
        self._renderer = StereoRenderer(self._rig, seed=self._seed + self._connections, tube_sides=self._tube_sides,
                                        scene=self._scene)
        self._connections += 1
        self._index = 0
        self._last_depth = None
        self._last_shape = None
        self._exposed_shape = None
        self._opening = None
        self._last_time_s = None
        self._last_images = None

    def grab(self) -> StereoFrame:
        """Render the arm as it is now.

        Returns:
            StereoFrame with raw (H, W, 3) uint8 BGR images, ``timestamp_s`` = simulated time and
            the frame index (0 for the first frame after ``connect()``).

        Raises:
            NotConnectedError: before ``connect()`` or after ``close()``.
        """
        if self._renderer is None:
            raise NotConnectedError(f"{type(self).__name__}: grab() before connect()")
        shape = self._shape_source()
        t_s = float(self._clock_s())
        # The renderer blurs the arm's motion over the exposure from the shape it had as the exposure
        # opened (``exposure_opens``), else from the previous frame's.
        previous = None if self._last_shape is None else (self._last_shape, self._last_time_s)
        if self._opening is not None and self._opening[1] < t_s and (
                previous is None or self._opening[1] > previous[1]):
            previous = self._opening
        images = self._renderer.render(shape, depth=True, t_s=t_s, previous=previous, frame_index=self._index)
        frame = StereoFrame(images.left, images.right, t_s, self._index)
        self._index += 1
        self._last_images = images
        self._last_depth = images.depth_left_m
        self._last_shape = shape
        self._exposed_shape = self._renderer.exposed_shape(shape, t_s, previous)
        self._last_time_s = t_s
        return frame

    def exposure_opens(self, shape: ArmShape, t_s: float) -> None:
        """The arm's shape at ``t_s``, as the next frame's exposure opens (the physics hands it over on
        its way to the frame's time): that frame's motion blur runs from it to the shape at the grab."""
        self._opening = (shape, float(t_s))

    def depth_left(self) -> np.ndarray:
        """Depth of the last grabbed frame: (H, W) float32 metres along the left optical axis at
        each RAW left pixel; ``inf`` where only background is seen. A copy: the caller may change it.

        Raises:
            NotConnectedError: not connected.
            DeviceError: no frame has been grabbed since ``connect()``.
        """
        if self._renderer is None:
            raise NotConnectedError(f"{type(self).__name__}: depth_left() before connect()")
        if self._last_depth is None:
            raise DeviceError(f"{type(self).__name__}: depth_left() before the first grab()")
        return self._last_depth.copy()

    @property
    def last_images(self) -> StereoImages | None:
        """The last grabbed frame as rendered: the raw images, their noise-free versions (``clean_left``,
        ``clean_right``) and the frame's number in the noise sequence (``frame_index``, the frame index);
        None before the first grab."""
        return self._last_images

    @property
    def noise_seed(self) -> int:
        """The seed of this connection's sensor noise (``twin.sensor.frame_generator(seed, index, side)``)."""
        return self.renderer.seed

    @property
    def effects(self) -> CameraEffects:
        """The camera effects the images go through (their random part: noise, YUYV)."""
        return self.renderer.effects

    def background(self, side: str) -> np.ndarray | None:
        """The noise-free image of the static scene for one eye (``StereoRenderer.background``)."""
        return self.renderer.background(side)

    def background_depth(self) -> np.ndarray | None:
        """The left depth of the static scene, metres (``StereoRenderer.background_depth``)."""
        return self.renderer.background_depth()

    @property
    def last_shape(self) -> ArmShape | None:
        """The arm's shape when the last grabbed frame was taken (world frame; the end of its exposure),
        None before the first grab."""
        return self._last_shape

    @property
    def exposed_shape(self) -> ArmShape | None:
        """The arm shape the last grabbed frame shows (world frame): at the middle of its exposure,
        where its motion blur is centred (``StereoRenderer.exposed_shape``); None before the first grab."""
        return self._exposed_shape

    def close(self) -> None:
        """Release the OpenGL context; closing twice is harmless."""
        renderer, self._renderer = self._renderer, None
        if renderer is not None:
            renderer.close()
