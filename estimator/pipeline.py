"""The centerline estimator: composes the stages, keeps warm-start state and per-stage timings.

Paper mode (sections 3-4 as written): full-frame rectification, segmentation, Canny contour,
online SOM on the contour warm-started from the previous frame, cubic-spline misalignment
compensation, least-squares triangulation of the n nodes, 6th-degree polynomial.

Default mode keeps the SOM as the tracker but works in a region of interest, trains a batch SOM
on all arm pixels, moves the chain onto the silhouette's medial axis with sub-pixel chords,
matches rows only near the same place along the arm with a disparity profile that bridges
stretches running along the rows, and finds the true ends from the silhouette and the end-cap
geometry.
"""

from __future__ import annotations

import copy
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from estimator.arm_region import TubeGeometry, find_tube, keep_in_corridor, saturation_split, without_wide_strays
from estimator.calibration import StereoCalibration
from estimator.centerline import centerline_nodes
from estimator.colour_model import ArmColourModel, value_floor
from estimator.config import EstimatorConfig
from estimator.correspondence import MIN_SINE, compensate_nodes, match_rows
from estimator.deblur import LinearBlur, blur_from_steps, deblur
from estimator.edges import step_widths, subpixel_edges, subpixel_edges_and_steps
from estimator.mount import MountLearner
from estimator.profile import BASE_RAMP_WIDTHS, BASE_SKIP_WIDTHS, base_ramp, measured_radius_m, with_width_cue
from estimator.refinement import Centerline2D, edge_distances, refinement_passes, window_medians
from estimator.sections import section_length_problem
from estimator.segmentation import (
    bounding_box,
    contour_points,
    has_holes,
    hsv_in_range,
    mask_points,
    remove_small_regions,
    segment,
)
from estimator.skeleton import resample_polyline
from estimator.smoothing import polynomial_smooth, robust_spline_profile
from estimator.triangulation import triangulate
from estimator.tube_fit import (
    CAP_SIGMA_PX,
    EDGE_SIGMA_PX,
    MIN_CAP_POINTS,
    RADIUS_BINS,
    EdgeSet,
    TubeFit,
    fit_tube,
    fuse_radius,
    misfit_edges,
    silhouette_lines,
)

COARSE_WIDTH_PX = 320  # the coarse images the arm is looked for on are about this wide
RADIUS_FIT_SIGMA_M = 0.001  # see _fit_tube
RADIUS_PRIOR_SIGMA_M = 0.004  # how far the configured radius may be off before the images correct it
MIN_TUBE_INLIERS = 0.8  # share of edges within a pixel of the fitted tube
MAX_TUBE_RMS_PX = 0.6  # RMS of those edges
OUTLINE_FAN_DEG = 70.0  # rays around an end, either side of the centerline's direction
OUTLINE_STEP_DEG = 10.0
OUTLINE_BACK_HALVES = 1.5  # outline points further back from the end than this many half widths are dropped
# A point is bridged when it lies in a stretch of either image without edges longer than this
# many radii: an end's cap or mount leaves about half of that (10-22 mm), a baseplate or a
# cable across the arm 35-60 mm (with the chords beside them that are not clean).
MEASURED_GAP_RADII = 1.2
EXPLAINED_SIGMAS = 1.5  # a tip outline the fitted end leaves above this RMS (in sigmas) is left out, and refitted
OUTLINE_OUTLIER_SIGMAS = 3.0  # ... unless only a few of its points (see _outline_inliers) miss it by over this many
MAX_OUTLINE_OUTLIERS = 0.125  # ... and at most this share of them (one ray in eight)
MAX_END_BRIDGE_WIDTHS = 1.0  # an end hidden over more than this many arm widths is a guess, not a measurement
# The fit's covariance overstates the error of a well-seen arm (typically 3-15 mm at the tip, where
# the error is 1-5 mm) but grows to 40-110 mm where an occluder hides the tip: only that is refused.
MAX_POINT_STD_M = 0.04
# A bridged stretch seen end-on (running towards or away from the cameras) shows the images little
# of itself: continuity alone places it, and where the fit also says it is unsure there the frame
# is refused. Unseen seed 131 (the last section swinging towards the cameras behind a baseplate):
# 180-220 mm bridged, seen at 0.37-0.50 of its length, 7.9-11 mm standard deviation, valid 11-15 mm
# off in four conditions. Over 2,699 unseen frames within 10 mm of the truth (seeds 10-21, 114-149)
# three have such a stretch, 5.6-7.7 mm off; 6 of the 15 false valid frames do. Occluders crossing
# side-on leave up to 11 mm there as well, and are right (42 frames over 7 mm, all within 10 mm).
END_ON_BRIDGE_FRACTION = 0.6  # the share of a bridged stretch's length its images show, below which it is end-on
MAX_END_ON_BRIDGE_STD_M = 0.007  # ... and the standard deviation within it above which it is a guess
# Sliding along the axis is left out of a point's standard deviation (it moves no point off the
# curve) but not out of where the tip is. A tip pointing nearly along a line of sight, or ending
# behind the arm's nearer part, slides almost unseen: the twin's pressure sequences (random levels
# on all seven valves, 4 x 60 frames, and a 60-frame sweep) put such tips 10-74 mm off along the
# arm, valid, with 8-17 mm of this standard deviation; tips within 10 mm had up to 12 mm. Beyond
# the 10 mm a valid frame promises, the frame is refused. On those 300 frames: false valid 14 -> 7,
# the worst tip 74 -> 31 mm off, valid 233 -> 226; the ramp's study sets (60 and 12 frames per
# condition) are unchanged. A bound at 7.8 mm caught four more but refused the ramp's middle frame
# in the CI's sparse lab and dim sets (8-9 mm there, tracked 5 s apart).
MAX_TIP_ALONG_STD_M = 0.010
# A tip pointing away from the camera hides its own end: past the rim's far arc the images show
# nothing of it, and the fit's standard deviation along the arm came out about half the error there.
# On the twin's random sequences (1,428 valid frames over 28 stored sets), tips within 18 degrees
# of pointing straight away: 27 frames, 6 of them 10-18 mm short with 6.4-9.5 mm of this standard
# deviation. Such tips are held to 6 mm: all six refused, with 10 of the 21 others (two of them
# 9-10 mm off). Tips pointing elsewhere keep the 10 mm bound (a 6 mm one everywhere refused 10x more).
# The frame is refused but tracked on: restarting the tracking after it (as after other refusals)
# put later frames of the random sequences 10-17 mm off.
AWAY_TIP_COSINE = 0.95  # cos 18 degrees, between the tip's direction and the line of sight to it
MAX_AWAY_TIP_ALONG_STD_M = 0.006
TIP_DIRECTION_M = 0.02  # the tip's direction is taken over this much of the arm
# A fitted tip that kinks at its end has bent to fit its outline, not followed the arm. On unseen
# scenes (tests/scenes.py, seeds 114-125 and 138-149, 1,355 valid frames) the turn between the last
# two TIP_DIRECTION_M of the fitted axis was under 5 degrees in 99 % of frames; the five over 15
# degrees (a tip pointing towards the cameras, its face seen, the fit ending it short and bent
# aside) were all 8.4-17.6 mm off at the tip. An arm curved at 5 /m turns 6 degrees there.
MAX_TIP_TURN_DEG = 15.0
# Along the rest of the axis the same bound holds (an arm bends smoothly; one turning 15 degrees in
# 40 mm is curved at 13 /m): a fit that folds there has traded a loop for the edges of a stretch it
# could not place (unseen scenes, seeds 114-125 and 138-149: 99 % of valid frames under 12 degrees;
# seven turned 16-53, the dense axis 12-19 mm off between the output points, one 10.1 mm off at one;
# held out, 10-21 and 126-137: nine, among them that set's one false valid frame). A fit tracked
# from the last frame carries such a fold on, so it is fitted afresh; folded again, refused.
MAX_AXIS_TURN_DEG = MAX_TIP_TURN_DEG
# The tip's standard deviation assumes its outline fits as well as the edges do. An outline the
# fitted end misses by more than TIP_OUTLINE_NOISE_PX RMS (tips within 10 mm: median 0.12 px, nine
# in ten under 0.4 px; false valid ones: median 0.45 px) has pulled the tip where it does not quite
# fit, so its standard deviation grows in proportion; beyond MAX_MISFIT_TIP_STD_M so grown, the
# frame is refused. The twin's stored sets (the ramp's 60- and 12-frame sets, the random preset's
# seeds 0-9, blur and bright_warm with seed 5, the random pressure sequences; 1,632 frames): false
# valid 33 -> 15, valid 1,393 -> 1,375. A bound at 6 mm refused a straight blurred arm of
# tests/scenes.py (6.1 mm at 0.50 px, 2 mm off); 0.35 px refused fewer (1,380 valid) but kept 20
# false valid.
TIP_OUTLINE_NOISE_PX = 0.3
MAX_MISFIT_TIP_STD_M = 0.008
# A free base (no mount, none learned yet: EstimatorConfig.base_mount, estimator.mount) ends where its
# cap's outline puts it, and a flat cap across the image rows says little of its depth: the fit may
# curl the last centimetres towards or away from the cameras, most in horizontal blur, where the
# tube's sides are blurred and only the cap is sharp. Its standard deviation says so, but too little:
# over 2,285 such valid frames of benchmarks/unseen_scenes.py (seeds 10-21, 30-77) the base's error
# passed 1.65 of it in one frame in ten and 3.2 in one in a hundred (the tip's: 1.1 and 2.3). Six
# came back valid 10.5-15.9 mm off at the base with 4.8-7.9 mm. Held to 5 mm, five of them are
# refused (all blurred) with 29 others of 4,320 (12 of them blurred; 0.8-9.7 mm off), tracked on; at
# 4.5 mm the sixth too, but with 59 others. The twin's arm hangs from its mount, which holds the base.
MAX_FREE_BASE_STD_M = 0.005
# An outline missed by more than 2.5 times that noise is not explained well enough to place the tip
# at all, however small its grown standard deviation: the fit traded the tip's place for the cap's
# turn (benchmarks/unseen_scenes.py, 690 valid frames: 4 over 0.75 px, three of them 27-36 mm off
# with 5.8-6.7 mm of grown standard deviation, the fourth 3.1 mm; below it one frame over 10 mm, its
# outline fitted to 0.19 px: another failure). The twin's ramp has none over it; its random shapes
# two (1.4 and 5.3 mm off). The frame is refused and tracked on, as a tip pointing away is: the rest
# of the shape fits.
MAX_TIP_MISFIT_PX = 0.75
# Two starts of the fit (the disparity profile and the last frame's tube) that end within this much
# cost of each other fit the images about equally well; where their tips lie further apart than
# AMBIGUOUS_TIP_M, the images do not say where the tip ends, and the frame is refused and tracked on.
# benchmarks/unseen_scenes.py, 444 second starts: 409 put the tips within 3 mm; of the 21 over 10 mm,
# two ended within this cost, one with its tips 23 mm apart (a tip pointing at the camera in a pan,
# valid 24 mm off: the other start's tip was 1.2 mm off), the other with the arm moved too far for it.
AMBIGUOUS_COST = 6.0
AMBIGUOUS_TIP_M = 0.015
MIN_FLOOR_PIXELS = 100  # an image's arm with fewer mask pixels does not set the gate's value floor
MATCHED_WEIGHT = 0.05  # a row-matched point of the left curve weighs more than this in the disparity profile
MIN_MATCHED_TIP_SHARE = 0.5  # under this share of the arm's last third matched, the tip's depth is a guess
# Such a tip's depth rests on its cap's outline alone (its side edges run along the rows, where they
# give no disparity), and a flat cap turned towards the camera or as far away outlines alike. Missed
# by more than this (RMS, pixels), the outline does not hold the depth: on fresh unseen sequences
# (seeds 30-41) one shape came back valid 37-38 mm off in dim light, blur and behind a cable, its
# outline missed by 0.54-0.69 px with 4.9-6.3 mm of grown standard deviation (under the 8 mm bound).
# Over 2,700 valid frames (unseen seeds 10-21, 30-41, 42-53 and the twin's stored sets) it refuses
# those three and three more, 3.0, 4.4 and 6.9 mm off; the twin's sets have none over it.
MAX_ROW_TIP_MISFIT_PX = 0.5
TIP_START_SHIFT_WIDTHS = 1.0  # see _tip_depth_ambiguity
OUTLINE_RESTART_ITERATIONS = 10  # see _tip_depth_ambiguity: the restarts of the outline stage alone ...
OUTLINE_RESTART_AMBIGUOUS_COST = 0.0  # ... which make the tip ambiguous only where they end lower in cost
# A restart of either kind that ends lower in cost than the fit with its tip further away than this
# makes the tip ambiguous too (short of AMBIGUOUS_TIP_M): the fit stopped in a basin the images like
# less, and a tip 8 mm from a better one may be 10 mm from the truth. Over the seven unseen seed sets
# (5,040 frames) it refused 5 false valid frames (10.8-13.5 mm away, 11.1-13.6 mm off) with 8 others
# (1.8-3.9 mm off, and two 8.4 and 8.9); on the twin, the paper's ramp's one frame over 10 mm (t = 56.0
# s, the tip 12.9 mm off) and the CI's occluded set's (10.5 mm), with 6 and 4 good frames of the ramp
# and the study's 420 (2.9-5.6 mm); an eighth seed set drawn after it was chosen: no frame changed.
# See _tip_depth_ambiguity.
BETTER_RESTART_TIP_M = 0.008
# Starting the fit from the previous frame's tube saves the disparity profile but measured worse
# (2.8 against 2.2 mm on a late-ramp stretch of the twin): the profile starts it better.
WARM_START_TUBE = False
# A tip further than this from the last frame's: fit again from the last tube, keep the lower cost.
SECOND_START_M = 0.003
# Moved further than this many arm widths, the last tube is only a fallback (for a first start the images
# leave unconstrained): it is then no nearer the arm than the cold start, and where the edges leave a
# stretch free (a baseplate across a bend) the two starts settle in different shapes whose costs say
# nothing about which is right (frames 5 s apart, t = 58 s: the last tube's shape won by cost and lay
# 15 mm off there; 64-110 mm moves, against at most 26 mm between the study's frames 1 s apart).
SECOND_START_MAX_WIDTHS = 1.0
MIN_CLEAN_CHORDS = 0.9  # below this share of clean chords after one refinement pass, a second one runs
MIN_WARM_CLEAN_CHORDS = 0.7  # below this share from the last frame's chain, the image is traced cold too (lab: >= 0.74)
REFINE_PASSES = 1  # chord passes of the 2D refinement (the tube fit does the sub-pixel work since)
MAX_CORRIDOR_CUT = 0.1  # share of the arm-coloured pixels touching the corridor that it may cut away
MAX_UNCOVERED = 0.01  # share of arm samples a warm-started chain may leave further than a width from it
BLUR_RETRY_PX = 1.5  # a frame whose blur differs from the one taken out by this much (or by BLUR_RETRY_DEG) is redone
BLUR_RETRY_DEG = 20.0
FOCUSED_STEP_PX = 2.0  # an edge's step (its 20-80 % rise) up to this wide counts as focused
BLURRED_EDGE_SIGMA = 0.6  # beyond it, the edge's sigma grows by this share of the excess width (0.3 before:
# 60-frame sets, false valid blur 7 -> 4, dim 1 -> 0, occluded 1 -> 0, random 1 -> 0, unseen random:1 13 -> 10,
# random:2 6 -> 4; lab 1.29 -> 1.25 mm; 1.0 and 0.15 both worse on blur: 9 and 6 false valid)
RESCUE_WINDOW_PX = 40.0  # unclean chords are compared with the clean ones within this arc either side
RESCUE_TOLERANCE_PX = 0.8  # ... and kept within this of their width (half of it in centre) ...
RESCUE_SPREADS = 3.0  # ... or this many robust spreads of the clean chords' widths, if larger
RESCUE_GAP_WIDTHS = 1.0  # not beside a stretch without clean chords longer than this many arm widths
# The connectors between sections (see _connector_centres and tube_fit's connectors), where the
# config gives their radius: a stretch of the centerline without clean chords is one when it is at
# most this many arm widths long (plus the half width kept clear on each side) ...
MAX_CONNECTOR_WIDTHS = 1.0
CONNECTOR_MIN_CONTRAST = 40.0  # ... and its colour differs from the arm's by this much (BGR distance) at its darkest
CONNECTOR_WEIGHT_FLOOR = 0.1  # below this share of the dip, a sample is the arm's shading, not the connector
MAX_CONNECTOR_ROW_PX = 4.0  # see _paired_connectors
EDGE_STRIDE = 1  # every sample of the 2D centerline (3 px apart); every second gave 1.84 mm, not 1.42, on the late ramp
SIDES = ("left", "right")
VIEW_EDGE_PX = 3.0  # an end this close to the edge of what the camera saw runs on out of view


