"""A free base whose outline the fit leaves unexplained is fitted again from the initial curve's base.

Seen from below its plane, the flat end of an arm without a visible mount shows as an ellipse whose
apex lies well past the axis's end (r |t . s| / Z: 7-8 px on the unseen scenes). With one end point
per image, the fit's first stage traded that tilt for length and left the face edge-on at the
apex; the outline stage could not turn it back. On fresh unseen sequences (benchmarks/unseen_scenes.py
``--first-seed 30``) a base outline missed by over 0.3 px RMS came with the base 5-7.5 mm off at the
median, and five frames were valid over 10 mm off for that alone. Seed 37's warm frame 0 is one:
10.2 mm off at the base, outline missed by 0.55-0.60 px; restarted, 0.6 mm at a lower cost. Seed 44's
blurred frame 0 comes from a third set of seeds, drawn only after the restart was built: 14.5 mm off
at the base before, 1.9 mm after.
"""

from __future__ import annotations

import numpy as np
import pytest

import estimator.pipeline as pipeline
import estimator.tube_fit as tube_fit
from estimator.metrics import score_against_backbone
from tests.unseen_draws import tracked


def _base_mm(result, truth) -> float:
    return score_against_backbone(result.points, truth)["base_mm"]


FRAMES = [(37, "warm"), (44, "blur")]


@pytest.mark.parametrize(("seed", "condition"), FRAMES)
def test_a_tilted_free_base_is_placed_at_its_face_not_at_the_outline_apex(monkeypatch, seed, condition):
    # Where the restart puts the base, whatever the bound on its uncertainty says of the frame (seed 44's
    # blurred base, 1.9 mm off, has 5.2 mm of standard deviation: refused since the twenty-first session).
    monkeypatch.setattr(pipeline, "MAX_FREE_BASE_STD_M", np.inf)
    _, results = tracked(seed, condition, 0)
    result, truth = results[0]
    assert result.valid
    assert _base_mm(result, truth) < 3.0  # 10.2 and 14.5 mm without the restart


@pytest.mark.parametrize(("seed", "condition"), FRAMES)
def test_without_the_restart_the_same_base_is_off(monkeypatch, seed, condition):
    monkeypatch.setattr(tube_fit, "BASE_RESTART_PX", np.inf)
    _, results = tracked(seed, condition, 0)
    result, truth = results[0]
    assert not result.valid or _base_mm(result, truth) > 8.0  # the test above measures the restart


def _fit_with_base_miss(miss_px: float):
    return tube_fit.TubeFit(knots=np.zeros(0), control=np.zeros((16, 3)), radius_bins=np.zeros(3),
                            radius_std=np.zeros(3), covariance=np.zeros((0, 0)), rms_px=0.1, inliers=1.0,
                            edge_u=np.zeros(0), edge_residual_px=np.zeros(0),
                            base_residual_px={0: np.full(6, miss_px), 1: np.full(6, 0.1)})


def test_the_restart_takes_the_first_control_points_back_tapering():
    control = np.zeros((16, 3))
    initial = np.column_stack([np.zeros(50), np.linspace(0.0, 0.6, 50), np.full(50, 1.0)])
    start = tube_fit._base_restart(_fit_with_base_miss(0.6), control, initial, {0: np.zeros((6, 2))})
    _, from_initial = tube_fit.fit_control_points(initial, 16)
    assert np.allclose(start[0], from_initial[0])
    assert np.allclose(start[tube_fit.BASE_RESTART_POINTS:], control[tube_fit.BASE_RESTART_POINTS:])
    moved = np.linalg.norm(start - control, axis=1)[:tube_fit.BASE_RESTART_POINTS]
    share = moved / np.linalg.norm(from_initial - control, axis=1)[:tube_fit.BASE_RESTART_POINTS]
    assert np.all(np.diff(share) < 0)  # the weight tapers towards the middle of the arm


@pytest.mark.parametrize(("miss_px", "outline", "initial"), [
    (0.2, {0: np.zeros((6, 2))}, True),  # the outline is explained: nothing to restart
    (0.6, {}, True),  # no outline of the base (a mount hides it)
    (0.6, {0: np.zeros((2, 2))}, True),  # too few outline points to have been fitted
    (0.6, {0: np.zeros((6, 2))}, False),  # no initial curve to take the base from
])
def test_no_restart_where_there_is_nothing_to_restart(miss_px, outline, initial):
    points = np.column_stack([np.zeros(50), np.linspace(0.0, 0.6, 50), np.full(50, 1.0)]) if initial else None
    assert tube_fit._base_restart(_fit_with_base_miss(miss_px), np.zeros((16, 3)), points, outline) is None
