"""What the ZED's sensor and image pipeline do to the optical image: the twin's camera effects.

A real camera does not deliver the clean colours a renderer draws. Here, in the order a camera
applies them: optical blur and camera shake (a linear motion-blur kernel), vignetting (cos^4-like
fall-off towards the corners), exposure gain (over-exposure clips), shot noise (grows with the
square root of the signal) plus read noise, and the ZED's YUYV 4:2:2 transport, which keeps one
chroma sample per horizontal pixel pair and is decoded with OpenCV's own converter, as the real
driver (``hardware.zed``) does. The arm's motion over the exposure is the renderer's job (it
renders sub-frames); everything here is per image.

Deterministic stages of the static scene are computed once (:meth:`SensorSimulator.static`);
per frame only the region that changed goes through them again, and then the noise and the
chroma subsampling run over the whole image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import cv2
import numba
import numpy as np
from scipy.special import ndtri


@dataclass(frozen=True)
class CameraEffects:
    """The camera effects of a scene (all off: an ideal camera).

    Attributes:
        exposure_gain: multiplies the image values (display units) before the noise; > 1 over-exposes.
        read_noise_dn: standard deviation of the signal-independent noise, 8-bit digital numbers.
        shot_noise_dn: standard deviation of the shot noise at full scale (255 DN); at a level I it
            is ``shot_noise_dn * sqrt(I / 255)``.
        vignetting: relative fall-off of brightness at the image's farthest corner (0: none).
        yuyv: deliver the images through YUYV 4:2:2 chroma subsampling, as the ZED over UVC.
        optics_blur_px: standard deviation of a Gaussian blur of the optics, pixels.
        exposure_s: the arm's motion is integrated over this exposure (0: instantaneous).
        motion_subframes: at most this many renders averaged over the exposure when ``exposure_s`` > 0
            (the renderer draws as many as keep the arm's steps between them under half a pixel: one,
            at the exposure's middle, for an arm that moves under a quarter pixel).
        shake_px: length of a linear motion-blur kernel (camera shake, a fast pan), pixels.
        shake_angle_deg: direction of that kernel in the image, degrees from the rows.
    """

    exposure_gain: float = 1.0
    read_noise_dn: float = 0.0
    shot_noise_dn: float = 0.0
    vignetting: float = 0.0
    yuyv: bool = False
    optics_blur_px: float = 0.0
    exposure_s: float = 0.0
    motion_subframes: int = 4
    shake_px: float = 0.0
    shake_angle_deg: float = 0.0

    def __post_init__(self) -> None:
        limits = {"exposure_gain": (1e-3, 16.0), "read_noise_dn": (0.0, 64.0), "shot_noise_dn": (0.0, 64.0),
                  "vignetting": (0.0, 0.95), "optics_blur_px": (0.0, 20.0), "exposure_s": (0.0, 0.5),
                  "shake_px": (0.0, 100.0), "shake_angle_deg": (-360.0, 360.0)}
        for name, (lo, hi) in limits.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not (
                    math.isfinite(value) and lo <= value <= hi):
                raise ValueError(f"{name}: expected a number in [{lo}, {hi}], got {value!r}")
        if not isinstance(self.yuyv, bool):
            raise ValueError(f"yuyv: expected true or false, got {self.yuyv!r}")
        m = self.motion_subframes
        if isinstance(m, bool) or not isinstance(m, int) or not 1 <= m <= 32:
            raise ValueError(f"motion_subframes: expected an integer in [1, 32], got {m!r}")

    @property
    def legacy(self) -> bool:
        """Only Gaussian blur, gain and read noise: the original sensor model, kept bit-identical."""
        return (self.shot_noise_dn == 0 and self.vignetting == 0 and not self.yuyv and self.shake_px == 0)

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def standard_normal_table() -> np.ndarray:
    """256 equiprobable quantiles of the standard normal, scaled to unit variance (float64).

    Indexing it with uniform random bytes draws Gaussian noise several times faster than
    numpy's normal generator; 256 levels are plenty for 8-bit images.
    """
    q = ndtri((np.arange(256) + 0.5) / 256.0)
    return q / np.sqrt(np.mean(q**2))


def noise_table(std_dn: float) -> np.ndarray:
    """(1, 256) float32 noise levels of standard deviation ``std_dn`` for ``cv2.LUT``."""
    return (standard_normal_table() * std_dn).astype(np.float32).reshape(1, 256)


def level_noise_table(read_noise_dn: float, shot_noise_dn: float) -> np.ndarray:
    """(256, 256) uint8: the noisy value of a pixel at level I drawn with random byte r.

    sigma(I)^2 = read^2 + shot^2 I / 255, and the result is rounded and clipped to 0..255.
    """
    level = np.arange(256, dtype=np.float64)[:, None]
    sigma = np.sqrt(read_noise_dn**2 + shot_noise_dn**2 * level / 255.0)
    noisy = level + sigma * standard_normal_table()[None, :]
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


@numba.njit(cache=True, nogil=True)
def _apply_level_noise(image, random, table):
    flat_in = image.reshape(-1)
    flat_r = random.reshape(-1)
    out = np.empty_like(flat_in)
    for i in range(flat_in.size):
        out[i] = table[flat_in[i], flat_r[i]]
    return out.reshape(image.shape)


@numba.njit(cache=True, nogil=True)
def _bgr_to_yuyv(image):
    """BGR -> packed YUYV (Y0 U Y1 V per pixel pair), BT.601 limited range, chroma averaged per pair."""
    h, w, _ = image.shape
    out = np.empty((h, w, 2), np.uint8)
    for y in range(h):
        for x in range(0, w - 1, 2):
            u_sum = 0.0
            v_sum = 0.0
            for k in range(2):
                b = float(image[y, x + k, 0])
                g = float(image[y, x + k, 1])
                r = float(image[y, x + k, 2])
                luma = 16.0 + 0.256788 * r + 0.504129 * g + 0.097906 * b
                out[y, x + k, 0] = np.uint8(min(max(luma + 0.5, 0.0), 255.0))
                u_sum += 128.0 - 0.148223 * r - 0.290993 * g + 0.439216 * b
                v_sum += 128.0 + 0.439216 * r - 0.367788 * g - 0.071427 * b
            out[y, x, 1] = np.uint8(min(max(0.5 * u_sum + 0.5, 0.0), 255.0))
            out[y, x + 1, 1] = np.uint8(min(max(0.5 * v_sum + 0.5, 0.0), 255.0))
    return out


def yuyv_round_trip(image_bgr: np.ndarray) -> np.ndarray:
    """The image as the ZED delivers it over UVC: encoded to YUYV 4:2:2, decoded by OpenCV."""
    if image_bgr.shape[1] % 2:
        raise ValueError(f"YUYV needs an even image width, got {image_bgr.shape[1]}")
    return cv2.cvtColor(_bgr_to_yuyv(np.ascontiguousarray(image_bgr)), cv2.COLOR_YUV2BGR_YUYV)


def shake_kernel(length_px: float, angle_deg: float) -> np.ndarray:
    """A normalised linear motion-blur kernel of ``length_px`` along ``angle_deg`` (anti-aliased).

    The angle is measured from the image rows towards +v (down). The segment's ends splat onto
    the pixels beside them, so the kernel has a pixel to spare at each end: cut there, a 9 px
    shake would blur like an 8.5 px one.
    """
    size = (int(math.ceil(length_px)) + 2) | 1
    kernel = np.zeros((size, size), np.float32)
    c = (size - 1) / 2.0
    dx, dy = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    for t in np.linspace(-length_px / 2.0, length_px / 2.0, 8 * size):
        x, y = c + t * dx, c + t * dy
        x0, y0 = int(math.floor(x)), int(math.floor(y))
        fx, fy = x - x0, y - y0
        for yy, xx, wgt in ((y0, x0, (1 - fx) * (1 - fy)), (y0, x0 + 1, fx * (1 - fy)),
                            (y0 + 1, x0, (1 - fx) * fy), (y0 + 1, x0 + 1, fx * fy)):
            if 0 <= yy < size and 0 <= xx < size:
                kernel[yy, xx] += wgt
    return kernel / kernel.sum()


def vignetting_map(K: np.ndarray, image_size: tuple[int, int], fall_off: float) -> np.ndarray:
    """(H, W) float32 brightness factor, 1 at the principal point, ``1 - fall_off`` at the farthest corner.

    Natural vignetting goes as cos^4 of the ray's angle; the exponent is scaled so that the
    farthest corner of this image loses ``fall_off``.
    """
    w, h = image_size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    r2 = ((u - K[0, 2]) / K[0, 0]) ** 2 + ((v - K[1, 2]) / K[1, 1]) ** 2
    if fall_off <= 0:
        return np.ones((h, w), np.float32)
    power = -math.log(1.0 - fall_off) / math.log(1.0 + float(r2.max()))
    return ((1.0 + r2) ** (-power)).astype(np.float32)


# The eyes' numbers in a frame's noise seed.
EYES = {"left": 0, "right": 1}


def frame_generator(seed: int, index: int, side: str) -> np.random.Generator:
    """The noise generator of one eye of frame ``index``: its own stream, seeded by (seed, index, eye).

    Each frame's noise is drawn from nothing but these three numbers, so a recorded frame's noise
    can be drawn again exactly from its noise-free image (``SensorSimulator.noisy``), whatever
    frames came before it.
    """
    if side not in EYES:
        raise ValueError(f"side: expected 'left' or 'right', got {side!r}")
    if isinstance(seed, bool) or isinstance(index, bool) or int(seed) < 0 or int(index) < 0:
        raise ValueError(f"seed and index: expected integers >= 0, got {seed!r} and {index!r}")
    return np.random.default_rng([int(seed), int(index), EYES[side]])


class SensorSimulator:
    """Apply :class:`CameraEffects` to one eye's raw optical images.

    Args:
        effects: the camera effects.
        K: (3, 3) the eye's camera matrix (the vignetting is centred on its principal point).
        image_size: (width, height) of the raw images.
        rng: the noise generator :meth:`apply` draws from when it is given none (the renderer gives
            each eye of each frame its own, ``frame_generator``).
    """

    def __init__(self, effects: CameraEffects, K: np.ndarray, image_size: tuple[int, int],
                 rng: np.random.Generator) -> None:
        self.effects = effects
        self._rng = rng
        e = effects
        self._gain_map = None
        if e.vignetting > 0 or (e.exposure_gain != 1.0 and not e.legacy):
            gain = vignetting_map(K, image_size, e.vignetting) * e.exposure_gain
            self._gain_map = cv2.merge([gain, gain, gain])
        self._kernel = shake_kernel(e.shake_px, e.shake_angle_deg) if e.shake_px > 0 else None
        self._legacy_lut = noise_table(e.read_noise_dn)
        self._level_table = None if e.legacy else level_noise_table(e.read_noise_dn, e.shot_noise_dn)

    @property
    def margin_px(self) -> int:
        """How far the deterministic stages spread a change (blur kernels' reach), pixels."""
        e = self.effects
        reach = 3.0 * e.optics_blur_px + (0.5 * e.shake_px + 1 if e.shake_px > 0 else 0.0)
        return int(math.ceil(reach)) + 1

    def deterministic(self, image: np.ndarray) -> np.ndarray:
        """Blur, shake, vignetting and gain (no noise): uint8 of the same shape."""
        e = self.effects
        if e.optics_blur_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), e.optics_blur_px)
        if self._kernel is not None:
            image = cv2.filter2D(image, -1, self._kernel, borderType=cv2.BORDER_REFLECT)
        return image

    def _gain(self, image: np.ndarray, box: tuple[int, int, int, int] | None = None) -> np.ndarray:
        if self._gain_map is None:
            return image
        if box is None:
            return cv2.multiply(image, self._gain_map, dtype=cv2.CV_8U)
        x0, y0, x1, y1 = box
        return cv2.multiply(image, self._gain_map[y0:y1, x0:x1], dtype=cv2.CV_8U)

    def static(self, raw: np.ndarray) -> np.ndarray:
        """The deterministic stages over a whole raw image (done once for the static scene)."""
        return self._gain(self.deterministic(raw))

    def apply(self, raw: np.ndarray, static_done: np.ndarray | None = None,
              box: tuple[int, int, int, int] | None = None, rng: np.random.Generator | None = None) -> np.ndarray:
        """The raw optical image as the camera delivers it: :meth:`clean`, then :meth:`noisy`.

        Args:
            raw: (H, W, 3) uint8 BGR optical image (after lens distortion).
            static_done: :meth:`static` of the static scene; with ``box``, only the region
                ``box`` (x0, y0, x1, y1) of ``raw`` differs from the static scene, so only it goes
                through the deterministic stages again.
            box: see ``static_done``.
            rng: the noise generator of this image (``frame_generator``); None draws from the one
                given to the constructor, image after image.
        """
        return self.noisy(self.clean(raw, static_done, box), rng)

    def clean(self, raw: np.ndarray, static_done: np.ndarray | None = None, box=None) -> np.ndarray:
        """The deterministic stages only (blur, shake, vignetting and gain; no noise, no YUYV): what
        :meth:`noisy` turns into the delivered image. Arguments as for :meth:`apply`; ``box`` may also
        be a list of boxes (each region that changed, e.g. the arm and a cable crossing the view)."""
        if self.effects.legacy:
            return self.deterministic(raw)
        if static_done is None or box is None:
            return self.static(raw)
        image = static_done.copy()
        h, w = raw.shape[:2]
        m = self.margin_px
        for x0, y0, x1, y1 in ([box] if isinstance(box, tuple) else box):
            X0, Y0, X1, Y1 = max(x0 - 2 * m, 0), max(y0 - 2 * m, 0), min(x1 + 2 * m, w), min(y1 + 2 * m, h)
            if X1 > X0 and Y1 > Y0:
                region = self.deterministic(np.ascontiguousarray(raw[Y0:Y1, X0:X1]))
                ix0, iy0 = max(x0 - m, X0), max(y0 - m, Y0)
                ix1, iy1 = min(x1 + m, X1), min(y1 + m, Y1)
                inner = region[iy0 - Y0:iy1 - Y0, ix0 - X0:ix1 - X0]
                image[iy0:iy1, ix0:ix1] = self._gain(np.ascontiguousarray(inner), (ix0, iy0, ix1, iy1))
        return image

    def noisy(self, clean: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """The random stages over a :meth:`clean` image: sensor noise drawn from ``rng`` (None: the
        constructor's generator), then the YUYV transport. The same ``clean`` and a generator in the
        same state give the same image, bit for bit (a recorded run re-applies the noise this way)."""
        rng = self._rng if rng is None else rng
        e = self.effects
        if e.legacy:
            return self._legacy_noise(clean, rng)
        image = clean
        if e.read_noise_dn > 0 or e.shot_noise_dn > 0:
            random = np.frombuffer(rng.bytes(image.size), dtype=np.uint8).reshape(image.shape)
            image = _apply_level_noise(np.ascontiguousarray(image), random, self._level_table)
        if e.yuyv:
            image = yuyv_round_trip(image)
        return image

    def _legacy_noise(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        e = self.effects
        if e.read_noise_dn > 0:
            u8 = np.frombuffer(rng.bytes(image.size), dtype=np.uint8).reshape(image.shape)
            noise = cv2.LUT(u8, self._legacy_lut)
            return cv2.addWeighted(image, e.exposure_gain, noise, 1.0, 0.0, dtype=cv2.CV_8U)
        if e.exposure_gain != 1.0:
            return cv2.convertScaleAbs(image, alpha=e.exposure_gain)
        return image