@dataclass(frozen=True, eq=False)
class EstimateResult:
    """One frame's estimate.

    Attributes:
        points: (n, 3) metres, left camera frame (x right, y down, z forward), base -> tip;
            (0, 3) when not valid.
        valid: False when no trustworthy centerline was found; ``reason`` says why.
        left_uv, right_uv: (n, 2) the 2D centerlines in raw pixel coordinates.
        timings_ms: milliseconds per stage (summed over both images, which are processed in
            parallel) and ``total`` (wall-clock time of the call).
        nodes_rect: side -> (n, 2) 2D centerline nodes in rectified pixels (for eqs. 9-11).
        misalignment_px: eq. (11) between the left and right nodes before compensation.
        flags: names of the plausibility checks this frame failed ("holes", "self_approach",
            "length", "behind_camera"). With ``plausibility_checks`` on (default mode) a failed
            check makes the frame invalid; off (paper mode, which reports every frame) the frame
            stays valid and the check is only named here.
        points_unsmoothed: (n, 3) metres, the triangulated node pairs before the polynomial (the
            paper's Q, paper path); (0, 3) otherwise.
        measured: (n,) True where the point is measured (silhouette edges near it in both images),
            False where the tube fit bridged it (occluded, hidden by a distractor of the arm's
            colour, or cut off); empty when not valid or without the tube fit.
        point_std_m: (n,) each point's standard deviation along its least certain direction, from
            the tube fit's covariance (metres), the tip's grown where its outline misfits the fitted
            end (``TIP_OUTLINE_NOISE_PX``); empty without the tube fit.
        radius_m: the tube's mean radius used by the fit, and ``radius_source`` where it came from
            ("configured", or "measured over N frames").
    """

    points: np.ndarray
    valid: bool
    reason: str
    left_uv: np.ndarray
    right_uv: np.ndarray
    timings_ms: dict[str, float]
    nodes_rect: dict[str, np.ndarray] = field(default_factory=dict)
    misalignment_px: float = float("nan")
    flags: tuple[str, ...] = ()
    points_unsmoothed: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    measured: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    point_std_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    radius_m: float = float("nan")
    radius_source: str = ""


class _NoArmError(Exception):
    """A frame without a trustworthy centerline; the message becomes ``EstimateResult.reason``."""


class _TooLongError(_NoArmError):
    """The estimate is longer than the arm can be: something past its tip may have been taken for it."""


class _OutOfViewError(_NoArmError):
    """The silhouette's end runs to the edge of the view: the arm goes on out of it, or something past
    its tip (joined to it across a gap) does."""


@dataclass
class _Side:
    """What one image contributes: ordered nodes and, in default mode, the refined curve."""

    nodes: np.ndarray  # (n, 2) rectified canvas pixels, base first
    curve: Centerline2D | None = None
    width_px: float = 0.0
    area_px: int = 0  # arm pixels in the mask
    learn: tuple | None = None  # (hsv, gate, mask, offset) of the region: what the colour model learns from
    image: np.ndarray | None = None  # the rectified region of interest (BGR), for sub-pixel edges
    offset: np.ndarray | None = None  # its top-left corner on the rectified canvas
    edges: tuple | None = None  # (edge points, their chords' centres, their steps' widths, (base, tip) ends,
    #                              outlines at both ends)
    steps: tuple | None = None  # (normals (K, 2), step widths (K,)) of the raw image's edges: how it is blurred


