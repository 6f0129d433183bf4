"""A tip whose fitted end misses its outline by more than ``MAX_TIP_MISFIT_PX`` is refused and tracked on.

In dim light an arm whose last stretch runs along the image rows came back valid with its tip 34 mm
off in depth: the fit turned the cap towards the camera and moved the end back along the arm, and the
outline was missed by 0.81 px RMS, which grew the tip's standard deviation to only 6 mm (the bound is
8). The frames kept here (benchmarks/unseen_scenes.py, drawn by ``tests.scenes``, not the twin, through
``tests.unseen_draws``) miss an outline by over 0.75 px and, without the bound, come back valid far off:
seed 35's lab frame 10 (12.8 mm). (Seed 31's warm frame 9, 37.7 mm off without the bound before the
free base's restart, now has its base placed right and its tip 8.3 mm off with the outline missed by
0.47 px; the earlier frames, seed 12's and seed 18's in dim light, are refused earlier or measured
since the dim gate keeps the arm's shaded side and sections.)
"""

from __future__ import annotations

import pytest

from estimator.pipeline import MAX_TIP_MISFIT_PX, TIP_OUTLINE_NOISE_PX
from tests.unseen_draws import false_valid, tracked


def test_the_bound_is_beyond_the_misfit_that_grows_the_std():
    assert MAX_TIP_MISFIT_PX >= 2.0 * TIP_OUTLINE_NOISE_PX


@pytest.mark.parametrize(("seed", "condition", "frame", "valid_before"), [(35, "lab", 10, 9)])
def test_a_tip_missing_its_outline_by_far_is_refused_and_tracked_on(seed, condition, frame, valid_before):
    estimator, results = tracked(seed, condition, frame)
    last, truth = results[-1]
    assert not last.valid  # without the bound: valid, 12.8 mm off
    assert "misses its outline" in last.reason and f"over {MAX_TIP_MISFIT_PX:g} px" in last.reason
    assert estimator._warm_fit is not None  # tracked on: the next frame starts from this shape
    assert false_valid(results[:-1]) == []  # the frames before it stay honest
    assert sum(result.valid for result, _ in results[:-1]) >= valid_before  # measured: 10 of 10
