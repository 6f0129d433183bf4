"""A tip along the image rows whose cap outline the fitted end misses beyond noise is refused.

Such a tip's depth rests on its flat cap's outline alone (its side edges give no disparity along the
rows), and a cap turned towards the camera outlines much as one turned as far away. On the fresh
unseen sequences (benchmarks/unseen_scenes.py ``--first-seed 30``, drawn by ``tests.scenes``, not the
twin) one shape came back valid 37-38 mm off in dim light, in blur and behind a cable, the outline
missed by 0.54-0.69 px and the tip's grown standard deviation 4.9-6.3 mm (under the 8 mm bound).
Since the twenty-second session the depth ambiguity's restarts of the outline stage alone find the
other basin too and refuse the same frame; the rule is tested here with them, and the refusal of a
restart ending lower in cost (twenty-third session), switched off.
"""

from __future__ import annotations

import numpy as np

import estimator.pipeline as pipeline
from tests.unseen_draws import false_valid, tracked, worst_mm


def test_the_bound_lies_between_the_outline_noise_and_the_far_misfit():
    assert pipeline.TIP_OUTLINE_NOISE_PX < pipeline.MAX_ROW_TIP_MISFIT_PX < pipeline.MAX_TIP_MISFIT_PX


def test_a_row_tip_missing_its_cap_is_refused_by_either_rule():
    _, results = tracked(31, "dim", 9)
    assert not results[-1][0].valid


def test_a_row_tip_missing_its_cap_is_refused_and_tracked_on(monkeypatch):
    monkeypatch.setattr(pipeline, "OUTLINE_RESTART_AMBIGUOUS_COST", -np.inf)
    monkeypatch.setattr(pipeline, "BETTER_RESTART_TIP_M", np.inf)
    estimator, results = tracked(31, "dim", 9)
    last, _ = results[-1]
    assert not last.valid  # without the bound: valid, 37.6 mm off
    assert "only its cap's outline gives its depth" in last.reason
    assert estimator._warm_fit is not None
    assert false_valid(results[:-1]) == []
    assert sum(result.valid for result, _ in results[:-1]) >= 8  # measured: 8 of 9


def test_without_the_bound_the_same_tip_is_far_off(monkeypatch):
    monkeypatch.setattr(pipeline, "MAX_ROW_TIP_MISFIT_PX", np.inf)
    monkeypatch.setattr(pipeline, "OUTLINE_RESTART_AMBIGUOUS_COST", -np.inf)
    monkeypatch.setattr(pipeline, "BETTER_RESTART_TIP_M", np.inf)
    _, results = tracked(31, "dim", 9)
    last, truth = results[-1]
    assert last.valid and worst_mm(last, truth) > 30.0  # what the test above guards against