class CenterlineEstimator:
    """Estimate the 3D centerline of the arm from raw stereo pairs.

    Args:
        calibration: the stereo calibration of the raw images.
        config: estimator settings; ``EstimatorConfig()`` is the default mode.
    """

    def __init__(self, calibration: StereoCalibration, config: EstimatorConfig | None = None) -> None:
        if not isinstance(calibration, StereoCalibration):
            raise TypeError(f"calibration: expected a StereoCalibration, got {type(calibration).__name__}")
        self.calibration = calibration
        self.config = config or EstimatorConfig()
        self._rect = calibration.rectification
        self._coarse_maps = {}
        # 1/4 of a 1280-pixel image; smaller images are searched at a finer scale (a VGA ZED at 1/2).
        self._scale = int(np.clip(calibration.image_size[0] // COARSE_WIDTH_PX, 1, 4))
        for side in SIDES:
            self._coarse_maps[side] = self._rect.nearest_map(side, self._scale)
        self._base_hint = None
        if self.config.base_pixel is not None:
            self._base_hint = self._rect.rectify_points(np.array([self.config.base_pixel]), "left")[0]
        self._warm: dict[str, np.ndarray | None] = {side: None for side in SIDES}
        self._track: dict[str, tuple[float, int]] = {}  # side -> (width, area) of the arm in the coarse mask
        self._gate_low = tuple(self.config.hsv_low)  # the colour gate's lower bound (saturation and value adapt)
        self._colour = ArmColourModel()
        self._updates = 0  # frames the colour model has been offered (it learns from every one of the first ten)
        self._radius: np.ndarray | None = None  # the tube's radius profile, learned over frames
        self._radius_info: np.ndarray | None = None
        self._last_fit: TubeFit | None = None
        self._warm_fit: TubeFit | None = None  # the last trusted frame's tube
        self._moving_fast = False  # the last frame's tube needed its second start
        self._radius_frames = 0
        self._tube_extras: tuple | None = None
        self._base = MountLearner()
        self._blur: LinearBlur | None = None  # the blur taken out of the images (``estimator.deblur``)

    def reset(self) -> None:
        """Forget the previous frame: the next estimate starts cold."""
        self._warm = {side: None for side in SIDES}
        self._track = {}
        self._gate_low = tuple(self.config.hsv_low)
        self._colour.reset()
        self._updates = 0
        self._base.reset()
        self._warm_fit = None
        self._moving_fast = False  # the last frame's tube needed its second start
        self._radius = self._radius_info = None
        self._radius_frames = 0
        self._blur = None

    def warm_up(self) -> None:
        """Compile the numba stages now, on a synthetic pair, so the first real frame is not slow.

        The compiled code is cached on disk; on a fresh install the first estimate would
        otherwise pay about a second of compilation. Leaves the warm-start state empty.
        """
        w, h = self.calibration.image_size
        cfg, baseline = self.config, self._rect.baseline_m
        # A straight tube of the configured radius and length at the depth where it spans 70 % of the
        # image's height, with flat ends as the tube fit models them (a thick cv2.line has round caps,
        # whose outline the fitted end rightly refuses): a frame every check accepts, so every stage
        # (the tube fit too) runs and compiles. Its outline is drawn densely on the rectified canvas and
        # taken into the raw image, so the lens's distortion bends it as it bends the real arm.
        length = cfg.arm_length_m if cfg.arm_length_m is not None else 0.6 * h * baseline / (0.1 * w)
        disparity = min(0.1 * w, 0.7 * h * baseline / length)
        half = max(cfg.arm_radius_m * disparity / baseline, 1.5)
        span = length * disparity / baseline
        # Centred on the raw image's centre as the rectified canvas (larger than the image) places it.
        cx, cy = self._rect.rectify_points(np.array([[0.5 * w, 0.5 * h]]), "left")[0]
        along = np.linspace(cy - 0.5 * span, cy + 0.5 * span, 64)
        images = []
        for side, shift in (("left", 0.0), ("right", -disparity)):
            image = np.full((h, w, 3), (200, 190, 180), np.uint8)
            x = cx + 0.5 * disparity + shift
            outline = np.concatenate([np.column_stack([np.full_like(along, x - half), along]),
                                      np.column_stack([np.full_like(along, x + half), along[::-1]])])
            top = along[0]
            mount = np.array([[x - 3 * half, top - half], [x + 3 * half, top - half], [x + 3 * half, top],
                              [x - 3 * half, top]])
            for shape, colour in ((mount, (40, 40, 40)), (outline, (20, 110, 245))):
                raw = self._rect.unrectify_points(shape, side)
                cv2.fillPoly(image, [np.round(raw * 16).astype(np.int32)], colour, cv2.LINE_AA, shift=4)
            images.append(image)
        self.estimate(*images)
        self.reset()

    # --- public entry point -------------------------------------------------------------

    def estimate(self, left_bgr: np.ndarray, right_bgr: np.ndarray) -> EstimateResult:
        """Estimate the centerline from one raw stereo pair.

        Args:
            left_bgr, right_bgr: (H, W, 3) uint8 BGR raw camera images (distorted, unrectified)
                of the calibration's image size.

        Returns:
            The estimate; ``valid=False`` with a reason (and the warm state untouched) when no arm
            is found or the silhouette cannot be trusted. A frame refused only because its tip,
            pointing away from the camera, may end elsewhere along the arm still seeds the next one.

        Raises:
            ValueError: an image has the wrong type, dtype or size for the calibration.
        """
        for name, image in (("left_bgr", left_bgr), ("right_bgr", right_bgr)):
            self._check_image(name, image)
        timings: dict[str, float] = {}
        start = time.perf_counter()
        self._flags: list[str] = []  # plausibility checks failed in this frame (both images append)
        self._unsmoothed = np.zeros((0, 3))
        self._tube_extras = None
        self._untrusted_end = ""  # set where the shape is fitted but a part of it (mostly an end) is not well known
        try:
            if self._rect.baseline_m <= 0:  # the right camera to the left: every depth would come out negative
                raise _NoArmError("points behind the camera: the calibration puts the right camera to the left of "
                                  "the left one (check the baseline sign in the calibration)")
            located = self._locate_both(left_bgr, right_bgr, timings)
            sides = self._process_both(left_bgr, right_bgr, timings, located)
            if self._blur_changed(sides):  # this frame again, with the blur it showed taken out
                sides = self._process_both(left_bgr, right_bgr, timings, located)
            self._orient_right_like_left(sides)
            if self.config.mode == "paper" or sides["left"].curve is None or sides["right"].curve is None:
                points, uv_left_rect, uv_right_rect = self._reconstruct_nodes(sides, timings)
            else:
                try:
                    points, uv_left_rect, uv_right_rect = self._reconstruct_dense(sides, timings)
                except (_TooLongError, _OutOfViewError) as too_long:
                    # Too long, or running out of view: an arm-coloured thing in line past the tip,
                    # across a gap, taken for the arm's end (an orange box on a shelf). Without the
                    # silhouette's last piece in both images the frame is judged again; where that
                    # fails, as first judged.
                    trimmed = self._without_last_piece(sides)
                    if trimmed is None:
                        raise
                    flags = self._flags[:]
                    try:
                        points, uv_left_rect, uv_right_rect = self._reconstruct_dense(trimmed, timings)
                    except _NoArmError:
                        self._flags = flags
                        raise too_long from None
                    sides = trimmed
            self._check_in_front(points)
        except _NoArmError as e:
            timings["total"] = (time.perf_counter() - start) * 1e3
            empty2 = np.zeros((0, 2))
            return EstimateResult(np.zeros((0, 3)), False, str(e), empty2, empty2, timings,
                                  flags=tuple(dict.fromkeys(self._flags)))
        with _timed(timings, "output"):
            left_uv = self._rect.unrectify_points(uv_left_rect, "left")
            right_uv = self._rect.unrectify_points(uv_right_rect, "right")
            self._warm_fit = self._last_fit
            for side in SIDES:
                self._warm[side] = sides[side].nodes
                # The area the next frame's corridor is held to: the arm's part of this frame's coarse
                # gate, read from the raw image as the corridor's will be (the fine mask's area, from the
                # deblurred crop, is a third larger on a blurred one than any corridor of it).
                coarse = (sides[side].area_px / self._scale**2 if located[side] is None
                          else np.count_nonzero(located[side][1]))
                self._track[side] = (sides[side].width_px / self._scale, coarse)
            self._learn_colours(sides)
        timings["total"] = (time.perf_counter() - start) * 1e3
        if self._untrusted_end:
            # Refused, but tracked on: the shape is as good as a valid frame's everywhere but at one end
            # (mostly the tip) or along one stretch bridged while seen end-on, so the next frame starts
            # from it as it did before the refusal existed.
            self._tube_extras = None
            empty2 = np.zeros((0, 2))
            return EstimateResult(np.zeros((0, 3)), False, self._untrusted_end, empty2, empty2, timings,
                                  flags=tuple(dict.fromkeys(self._flags)))
        extras = {}
        if self._tube_extras is not None:
            measured, std, radius, source = self._tube_extras
            extras = {"measured": measured, "point_std_m": std, "radius_m": radius, "radius_source": source}
            self._tube_extras = None
        nodes = {side: sides[side].nodes for side in SIDES}
        misalignment = float(np.mean(np.abs(nodes["left"][:, 1] - nodes["right"][:, 1])))
        return EstimateResult(points, True, "", left_uv, right_uv, timings, nodes, misalignment,
                              tuple(dict.fromkeys(self._flags)), self._unsmoothed, **extras)

    # --- per image ----------------------------------------------------------------------

    def _locate_both(self, left_bgr: np.ndarray, right_bgr: np.ndarray, timings: dict) -> dict:
        """side -> where the arm is (``_locate``), or None for the whole image (``roi`` off)."""
        if not self.config.roi:
            return {side: None for side in SIDES}
        with _timed(timings, "locate"):
            return self._locate({"left": left_bgr, "right": right_bgr})

    def _process_both(self, left_bgr: np.ndarray, right_bgr: np.ndarray, timings: dict,
                      located: dict) -> dict[str, _Side]:
        """Both images at once: the right one on a worker thread (OpenCV and the compiled
        stages release the GIL), the left one here (or one after the other, see
        ``use_second_thread``). Stage timings add up both images."""
        right_timings: dict[str, float] = {}
        if _SECOND_THREAD:
            future = _worker().submit(self._process_side, right_bgr, "right", right_timings, located["right"])
            try:
                left = self._process_side(left_bgr, "left", timings, located["left"])
            finally:
                right = future.exception() or future.result()  # always wait: the worker shares state
        else:
            left = self._process_side(left_bgr, "left", timings, located["left"])
            right = self._process_side(right_bgr, "right", right_timings, located["right"])
        for stage, ms in right_timings.items():
            timings[stage] = timings.get(stage, 0.0) + ms
        if isinstance(right, BaseException):
            raise right
        return {"left": left, "right": right}

    def _blur_changed(self, sides: dict[str, _Side]) -> bool:
        """Measure the blur both raw images show (their edges' steps) and keep it for the next frame; True
        when it differs from the one taken out of this frame's images (none at a sequence's start, or
        where it came on): the frame is then processed again with the new one."""
        measured = [sides[side].steps for side in SIDES if sides[side].steps is not None]
        if not measured:
            return False
        blur = blur_from_steps(np.concatenate([m[0] for m in measured]), np.concatenate([m[1] for m in measured]))
        used, self._blur = self._blur, blur
        if blur is None:
            return used is not None
        return blur.differs_from(used, BLUR_RETRY_PX, BLUR_RETRY_DEG)

    def _check_image(self, name: str, image) -> None:
        w, h = self.calibration.image_size
        if not isinstance(image, np.ndarray):
            raise ValueError(f"{name}: expected a numpy array (H, W, 3) uint8 BGR, got {type(image).__name__}")
        if image.dtype != np.uint8:
            raise ValueError(f"{name}: expected dtype uint8, got {image.dtype}")
        if image.shape != (h, w, 3):
            raise ValueError(f"{name}: expected shape {(h, w, 3)} (the calibration's image_size {w}x{h}, BGR), "
                             f"got {image.shape}")

    def _process_side(self, image: np.ndarray, side: str, timings: dict, located=None) -> _Side:
        cfg = self.config
        with _timed(timings, "rectify"):
            roi = (0, 0, *self._rect.size) if located is None else located[0]
            crop = raw = self._rect.rectify_image(image, side, roi)
        if self._blur is not None and cfg.deblur:
            with _timed(timings, "deblur"):
                crop = deblur(raw, self._blur)
        with _timed(timings, "segment"):
            learn = located is not None
            colour_filter = None
            if learn and self._colour.active:
                colour_filter = self._protected_colour_filter(side, roi)
            # Where the arm was located, only what lies near it is kept below: specks elsewhere do not matter.
            mask, hsv, gate = segment(crop, cfg, self._gate_low, colour_filter, drop_small=not learn)
            if located is not None:
                mask = cv2.bitwise_and(mask, _upsampled(located[1], roi, mask.shape, self._scale))
            if not mask.any():
                raise _NoArmError(f"no arm found in the {side} image")
            offset = np.array(roi[:2], dtype=np.float64)
            with self._plausibility("holes"):
                if has_holes(mask, cfg.min_area_px):
                    raise _NoArmError(f"self-overlap in the {side} image: the silhouette encloses a loop")
            samples = (mask_points(mask, cfg.mask_stride) if cfg.som_input == "mask"
                       else contour_points(mask, cfg.canny_low, cfg.canny_high, cfg.contour_step))
            if len(samples) < 3:
                raise _NoArmError(f"no arm found in the {side} image: only {len(samples)} arm samples")
        warm = self._warm[side]
        started_over: list[bool] = []  # _trace notes here when it already traced the image cold
        try:
            nodes, curve, width = self._trace(mask, samples, offset, side, warm, timings, started_over)
        except _NoArmError:
            if warm is None or cfg.mode != "default" or started_over:
                raise
            # The last frame's chain can lead this one astray where the arm moved far since (frames
            # seconds apart): the chain crosses itself or leaves the silhouette. Started over from
            # this image alone, the frame is judged as a first frame is.
            nodes, curve, width = self._trace(mask, samples, offset, side, None, timings)
        edges = steps = None
        if cfg.medial_refinement:
            if cfg.tube_fit:
                with _timed(timings, "edges"):
                    edges = _silhouette_edges(crop, mask, curve, offset)
                if cfg.deblur:
                    with _timed(timings, "blur"):
                        steps = _raw_steps(raw, curve, offset, edges, deblurred=crop is not raw)
        else:
            nodes = nodes + offset
            width = float(np.count_nonzero(mask)) / max(_polyline_length(nodes), 1.0)
            with self._plausibility("self_approach"):
                _check_self_approach(nodes, width, cfg.max_self_approach, side)
        return _Side(nodes, curve, width, int(np.count_nonzero(mask)), (hsv, gate, mask, offset) if learn else None,
                     crop, offset, edges, steps)

    def _check_ends_in_view(self, ends: np.ndarray, side: str) -> None:
        """Raise where the silhouette's tip, or a free base, ends at the edge of what the camera saw:
        the arm goes on out of view, and the tube fitted to what is in view ended there, valid and
        12-34 mm short (benchmarks/unseen_scenes.py, seeds 71 and 73: an arm hanging out of the
        bottom of the image). ``ends``: (2, 2) base and tip, rectified canvas pixels."""
        margin = self._rect.view_margin_px(side)
        h, w = margin.shape
        names = ("tip",) if self.config.base_mount else ("base", "tip")
        for name in names:
            x, y = ends[0 if name == "base" else 1]
            if not (np.isfinite(x) and np.isfinite(y)):
                continue
            u, v = min(max(int(round(x)), 0), w - 1), min(max(int(round(y)), 0), h - 1)
            if margin[v, u] <= VIEW_EDGE_PX:
                raise _OutOfViewError(f"the {name} is out of view in the {side} image: the arm runs on past the "
                                      "image's edge there")

    def _base_now(self) -> np.ndarray | None:
        """Where the arm's base is in the rectified left image, to start an untracked chain from: the
        configured ``base_pixel``, else (default mode) the base end of the last frame's chain, else
        None (the end nearest the top edge, as the paper's setting has it).

        The base does not move while the tip swings. An arm that curls up past its base (the tip
        above it in the image) was started from its tip by the top edge rule whenever tracking
        let go: tip and base swapped, every point on the arm, valid with the tip 560 mm off.
        """
        if self._base_hint is not None:
            return self._base_hint
        if self._warm["left"] is None or self.config.mode != "default":
            return None
        return self._warm["left"][0]

    def _trace(self, mask: np.ndarray, samples: np.ndarray, offset: np.ndarray, side: str,
               warm: np.ndarray | None, timings: dict,
               started_over: list | None = None) -> tuple[np.ndarray, Centerline2D | None, float]:
        """The ordered 2D centerline of one image's mask, the SOM started from ``warm`` (the last
        frame's nodes) or cold: (nodes, the refined curve or None, the arm's width in pixels or 0).
        Nodes and curve are in rectified image pixels once refined (in the crop's without refinement).
        ``started_over`` gets an entry when the warm chain left arm pixels uncovered and the image was
        traced cold instead."""
        cfg = self.config
        with _timed(timings, "centerline"):
            base = self._base_now()
            hint = base - offset if (side == "left" and base is not None) else None
            nodes = centerline_nodes(mask, samples, cfg, warm=None if warm is None else warm - offset, base_hint=hint)
            # A chain started from the last frame may not follow a fast swing to its end: if arm
            # pixels lie far from it, start this image over from its skeleton.
            if (warm is not None and cfg.mode == "default" and side in self._track
                    and _uncovered(samples, nodes, self._track[side][0] * self._scale) > MAX_UNCOVERED):
                nodes = centerline_nodes(mask, samples, cfg, warm=None, base_hint=hint)
                if started_over is not None:
                    started_over.append(True)
            if len(nodes) < 3:
                raise _NoArmError(f"no centerline found in the {side} image")
        if not cfg.medial_refinement:
            return nodes, None, 0.0
        with _timed(timings, "refine"):
            curve = self._refined(mask, nodes)
            if (curve is not None and warm is not None and cfg.mode == "default" and not started_over
                    and curve.valid.mean() < MIN_WARM_CLEAN_CHORDS):
                # A blurred arm's mask is ragged, and a chain carried over from the last frame can
                # settle off its axis there: few chords come out clean (44-68 % of them against 84 %
                # traced cold, blur, where the arm then went unmeasured over 200-400 mm). Traced
                # again cold, the curve with more clean chords is kept.
                with _timed(timings, "centerline"):
                    cold = centerline_nodes(mask, samples, cfg, warm=None, base_hint=hint)
                cold_curve = self._refined(mask, cold) if len(cold) >= 3 else None
                if cold_curve is not None and cold_curve.valid.mean() > curve.valid.mean():
                    nodes, curve = cold, cold_curve
            if curve is None:
                raise _NoArmError(f"the {side} centerline does not follow the silhouette")
            width = 2.0 * float(np.nanmedian(curve.half_width_px))
            gap_limit = cfg.max_bridge_widths if cfg.tube_fit else cfg.max_gap_widths
            if curve.longest_unsupported_px() > gap_limit * width:
                raise _NoArmError(f"self-overlap or occlusion in the {side} image: "
                                  f"{curve.longest_unsupported_px() / width:.1f} arm widths without a clean "
                                  "silhouette")
            _check_self_approach(curve.points, width, cfg.max_self_approach, side)
            curve = curve.shifted(offset)
            return resample_polyline(curve.points, cfg.n_points), curve, width

    def _refined(self, mask: np.ndarray, nodes: np.ndarray) -> Centerline2D | None:
        """The chain's nodes moved onto the silhouette's chord midpoints (``estimator.refinement``),
        or None where the chain does not follow the silhouette."""
        # The SOM's chain is close to the axis; the baselines' zig-zag needs a second pass.
        passes = REFINE_PASSES if self.config.centerline == "som" else 2
        refined = refinement_passes(mask, nodes, extend_ends=self.config.extend_ends)
        curve = None
        for _ in range(passes):
            curve = next(refined, None)
        if passes < 2 and curve is not None and curve.valid.mean() < MIN_CLEAN_CHORDS:
            # Nodes that lag a fast swing leave the chords oblique near the tip: a second pass,
            # with normals from the first, straightens them.
            curve = next(refined, None)
        return curve

    def _locate(self, images: dict[str, np.ndarray]) -> dict[str, tuple[tuple[int, int, int, int], np.ndarray]]:
        """Where the arm is in each image: a region of interest and the coarse mask of its pixels.

        On 1/4-scale rectified images: the colour gate, then the arm's pixels among everything of
        its colour (``estimator.arm_region``): the corridor around the previous frame's arm when it
        holds the whole arm, else a cold search for the tube; when the gate lets in a wall or a
        floor (warm light), its saturation floor rises to the arm's dye.
        """
        cfg = self.config
        min_area = max(cfg.min_area_px // self._scale**2, 2)

        def with_specks(hsv_, low):  # the colour gate, opened; its small regions still in
            return _open(self._colour.apply(hsv_, hsv_in_range(hsv_, low, cfg.hsv_high)))

        def gated(hsv_, low):
            return remove_small_regions(with_specks(hsv_, low), min_area)

        def one_side(side):  # the coarse image, its gate with specks, and the tracked arm's part of it
            hsv_ = cv2.cvtColor(cv2.remap(images[side], self._coarse_maps[side], None, cv2.INTER_NEAREST),
                                cv2.COLOR_BGR2HSV)
            gate_ = with_specks(hsv_, self._gate_low)
            return hsv_, gate_, self._keep_tracked_side(side, gate_, min_area)

        future = _beside(one_side, "right")
        try:
            left = one_side("left")
        finally:
            if future is not None:
                wait([future])  # always, even when the left one failed: the worker reads shared state
        per_side = {"left": left, "right": future.result() if future is not None else one_side("right")}
        hsv = {side: per_side[side][0] for side in SIDES}
        tracked = [per_side[side][2] for side in SIDES]
        keep = None if any(k is None for k in tracked) else dict(zip(SIDES, tracked, strict=True))

        def gates(low):
            return {side: gated(hsv[side], low) for side in SIDES}

        if keep is None:
            gate = {side: remove_small_regions(per_side[side][1], min_area) for side in SIDES}
            base = self._base_now()
            geometry = TubeGeometry(self._rect.focal_px / self._scale, self._rect.baseline_m, cfg.arm_radius_m,
                                    cfg.arm_length_m, None if base is None else tuple(base / self._scale))
            keep, why = find_tube(gate, geometry, min_area)
            if keep is None and self._colour.active:  # the model may have learned the wrong colours
                self._colour.reset()
                gate = gates(self._gate_low)
                keep, why = find_tube(gate, geometry, min_area)
            if keep is None:
                floor = max(saturation_split(hsv[side], gate[side], int(cfg.hsv_low[1])) for side in SIDES)
                if floor > self._gate_low[1]:
                    low = (self._gate_low[0], floor, self._gate_low[2])
                    keep, why_raised = find_tube(gates(low), geometry, min_area)
                    if keep is not None:
                        self._gate_low = low
            if keep is None:
                raise _NoArmError(why)
            # The tube was found by its shape: teach the colour model its colours against the other
            # things of its colour in view, so a distractor it touches falls away pixel by pixel.
            for side in SIDES:
                grown = cv2.dilate(keep[side], np.ones((5, 5), np.uint8))
                self._colour.update(hsv[side], gate[side], cv2.erode(keep[side], _CROSS), cv2.bitwise_not(grown))
            if self._colour.active:
                keep = {side: cv2.bitwise_and(keep[side], self._colour.apply(hsv[side], keep[side])) for side in SIDES}
        out = {}
        w, h = self._rect.size
        m = cfg.roi_margin_px
        for side in SIDES:
            box = bounding_box(keep[side])
            if box is None:
                raise _NoArmError(f"no arm found in the {side} image")
            x0, y0, x1, y1 = (v * self._scale for v in box)
            out[side] = ((max(x0 - m, 0), max(y0 - m, 0), min(x1 + m, w), min(y1 + m, h)), keep[side])
        return out

    def _protected_colour_filter(self, side: str, roi: tuple[int, int, int, int]):
        """The colour model's filter, except within the arm's reach of the previous frame's centerline.

        A blurred or anti-aliased edge mixes the arm's colour with the wall's into the hue and
        saturation of wood or skin: there the model would cut the arm's own edges. Near where the
        arm was, every colour of the gate stays; beyond, where a distractor touching the arm
        bulges out of the tube, the model decides.
        """
        previous = self._warm[side]
        if previous is None or side not in self._track:
            return self._colour.apply
        width = self._track[side][0] * self._scale
        offset = np.array(roi[:2], dtype=np.float64)
        reach = 0.5 * width + max(0.25 * width, 4.0)

        def apply(hsv: np.ndarray, gate: np.ndarray) -> np.ndarray:
            near = _corridor_mask(gate.shape, _extended(previous - offset, width), reach)
            return cv2.bitwise_or(self._colour.apply(hsv, gate), cv2.bitwise_and(gate, near))

        return apply

    def _learn_colours(self, sides: dict[str, _Side]) -> None:
        """Teach the colour model the arm's colours against the gate's other colours more than two arm
        widths from its centerline, in a trusted frame.

        The arm's samples are its mask's pixels within its half width of the centerline: edge pixels
        included (blurred or shadowed edges mix the arm's colour with the background's and must stay
        the arm's), a distractor bulging out of the silhouette excluded. The gate's value floor is
        set from the same frame (``colour_model.value_floor``): in dim light the arm's shaded side
        falls under the configured one.
        """
        self._updates += 1
        if self._updates > 10 and self._updates % 5:  # learn every frame at first, then every fifth
            return
        floors = []
        for side in SIDES:
            s = sides[side]
            if s.learn is None or s.curve is None:
                continue
            hsv, gate, mask, offset = s.learn
            curve = s.curve.points - offset
            interior = cv2.bitwise_and(mask, _corridor_mask(mask.shape, curve, 0.5 * s.width_px))
            near = _corridor_mask(mask.shape, curve, 2.0 * s.width_px)
            self._colour.update(hsv, gate, interior, cv2.bitwise_not(near))
            values = hsv[..., 2][mask > 0]
            if len(values) > MIN_FLOOR_PIXELS:
                floors.append(value_floor(values, self.config.hsv_low[2]))
        if floors:
            self._gate_low = (self._gate_low[0], self._gate_low[1], min(floors))

    def _keep_tracked_side(self, side: str, gate: np.ndarray, min_area: int) -> np.ndarray | None:
        """The arm's coarse pixels near the previous frame's centerline in one image (regions of the
        gate smaller than ``min_area`` left out), or None when that does not hold the whole arm (it
        moved too far, or there is no previous frame)."""
        if any(self._warm[s] is None for s in SIDES) or len(self._track) < 2:
            return None
        width, area = self._track[side]
        curve = self._warm[side] / self._scale
        # Half the tube's width plus how far it may move in a frame: a distractor the arm touches
        # is cut off at the corridor's edge.
        reach = 0.5 * width + max(0.5 * width, 3.0)
        kept, cut = keep_in_corridor(gate, _extended(curve, width), reach, reach, with_cut=True, min_area_px=min_area)
        kept, cut = without_wide_strays(kept, cut, curve, reach, width)
        if np.count_nonzero(kept) < 0.8 * area:
            return None
        cut_px = np.count_nonzero(cut)
        if cut_px > MAX_CORRIDOR_CUT * np.count_nonzero(kept):
            return None
        if cut_px:
            # Arm-coloured pixels cut off next to an end: the tip (or the arm) swung out of the corridor.
            ends = np.zeros_like(cut)
            for end in (curve[0], curve[-1]):
                cv2.circle(ends, (int(round(end[0])), int(round(end[1]))), int(round(2.5 * width)), 255, -1)
            if np.count_nonzero(cv2.bitwise_and(cut, ends)) > 0.25 * width * width:
                return None
        return kept

    def _orient_right_like_left(self, sides: dict[str, _Side]) -> None:
        """Make the right chain start at the same end as the left one (same rows after rectification)."""
        left, right = sides["left"].nodes, sides["right"].nodes
        keep = abs(left[0, 1] - right[0, 1]) + abs(left[-1, 1] - right[-1, 1])
        flip = abs(left[0, 1] - right[-1, 1]) + abs(left[-1, 1] - right[0, 1])
        if flip < keep:
            r = sides["right"]
            curve = None if r.curve is None else Centerline2D(r.curve.points[::-1], r.curve.valid[::-1],
                                                              r.curve.half_width_px[::-1],
                                                              r.curve.arc_px[-1] - r.curve.arc_px[::-1])
            edges = None if r.edges is None else (*r.edges[:3], r.edges[3][::-1].copy(), r.edges[4][::-1],
                                                  r.edges[5][::-1].copy())
            sides["right"] = _Side(r.nodes[::-1].copy(), curve, r.width_px, r.area_px, r.learn, r.image, r.offset,
                                   edges)

    # --- stereo -------------------------------------------------------------------------

    def _reconstruct_nodes(self, sides: dict[str, _Side], timings: dict):
        """Paper path: compensate the right nodes, triangulate the n pairs, fit a polynomial."""
        cfg = self.config
        left, right = sides["left"].nodes, sides["right"].nodes
        with _timed(timings, "match"):
            spacing = 1.0 / (len(left) - 1)  # one node's share of the arm
            if cfg.compensation == "nearest":  # the crossing nearest node j's place, within a node of it
                right = compensate_nodes(left, right, window=spacing, min_sine=MIN_SINE)
            elif cfg.compensation == "nearest_image":
                right = compensate_nodes(left, right, nearest="image")
            elif cfg.compensation == "windowed":
                right = compensate_nodes(left, right, window=2.0 * spacing, min_sine=MIN_SINE)
        with _timed(timings, "triangulate"):
            points_rect = triangulate(self._rect.P["left"], self._rect.P["right"], left, right)
            points = self._rect.to_left_camera(points_rect)
            self._unsmoothed = points
        with _timed(timings, "smooth"):
            if cfg.smoothing_degree > 0:
                points = polynomial_smooth(points, cfg.smoothing_degree)
            with self._plausibility("length"):
                self._check_length(points)
        return points, left, right

    @contextmanager
    def _plausibility(self, check: str):
        """Run one plausibility check: with ``plausibility_checks`` its failure drops the frame,
        without it (the paper reports every frame) the check is only named in the result's flags."""
        try:
            yield
        except _NoArmError:
            if self.config.plausibility_checks:
                raise
            self._flags.append(check)

    def _check_in_front(self, points: np.ndarray) -> None:
        """Raise unless the estimate lies in front of the camera.

        Non-finite points, or a median depth <= 0 (the whole arm behind the camera: a reversed
        baseline), are never returned. Single points behind the camera (rows matched on the wrong
        branch) are a plausibility check: flagged, and dropped only with ``plausibility_checks``.
        """
        # Never a confident wrong answer. The calibration's baseline was checked before (see estimate()),
        # so what remains is the images: the same one twice, or left and right handed over swapped.
        if not np.all(np.isfinite(points)):
            raise _NoArmError("no depth: the arm is at the same place in both images (zero disparity: the same "
                              "image given as left and right?)")
        if np.median(points[:, 2]) <= 0:
            raise _NoArmError("points behind the camera: the arm lies further left in the left image than in the "
                              "right one (negative disparity): are the left and right images swapped?")
        with self._plausibility("behind_camera"):
            if np.any(points[:, 2] <= 0):
                raise _NoArmError("triangulated points behind the camera: left and right centerlines disagree")

    def _reconstruct_dense(self, sides: dict[str, _Side], timings: dict):
        """Default path: a disparity profile along the left curve, then cap-trimmed ends; then the tube
        fitted to both images' edges. A tracked arm skips the profile: the previous frame's tube is a
        better start, and if the fit from it fails, the profile is computed after all."""
        cfg = self.config
        if cfg.tube_fit and self._warm_fit is not None and WARM_START_TUBE:
            try:
                with _timed(timings, "tube"):
                    return self._tube_output(self._fit_tube(sides, None, self._warm_fit.control))
            except _NoArmError:
                pass
        left, right = sides["left"].curve, sides["right"].curve
        tau = left.arc_px / max(left.arc_px[-1], 1e-9)
        with _timed(timings, "match"):
            disparity, weight = match_rows(left.points, right.points, right_valid=right.valid)
            ramp = base_ramp(left, BASE_SKIP_WIDTHS, BASE_RAMP_WIDTHS)
            weight = np.where(left.valid, weight, 0.0) * ramp
            if np.count_nonzero(weight > MATCHED_WEIGHT) < max(8, len(tau) // 5):
                raise _NoArmError("left and right centerlines do not match row by row" + _length_mismatch(left, right))
            self._check_single_tube(disparity, weight, left)
            # Rows do not match along a stretch that runs along them: where most of the arm's last
            # third does, the profile guesses the tip's depth (``_tip_depth_ambiguity``).
            tail = weight[(2 * len(weight)) // 3:]
            tip_unmatched = float(np.mean(tail > MATCHED_WEIGHT)) < MIN_MATCHED_TIP_SHARE
            x, y, w = with_width_cue(tau, disparity, weight, left, ramp)
            knots = int(np.clip(left.arc_px[-1] / 30.0, 3, 30))
            # The arm leaves its fixed mount along the mount's axis, across the line of sight:
            # depth changes only quadratically there, so the profile continues flat to the base.
            try:
                profile = robust_spline_profile(x, y, w, tau, knots=knots, flat_start=True)
            except ValueError as e:  # too few distinct places along the arm for the spline's knots
                raise _NoArmError(f"no disparity profile along the arm: {e}") from e
            if np.any(profile <= 0):
                raise _NoArmError("non-positive disparity: left and right centerlines disagree")
        with _timed(timings, "triangulate"):
            dense = self._disparity_points(left.points, profile)
            if cfg.extend_ends:
                radii = [measured_radius_m(disparity, weight, left, self._rect.baseline_m, near_end=end)
                         for end in (0, -1)]
                span = tuple(self._cap_trim(sides, dense, end, radius if np.isfinite(radius) else cfg.arm_radius_m)
                             for end, radius in zip((0, -1), radii, strict=True))
                grid = np.linspace(span[0], span[1], len(tau))
                uv_left = np.column_stack([np.interp(grid, tau, left.points[:, k]) for k in range(2)])
                dense = self._disparity_points(uv_left, np.interp(grid, tau, profile))
        with _timed(timings, "smooth"):
            if cfg.smoothing_degree > 0:
                dense = polynomial_smooth(dense, cfg.smoothing_degree)
            if not cfg.tube_fit:  # the tube fit's own length is checked: depth noise lengthens this one
                self._check_length(dense)
            points_rect = resample_polyline(dense, cfg.n_points)
        if cfg.tube_fit:
            with _timed(timings, "tube"):
                points_rect = self._fit_tube(sides, dense, tip_unmatched=tip_unmatched)
        return self._tube_output(points_rect)

    def _tube_output(self, points_rect: np.ndarray):
        points = self._rect.to_left_camera(points_rect)
        uv_l = _project_rect(self._rect.P["left"], points_rect)
        uv_r = _project_rect(self._rect.P["right"], points_rect)
        return points, uv_l, uv_r

    def _fit_tube(self, sides: dict[str, _Side], dense: np.ndarray | None,
                  warm_control: np.ndarray | None = None, tip_unmatched: bool = False) -> np.ndarray:
        """The 3D centerline from a tube fitted to the sub-pixel edges of both images (``estimator.tube_fit``),
        started from the disparity-profile estimate or the previous frame's tube; (n, 3) rectified-frame
        points, base first. The edges were measured with each image (``_silhouette_edges``).
        """
        cfg = self.config
        self._untrusted_end = ""  # this fit's own verdict, not an earlier attempt's
        P = self._rect.P["left"]
        f, centre = self._rect.focal_px, np.array([P[0, 2], P[1, 2]])
        side_ids, xy, chord, steps = [], [], [], []
        ends = {"base": np.full((2, 2), np.nan), "tip": np.full((2, 2), np.nan)}
        tip_outline: dict[int, np.ndarray] = {}
        # A free base end (no mount: see EstimatorConfig.base_mount) is fitted to its outline, as the
        # tip is, until where the base is has been learned.
        outline_base = not cfg.base_mount and self._base.prior is None
        base_outline: dict[int, np.ndarray] = {}
        connector_views: list[np.ndarray] = []
        for k, side in enumerate(SIDES):
            if sides[side].edges is None:
                raise _NoArmError(f"no silhouette edges measured in the {side} image")
            points, centres, widths, (base, tip), outlines, seen_connectors = sides[side].edges
            self._check_ends_in_view(np.array([base, tip]), side)
            connector_views.append(seen_connectors)
            xy.append((points - centre) / f)
            steps.append(widths)
            chord.append((centres - centre) / f)
            side_ids.append(np.full(len(points), k))
            ends["base"][k] = (base - centre) / f
            ends["tip"][k] = (tip - centre) / f
            tip_outline[k] = (outlines[1] - centre) / f
            if outline_base:
                base_outline[k] = (outlines[0] - centre) / f
        side_ids = np.concatenate(side_ids)
        edges = EdgeSet(side_ids, np.concatenate(xy), np.concatenate(chord), _edge_weights(np.concatenate(steps)))
        if self._radius is None:
            self._radius = np.full(RADIUS_BINS, cfg.arm_radius_m)
            self._radius_info = np.full(RADIUS_BINS, 1.0 / RADIUS_PRIOR_SIGMA_M**2)
        # The fit holds each bin's radius only loosely to the learned one: the apparent width of the
        # tube changes a little with its pose and its shading, and a radius held tighter than a
        # millimetre pulled depth off with it (late ramp, lab: 1.7 -> 2.2 mm RMSE at 0.03 mm).
        sigma = np.maximum(1.0 / np.sqrt(self._radius_info), RADIUS_FIT_SIGMA_M)
        connectors = None
        if cfg.connector_radius_m is not None:
            connectors = _paired_views(connector_views, lambda k: _connector_centres(
                sides[SIDES[k]].image, sides[SIDES[k]].curve, sides[SIDES[k]].offset, bands=True))
        if connectors is not None:
            connectors = (connectors - centre) / f  # paired in pixels, fitted in normalised coordinates

        def fit_from(start, edges_, **stage):
            return fit_tube(edges_, ends, dense, self._radius, sigma, focal_px=f, baseline_m=self._rect.baseline_m,
                            base_prior=self._base.prior, initial_control=start, tip_outline=tip_outline,
                            connectors=connectors, connector_radius_m=cfg.connector_radius_m or 0.0,
                            base_outline=base_outline, **stage)

        second = None
        ambiguous_tip = 0.0
        if warm_control is None and self._warm_fit is not None and self._moving_fast:
            # The arm moved far at the last frame, so the second start (below) will likely be needed:
            # it runs on the idle second thread beside the first, on copies of everything it reads.
            # Whether it is used is decided as without it, so the result is the same either way.
            second = _beside(fit_tube, edges, copy.deepcopy(ends), dense, self._radius.copy(), sigma.copy(),
                                focal_px=f, baseline_m=self._rect.baseline_m,
                                base_prior=copy.deepcopy(self._base.prior),
                                initial_control=self._warm_fit.control.copy(),
                                tip_outline={k: v.copy() for k, v in tip_outline.items()},
                                connectors=None if connectors is None else connectors.copy(),
                                connector_radius_m=cfg.connector_radius_m or 0.0,
                                base_outline={k: v.copy() for k, v in base_outline.items()})
        fit = fit_from(warm_control, edges)
        depth_ambiguity = 0.0
        if tip_unmatched and warm_control is None and fit is not None:
            # Restarted with both stages and with the outline stage alone (see _tip_depth_ambiguity).
            depth_ambiguity = max(
                self._tip_depth_ambiguity(fit, lambda start: fit_from(start, edges)),
                self._tip_depth_ambiguity(fit, lambda start: fit_from(
                    start, edges, outline_stage=True, initial_radii=fit.radius_bins,
                    iterations=OUTLINE_RESTART_ITERATIONS), OUTLINE_RESTART_AMBIGUOUS_COST))
        moved = self._moved_from_last(fit)
        near = SECOND_START_MAX_WIDTHS * 2.0 * float(np.mean(self._radius))
        self._moving_fast = (warm_control is None and self._warm_fit is not None
                             and (SECOND_START_M < moved <= near or (moved > near and not _acceptable(fit))))
        if second is not None and not self._moving_fast:
            second.cancel()
        if self._moving_fast:
            # A second start from the previous frame's tube: the fit can settle where a bend near the
            # tip trades depth for shape (late ramp, lab: the tip 20 mm off in depth at a higher cost
            # than the tube near the truth). Only where the tube moved far from the last frame's
            # (tracking slowly, both starts end alike). The lower cost wins. Moved further than an arm
            # width, the last tube is only a fallback where the first start failed or left a stretch
            # unconstrained (a 0.5 s sweep's return: the base 97 mm uncertain, 4 mm from the last tube).
            other = second.result() if second is not None else fit_from(self._warm_fit.control, edges)
            if moved <= near and other is not None and fit is not None and abs(other.cost - fit.cost) < AMBIGUOUS_COST:
                one = np.array([1.0])
                ambiguous_tip = float(np.linalg.norm(other.points(one)[0] - fit.points(one)[0]))
            if other is not None and (fit is None or (other.cost < fit.cost if moved <= near else _acceptable(other))):
                fit = other
        if fit is None:
            raise _NoArmError("the tube could not be fitted to the silhouettes' edges")
        misfit = misfit_edges(fit, edges, self._rect.baseline_m)
        if misfit.any():
            # A stretch of one silhouette line the tube does not follow is an occluder's edge along
            # the tube's side, not the tube's: fitted again without it, from where the fit ended.
            # Where it follows neither line of one image over the same stretch, that image and the
            # tube disagree about the arm itself.
            _check_one_line_off(fit, edges, misfit, self._rect.baseline_m, float(np.mean(self._radius)))
            kept = edges.subset(~misfit)
            refit = fit_from(fit.control, kept)
            if refit is not None:
                fit, edges = refit, kept
        # An outline round an end that the fitted end does not explain was not all the tube's (an
        # arm-coloured cable touching the tip, an occluder lending it its edge): that image's
        # observations of that end are left out and the tube fitted again. A few rays that alone
        # miss it by far met something else (``_outline_inliers``): only they are left out. Outline
        # points are expected as sharp as the image's edges are: blur widens both.
        unexplained, pruned = [], {}
        for end, outlines_, residuals in (("tip", tip_outline, fit.tip_residual_px),
                                          ("base", base_outline, fit.base_residual_px)):
            for k, outline in outlines_.items():
                if len(outline) >= MIN_CAP_POINTS:
                    keep = _outline_inliers(residuals.get(k), len(outline),
                                            CAP_SIGMA_PX / np.median(_edge_weights(steps[k])))
                    if keep is None:
                        unexplained.append((end, k))
                    elif not keep.all():
                        pruned[end, k] = keep
        # An image's outline of the tip the fitted end does not explain, with no outline of it in the other
        # image: nothing is left to say where the tip ends but one image's end point, which the outline
        # contradicted.
        lone = next((k for end, k in unexplained if end == "tip"
                     and len(tip_outline.get(1 - k, ())) < MIN_CAP_POINTS), None)
        # Neither image's outline explained: both are left out with their end points, and nothing is
        # left to end the tube but where its edges stop (a blurred tip: 23 mm short, valid).
        neither = all(("tip", k) in unexplained for k in range(len(SIDES)))
        if unexplained or pruned:
            for end, k in unexplained:
                del (tip_outline if end == "tip" else base_outline)[k]
                ends[end][k] = np.nan
            for (end, k), keep in pruned.items():
                outlines_ = tip_outline if end == "tip" else base_outline
                outlines_[k] = outlines_[k][keep]
            refit = fit_from(warm_control, edges)
            if refit is not None:
                fit = refit
        if fit.inliers < MIN_TUBE_INLIERS or fit.rms_px > MAX_TUBE_RMS_PX:
            raise _NoArmError(f"the silhouettes do not fit one tube: {fit.inliers:.0%} of their edges within "
                              f"a pixel, {fit.rms_px:.2f} px RMS")
        us = np.linspace(0.0, 1.0, 241)
        axis = fit.points(us)
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(axis, axis=0), axis=1))])
        at = np.interp(np.linspace(0.0, arc[-1], cfg.n_points), arc, us)
        points = fit.points(at)
        self._check_length(points)
        if cfg.section_lengths_m is not None and len(fit.connector_u):
            problem = section_length_problem(np.interp(fit.connector_u, us, arc), float(arc[-1]), cfg.section_lengths_m)
            if problem is not None:
                raise _NoArmError(problem)
        radius = float(np.mean(fit.radius_bins))
        # The tip's outline, where it was fitted, is seen as well as any edge; an image left without
        # an end of the tip marks nothing beyond its last edges as measured.
        seen = [k for k, outline in tip_outline.items() if len(outline) >= MIN_CAP_POINTS]
        edge_u = np.concatenate([fit.edge_u, np.ones(len(seen))])
        edge_side = np.concatenate([edges.side, np.array(seen, dtype=edges.side.dtype)])
        tip_seen = tuple(k in seen or bool(np.all(np.isfinite(ends["tip"][k]))) for k in range(len(SIDES)))
        measured = _measured(at, edge_u, edge_side, MEASURED_GAP_RADII * radius / max(arc[-1], 1e-9), tip_seen)
        if len(seen) == 2:
            measured[-1] = True  # the tip itself was fitted to its outline in both images
        elif not all(tip_seen):
            measured[-1] = False  # an image saw no end of the tip
        if sum(len(outline) >= MIN_CAP_POINTS for outline in base_outline.values()) == len(SIDES):
            measured[0] = True  # so was a free base's end
        bridged = _longest_unseen(edge_u, edge_side, MEASURED_GAP_RADII * radius / max(arc[-1], 1e-9), tip_seen,
                                  us, arc)
        if bridged > cfg.max_bridge_widths * 2.0 * radius:
            raise _NoArmError(f"{bridged * 1e3:.0f} mm of the arm bridged without its edges in both images "
                              f"(more than {cfg.max_bridge_widths:g} arm widths: occluded or out of view)")
        # Between two measured stretches the fit interpolates; past the last one it extrapolates.
        # The base is where the mount is: once the mount is learned, a hidden base is bridged like a middle.
        base_limit = cfg.max_bridge_widths if self._base.prior is not None else MAX_END_BRIDGE_WIDTHS
        for name, run, limit in (("base", _end_run(~measured, points), base_limit),
                                 ("tip", _end_run(~measured[::-1], points[::-1]), MAX_END_BRIDGE_WIDTHS)):
            if run > limit * 2.0 * radius:
                raise _NoArmError(f"the {name} is hidden: its last {run * 1e3:.0f} mm have no edges in both images")
        std = fit.point_std_m(at)
        std[-1], misfit, image = _tip_std_with_misfit(float(std[-1]), fit.tip_residual_px)
        if outline_base and std[0] > MAX_FREE_BASE_STD_M:
            self._untrusted_end = (f"where the base ends is uncertain: {std[0] * 1e3:.1f} mm standard deviation "
                                   f"(over {MAX_FREE_BASE_STD_M * 1e3:g} mm) with no mount or learned base to hold it")
        if misfit > TIP_OUTLINE_NOISE_PX and std[-1] > MAX_MISFIT_TIP_STD_M:
            raise _NoArmError(f"the fitted tip misses its outline in the {SIDES[image]} image by {misfit:.2f} px "
                              f"RMS: its place is uncertain ({std[-1] * 1e3:.0f} mm standard deviation, counting "
                              "the misfit)")
        end_on = _end_on_bridge(measured, points, std, self._rect.baseline_m)
        if end_on is not None:
            length, shown, worst = end_on
            self._untrusted_end = (f"{length * 1e3:.0f} mm of the arm bridged while seen end-on (the images show "
                                   f"{shown:.0%} of its length): its place is a guess, {worst * 1e3:.1f} mm "
                                   f"standard deviation (over {MAX_END_ON_BRIDGE_STD_M * 1e3:g} mm)")
        # (the reasons below, where they hold too, say more and replace it)
        if neither:
            self._untrusted_end = ("where the tip ends is uncertain: neither image's outline of it fits the tube, "
                                   "so only where its edges stop ends it")
        if tip_unmatched and misfit > MAX_ROW_TIP_MISFIT_PX:
            self._untrusted_end = ("where the tip ends is uncertain: its stretch runs along the image rows, so only "
                                   f"its cap's outline gives its depth, and the fitted end misses that outline in the "
                                   f"{SIDES[image]} image by {misfit:.2f} px RMS (over {MAX_ROW_TIP_MISFIT_PX:g} px)")
        if ambiguous_tip > AMBIGUOUS_TIP_M:
            self._untrusted_end = (f"where the tip ends is uncertain: fitted from the last frame's shape and afresh, "
                                   f"the tube fits about as well with its tip {ambiguous_tip * 1e3:.0f} mm apart")
        if depth_ambiguity > 0.0:
            self._untrusted_end = (f"where the tip ends is uncertain: its stretch runs along the image rows, and "
                                   f"started nearer or further the tube fits as well or better with its tip "
                                   f"{depth_ambiguity * 1e3:.0f} mm away")
        if lone is not None:
            self._untrusted_end = (f"where the tip ends is uncertain: the {SIDES[lone]} image's outline of it does not "
                                   f"fit the tube, and the {SIDES[1 - lone]} image shows no outline of it")
        if misfit > MAX_TIP_MISFIT_PX:
            # Refused, tracked on (as an away tip is, below): the shape fits everywhere but the tip's end.
            self._untrusted_end = (f"the fitted tip misses its outline in the {SIDES[image]} image by {misfit:.2f} px "
                                   f"RMS (over {MAX_TIP_MISFIT_PX:g} px): where the tip ends is not known")
        if np.max(std) > MAX_POINT_STD_M:
            worst = int(np.argmax(std))
            raise _NoArmError(f"the images barely constrain the arm near point {worst} of {len(at)}: "
                              f"{std[worst] * 1e3:.0f} mm standard deviation")
        along = float(fit.along_std_m(np.array([1.0]))[0])
        if along > MAX_TIP_ALONG_STD_M:
            raise _NoArmError(f"where the tip ends is uncertain: {along * 1e3:.0f} mm standard deviation along the arm "
                              "(it points nearly along a line of sight, or its end is hidden behind the arm)")
        if along > MAX_AWAY_TIP_ALONG_STD_M and _away_cosine(axis, arc, self._rect.baseline_m) > AWAY_TIP_COSINE:
            self._untrusted_end = (f"where the tip ends is uncertain: {along * 1e3:.1f} mm standard deviation along "
                                   "the arm (it points away from the camera, its end behind itself)")
        turn = _tip_turn_deg(axis, arc)
        if turn > MAX_TIP_TURN_DEG and not self._untrusted_end:  # a reason above says more where it holds
            self._untrusted_end = (f"where the tip ends is uncertain: the fitted tube turns {turn:.0f} degrees over "
                                   f"its last {2 * TIP_DIRECTION_M * 1e3:.0f} mm (over {MAX_TIP_TURN_DEG:g}), bent "
                                   "to its end's outline rather than following the arm")
        # Checked last: a tube longer than the arm is cut back first (something past its tip), and a
        # frame refused above for a reason of its own keeps it, tracked on.
        fold, where = _largest_inner_turn(axis, arc)
        if fold > MAX_AXIS_TURN_DEG and not self._untrusted_end:
            raise _NoArmError(f"the fitted tube folds: it turns {fold:.0f} degrees over "
                              f"{2 * TIP_DIRECTION_M * 1e3:.0f} mm at {where * 1e3:.0f} mm from its base "
                              f"(over {MAX_AXIS_TURN_DEG:g}; an arm bends smoothly)")
        self._last_fit = fit
        source = (f"measured over {self._radius_frames} frames" if self._radius_frames else "configured")
        self._tube_extras = (measured, std, radius, source)
        self._radius, self._radius_info = fuse_radius(self._radius, self._radius_info, fit)
        self._radius_frames += 1
        self._base.observe(fit)
        return points

    def _tip_depth_ambiguity(self, fit: TubeFit, fit_from, within: float = AMBIGUOUS_COST) -> float:
        """How far from the fitted tip the tube's tip ends when the fit is started again with the tip's
        depth moved (the last third's control points shifted along their lines of sight by up to
        ``TIP_START_SHIFT_WIDTHS`` arm widths, towards and away from the cameras) and ends either
        within ``within`` of the first fit's cost with its tip more than ``AMBIGUOUS_TIP_M`` away, or
        lower in cost with its tip more than ``BETTER_RESTART_TIP_M`` away; 0 where no start does.

        Where the tip's stretch runs along the image rows, its disparity is not matched and the
        profile only guesses its depth. An independent dim scene's tip, bent sideways and away, came
        back valid 29 mm off in depth at cost 99; started from the true shape the fit ends 0.4 mm off
        at 87, and started one arm width further away, at 87 too. The lower cost is not trusted to
        decide (taken, it put another tip 11 mm off on the twin's random shapes): the images do not
        say where the tip ends, and the frame is refused.

        ``fit_from`` runs both stages of the fit (the ends by their end points, then by their outlines)
        or the outline stage alone. The first stage, blind to the cap's depth, can carry a start back
        into the first fit's basin: an independent warm scene's tip along the rows came back valid 31 mm
        off at cost 82, both restarts of both stages falling back there, while the outline stage alone
        ends near the truth from either start (68 and 70). Those restarts count only where they end
        lower in cost than the first fit (``OUTLINE_RESTART_AMBIGUOUS_COST``, 0): over the seven unseen
        seed sets, counted within ``AMBIGUOUS_COST`` they refused 16 good frames for that one, within 3,
        7 (1.6-6.3 mm off), five of which had a restart 1.3-1.7 higher with the tip 15-25 mm away (a
        flat valley, the frame right); at 0, two (and on the twin's paper ramp, ``softarm run``, t = 49.8
        and 49.9 s).
        """
        count = len(fit.control)
        first = (2 * count) // 3
        ramp = np.clip((np.arange(count) - first) / max(count - 1 - first, 1), 0.0, 1.0)[:, None]
        sight = fit.control - np.array([0.5 * self._rect.baseline_m, 0.0, 0.0])
        sight /= np.linalg.norm(sight, axis=1, keepdims=True)
        shift = TIP_START_SHIFT_WIDTHS * 2.0 * float(np.mean(self._radius))
        nearer, further = (fit.control + sign * shift * ramp * sight for sign in (1.0, -1.0))
        # The two restarts are independent: one runs on the idle second thread beside the other (the
        # lab ramp's frames that need them took 18-22 ms, the rest 13 ms; now 16-20 ms).
        pending = _beside(fit_from, further)
        others = [fit_from(nearer), pending.result() if pending is not None else fit_from(further)]
        one = np.array([1.0])
        apart = 0.0
        for other in others:
            if other is None:
                continue
            away = float(np.linalg.norm(other.points(one)[0] - fit.points(one)[0]))
            if ((other.cost < fit.cost + within and away > AMBIGUOUS_TIP_M)
                    or (other.cost < fit.cost and away > BETTER_RESTART_TIP_M)):
                apart = max(apart, away)
        return apart

    def _moved_from_last(self, fit: TubeFit | None) -> float:
        """How far a fit's tip lies from the previous frame's (metres; infinite without a fit)."""
        if fit is None or self._warm_fit is None:
            return math.inf
        ends = np.array([1.0])
        return float(np.linalg.norm(fit.points(ends)[0] - self._warm_fit.points(ends)[0]))

    def _without_last_piece(self, sides: dict[str, _Side]) -> dict[str, _Side] | None:
        """Both images' sides without the last piece of their silhouettes (the mask's part beyond the
        centerline's last stretch off the mask, and the curve's points from that stretch on), their
        edges measured again; None where an image has no such piece or too little is left."""
        cfg = self.config
        out = {}
        for side in SIDES:
            s = sides[side]
            if s.curve is None or s.learn is None or s.image is None:
                return None
            mask = s.learn[2]
            labels = cv2.connectedComponents(mask, connectivity=8)[1]
            local = np.round(s.curve.points - s.offset).astype(np.int64)
            h, w = mask.shape
            inside = (local[:, 0] >= 0) & (local[:, 1] >= 0) & (local[:, 0] < w) & (local[:, 1] < h)
            label = np.zeros(len(local), np.int64)
            label[inside] = labels[local[inside, 1], local[inside, 0]]
            on = np.flatnonzero(label > 0)
            if len(on) < 2:
                return None
            last = label[on[-1]]
            before = on[label[on] != last]
            if len(before) == 0:
                return None
            cut = int(before[-1]) + 1  # the first point past the last piece before the far one
            if cut < 6 or not np.any(label[cut:on[-1]] == 0):
                return None  # the far piece touches the rest (no gap): not a piece of its own
            c = s.curve
            curve = Centerline2D(c.points[:cut].copy(), c.valid[:cut].copy(), c.half_width_px[:cut].copy(),
                                 c.arc_px[:cut].copy())
            if np.count_nonzero(curve.valid) < 6:
                return None
            far = np.unique(label[cut:])  # the far piece, and anything else the dropped points touch
            kept = np.where((labels > 0) & ~np.isin(labels, far), 255, 0).astype(np.uint8)
            edges = _silhouette_edges(s.image, kept, curve, s.offset)
            learn = (s.learn[0], s.learn[1], kept, s.learn[3])
            out[side] = replace(s, nodes=resample_polyline(curve.points, cfg.n_points), curve=curve,
                                area_px=int(np.count_nonzero(kept)), learn=learn, edges=edges)
        return out

    def _check_single_tube(self, disparity: np.ndarray, weight: np.ndarray, left: Centerline2D) -> None:
        """Raise when the silhouette is too wide for one tube at its depth: two parts overlap.

        The reference radius is the larger of the configured one and the one measured over the
        whole arm, so sections of different radii do not look like overlaps.
        """
        cfg = self.config
        good = (weight > 0.05) & np.isfinite(left.half_width_px) & (disparity > 0)
        if np.count_nonzero(good) < 8:
            return
        radius = np.nanmax([cfg.arm_radius_m, measured_radius_m(disparity, weight, left, self._rect.baseline_m)])
        expected = disparity[good] * 2.0 * radius / self._rect.baseline_m
        wide = float(np.mean(2.0 * left.half_width_px[good] / expected > cfg.max_width_ratio))
        if wide > cfg.max_wide_fraction:
            raise _NoArmError(f"self-overlap: along {wide:.0%} of the arm the silhouette is wider than one arm "
                              f"of radius {radius * 1e3:.0f} mm at that depth")

    def _check_length(self, points: np.ndarray) -> None:
        """Raise when the estimate is much shorter than the arm (part of it is hidden) or much
        longer (left and right centerlines were matched wrongly: points scatter in depth)."""
        cfg = self.config
        if cfg.arm_length_m is None:
            return
        length = _polyline_length(points)
        if length < cfg.min_length_fraction * cfg.arm_length_m:
            raise _NoArmError(f"only {length * 1e3:.0f} mm of the {cfg.arm_length_m * 1e3:.0f} mm arm is visible "
                              "(folded behind itself or out of view)")
        if length > cfg.max_length_fraction * cfg.arm_length_m:
            raise _TooLongError(f"implausible estimate: {length * 1e3:.0f} mm long for a {cfg.arm_length_m * 1e3:.0f} "
                                "mm arm (something past its tip taken for it, or left and right centerlines matched "
                                "wrongly)")

    def _disparity_points(self, uv_left: np.ndarray, disparity: np.ndarray) -> np.ndarray:
        """(M, 3) rectified-frame points from left pixels and disparities (eqs. 7-8)."""
        uv_right = uv_left - np.column_stack([disparity, np.zeros_like(disparity)])
        return triangulate(self._rect.P["left"], self._rect.P["right"], uv_left, uv_right)

    def _cap_trim(self, sides: dict[str, _Side], dense: np.ndarray, end: int, radius: float) -> float:
        """Where the axis really ends on the left curve, as tau in [0, 1].

        The left curve runs out to the silhouette's ends, and the silhouette of a flat-ended tube
        reaches past the axis end by the cap's projected half-axis, f r |t . s| / Z pixels along
        the curve (t the axis direction, s the line of sight). Depth comes from the profile, not
        from the silhouette's extreme points: those lie on the cap's rim, up to r nearer.
        """
        arc3 = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
        index = np.arange(len(arc3))
        inside = float(np.interp(2 * radius if end == 0 else arc3[-1] - 2 * radius, arc3, index))
        axis = dense[end] - np.array([np.interp(inside, index, dense[:, k]) for k in range(3)])
        axis /= np.linalg.norm(axis) + 1e-12
        sight = dense[end] / (np.linalg.norm(dense[end]) + 1e-12)
        overshoot_px = self._rect.focal_px * radius * abs(float(axis @ sight)) / dense[end, 2]
        length = sides["left"].curve.arc_px[-1]
        pull = min(overshoot_px, 0.25 * length) / length
        return pull if end == 0 else 1.0 - pull


# --- helpers ------------------------------------------------------------------------------


_SECOND_THREAD = True  # see use_second_thread
_WORKER: ThreadPoolExecutor | None = None
_WORKER_LOCK = threading.Lock()


def use_second_thread(enabled: bool) -> None:
    """Whether estimators process the right image on a thread of their own (the default) while the
    left one runs on the caller's thread, or both on the caller's thread.

    A process that owns one core (a study's worker, a Ray task of one CPU) turns it off: the second
    thread would take time from the other workers' cores, and its speed would not be one core's.
    The results are the same either way.
    """
    global _SECOND_THREAD
    _SECOND_THREAD = bool(enabled)


def _worker() -> ThreadPoolExecutor:
    """One shared thread for the second image of every estimator in the process."""
    global _WORKER
    with _WORKER_LOCK:
        if _WORKER is None:
            _WORKER = ThreadPoolExecutor(max_workers=1, thread_name_prefix="estimator-right")
        return _WORKER


def _beside(function, *args, **kwargs):
    """``function(*args, **kwargs)`` started on the second thread (a future), or None without one."""
    return _worker().submit(function, *args, **kwargs) if _SECOND_THREAD else None


@contextmanager
def _timed(timings: dict, stage: str):
    start = time.perf_counter()
    try:
        yield
    finally:
        timings[stage] = timings.get(stage, 0.0) + (time.perf_counter() - start) * 1e3


def _acceptable(fit: TubeFit | None) -> bool:
    """Whether a fit exists and the images constrain every stretch of it (see MAX_POINT_STD_M)."""
    return fit is not None and float(np.max(fit.point_std_m(_STD_CHECK_AT))) <= MAX_POINT_STD_M


_STD_CHECK_AT = np.linspace(0.0, 1.0, 21)


def _chord_normals(curve: Centerline2D) -> tuple[np.ndarray, np.ndarray]:
    """(unit normals (M, 2) of the curve at its samples, the chords measured: clean ones, every ``EDGE_STRIDE``-th)."""
    tangent = np.gradient(curve.points, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True) + 1e-12
    normals = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    return normals, curve.valid & (np.arange(len(curve.valid)) % EDGE_STRIDE == 0)


def _raw_steps(raw: np.ndarray, curve: Centerline2D, offset: np.ndarray, edges: tuple, deblurred: bool):
    """(normals (K, 2), step widths (K,)) of the raw image's edges along ``curve``: what tells how it is
    blurred. Only where the edges measured for the fit are wider than focused, or the image was
    deblurred, are the widths read again with the levels settled (``step_widths``); a focused image
    reports none (no blur) and costs nothing more."""
    widths = edges[2]
    if not deblurred and (len(widths) == 0 or np.median(widths) <= FOCUSED_STEP_PX):
        return np.zeros((0, 2)), np.zeros(0)
    normals, pick = _chord_normals(curve)
    found = step_widths(raw, curve.points - offset, normals, curve.half_width_px, pick)
    ok = found > 0
    both = np.concatenate([-normals[ok[:, 0]], normals[ok[:, 1]]])
    return both, np.concatenate([found[ok[:, 0], 0], found[ok[:, 1], 1]])


def _silhouette_edges(image: np.ndarray, mask: np.ndarray, curve: Centerline2D, offset: np.ndarray):
    """Sub-pixel silhouette edges of one image's clean chords, its two ends and the outline around
    each end (rectified canvas pixels).

    Only clean chords: searching at the neighbours' width where a chord is not clean finds the
    baseplates' and the caps' edges as often as the tube's (measured: 2.2 -> 9.9 mm RMSE).

    Returns:
        (edge points (K, 2), the centres of their chords (K, 2), their steps' widths (K,), (2, 2) base
        and tip ends, (outline at the base (M, 2), outline at the tip (M, 2)), the connectors' centres
        (C, 2) base first (``_connector_centres``)).
    """
    normals, pick = _chord_normals(curve)
    offsets, _, steps = subpixel_edges_and_steps(image, curve.points - offset, normals, curve.half_width_px, pick)
    rescued = _rescued_chords(image, curve, offset, normals, offsets, pick)
    if rescued is not None:
        take, more, more_steps = rescued
        offsets[take], steps[take] = more, more_steps
    points, centres, widths = [], [], []
    for column in range(2):
        ok = np.isfinite(offsets[:, column])
        points.append(curve.points[ok] + offsets[ok, column][:, None] * normals[ok])
        centres.append(curve.points[ok])
        widths.append(steps[ok, column])
    ends = np.array([_subpixel_end(image, offset, curve, end) for end in (0, -1)])
    mask01 = (mask > 0).astype(np.float32)
    outlines = tuple(_end_outline(image, mask01, offset, curve, end) for end in (0, -1))
    connectors = _connector_centres(image, curve, offset)
    return np.concatenate(points), np.concatenate(centres), np.concatenate(widths), ends, outlines, connectors


def _connector_centres(image: np.ndarray, curve: Centerline2D, offset: np.ndarray, bands: bool = False) -> np.ndarray:
    """Where the centerline crosses each short stretch of another colour between two of the arm's:
    the connectors between sections (rectified pixels, base first; (0, 2) if none).

    Each is the centroid of the dip of the arm's colour along the centerline across the stretch (the
    colour projected onto the arm's minus the darkest's, weights clipped to [0, 1]): a symmetric blur
    spreads the dip without moving its centroid. A stretch longer than ``MAX_CONNECTOR_WIDTHS`` arm
    widths, or without a clear dip, is something else (an occluder, an overlap) and is left out.
    With ``bands``, also across the short dark bands along clean chords (``_dark_bands``).
    """
    valid = curve.valid
    support = np.flatnonzero(valid)
    if len(support) < 6:
        return np.zeros((0, 2))
    width = 2.0 * float(np.median(curve.half_width_px[support]))
    arc = curve.arc_px
    flags = valid[support[0]:support[-1] + 1].astype(np.int8)
    starts = np.flatnonzero(np.diff(flags) == -1) + support[0]  # last supported point before each run
    stops = np.flatnonzero(np.diff(flags) == 1) + support[0] + 1  # first supported point after it
    taken = list(zip(starts, stops, strict=True))
    for i, j in _dark_bands(image, curve, offset, width, int(support[0]), int(support[-1])) if bands else ():
        # where the mask's closing left the chords clean across a band
        if not any(i <= b and a <= j for a, b in taken):
            taken.append((i, j))
    taken.sort()
    starts, stops = [a for a, _ in taken], [b for _, b in taken]
    found = []
    for i, j in zip(starts, stops, strict=True):
        if arc[j] - arc[i] > MAX_CONNECTOR_WIDTHS * width + width:  # plus the half widths kept clear each side
            continue
        t = np.arange(arc[i], arc[j] + 1e-9, 0.5)
        row = _colours_along(image, curve, offset, t)
        if row is None:
            continue
        colour = row.reshape(-1, 3).astype(np.float64)
        ends = max(int(0.25 * width / 0.5), 2)
        arm = 0.5 * (colour[:ends].mean(axis=0) + colour[-ends:].mean(axis=0))
        dark = colour[np.argmax(np.linalg.norm(colour - arm, axis=1))]
        span = dark - arm
        contrast = float(np.linalg.norm(span))
        if contrast < CONNECTOR_MIN_CONTRAST:
            continue
        weight = np.clip((colour - arm) @ span / contrast**2, 0.0, 1.0)
        weight = np.maximum(weight - CONNECTOR_WEIGHT_FLOOR, 0.0)
        if weight.sum() <= 0.0:
            continue
        at = float(np.sum(weight * t) / weight.sum())
        found.append([np.interp(at, arc, curve.points[:, 0]), np.interp(at, arc, curve.points[:, 1])])
    return np.array(found, np.float64).reshape(-1, 2)


def _colours_along(image: np.ndarray, curve: Centerline2D, offset: np.ndarray, t: np.ndarray) -> np.ndarray | None:
    """(1, N, 3) the image's colour (bilinear) at arc lengths ``t`` along the centerline, or None where
    any of them falls outside the image."""
    path = np.column_stack([np.interp(t, curve.arc_px, curve.points[:, k]) for k in range(2)]) - offset
    h, w = image.shape[:2]
    if np.any(path < 0) or np.any(path[:, 0] > w - 1) or np.any(path[:, 1] > h - 1):
        return None
    return cv2.remap(image, path[:, 0].astype(np.float32).reshape(1, -1), path[:, 1].astype(np.float32).reshape(1, -1),
                     cv2.INTER_LINEAR)


def _paired_views(views: list[np.ndarray], with_bands) -> np.ndarray | None:
    """``_paired_connectors`` of the images' connectors (``views``: left, right), or where they do not
    pair, of those with the dark bands along clean chords too (``with_bands(k)``: image k's, with
    ``bands``), in one image and then in both: bands are looked for only where the connectors at the
    mask's gaps leave the images disagreeing (0.5-1 ms an image).

    Not where both images show fewer than the arm has, alike: on the twin's blurred ramp (t = 47-58 s,
    the second connector at no gap in either image) the bands' second connector took the RMSE of the
    valid frames 1.38 -> 1.43 mm and its false valid frames 0 -> 2 (the tip's depth further off)."""
    paired = _paired_connectors(*views)
    if paired is not None:
        return paired
    banded = [with_bands(0), with_bands(1)]
    for pair in ((banded[0], views[1]), (views[0], banded[1]), banded):
        paired = _paired_connectors(*pair)
        if paired is not None:
            return paired
    return None


def _dark_bands(image: np.ndarray, curve: Centerline2D, offset: np.ndarray, width: float, first: int,
                last: int) -> list[tuple[int, int]]:
    """Stretches ``(i, j)`` of the centerline (point indices, half a width clear either side) across
    a short band darker than the arm around it, between points ``first`` and ``last``.

    A connector seen at a slant is a band a few pixels wide that the mask's median and closing fill
    in: its chords stay clean, and only the image's colour along the centerline shows it (the
    twin's ramp at t = 58 s: one connector of two, or neither, found in the left image this way,
    so none were paired). Darker than the running median of the arm's colour over two widths by
    ``CONNECTOR_MIN_CONTRAST``, over at most ``MAX_CONNECTOR_WIDTHS`` widths."""
    arc = curve.arc_px
    t = np.arange(arc[first], arc[last] + 1e-9, 0.5)
    row = _colours_along(image, curve, offset, t) if len(t) >= 8 and width > 0 else None
    if row is None:
        return []
    colour = row.reshape(-1, 3).astype(np.float64)
    # A one-row image's square median is the running median along it, the ends repeated.
    local = cv2.medianBlur(row, 2 * int(2.0 * width / 0.5 / 2) + 1).reshape(-1, 3).astype(np.float64)
    luma = np.array([0.114, 0.587, 0.299])
    dark = (np.linalg.norm(colour - local, axis=1) >= CONNECTOR_MIN_CONTRAST) & (colour @ luma < local @ luma)
    flags = np.concatenate([[0], dark.astype(np.int8), [0]])
    out = []
    for a, b in zip(np.flatnonzero(np.diff(flags) == 1), np.flatnonzero(np.diff(flags) == -1), strict=True):
        if a == 0 or b == len(t) or (t[b - 1] - t[a]) > MAX_CONNECTOR_WIDTHS * width:
            continue  # touching the ends of the stretch looked at, or too long for a connector
        i = int(np.searchsorted(arc, t[a] - 0.5 * width, side="right")) - 1
        j = int(np.searchsorted(arc, t[b - 1] + 0.5 * width, side="left"))
        if i >= first and j <= last:
            out.append((i, j))
    return out


def _paired_connectors(left: np.ndarray, right: np.ndarray) -> np.ndarray | None:
    """(K, 2, 2) the connectors seen in both images (rectified pixels), paired in order along the
    arm, or None where the images do not show as many of them, within ``MAX_CONNECTOR_ROW_PX`` of the
    same rows: one is hidden in one image, or an occluder's crossing was taken for one. (Tilted, a
    connector's band is centred a little differently in each image: up to 1.4 px apart in rows on the
    twin's ramp; paired wrongly, they lie sections apart.)"""
    if len(left) == 0 or len(left) != len(right):
        return None
    if np.max(np.abs(left[:, 1] - right[:, 1])) > MAX_CONNECTOR_ROW_PX:
        return None
    return np.stack([left, right], axis=1)


def _rescued_chords(image: np.ndarray, curve: Centerline2D, offset: np.ndarray, normals: np.ndarray,
                    offsets: np.ndarray, clean: np.ndarray):
    """Edges of the chords the mask called unclean where the image itself shows the tube there:
    ``(chords taken, their offsets (K, 2), their steps (K, 2))``, or None.

    A blurred arm over a textured wall leaves a ragged mask (the halo of the blurred step passes
    the colour gate in patches), so half the chords of a straight arm fail the mask's width test
    and whole sections went unmeasured (the twin's blur preset: 220-400 mm bridged, the frame
    invalid). The image's own edges there agree with their clean neighbours' (most within 0.3 px
    in width and centre). Each unclean chord between the outermost clean ones is searched at the
    width interpolated from the clean chords and kept only where both its edges are found and its
    width and centre agree with the clean chords' within ``RESCUE_WINDOW_PX`` of arc: a chord cut
    by a baseplate or an occluder, or one across the end cap, is several pixels off and stays out.
    """
    width = offsets[:, 1] - offsets[:, 0]
    good = clean & np.isfinite(width)
    idx = np.flatnonzero(good)
    if len(idx) < 6:
        return None
    arc = curve.arc_px
    probe = ~clean & (arc > arc[idx[0]]) & (arc < arc[idx[-1]])
    if not probe.any():
        return None
    half = np.interp(arc, arc[idx], curve.half_width_px[idx])
    # Beside a stretch longer than a width without clean chords (a baseplate, an occluder) a chord is
    # partly cut even where its width passes (refinement._away_from_gaps): it stays out.
    width_px = 2.0 * float(np.median(curve.half_width_px[idx]))
    flags = np.concatenate([[1], clean.astype(np.int8), [1]])
    for a, b in zip(np.flatnonzero(np.diff(flags) == -1), np.flatnonzero(np.diff(flags) == 1), strict=True):
        if b - a >= 2 and arc[b - 1] - arc[a] > RESCUE_GAP_WIDTHS * width_px:
            probe &= (np.abs(arc - arc[a]) >= 0.5 * width_px) & (np.abs(arc - arc[b - 1]) >= 0.5 * width_px)
    more, _, more_steps = subpixel_edges_and_steps(image, curve.points - offset, normals, half, probe)
    centre = 0.5 * (offsets[:, 0] + offsets[:, 1])
    lo = np.searchsorted(arc[idx], arc - RESCUE_WINDOW_PX)
    hi = np.searchsorted(arc[idx], arc + RESCUE_WINDOW_PX)
    local_width = window_medians(width[idx], lo, hi, np.nan)
    local_centre = window_medians(centre[idx], lo, hi, np.nan)
    spread = 1.4826 * np.median(np.abs(width[idx] - local_width[idx]))
    tolerance = max(RESCUE_TOLERANCE_PX, RESCUE_SPREADS * spread)
    take = (probe & np.isfinite(more[:, 1] - more[:, 0])
            & (np.abs(more[:, 1] - more[:, 0] - local_width) <= tolerance)
            & (np.abs(0.5 * (more[:, 0] + more[:, 1]) - local_centre) <= 0.5 * tolerance))
    if not take.any():
        return None
    return take, more[take], more_steps[take]


def _edge_weights(steps: np.ndarray) -> np.ndarray:
    """Weight of each edge in the tube fit from how wide its step is: a blurred edge's place is
    less certain than a focused one's: its sigma grows by ``BLURRED_EDGE_SIGMA`` of the width beyond
    ``FOCUSED_STEP_PX`` (a focused edge rises over 0.8-1.7 px, shading and anti-aliasing included)."""
    excess = np.maximum(np.asarray(steps, np.float64) - FOCUSED_STEP_PX, 0.0)
    sigma = np.sqrt(EDGE_SIGMA_PX**2 + (BLURRED_EDGE_SIGMA * excess) ** 2)
    return EDGE_SIGMA_PX / sigma


def _end_outline(image: np.ndarray, mask01: np.ndarray, offset: np.ndarray, curve: Centerline2D,
                 end: int) -> np.ndarray:
    """Sub-pixel points of the silhouette's outline around one end: rays fanned out from the last
    clean chord's centre towards the end, each moved from the mask's edge to the image's.

    The outline keeps its focused-edge sigma when blurred: weighted down like the sides' edges, it
    measured worse (the twin's blur preset, 100 late-ramp frames: 12 -> 19 frames valid while over
    10 mm off), since the tip's outline is often all that fixes its depth."""
    inside = np.flatnonzero(curve.valid)
    if len(inside) == 0:
        return np.zeros((0, 2))
    i = inside[0] if end == 0 else inside[-1]
    along = curve.points[end] - curve.points[i]
    reach = float(np.linalg.norm(along))
    if reach < 1.0:
        return np.zeros((0, 2))
    along /= reach
    across = np.array([-along[1], along[0]])
    origin = curve.points[i] - offset
    half = float(curve.half_width_px[i]) if np.isfinite(curve.half_width_px[i]) else reach
    angles = np.radians(np.arange(-OUTLINE_FAN_DEG, OUTLINE_FAN_DEG + 1e-9, OUTLINE_STEP_DEG))
    directions = np.cos(angles)[:, None] * along + np.sin(angles)[:, None] * across
    guesses = edge_distances(mask01, origin, directions, 3.0 * max(half, reach) + 10.0)
    ok = guesses > 1.0
    if not ok.any():
        return np.zeros((0, 2))
    starts = np.repeat(origin[None], int(ok.sum()), axis=0)
    offsets, _ = subpixel_edges(image, starts, directions[ok], guesses[ok], np.ones(int(ok.sum()), bool))
    found = np.isfinite(offsets[:, 1])
    points = curve.points[i] + offsets[found, 1][:, None] * directions[ok][found]
    # Only the outline near the end: from a last clean chord far back, the outer rays meet the
    # sides where the tube has curved away from the straight end the fit's outline model assumes
    # (2-4 px off on the twin's late ramp).
    near = (points - curve.points[i]) @ along >= reach - OUTLINE_BACK_HALVES * half
    return points[near]


def _subpixel_end(image: np.ndarray, offset: np.ndarray, curve: Centerline2D, end: int) -> np.ndarray:
    """Where the silhouette ends along the centerline (rectified pixels), from the image: the mask's
    end moved to the halfway crossing of the colour profile along the centerline's direction."""
    inside = np.flatnonzero(curve.valid)
    if len(inside) == 0:
        return curve.points[end]
    i = inside[0] if end == 0 else inside[-1]
    direction = curve.points[end] - curve.points[i]
    reach = float(np.linalg.norm(direction))
    if reach < 1.0:
        return curve.points[end]
    direction /= reach
    point = curve.points[i][None] - offset
    # A "chord" along the centerline: its +n edge guess is the mask's end.
    offsets, _ = subpixel_edges(image, point, direction[None], np.array([reach]), np.array([True]))
    if not np.isfinite(offsets[0, 1]):
        return curve.points[end]
    return curve.points[i] + offsets[0, 1] * direction


def _length_mismatch(left: Centerline2D, right: Centerline2D) -> str:
    """Why two centerlines may not match: one much shorter than the other (a fold or an occluder
    hides part of the arm in that image); empty when their lengths agree."""
    lengths = {"left": float(left.arc_px[-1]), "right": float(right.arc_px[-1])}
    short = min(lengths, key=lengths.get)
    ratio = lengths[short] / max(max(lengths.values()), 1e-9)
    if ratio >= 0.75:
        return ""
    return (f": the {short} one is {ratio:.0%} as long as the other (part of the arm is not visible in the "
            f"{short} image: folded over itself or hidden)")


def _uncovered(samples: np.ndarray, nodes: np.ndarray, width_px: float) -> float:
    """Share of the arm's samples further than about one arm width from the node chain (the chain
    drawn one width either side of it, looked up at the samples)."""
    if len(samples) == 0 or len(nodes) < 2 or width_px <= 0:
        return 0.0
    lo = np.floor(np.minimum(samples.min(axis=0), nodes.min(axis=0)) - width_px - 2).astype(int)
    hi = np.ceil(np.maximum(samples.max(axis=0), nodes.max(axis=0)) + width_px + 2).astype(int)
    band = np.zeros((hi[1] - lo[1] + 1, hi[0] - lo[0] + 1), np.uint8)
    cv2.polylines(band, [np.round(nodes - lo).astype(np.int32)], False, 255, max(int(round(2.0 * width_px)), 1))
    at = np.round(samples - lo).astype(int)
    return float(np.mean(band[at[:, 1], at[:, 0]] == 0))


def _measured(at: np.ndarray, edge_u: np.ndarray, edge_side: np.ndarray, gap_u: float,
              tip_seen: tuple[bool, bool] = (True, True)) -> np.ndarray:
    """(n,) False where an output u falls in a stretch of either image without edges longer than
    ``gap_u`` (an occluder, a baseplate, the arm hidden at an end), True elsewhere. In an image
    whose end of the tip was not seen (``tip_seen``) nothing marks where the arm ends, so no point
    beyond its last edges is measured.

    A stretch, not a distance: however the output points fall along the arm, one inside an
    occluded stretch is bridged, even next to its edge.
    """
    out = np.ones(len(at), bool)
    for lo, hi in _unseen_stretches(edge_u, edge_side, gap_u, tip_seen):
        # an output point on the edge bounding a stretch is measured; the arm's ends bound none
        out &= ~(((at > lo) | (lo <= 0.0)) & ((at < hi) | (hi >= 1.0)))
    return out


def _check_one_line_off(fit: TubeFit, edges: EdgeSet, misfit: np.ndarray, baseline_m: float, radius_m: float) -> None:
    """Raise when the tube follows neither silhouette line of one image over the same stretch of arc:
    not an occluder along one side, but that image and the fitted tube disagreeing about the arm."""
    lines = silhouette_lines(fit, edges, baseline_m)
    length = float(np.sum(np.linalg.norm(np.diff(fit.points(np.linspace(0.0, 1.0, 121)), axis=0), axis=1)))
    for image, side in enumerate(SIDES):
        spans = []
        for line in (-1.0, 1.0):
            u = fit.edge_u[misfit & (edges.side == image) & (lines == line)]
            spans.append((u.min(), u.max()) if len(u) else None)
        if spans[0] and spans[1] and min(spans[0][1], spans[1][1]) >= max(spans[0][0], spans[1][0]):
            over = (max(spans[0][1], spans[1][1]) - min(spans[0][0], spans[1][0])) * length
            raise _NoArmError(f"the tube follows neither side of the {side} image's silhouette over "
                              f"{over * 1e3:.0f} mm of the arm ({over / (2.0 * radius_m):.1f} arm widths): that "
                              "image and the other disagree about the arm there")


def _tip_std_with_misfit(std_m: float, tip_residual_px: dict) -> tuple[float, float, int]:
    """The tip's standard deviation grown by how far its worse image's outline misfits the fitted
    end beyond ``TIP_OUTLINE_NOISE_PX`` RMS: ``(std, that RMS misfit in pixels, that image)``."""
    misfit, image = 0.0, 0
    for k, residuals in tip_residual_px.items():
        if len(residuals):
            rms = float(np.sqrt(np.mean(np.square(residuals))))
            if rms > misfit:
                misfit, image = rms, k
    return std_m * max(1.0, misfit / TIP_OUTLINE_NOISE_PX), misfit, image


def _arc_direction(axis: np.ndarray, arc: np.ndarray, back_from: float, back_to: float) -> np.ndarray:
    """Unit direction of the axis between ``back_from`` and ``back_to`` metres of arc before its end
    (zero if those meet one sample): the tip's heading for the refusal rules below."""
    i = int(np.searchsorted(arc, arc[-1] - back_from))
    j = min(int(np.searchsorted(arc, arc[-1] - back_to)), len(axis) - 1)
    v = axis[j] - axis[min(i, j - 1)]
    return v / max(float(np.linalg.norm(v)), 1e-12)


def _away_cosine(axis: np.ndarray, arc: np.ndarray, baseline_m: float) -> float:
    """Cosine between the tip's direction (over its last ``TIP_DIRECTION_M`` of arc) and the line of
    sight to the tip from midway between the cameras; 1 points straight away from them."""
    sight = axis[-1] - np.array([0.5 * baseline_m, 0.0, 0.0])
    norm = float(np.linalg.norm(sight))
    return float(_arc_direction(axis, arc, TIP_DIRECTION_M, 0.0) @ sight / norm) if norm > 0 else 0.0


def _tip_turn_deg(axis: np.ndarray, arc: np.ndarray) -> float:
    """The angle (degrees) between the axis's directions over its last two ``TIP_DIRECTION_M`` of arc."""
    cosine = float(_arc_direction(axis, arc, 2.0 * TIP_DIRECTION_M, TIP_DIRECTION_M)
                   @ _arc_direction(axis, arc, TIP_DIRECTION_M, 0.0))
    return math.degrees(math.acos(min(1.0, max(-1.0, cosine))))


def _largest_inner_turn(axis: np.ndarray, arc: np.ndarray) -> tuple[float, float]:
    """The largest angle (degrees) between the axis's directions over ``TIP_DIRECTION_M`` of arc
    before and after one of its samples, and that sample's arc (m); only samples at least two such
    stretches short of the tip (its own turn is ``_tip_turn_deg``'s, with its own reason)."""
    n = len(axis)
    k = np.flatnonzero((arc >= TIP_DIRECTION_M) & (arc <= arc[-1] - 2.0 * TIP_DIRECTION_M))
    if len(k) == 0:
        return 0.0, 0.0
    before = np.minimum(np.searchsorted(arc, arc[k] - TIP_DIRECTION_M), k - 1)
    after = np.maximum(np.minimum(np.searchsorted(arc, arc[k] + TIP_DIRECTION_M), n - 1), k + 1)
    u, v = axis[k] - axis[before], axis[after] - axis[k]
    norm = np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-24)
    turns = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", u, v) / norm, -1.0, 1.0)))
    best = int(np.argmax(turns))
    return float(turns[best]), float(arc[k[best]])


