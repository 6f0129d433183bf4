"""An arm bending towards the camera: its last section, nearer, is drawn wider, and the slanted
connector before it is a wide dark band. The cold search's walk from the base stopped at that band
in one image and crossed it in the other; the short trace was taken with the full one (lengths
within a factor of two), and the frame was refused as "the left one is 54 % as long as the other".
The walk from the tip's end crosses the band, so the cold search takes, of the stereo pairs that run
over the first match, the fullest (``estimator.arm_region._fullest_match``). The scene is drawn by
``tests.scenes`` (benchmarks/unseen_scenes.py, seed 13, lab, frame 7), not the twin.
"""

from __future__ import annotations

import numpy as np

from estimator import CenterlineEstimator
from estimator.arm_region import Trace, TubeGeometry, _fullest_match
from estimator.metrics import score_against_backbone
from tests.scenes import Lab, Section, backbone, render_lab_scenes, zed_like_calibration

GEOMETRY = TubeGeometry(focal_px=175.0, baseline_m=0.12, radius_m=0.025, length_m=0.685)
SHAPE = (180, 320)


def _vertical(u: float, top: float, bottom: float, half: float = 5.0) -> Trace:
    """A straight vertical trace of a coarse mask, from ``top`` to ``bottom`` (rows), at column ``u``."""
    v = np.arange(top, bottom + 1.0) if bottom >= top else np.arange(top, bottom - 1.0, -1.0)
    return Trace(np.column_stack([np.full(len(v), u), v]), half, 1.0)


def test_the_fullest_pair_over_the_first_match_is_taken():
    left_short, right_full = _vertical(200.0, 10.0, 70.0), _vertical(160.0, 10.0, 130.0)
    # the same tube walked from its tip's end in both images: it runs over the first match
    left_up, right_up = _vertical(200.0, 130.0, 10.0), _vertical(160.0, 130.0, 10.0)
    # a longer tube elsewhere in the image (a cable): it does not run over the first match
    cable_left, cable_right = _vertical(60.0, 5.0, 170.0, half=4.0), _vertical(20.0, 5.0, 170.0, half=4.0)
    left, right = _fullest_match(left_short, right_full, [left_short, cable_left, left_up],
                                 [right_full, cable_right, right_up], GEOMETRY, SHAPE)
    assert left is left_up and right is right_up


def test_a_fuller_pair_that_widens_beyond_the_first_match_is_not_taken():
    left, right = _vertical(200.0, 10.0, 70.0), _vertical(160.0, 10.0, 70.0)
    # walked from the far end of a box the arm's tip rests against: as wide as three tubes beyond the arm
    halves = np.where(np.arange(10.0, 131.0) > 75.0, 15.0, 5.0)[::-1]
    box_left = Trace(_vertical(200.0, 130.0, 10.0).path, 5.0, 1.0, halves)
    box_right = Trace(_vertical(160.0, 130.0, 10.0).path, 5.0, 1.0, halves)
    assert _fullest_match(left, right, [left, box_left], [right, box_right], GEOMETRY, SHAPE) == (left, right)
    # the same walk where the tube beyond is drawn 1.5 times wider (nearer the camera): taken
    nearer = np.where(np.arange(10.0, 131.0) > 75.0, 7.5, 5.0)[::-1]
    near_left = Trace(box_left.path, 5.0, 1.0, nearer)
    near_right = Trace(box_right.path, 5.0, 1.0, nearer)
    assert _fullest_match(left, right, [left, near_left], [right, near_right], GEOMETRY, SHAPE) == (near_left,
                                                                                                    near_right)


def test_without_a_fuller_pair_the_first_match_stays():
    left, right = _vertical(200.0, 10.0, 130.0), _vertical(160.0, 10.0, 130.0)
    cable_left, cable_right = _vertical(60.0, 5.0, 170.0, half=4.0), _vertical(20.0, 5.0, 170.0, half=4.0)
    assert _fullest_match(left, right, [left, cable_left], [right, cable_right], GEOMETRY, SHAPE) == (left, right)


def test_a_wide_connector_near_the_camera_does_not_end_the_cold_search():
    calib = zed_like_calibration()
    bend = 7.0 / 11.0
    curvature, planes = (4.006, 3.836, 1.790), (1.316, 2.553, 0.901)
    sections = [Section(length, curvature[i] * bend, planes[i], 0.276 * (i == 2))
                for i, length in enumerate((0.235, 0.23, 0.22))]
    points, joints = backbone(sections, (0.0707, -0.3203, 0.8897), tilt_rad=-0.0298)
    scene = render_lab_scenes(calib, points, joints, conditions={"lab": Lab(wall="plaster")}, seed=1307)["lab"]
    result = CenterlineEstimator(calib).estimate(scene.left, scene.right)
    assert result.valid, result.reason  # before: "the left one is 54% as long as the other"
    assert score_against_backbone(result.points, scene.gt_points)["max_mm"] <= 5.0  # measured 1.3 mm
