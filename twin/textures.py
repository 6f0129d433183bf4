"""Procedural textures for the twin's lab scenes: plaster, bricks, wood grain, a cluttered wall.

Real labs do not have single-colour walls. These textures give the estimator what it meets
there: low-contrast mottling, regular edges (mortar lines), and the brown-orange of wood whose
hue sits inside the arm's own colour range. Each is a pure function of its arguments and a
seed, so a scene renders the same images every time.

All textures are (H, W, 3) uint8 display RGB (gamma-encoded, like the colours in the TOML files).
"""

from __future__ import annotations

import cv2
import numpy as np

PATTERNS = ("plaster", "bricks", "wood", "clutter")


def value_noise(shape: tuple[int, int], feature_px: float, rng: np.random.Generator, octaves: int = 4) -> np.ndarray:
    """Smooth noise in [-1, 1]: random grids upsampled bicubically, halving the feature size per octave.

    Args:
        shape: (H, W) of the result.
        feature_px: size of the coarsest features, pixels.
        rng: the random generator (the only source of randomness).
        octaves: number of layers; each has half the feature size and half the amplitude.
    """
    h, w = shape
    total = np.zeros((h, w), np.float32)
    amplitude, weight = 1.0, 0.0
    size = max(float(feature_px), 2.0)
    for _ in range(octaves):
        gh, gw = max(int(h / size) + 2, 2), max(int(w / size) + 2, 2)
        grid = rng.uniform(-1.0, 1.0, (gh, gw)).astype(np.float32)
        total += amplitude * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        weight += amplitude
        amplitude *= 0.5
        size = max(size / 2.0, 2.0)
    return np.clip(total / weight, -1.0, 1.0)


def _shade(base_rgb, factor: np.ndarray) -> np.ndarray:
    """Base colour times a per-pixel factor, as uint8 display RGB."""
    rgb = np.asarray(base_rgb, np.float32)[None, None, :] * factor[..., None]
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)


def plaster(shape, base_rgb, contrast: float, feature_px: float, rng) -> np.ndarray:
    """A painted wall: mottled brightness of +-``contrast`` around the base colour."""
    return _shade(base_rgb, 1.0 + contrast * value_noise(shape, feature_px, rng))


def bricks(shape, base_rgb, contrast: float, feature_px: float, rng) -> np.ndarray:
    """Brick courses of ``feature_px`` height with light mortar joints; each brick its own shade."""
    h, w = shape
    course = max(int(feature_px), 6)
    length = 2 * course + course // 2
    rows = np.arange(h)[:, None] // course
    offset = (rows % 2) * (length // 2)
    cols = (np.arange(w)[None, :] + offset) // length
    shades = rng.uniform(-1.0, 1.0, (int(rows.max()) + 2, int(w / length) + 3)).astype(np.float32)
    factor = 1.0 + contrast * shades[rows, cols]
    factor += 0.3 * contrast * value_noise(shape, feature_px / 3.0, rng, octaves=2)
    mortar = ((np.arange(h)[:, None] % course) < max(course // 8, 1)) | (
        ((np.arange(w)[None, :] + offset) % length) < max(course // 8, 1))
    rgb = _shade(base_rgb, factor)
    rgb[mortar] = np.clip(np.array([0.82, 0.80, 0.76]) * 255, 0, 255).astype(np.uint8)
    return rgb


def wood(shape, base_rgb, contrast: float, feature_px: float, rng) -> np.ndarray:
    """Wood grain along the texture's width: rings distorted by noise, darker late wood."""
    h, w = shape
    y = np.arange(h, dtype=np.float32)[:, None] + 0.0 * np.arange(w, dtype=np.float32)[None, :]
    warp = feature_px * 1.5 * value_noise(shape, 6.0 * feature_px, rng, octaves=3)
    rings = np.sin(2.0 * np.pi * (y + warp) / max(feature_px, 2.0))
    streaks = value_noise((h, max(w // 16, 2)), feature_px / 2.0, rng, octaves=2)
    streaks = cv2.resize(streaks, (w, h), interpolation=cv2.INTER_LINEAR)
    factor = 1.0 + contrast * (0.7 * rings ** 3 + 0.3 * streaks)
    return _shade(base_rgb, factor)


def clutter(shape, base_rgb, contrast: float, feature_px: float, rng) -> np.ndarray:
    """A plaster wall with posters, notes and a whiteboard: rectangles of many hues, orange ones too."""
    h, w = shape
    rgb = plaster(shape, base_rgb, contrast, feature_px, rng)
    for _ in range(int(rng.integers(6, 12))):
        rw, rh = int(rng.uniform(0.05, 0.2) * w), int(rng.uniform(0.06, 0.25) * h)
        x0, y0 = int(rng.uniform(0, w - rw)), int(rng.uniform(0, h - rh))
        hue = rng.uniform(0, 180)
        sat = rng.uniform(40, 230)
        val = rng.uniform(120, 250)
        colour = cv2.cvtColor(np.array([[[hue, sat, val]]], np.uint8), cv2.COLOR_HSV2RGB)[0, 0]
        patch = np.clip(colour[None, None, :].astype(np.float32)
                        * (1.0 + 0.5 * contrast * value_noise((rh, rw), feature_px / 2, rng, 2))[..., None], 0, 255)
        rgb[y0:y0 + rh, x0:x0 + rw] = patch.astype(np.uint8)
    return rgb


def procedural_texture(pattern: str, shape: tuple[int, int], base_rgb, contrast: float, feature_px: float,
                       seed: int) -> np.ndarray:
    """One of :data:`PATTERNS` as (H, W, 3) uint8 display RGB.

    Raises:
        ValueError: an unknown pattern (names the allowed ones).
    """
    makers = {"plaster": plaster, "bricks": bricks, "wood": wood, "clutter": clutter}
    if pattern not in makers:
        raise ValueError(f"unknown texture pattern {pattern!r}; expected one of {', '.join(PATTERNS)}")
    rng = np.random.default_rng(seed)
    return makers[pattern](tuple(shape), base_rgb, float(contrast), float(feature_px), rng)