def _outline_inliers(residuals_px: np.ndarray | None, count: int, sigma_px: float) -> np.ndarray | None:
    """Which points of a tip's outline (``count`` of them, with these residuals) the fitted end
    explains: all where they are ``_explained`` together; else, where the rest are and at most
    ``MAX_OUTLINE_OUTLIERS`` of them miss it by over ``OUTLINE_OUTLIER_SIGMAS``, all but those (a
    ray that met a notch in the mask or the wall's texture instead of the cap: the twin's
    bright_warm ramp at t = 53 s, one ray of eight 4.8 px off, the rest 0.3 px RMS, and the whole
    right tip was left out, the frame refused as hidden); None where the outline as a whole is not
    explained (a cable or an occluder along the cap moves several rays)."""
    if residuals_px is None or len(residuals_px) != count:
        return None
    if _explained(residuals_px, sigma_px):
        return np.ones(count, bool)
    keep = np.abs(np.nan_to_num(residuals_px, nan=np.inf)) <= OUTLINE_OUTLIER_SIGMAS * sigma_px
    if (count - np.count_nonzero(keep) > MAX_OUTLINE_OUTLIERS * count or np.count_nonzero(keep) < MIN_CAP_POINTS
            or not _explained(residuals_px[keep], sigma_px)):
        return None
    return keep


