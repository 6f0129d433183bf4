"""An arm that runs on out of the image is refused, not fitted short to what is in view.

The rectified canvas is grown to hold every raw pixel, so its rims are black; an arm hanging out of
the bottom of the image ends there in the mask, its tube was fitted to what was in view, and the
frame came back valid with the tip 12-34 mm short (benchmarks/unseen_scenes.py, a fresh set of seeds
66-77 drawn this session: seeds 71 and 73, 20 of that set's 26 false valid frames).
"""

from __future__ import annotations

import numpy as np

from estimator import CenterlineEstimator
from tests.unseen_draws import unseen_calibration, unseen_frames


def test_the_view_margin_is_zero_on_the_canvas_rim_and_grows_inward():
    rect = unseen_calibration().rectification
    margin = rect.view_margin_px("left")
    w, h = rect.size
    assert margin.shape == (h, w)
    assert margin[0, 0] <= 1.0 and margin[h - 1, w - 1] <= 1.0  # the rim: nothing beyond it was seen
    assert margin[h // 2, w // 2] > 100.0  # the middle of the view


def test_an_arm_hanging_out_of_the_image_is_refused():
    left, right, _ = unseen_frames(73, "lab", 0)[0]
    result = CenterlineEstimator(unseen_calibration()).estimate(left, right)
    assert not result.valid  # before: valid with the tip 13.9 mm short
    assert "out of view" in result.reason and "tip" in result.reason


def test_an_arm_within_the_image_is_not_refused_for_it():
    left, right, truth = unseen_frames(72, "lab", 0)[0]
    rect = unseen_calibration().rectification
    tip = rect.rectify_points(unseen_calibration().project(np.asarray(truth)[-1:], "left"), "left")[0]
    assert rect.view_margin_px("left")[int(tip[1]), int(tip[0])] > 20.0  # the tip well inside the view
    result = CenterlineEstimator(unseen_calibration()).estimate(left, right)
    assert "out of view" not in result.reason
