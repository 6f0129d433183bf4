"""Estimator settings: one frozen dataclass, two presets (the paper as written, and our default).

A field left at ``None`` takes its mode's preset, so ``EstimatorConfig(mode="paper")`` is the
faithful reproduction and any field can still be overridden for a study.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, fields

import numpy as np

from estimator.som import ORDERS as SOM_ORDERS

MODES = ("default", "paper")
CENTERLINES = ("som", "competitive", "kmeans++", "thinning", "skeleton")
COMPENSATIONS = ("none", "nearest", "nearest_image", "windowed")

# Preset values per mode for the fields that default to None.
_PRESETS = {
    "paper": {
        "roi": False,
        "close_ksize": 0,  # "remove isolated pixels": an opening; no closing (see the README's table)
        "som_input": "contour",
        "som_schedule": "online",
        "som_refine_iterations": 0,
        "medial_refinement": False,
        "extend_ends": False,
        "compensation": "nearest",
        "smoothing_degree": 6,
        "som_time": "sample",
        "som_order": "given",
        "plausibility_checks": False,  # the paper reports every frame
        "tube_fit": False,
        "deblur": False,
    },
    "default": {
        "roi": True,
        "close_ksize": 5,
        "som_input": "mask",
        "som_schedule": "batch",
        "som_refine_iterations": 6,
        "medial_refinement": True,
        "extend_ends": True,
        "compensation": "windowed",
        "smoothing_degree": 0,  # 0: penalised spline instead of a polynomial
        "som_time": "epoch",
        "som_order": "shuffled",
        "plausibility_checks": True,
        "tube_fit": True,
        "deblur": True,
    },
}


@dataclass(frozen=True)
class EstimatorConfig:
    """How the centerline is estimated. Pixel sizes refer to the full-resolution image.

    Attributes:
        mode: "default" (the best we can make) or "paper" (faithful reproduction of Zou et al.).
        centerline: 2D centerline stage: "som" (paper), or a baseline of section 4.3:
            "competitive" (Algorithm 2), "kmeans++" (Algorithm 3), "thinning" (skeleton sampled
            at equal intervals), "skeleton" (ordered skeleton traversal, mBEST-like).
        n_points: output points base -> tip (Table 1: n = 20 SOM neurons).
        hsv_low, hsv_high: inclusive HSV range of the arm in OpenCV units (H 0..180). The default
            segments an orange arm; if ``hsv_low[0] > hsv_high[0]`` the hue range wraps through 0.
        median_ksize: median filter aperture (odd).
        open_ksize, close_ksize: morphological opening (removes isolated pixels) and closing
            (fills small holes) kernel sizes; 0 disables. The paper preset does not close: a
            closing about as wide as a dark connector between two sections bridges it in one view
            and not in the other, and the two contours, traced differently, give the SOMs
            different biases.
        canny_low, canny_high: Canny thresholds applied to the binary mask.
        contour_step: equal-interval downsampling of the contour (keep every k-th point).
        min_area_px: connected regions smaller than this are noise, not arm.
        base_pixel: (u, v) of the arm's base in the raw LEFT image; None means "the chain end
            nearest the top edge of the left image".
        som_alpha0, som_epochs, som_radius: Table 1 (alpha0 = 0.2, lambda = 15, N = 2).
        som_time: what t in alpha(t) = alpha0 / (1 + t / lambda) counts: "sample" (every presented
            point; the paper preset: it reproduces the paper best, see the README's table of
            ambiguities) or "epoch" (Remark 2 read as training rounds; alpha ends near 0.1).
        som_sigma: width of the Gaussian neighbourhood eta(r) in node units; None ties it to the
            radius (N / 2), so N matters beyond the nearest neighbours (Fig 5c). The radius
            N(t) = N (1 - t / lambda) shrinks and nodes beyond ceil(N(t)) are not moved.
        som_seed: seed of the per-epoch presentation order (fixed, so results are reproducible
            and independent of the order of the input points).
        som_order: presentation order of the points in each epoch: "given" (Algorithm 1's "for
            each P_k" literally: the contour's traversal order; deterministic, the paper preset)
            or "shuffled" (seeded, after sorting: independent of the input order; the result
            then depends on ``som_seed``).
        som_shrink: shrink the neighbourhood radius N(t) = N (1 - t / lambda) (Remark 1) or keep
            it at N.
        som_compiled: run the numba-compiled SOM (True) or the numpy reference (False, paper speed).
        som_input: "contour" (paper) or "mask" (all arm pixels: unbiased centre).
        som_schedule: "online" (Algorithm 1) or "batch" (deterministic batch SOM).
        som_refine_iterations: batch SOM iterations (default mode; after warm start or cold init).
        mask_stride: use every k-th mask pixel in each direction as SOM input.
        medial_refinement: move each centerline sample to the midpoint of the silhouette chord
            normal to the curve (sub-pixel, unbiased on bends).
        extend_ends: extend both ends to where the silhouette ends, corrected for the end-cap
            geometry using ``arm_radius_m``.
        arm_radius_m: tube radius; the default mode measures the radius from width and disparity
            and uses this where it cannot (end-cap correction) and as a floor for the overlap check.
        connector_radius_m: radius of the discs that join the arm's sections (baseplates), or None.
            Where given, the default mode finds them in both images as short stretches of another
            colour along the arm and lets each fix the depth of its place on the axis: where a
            section runs along the image rows its silhouette lines carry no disparity, the
            connector's band across it does. Their band is centred off the axis towards the camera,
            by an amount that depends on this radius. None: connectors are not used.
        base_mount: the arm hangs from a mount wider than the tube, whose face hides the base's end:
            the silhouette ends where the tube enters it, short of the end of the axis on the side
            facing the camera. False: the base is a free end (a flat cap, as the tip is), and until
            the default mode has learned where the base is, the base's outline in both images fixes
            it as the tip's does. Taken for a mount, a free end was placed up to 6 mm too far along
            the arm and, in a 9-11 px pan, up to 12 mm off in depth while the frame was valid.
        section_lengths_m: ((min, max), ...) for each section from the base, the range of its length
            in metres: from the mount's face to the first connector's middle, between connectors'
            middles, from the last one's middle to the tip (what the arm can reach, every actuator
            at either end of its range). With ``connector_radius_m``, the default mode checks each
            stretch between the connectors it located: a tip seen end-on beyond the last connector,
            its last 60-80 mm hidden behind the rest, leaves a section far too short while every
            point it shows fits the images. None: not checked (the whole length still is).
        arm_length_m: nominal arm length; an estimate shorter than ``min_length_fraction`` of it
            means part of the arm is hidden (folded behind itself, out of view): invalid.
            None disables the check.
        min_length_fraction: see ``arm_length_m``.
        max_length_fraction: an estimate longer than this fraction of ``arm_length_m`` took in
            something past the tip (an arm-coloured box just beyond it: the twin's lab, 835 mm for
            its 685 mm arm, valid before) or comes from wrongly matched left and right centerlines
            (its points scatter in depth): invalid. The twin's arm measures 645-736 mm on every
            sequence tried (random levels on all seven valves); raise it for an arm that stretches more.
        max_bridge_widths: with the tube fit, the longest stretch of the 2D centerline without a
            clean silhouette chord (an occluder, a distractor the arm touches) that the fit may
            bridge, in arm widths; the fit then marks the points it bridged (``measured``).
        max_gap_widths: a stretch longer than this many arm widths without a clean silhouette
            chord (baseplates hide about one) means parts overlap or are occluded: invalid.
        max_width_ratio: a single tube's apparent width is 2 r / B times its disparity; a
            silhouette wider than this factor times that along ``max_wide_fraction`` of the arm
            holds two overlapping parts: invalid (default mode).
        compensation: misalignment compensation: "nearest" (the paper: cubic spline on the right
            nodes; of the spline's crossings of left node j's row within one node's share of the
            arm from node j's place, by arc length fraction on each image's spline, the nearest;
            where the spline crosses that row at under 15 degrees, or not there at all, the row
            cannot say where node j is: the node goes to the right spline's point at the arc
            length carried from the nodes the rows pin and the tip), "nearest_image" (of all
            crossings, the one nearest right node j in the image: jumps to the other branch where
            the arm crosses a row twice; no crossing: the node is kept), "windowed" (as "nearest",
            within two nodes' share), "none".
        plausibility_checks: drop frames that fail a plausibility check (a loop in the
            silhouette, a centerline touching itself, an estimate much shorter or longer than the
            arm, points behind the camera) as invalid (default mode), or keep them and only name
            the checks in ``EstimateResult.flags`` (paper mode: the paper reports every frame).
        smoothing_degree: degree of the polynomial fit of the 3D curve (paper: 6); 0 selects a
            penalised cubic spline on disparity (default mode).
        roi_margin_px: margin around the previous frame's arm when processing a region of interest.
        roi: process only a region of interest around the arm (found on a coarse image).
        max_self_approach: a centerline that comes closer to itself than this fraction of the arm
            width (between parts more than two widths apart along it) is a self-overlap: invalid.
        tube_fit: refine the 3D centerline by fitting a tube (a B-spline axis with a radius) to the
            sub-pixel silhouette edges of both images (default mode).
        deblur: measure a linear motion blur (camera shake, a fast pan) from the edges' steps and take
            it out of both images before the arm is measured (``estimator.deblur``; default mode,
            with ``tube_fit``).
    """

    mode: str = "default"
    centerline: str = "som"
    n_points: int = 20
    hsv_low: tuple[int, int, int] = (5, 100, 50)
    hsv_high: tuple[int, int, int] = (25, 255, 255)
    median_ksize: int = 5
    open_ksize: int = 3
    close_ksize: int | None = None
    canny_low: int = 50
    canny_high: int = 150
    contour_step: int = 4
    min_area_px: int = 150
    base_pixel: tuple[float, float] | None = None
    som_alpha0: float = 0.2
    som_epochs: int = 15
    som_radius: int = 2
    som_time: str | None = None
    som_sigma: float | None = None
    som_seed: int = 0
    som_order: str | None = None
    som_shrink: bool = True
    som_compiled: bool = True
    som_input: str | None = None
    som_schedule: str | None = None
    som_refine_iterations: int | None = None
    mask_stride: int = 2
    medial_refinement: bool | None = None
    extend_ends: bool | None = None
    arm_radius_m: float = 0.025
    arm_length_m: float | None = 0.685
    connector_radius_m: float | None = None
    base_mount: bool = False
    section_lengths_m: tuple | None = None
    compensation: str | None = None
    smoothing_degree: int | None = None
    roi: bool | None = None
    roi_margin_px: int = 48
    max_self_approach: float = 0.8
    max_gap_widths: float = 2.0
    max_bridge_widths: float = 4.0
    min_length_fraction: float = 0.7
    max_length_fraction: float = 1.15
    max_width_ratio: float = 1.35
    max_wide_fraction: float = 0.08
    plausibility_checks: bool | None = None
    tube_fit: bool | None = None
    deblur: bool | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode: expected one of {MODES}, got {self.mode!r}")
        for name, value in _PRESETS[self.mode].items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, value)
        _check(self.centerline in CENTERLINES, "centerline", f"one of {CENTERLINES}", self.centerline)
        _check(self.compensation in COMPENSATIONS, "compensation", f"one of {COMPENSATIONS}", self.compensation)
        _check(self.som_input in ("contour", "mask"), "som_input", "'contour' or 'mask'", self.som_input)
        _check(self.som_schedule in ("online", "batch"), "som_schedule", "'online' or 'batch'", self.som_schedule)
        _check(self.som_time in ("epoch", "sample"), "som_time", "'epoch' or 'sample'", self.som_time)
        _check(self.som_order in SOM_ORDERS, "som_order", f"one of {SOM_ORDERS}", self.som_order)
        _check(_int(self.n_points) and 3 <= self.n_points <= 500, "n_points", "an integer in [3, 500]",
               self.n_points)
        for name in ("hsv_low", "hsv_high"):
            given = getattr(self, name)
            _check(isinstance(given, tuple | list), name, "(H, S, V) integers with H in [0, 180], S and V in [0, 255]",
                   given)
            value = tuple(given)
            ok = len(value) == 3 and all(_int(v) for v in value)
            ok = ok and 0 <= value[0] <= 180 and all(0 <= v <= 255 for v in value[1:])
            _check(ok, name, "(H, S, V) integers with H in [0, 180], S and V in [0, 255]", getattr(self, name))
            object.__setattr__(self, name, value)
        _check(self.hsv_low[1] <= self.hsv_high[1] and self.hsv_low[2] <= self.hsv_high[2], "hsv_low",
               "S and V not above hsv_high", self.hsv_low)
        _check(_int(self.median_ksize) and self.median_ksize in (0, 1, 3, 5, 7, 9), "median_ksize",
               "0 (off) or an odd size up to 9", self.median_ksize)
        for name in ("open_ksize", "close_ksize", "contour_step", "min_area_px", "mask_stride", "roi_margin_px",
                     "som_epochs", "som_radius", "som_refine_iterations", "som_seed"):
            _check(_int(getattr(self, name)) and getattr(self, name) >= 0, name, "a non-negative integer",
                   getattr(self, name))
        _check(self.contour_step >= 1 and self.mask_stride >= 1, "contour_step", "at least 1", self.contour_step)
        _check(self.som_epochs >= 1, "som_epochs", "at least 1", self.som_epochs)
        for name in ("canny_low", "canny_high"):  # OpenCV's Canny takes them in either order
            _check(_number(getattr(self, name)) and getattr(self, name) >= 0, name, "a non-negative number",
                   getattr(self, name))
        _check(_number(self.som_alpha0) and 0 < self.som_alpha0 <= 1, "som_alpha0", "a number in (0, 1]",
               self.som_alpha0)
        _check(self.som_sigma is None or (_number(self.som_sigma) and self.som_sigma > 0), "som_sigma",
               "a positive number or None (N / 2)", self.som_sigma)
        _check(_number(self.arm_radius_m) and self.arm_radius_m > 0, "arm_radius_m", "a positive number of metres",
               self.arm_radius_m)
        _check(_int(self.smoothing_degree) and 0 <= self.smoothing_degree <= 12, "smoothing_degree",
               "an integer in [0, 12]", self.smoothing_degree)
        _check(_number(self.max_self_approach) and 0 <= self.max_self_approach < 5, "max_self_approach",
               "a fraction in [0, 5)", self.max_self_approach)
        _check(self.arm_length_m is None or (_number(self.arm_length_m) and self.arm_length_m > 0), "arm_length_m",
               "a positive length or None", self.arm_length_m)
        _check(self.connector_radius_m is None or (_number(self.connector_radius_m) and self.connector_radius_m > 0),
               "connector_radius_m", "a positive number of metres or None", self.connector_radius_m)
        if self.section_lengths_m is not None:
            object.__setattr__(self, "section_lengths_m", _section_ranges(self.section_lengths_m))
            _check(self.connector_radius_m is not None, "section_lengths_m",
                   "connector_radius_m as well (the connectors mark where the sections meet)", self.section_lengths_m)
        _check(_number(self.min_length_fraction) and 0 <= self.min_length_fraction < 1, "min_length_fraction",
               "a fraction in [0, 1)", self.min_length_fraction)
        _check(_number(self.max_length_fraction) and self.max_length_fraction > 1, "max_length_fraction",
               "a fraction above 1", self.max_length_fraction)
        for name in ("max_gap_widths", "max_bridge_widths"):
            _check(_number(getattr(self, name)) and getattr(self, name) > 0, name, "a positive number",
                   getattr(self, name))
        _check(_number(self.max_width_ratio) and self.max_width_ratio > 1, "max_width_ratio", "a ratio above 1",
               self.max_width_ratio)
        _check(_number(self.max_wide_fraction) and 0 < self.max_wide_fraction <= 1, "max_wide_fraction",
               "a fraction in (0, 1]", self.max_wide_fraction)
        if self.base_pixel is not None:
            _check(isinstance(self.base_pixel, tuple | list), "base_pixel", "(u, v) pixels", self.base_pixel)
            bp = tuple(self.base_pixel)
            _check(len(bp) == 2 and all(_number(v) for v in bp), "base_pixel", "(u, v) pixels, finite numbers",
                   self.base_pixel)
            object.__setattr__(self, "base_pixel", (float(bp[0]), float(bp[1])))
        for name in ("roi", "medial_refinement", "extend_ends", "som_compiled", "som_shrink", "plausibility_checks",
                     "tube_fit", "deblur", "base_mount"):
            _check(isinstance(getattr(self, name), bool), name, "true or false", getattr(self, name))

    @classmethod
    def from_dict(cls, values: dict, source: str = "estimator config") -> EstimatorConfig:
        """Build from a TOML table; unknown keys and bad values name ``source`` and the key."""
        known = {f.name for f in fields(cls)}
        for key in values:
            if key not in known:
                raise ValueError(f"{source}: unknown key {key!r}; known keys: {', '.join(sorted(known))}")
        try:
            return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})
        except ValueError as e:
            raise ValueError(f"{source}: {e}") from e

    def replace(self, **changes) -> EstimatorConfig:
        """A copy with some fields changed; preset fields follow a changed mode unless given."""
        if "mode" in changes and changes["mode"] != self.mode:
            base = {f.name: getattr(self, f.name) for f in fields(self)}
            for name in _PRESETS[self.mode]:
                base[name] = None
            base.update(changes)
            return EstimatorConfig(**base)
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _section_ranges(value) -> tuple[tuple[float, float], ...]:
    """``section_lengths_m`` as a tuple of (min, max) floats, checked: two sections or more, each
    range finite with 0 < min <= max."""
    expected = "two or more [min, max] ranges in metres, one per section, 0 < min <= max"
    _check(isinstance(value, tuple | list) and len(value) >= 2, "section_lengths_m", expected, value)
    out = []
    for pair in value:
        _check(isinstance(pair, tuple | list) and len(pair) == 2 and all(_number(v) for v in pair)
               and 0 < pair[0] <= pair[1], "section_lengths_m", expected, value)
        out.append((float(pair[0]), float(pair[1])))
    return tuple(out)


def _int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _number(value) -> bool:
    """A finite real number (numpy's too), not a boolean (True would read as 1, a string cannot be compared)."""
    return (isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)
            and math.isfinite(float(value)))


def _check(ok: bool, name: str, expected: str, got) -> None:
    if not ok:
        raise ValueError(f"{name}: expected {expected}, got {got!r}")