def _explained(residuals_px: np.ndarray | None, sigma_px: float) -> bool:
    """Whether a fitted model explains its observations: their RMS residual within
    ``EXPLAINED_SIGMAS`` of their sigma. Measured on the twin's tips (1,004 frames within 10 mm, seven
    conditions): median 0.24 sigma, 99th percentile 1.02, one frame over 1.5."""
    if residuals_px is None or len(residuals_px) == 0:
        return False
    return float(np.sqrt(np.mean(np.square(residuals_px)))) <= EXPLAINED_SIGMAS * sigma_px


def _end_on_bridge(measured: np.ndarray, points: np.ndarray, std: np.ndarray,
                   baseline_m: float) -> tuple[float, float, float] | None:
    """The first stretch of bridged points between the ends that is seen end-on and unsure (see
    ``END_ON_BRIDGE_FRACTION``) as (3D length, share of it the images show, largest standard
    deviation in it), counted to its measured neighbours; None where no stretch is both."""
    bridged = ~np.asarray(measured, bool)
    bridged[[0, -1]] = False  # the ends have checks of their own
    sight_from = np.array([0.5 * baseline_m, 0.0, 0.0])
    start = 0
    while start < len(bridged):
        if not bridged[start]:
            start += 1
            continue
        stop = start
        while bridged[stop + 1]:
            stop += 1
        steps = np.diff(points[start - 1:stop + 2], axis=0)
        sight = 0.5 * (points[start - 1:stop + 1] + points[start:stop + 2]) - sight_from
        sight /= np.linalg.norm(sight, axis=1, keepdims=True)
        length = float(np.linalg.norm(steps, axis=1).sum())
        across = steps - np.sum(steps * sight, axis=1, keepdims=True) * sight
        shown = float(np.linalg.norm(across, axis=1).sum()) / max(length, 1e-12)
        worst = float(np.max(std[start:stop + 1]))
        if shown < END_ON_BRIDGE_FRACTION and worst > MAX_END_ON_BRIDGE_STD_M:
            return length, shown, worst
        start = stop + 1
    return None


