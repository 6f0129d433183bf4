"""Undo a linear motion blur (camera shake, a fast pan) before the arm is measured.

Blurred along one direction, every edge of the arm becomes a ramp several pixels wide, and where
it is read the background's texture is mixed into it: the sub-pixel edges wander, the tip's outline
melts into the wall, and the fit leans on its prior (the twin's 9 px shake: 82 % of the ramp's
frames valid at 2.0x the focused RMSE). A linear blur is known once its length and direction are:
each edge's step is the sharp step convolved with the blur's segment projected on the edge's
normal, so the steps' widths over the arm's many normals give the segment (``blur_from_steps``),
and a Wiener filter takes it out of the image (``deblur``). A focused image is left untouched, and so
is a blur no one segment explains (the arm's own motion: it grows along the arm).

The 20-80 % rise of a step blurred by a segment of projected length ``w`` is ``0.6 w`` (a linear
ramp), added in quadrature to the focused step's rise. Measured by ``estimator.edges.step_widths`` on
the twin's lab images (focused rise 1.55 px) blurred by known segments along the rows: 3 / 5 / 7 / 9
/ 12 px read back as 3.4 / 5.1 / 7.0 / 9.0 / 12.0 px with the focused rise taken as 1.1 px (the
quadrature overstates a narrow blur's share in a wide one's rise: taken as 1.55 px, 9 px read 8.8).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.fft

FOCUSED_RISE_PX = 1.1  # a focused edge's 20-80 % rise, as the blur's length is read (module docstring)
RAMP_RISE = 0.6  # 20-80 % rise of a linear ramp, per pixel of its length
MIN_BLUR_PX = 4.0  # shorter blurs are left in: the edges' own widths already weigh them
MAX_BLUR_PX = 40.0  # longer ones are not measured (the edges' levels are read within 12 px) and left alone
MIN_STEPS = 30  # edges needed to measure a blur
# The Wiener filter's noise-to-signal ratio: its gain stops at 1 / (2 sqrt(this)) = 3.5 where the
# blur's spectrum vanishes. Oracle kernels on the twin's blur preset: 0.005 lets noise through (48 of
# 60 frames valid), 0.05 leaves the edges soft (3 false valid); 0.02: 57 of 60, 1.36 mm.
WIENER_NOISE = 0.02
HUBER = 2.0  # robust scales (in median absolute deviations) of the fit of the steps' widths: Huber's first,
TUKEY = 4.685  # then Tukey's (a lamp post's or a connector's edge, three times too wide, weighs nothing)
# A blur is taken out only where one segment explains the steps: their median misfit at most this share of
# L^2. The camera's shake: 0.05-0.14 on every sequence measured; the arm's own motion blur (a long exposure
# of a fast swing, the camera still) grows along the arm and turns with its motion: 0.27-0.76, and taken
# out as one segment it left rings inside the arm (10 of 60 frames refused for a loop in the silhouette).
MAX_SPREAD = 0.2
RIDGE = 1e-2  # pulls unmeasured directions of the blur towards none (squared pixels, per edge)


@dataclasses.dataclass(frozen=True)
class LinearBlur:
    """A straight-line blur: ``length_px`` along ``angle_deg`` (from the image rows towards +v, in [0, 180))."""

    length_px: float
    angle_deg: float

    def differs_from(self, other: LinearBlur | None, length_px: float, angle_deg: float) -> bool:
        """True when ``other`` is none, or longer or shorter by ``length_px``, or turned by ``angle_deg``."""
        if other is None:
            return True
        turn = abs((self.angle_deg - other.angle_deg + 90.0) % 180.0 - 90.0)
        return abs(self.length_px - other.length_px) > length_px or turn > angle_deg


def blur_from_steps(normals: np.ndarray, widths: np.ndarray) -> LinearBlur | None:
    """The linear blur that explains the edges' step widths, or None (focused, or too few edges).

    Args:
        normals: (K, 2) unit normals of the edges (image pixels).
        widths: (K,) their steps' 20-80 % rises, px; 0 or NaN where none was measured.

    The squared projected length ``w_i**2 = (width_i**2 - FOCUSED_RISE_PX**2) / RAMP_RISE**2`` is
    ``n_i^T M n_i`` for the blur's second-moment matrix ``M = L**2 d d^T``; M is fitted robustly (a
    lamp post beside the arm, a connector's rim) with a light ridge, so that directions no edge
    faces (an arm hanging straight down shows only horizontal normals) count as unblurred. The
    segment is M's principal axis; None where it leaves the steps spread more than ``MAX_SPREAD``
    (a blur that is not one segment: the arm's own motion).
    """
    normals = np.asarray(normals, np.float64).reshape(-1, 2)
    widths = np.asarray(widths, np.float64).reshape(-1)
    ok = np.isfinite(widths) & (widths > 0) & np.all(np.isfinite(normals), axis=1)
    if np.count_nonzero(ok) < MIN_STEPS:
        return None
    n, w = normals[ok], widths[ok]
    y = (w**2 - FOCUSED_RISE_PX**2) / RAMP_RISE**2  # not clipped at 0: a focused edge's noise must average out
    design = np.column_stack([n[:, 0] ** 2, 2.0 * n[:, 0] * n[:, 1], n[:, 1] ** 2])
    weight = np.ones(len(y))
    m = np.zeros(3)
    for k in range(8):  # Huber's weights to settle, then Tukey's, which drop the gross outliers
        a = design * weight[:, None]
        m = np.linalg.solve(a.T @ design + RIDGE * len(y) * np.eye(3), a.T @ y)
        residual = np.abs(y - design @ m)
        scale = 1.4826 * np.median(residual) + 1e-6
        if k < 4:
            weight = np.minimum(1.0, HUBER * scale / np.maximum(residual, 1e-12))
        else:
            weight = np.clip(1.0 - (residual / (TUKEY * scale)) ** 2, 0.0, None) ** 2
    values, vectors = np.linalg.eigh(np.array([[m[0], m[1]], [m[1], m[2]]]))
    length = math.sqrt(max(values[1], 0.0))
    if not MIN_BLUR_PX <= length <= MAX_BLUR_PX:
        return None
    dx, dy = vectors[:, 1]
    segment = length**2 * (n @ np.array([dx, dy])) ** 2  # the steps one segment along the principal axis gives
    if np.median(np.abs(y - segment)) > MAX_SPREAD * length**2:
        return None  # no one segment explains the steps: the arm moved, not the camera
    return LinearBlur(length, math.degrees(math.atan2(dy, dx)) % 180.0)


def line_kernel(blur: LinearBlur) -> np.ndarray:
    """(S, S) float64 kernel, summing to 1: the segment, sampled finely and shared bilinearly
    between the pixels around each sample (S odd, the segment centred)."""
    half = 0.5 * blur.length_px
    size = 2 * int(math.ceil(half)) + 3
    centre = (size - 1) / 2.0
    t = np.linspace(-half, half, max(int(16 * blur.length_px), 2))
    x = centre + t * math.cos(math.radians(blur.angle_deg))
    y = centre + t * math.sin(math.radians(blur.angle_deg))
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    kernel = np.zeros((size, size))
    for oy, ox, share in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)), (1, 0, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(kernel, (y0 + oy, x0 + ox), share)
    return kernel / kernel.sum()


def deblur(image: np.ndarray, blur: LinearBlur, noise: float | None = None) -> np.ndarray:
    """``image`` (H, W, C) uint8 with ``blur`` taken out by a Wiener filter (``noise``: its noise-to-signal
    ratio, ``WIENER_NOISE`` if None); same shape and dtype.

    The image is mirrored beyond its borders first (fading to its mean colour), so the filter's
    wrap-around does not carry one border's content to the other.
    """
    noise = WIENER_NOISE if noise is None else noise
    kernel = line_kernel(blur)
    size = kernel.shape[0]
    pad = 2 * size
    h, w = image.shape[:2]
    rows = scipy.fft.next_fast_len(h + 2 * pad, real=True)
    cols = scipy.fft.next_fast_len(w + 2 * pad, real=True)
    # Mirrored beyond the borders, fading to the mean colour over ``pad``: the transform repeats the
    # image, and where one border met the opposite one a sharp step would ring back into both.
    pixels = np.asarray(image, np.float32)
    mean = pixels.reshape(-1, pixels.shape[2]).mean(axis=0)
    padded = np.pad(pixels, ((pad, rows - h - pad), (pad, cols - w - pad), (0, 0)), mode="symmetric") - mean
    padded *= (_fade(rows, pad, h)[:, None] * _fade(cols, pad, w)[None, :])[:, :, None]
    psf = np.zeros((rows, cols))
    psf[:size, :size] = kernel
    psf = np.roll(psf, (-(size // 2), -(size // 2)), axis=(0, 1))  # the kernel's centre at the origin
    transfer = scipy.fft.rfft2(psf)
    gain = (np.conj(transfer) / (np.abs(transfer) ** 2 + noise)).astype(np.complex64)
    spectrum = scipy.fft.rfft2(padded, axes=(0, 1))
    restored = scipy.fft.irfft2(spectrum * gain[:, :, None], s=(rows, cols), axes=(0, 1))
    # (the mean was taken out: the filter's gain at zero frequency, 1 / (1 + noise), would dim the image)
    return np.clip(np.rint(restored[pad:pad + h, pad:pad + w] + mean), 0, 255).astype(np.uint8)


def _fade(total: int, pad: int, inner: int) -> np.ndarray:
    """(total,) float32: 1 over the image's ``inner`` samples (from ``pad``), falling linearly to 0 over
    ``pad`` samples on either side of it, 0 beyond."""
    index = np.arange(total, dtype=np.float32)
    outside = np.maximum(np.maximum(pad - index, index - (pad + inner - 1)), 0.0)
    return np.clip(1.0 - outside / pad, 0.0, 1.0)
