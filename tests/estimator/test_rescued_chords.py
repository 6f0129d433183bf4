"""Chords a ragged mask called unclean, measured from the image where it shows the tube (issue 10, blur).

A 9 px horizontal pan over a textured wall leaves the arm's mask ragged; the chords there fail the
mask's width test although the image's edges are as good as their neighbours'. ``_rescued_chords``
measures them at the clean chords' width and keeps those that agree; a baseplate's chords, and the
ones beside it, stay out.
"""

import cv2
import numpy as np

from estimator.edges import subpixel_edges_and_steps
from estimator.pipeline import _rescued_chords
from estimator.refinement import Centerline2D

# The tube's true edges, x in pixels with pixel k's centre at k (as the estimator counts): 31.8 px wide and
# off-centre of the chords.
LEFT_EDGE, RIGHT_EDGE = 83.8, 115.6
PLATE_Y = (138.0, 146.0)  # a dark baseplate, wider than the tube
PLATE_UNCLEAN = (122.0, 162.0)  # the mask's chords it spoils (longer than a width)
RAGGED = ((45.0, 75.0), (195.0, 222.0))  # stretches a ragged mask called unclean (each under a width)


def _blurred_tube_image(seed=3):
    rng = np.random.default_rng(seed)
    h, w, s = 300, 200, 8  # supersampled, so the edges fall between pixels
    wall = np.empty((h * s, w * s, 3), np.float32)
    wall[:] = (150, 170, 190)
    for by in range(0, h * s, 12 * s):  # bricks of varying shade, joints offset every other row
        shift = (by // (12 * s)) % 2 * 10 * s
        for bx in range(-shift, w * s, 20 * s):
            wall[by:by + 12 * s, max(bx, 0):bx + 20 * s] *= rng.uniform(0.8, 1.1)
    xs = (np.arange(w * s) + 0.5) / s - 0.5
    tube = (xs >= LEFT_EDGE) & (xs < RIGHT_EDGE)
    wall[:, tube] = (30, 110, 230)
    ys = (np.arange(h * s) + 0.5) / s - 0.5
    plate = (ys >= PLATE_Y[0]) & (ys < PLATE_Y[1])
    wall[np.ix_(plate, (xs >= 70) & (xs < 130))] = (40, 40, 40)
    image = cv2.resize(wall, (w, h), interpolation=cv2.INTER_AREA)
    image = cv2.filter2D(image, -1, np.ones((1, 9), np.float32) / 9.0, borderType=cv2.BORDER_REPLICATE)
    image += rng.normal(0.0, 2.0, image.shape).astype(np.float32)
    return np.clip(np.round(image), 0, 255).astype(np.uint8)


def _curve():
    ys = np.arange(30.0, 271.0, 3.0)
    points = np.column_stack([np.full(len(ys), 100.0), ys])
    unclean = np.zeros(len(ys), bool)
    for lo, hi in (PLATE_UNCLEAN, *RAGGED):
        unclean |= (ys >= lo) & (ys <= hi)
    half = np.where(unclean, np.nan, 16.0)
    return Centerline2D(points, ~unclean, half, ys - ys[0])


def test_ragged_stretches_are_measured_and_the_baseplate_is_left_out():
    image, curve = _blurred_tube_image(), _curve()
    normals = np.tile([[-1.0, 0.0]], (len(curve.points), 1))  # the pipeline's normal of a downward tangent
    offsets, _, steps = subpixel_edges_and_steps(image, curve.points, normals, curve.half_width_px, curve.valid)
    assert np.isfinite(offsets[curve.valid]).all()
    take, more, more_steps = _rescued_chords(image, curve, np.zeros(2), normals, offsets, curve.valid)
    ys = curve.points[:, 1]
    assert not (take & curve.valid).any()  # only unclean chords are added
    # +n is -x: column 1 is the left edge, column 0 the right one. Over the bricks a blurred edge comes
    # out up to 0.8-1.2 px off on the clean chords too; the rescued ones are no worse.
    def errors(o):
        return np.concatenate([100.0 - o[:, 1] - LEFT_EDGE, 100.0 - o[:, 0] - RIGHT_EDGE])

    rescued, clean = errors(more), errors(offsets[curve.valid])
    assert np.abs(rescued).max() <= 1.0
    assert np.sqrt(np.mean(rescued**2)) <= 1.2 * np.sqrt(np.mean(clean**2)), (rescued, clean)
    assert (more_steps > 3.0).all()  # blurred steps, so the fit weights them as such
    for lo, hi in RAGGED:
        inside = (ys >= lo) & (ys <= hi)
        assert take[inside].mean() >= 0.9, (lo, hi, take[inside])
    # The baseplate's chords and those within half a width of its stretch stay out.
    near_plate = (ys >= PLATE_UNCLEAN[0] - 16.0) & (ys <= PLATE_UNCLEAN[1] + 16.0)
    assert not take[near_plate].any()


def test_a_chord_off_in_width_is_not_taken():
    """An unclean chord whose image edges are wider than its neighbours' (a distractor of the arm's colour
    touching it) stays unmeasured."""
    image, curve = _blurred_tube_image(), _curve()
    ys = curve.points[:, 1]
    lo, hi = RAGGED[1]
    image[int(lo) + 2:int(hi) - 2, 116:124] = (30, 110, 230)  # the tube 8 px wider over the stretch
    normals = np.tile([[-1.0, 0.0]], (len(curve.points), 1))
    offsets, _, _ = subpixel_edges_and_steps(image, curve.points, normals, curve.half_width_px, curve.valid)
    take, _, _ = _rescued_chords(image, curve, np.zeros(2), normals, offsets, curve.valid)
    wide = (ys >= lo + 6) & (ys <= hi - 6)
    assert wide.any() and not take[wide].any()