def _end_run(flags: np.ndarray, points: np.ndarray) -> float:
    """3D length of the flagged stretch that starts at the first point (0 if the first is not flagged)."""
    if len(flags) == 0 or not flags[0]:
        return 0.0
    stop = int(np.argmin(flags)) if not flags.all() else len(flags) - 1
    return float(np.linalg.norm(np.diff(points[:stop + 1], axis=0), axis=1).sum())


def _unseen_stretches(edge_u: np.ndarray, edge_side: np.ndarray, gap_u: float,
                      tip_seen: tuple[bool, bool] = (True, True)) -> list[tuple[float, float]]:
    """The stretches of u (merged over both images) that either image shows without edges for
    longer than ``gap_u``: the same stretches ``_measured`` marks its points bridged in, but with
    their ends where the edges stop, not where the output points happen to fall."""
    stretches = []
    for side in (0, 1):
        u = np.sort(edge_u[edge_side == side])
        if not tip_seen[side]:
            u = u[u < 1.0 - 1e-9]  # edges past the tube's end attach to it; without the tip they end nothing
        bounds = np.concatenate([[0.0], u, [1.0 if tip_seen[side] else np.inf]])
        wide = np.diff(bounds) > gap_u
        stretches += [(lo, min(hi, 1.0)) for lo, hi in zip(bounds[:-1][wide], bounds[1:][wide], strict=True)]
    merged: list[tuple[float, float]] = []
    for lo, hi in sorted(stretches):
        if merged and lo <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
        else:
            merged.append((lo, hi))
    return merged


