"""A fitted tip that kinks at its end is refused: it bent to fit its outline instead of following the arm.

benchmarks/unseen_scenes.py, seed 118 (drawn by ``tests.scenes``, not the twin), frame 6: the last
section points towards the cameras at about 30 degrees, its flat face seen. The fit ended the tube
11 mm short and turned its last 40 mm by 23-26 degrees to meet the face's outline; the outline fitted,
the tip's standard deviation said 3 mm, and the frame came back valid 14-18 mm off at the tip in the
lab, warm and occluded conditions. The arm, curved at its most, turns about 6 degrees there.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimator.pipeline import MAX_TIP_TURN_DEG, TIP_DIRECTION_M, _tip_turn_deg
from tests.unseen_draws import false_valid, tracked


def _axis(curvature: float, kink_deg: float = 0.0, length: float = 0.3, count: int = 241) -> tuple:
    """An axis of constant curvature in the x-z plane, its last ``TIP_DIRECTION_M`` turned further
    by ``kink_deg``; with its arc length."""
    s = np.linspace(0.0, length, count)
    heading = curvature * s + np.radians(kink_deg) * (s > length - TIP_DIRECTION_M)
    steps = np.column_stack([np.sin(heading), np.zeros_like(s), np.cos(heading)])[:-1] * np.diff(s)[:, None]
    axis = np.vstack([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0] + np.cumsum(steps, axis=0)])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(axis, axis=0), axis=1))])
    return axis, arc


def test_a_straight_or_evenly_curved_tip_turns_as_its_curvature_says():
    assert _tip_turn_deg(*_axis(0.0)) == pytest.approx(0.0, abs=1e-6)
    # the mean directions of two stretches 20 mm long, 20 mm apart, differ by curvature x 20 mm
    assert _tip_turn_deg(*_axis(5.0)) == pytest.approx(math.degrees(5.0 * TIP_DIRECTION_M), rel=0.05)


def test_a_kinked_tip_turns_past_the_bound():
    assert _tip_turn_deg(*_axis(2.0, kink_deg=25.0)) > MAX_TIP_TURN_DEG
    assert _tip_turn_deg(*_axis(2.0, kink_deg=5.0)) < MAX_TIP_TURN_DEG


@pytest.mark.parametrize("condition", ["lab", "warm"])
def test_a_tip_towards_the_cameras_bent_to_its_face_is_refused_not_valid_off(condition):
    """Frames 0-5 stay valid; frame 6 is refused with the reason instead of coming back 14-18 mm off."""
    _, results = tracked(118, condition, 6)
    assert false_valid(results) == []
    assert all(result.valid for result, _ in results[:6]), [r.reason for r, _ in results[:6]]
    last = results[-1][0]
    assert not last.valid and "degrees over its last 40 mm" in last.reason, last.reason
