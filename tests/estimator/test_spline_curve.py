"""The compiled splines of the 2D refinement give what SciPy's do (they replaced them for speed)."""

import numpy as np
import pytest
from scipy.interpolate import make_interp_spline, make_lsq_spline

from estimator.spline_curve import evaluate, interpolating_spline, least_squares_spline


def _curve(count, seed=0):
    rng = np.random.default_rng(seed)
    x = np.concatenate([[0.0], np.sort(rng.uniform(1.0, 300.0, count - 1))])
    y = np.column_stack([40 * np.sin(x / 50), 30 * np.cos(x / 70)]) + rng.normal(0, 0.3, (count, 2))
    return x, y


@pytest.mark.parametrize("count", [4, 5, 9, 40])
def test_interpolating_spline_is_scipys_not_a_knot_cubic(count):
    x, y = _curve(count)
    knots, coefficients, solved = interpolating_spline(x, y)
    assert solved
    reference = make_interp_spline(x, y, k=3)
    at = np.linspace(-10.0, x[-1] + 10.0, 300)  # beyond both ends too
    values, derivatives = evaluate(knots, coefficients, at)
    np.testing.assert_allclose(knots, reference.t)
    np.testing.assert_allclose(values, reference(at), atol=1e-9)
    np.testing.assert_allclose(derivatives, reference.derivative()(at), atol=1e-9)
    np.testing.assert_allclose(evaluate(knots, coefficients, x)[0], y, atol=1e-9)  # through every sample


def test_least_squares_spline_is_scipys_and_continues_its_end_pieces():
    x, y = _curve(60, seed=3)
    knots = np.concatenate([[0.0] * 4, np.linspace(0.0, x[-1], 12)[1:-1], [x[-1]] * 4])
    coefficients, solvable = least_squares_spline(x, y, knots)
    reference = make_lsq_spline(x, y, knots, k=3)
    at = np.linspace(-20.0, x[-1] + 20.0, 300)
    values, derivatives = evaluate(knots, coefficients, at)
    assert solvable
    np.testing.assert_allclose(values, reference(at), atol=1e-9)
    np.testing.assert_allclose(derivatives, reference.derivative()(at), atol=1e-9)


def test_least_squares_spline_says_when_a_coefficient_has_no_samples():
    x = np.linspace(0.0, 10.0, 30)
    knots = np.concatenate([[0.0] * 4, [1.0, 2.0, 3.0, 40.0, 50.0], [60.0] * 4])  # nothing beyond x = 10
    _, solvable = least_squares_spline(x, np.column_stack([x, x]), knots)
    assert not solvable


def test_weighted_least_squares_spline_is_scipys_with_square_root_weights():
    x, y = _curve(80, seed=5)
    weights = np.random.default_rng(5).uniform(0.02, 1.0, len(x))
    knots = np.concatenate([[0.0] * 4, np.linspace(0.0, x[-1], 9)[1:-1], [x[-1]] * 4])
    coefficients, solvable = least_squares_spline(x, y, knots, weights)
    reference = make_lsq_spline(x, y, knots, k=3, w=np.sqrt(weights))  # SciPy weighs residuals, not squares
    assert solvable
    np.testing.assert_allclose(evaluate(knots, coefficients, x)[0], reference(x), atol=1e-9)


@pytest.mark.parametrize("x", [
    [0.0, 25.0, 50.0, 75.0, 99.0, 100.0],  # six samples for seven coefficients
    np.repeat([0.0, 10.0, 40.0, 60.0, 100.0], 8),  # many samples at five places: still too few places
    np.linspace(0.0, 30.0, 40),  # nothing beyond 30: the last basis functions have no samples
], ids=["too-few-samples", "too-few-places", "empty-end"])
def test_least_squares_spline_says_when_the_samples_cannot_determine_it(x):
    """Every basis function needs a sample of its own (Schoenberg-Whitney); elimination on the
    singular normal matrix would otherwise return rounding noise as an answer."""
    x = np.asarray(x, np.float64)
    knots = np.concatenate([[0.0] * 4, [40.0, 45.0, 50.0] if len(x) > 6 else [25.0, 50.0, 75.0], [100.0] * 4])
    _, solvable = least_squares_spline(x, np.column_stack([x, x]), knots)
    assert not solvable
    weights = np.ones_like(x)
    _, solvable = least_squares_spline(x, np.column_stack([x, x]), knots, weights)
    assert not solvable


def test_samples_of_zero_weight_do_not_determine_a_spline():
    x = np.linspace(0.0, 100.0, 60)
    knots = np.concatenate([[0.0] * 4, [25.0, 50.0, 75.0], [100.0] * 4])
    weights = np.where(x > 70.0, 0.0, 1.0)  # nothing counts within the last basis function's support
    assert least_squares_spline(x, np.column_stack([x, x]), knots)[1]
    assert not least_squares_spline(x, np.column_stack([x, x]), knots, weights)[1]