def _longest_unseen(edge_u: np.ndarray, edge_side: np.ndarray, gap_u: float, tip_seen: tuple[bool, bool],
                    us: np.ndarray, arc: np.ndarray) -> float:
    """Longest 3D length of arm (``arc`` the arc length at tube parameters ``us``) in a stretch
    either image shows without edges. Measured from edge to edge: counted in output points, one
    occluder 3 arm widths wide read as anything from 3 to 5 depending on where the points fell."""
    lengths = [np.interp(hi, us, arc) - np.interp(lo, us, arc)
               for lo, hi in _unseen_stretches(edge_u, edge_side, gap_u, tip_seen)]
    return float(max(lengths, default=0.0))


def _extended(curve: np.ndarray, length: float) -> np.ndarray:
    """The polyline continued straight by ``length`` at both ends (the arm may lengthen between frames)."""
    if len(curve) < 2:
        return curve
    head = curve[0] - length * _unit(curve[1] - curve[0])
    tail = curve[-1] + length * _unit(curve[-1] - curve[-2])
    return np.vstack([head, curve, tail])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-12)


def _corridor_mask(shape: tuple[int, int], curve: np.ndarray, half_width: float) -> np.ndarray:
    from estimator.arm_region import corridor

    return corridor(shape, curve, half_width)


