"""The tip's standard deviation counts how far the fitted end misses the tip's outline."""

import numpy as np
import pytest

from estimator.pipeline import MAX_MISFIT_TIP_STD_M, TIP_OUTLINE_NOISE_PX, _tip_std_with_misfit


def test_an_outline_that_fits_leaves_the_tip_std_as_the_fit_gives_it():
    residuals = {0: np.array([0.1, -0.2, 0.15, 0.05]), 1: np.array([-0.1, 0.1, 0.2, -0.25])}
    std, misfit, image = _tip_std_with_misfit(0.005, residuals)
    assert std == 0.005
    assert misfit == pytest.approx(np.sqrt(np.mean(np.square(residuals[1]))))
    assert image == 1


def test_a_misfitting_outline_grows_the_tip_std_in_proportion_from_its_worse_image():
    left = np.full(6, 2.0 * TIP_OUTLINE_NOISE_PX)  # twice the noise an outline is expected to fit within
    right = np.full(6, 0.5 * TIP_OUTLINE_NOISE_PX)
    std, misfit, image = _tip_std_with_misfit(0.005, {0: left, 1: right})
    assert (std, image) == (pytest.approx(0.010), 0)
    assert misfit == pytest.approx(2.0 * TIP_OUTLINE_NOISE_PX)
    assert std > MAX_MISFIT_TIP_STD_M  # such a tip is refused (pipeline._fit_tube)


def test_an_image_without_tip_observations_does_not_count():
    std, misfit, image = _tip_std_with_misfit(0.004, {0: np.zeros(0), 1: np.array([0.9, -0.9])})
    assert (std, misfit, image) == (pytest.approx(0.012), pytest.approx(0.9), 1)
    assert _tip_std_with_misfit(0.004, {}) == (0.004, 0.0, 0)