def _open(mask: np.ndarray) -> np.ndarray:
    """Opening by a 3x3 cross: drops one-pixel lines (a thin cable, a texture's grain) in the coarse mask."""
    return cv2.morphologyEx(mask, cv2.MORPH_OPEN, _CROSS)


_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def _upsampled(coarse_keep: np.ndarray, roi: tuple[int, int, int, int], shape: tuple[int, int],
               scale: int) -> np.ndarray:
    """The coarse keep-mask, grown by one coarse pixel, at full resolution over the region of interest."""
    grown = cv2.dilate(coarse_keep, np.ones((3, 3), np.uint8))
    x0, y0 = roi[0], roi[1]
    h, w = shape
    # Full-resolution pixel (x, y) takes coarse pixel ((x + s/2) // s, (y + s/2) // s), the last row or
    # column beyond the coarse image: the block of coarse pixels the region needs, edges repeated,
    # blown up s times (nearest neighbour) and cut at the offset.
    half = scale // 2
    r0, c0 = (y0 + half) // scale, (x0 + half) // scale
    r1, c1 = (y0 + h - 1 + half) // scale + 1, (x0 + w - 1 + half) // scale + 1
    padded = cv2.copyMakeBorder(grown, 0, max(r1 - grown.shape[0], 0), 0, max(c1 - grown.shape[1], 0),
                                cv2.BORDER_REPLICATE)
    block = padded[r0:r1, c0:c1]
    blown = cv2.resize(block, (block.shape[1] * scale, block.shape[0] * scale), interpolation=cv2.INTER_NEAREST)
    dy, dx = y0 + half - r0 * scale, x0 + half - c0 * scale
    return blown[dy:dy + h, dx:dx + w]


def _polyline_length(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def _check_self_approach(points: np.ndarray, width_px: float, fraction: float, side: str) -> None:
    """Raise when the centerline passes closer to itself than ``fraction`` of the arm width."""
    if fraction <= 0 or width_px <= 0 or len(points) < 3:
        return
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    # Samples every quarter width are dense enough to see two parts touch.
    keep = np.searchsorted(arc, np.arange(0.0, arc[-1], 0.25 * width_px))
    p, a = points[keep], arc[keep]
    d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(axis=2)
    apart = np.abs(a[:, None] - a[None]) > 2.5 * width_px
    if np.any(apart & (d2 < (fraction * width_px) ** 2)):
        raise _NoArmError(f"self-overlap in the {side} image: the centerline crosses or touches itself")


def _project_rect(P: np.ndarray, points: np.ndarray) -> np.ndarray:
    h = points @ P[:, :3].T + P[:, 3]
    return h[:, :2] / h[:, 2:3]
