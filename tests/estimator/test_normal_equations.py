"""The tube fit's normal equations (estimator.tube_fit._normal_equations) against a dense reference.

The compiled sums take shortcuts for speed: each edge adds the whole block of its four control points
and the lower triangle is then mirrored from the upper one. Whatever the shortcut, J^T W J and
J^T W r must be what a plain Jacobian (central differences of the residuals) gives.
"""

import numpy as np
import pytest

from estimator.bspline import clamped_knots
from estimator.tube_fit import _bases, _normal_equations

FOCAL_PX = 700.0
BASELINE_M = 0.12
COUNT = 8  # control points
BINS = 2  # radius bins
NO_ROBUST = 1e9  # a Huber threshold no residual reaches: every weight is 1


def _problem(seed: int):
    """A bent tube 0.8 m in front of the cameras and 80 edges seen by both, near its axis' image."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, COUNT)
    control = np.column_stack([0.05 * np.sin(2.0 * s), -0.3 + 0.6 * s, 0.8 + 0.1 * s ** 2])
    control += rng.normal(0.0, 0.003, control.shape)
    radii = np.array([0.021, 0.019])
    n = 80
    us = np.sort(rng.uniform(0.0, 1.0, n))
    sides = np.arange(n) % 2  # left and right camera in turn
    signs = np.where((np.arange(n) // 2) % 2 == 0, 1.0, -1.0)
    bins = np.minimum((us * BINS).astype(np.int64), BINS - 1)
    # the axis' image moved by a few pixels: about a half width (~17 px) from either silhouette line
    knots = clamped_knots(COUNT)
    firsts, values, _ = _bases(knots, COUNT, us)
    axis = np.einsum("ij,ijc->ic", values, control[firsts[:, None] + np.arange(4)[None, :]])
    xs = (axis[:, 0] - BASELINE_M * sides) / axis[:, 2] + rng.normal(0.0, 0.004, n)
    ys = axis[:, 1] / axis[:, 2] + rng.normal(0.0, 0.005, n)
    sigmas = rng.uniform(0.3, 1.5, n)
    return (knots, us, control, radii, bins, np.zeros(n, np.int64), sides.astype(np.int64), xs, ys, signs,
            sigmas)


def _evaluate(problem, control, radii, want_system):
    knots, us, _, _, bins, kinds, sides, xs, ys, signs, sigmas = problem
    return _normal_equations(_bases(knots, COUNT, us), control, radii, bins, BASELINE_M, FOCAL_PX, kinds, sides,
                             xs, ys, signs, sigmas, NO_ROBUST, want_system)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_normal_equations_are_those_of_the_dense_jacobian(seed):
    problem = _problem(seed)
    control, radii, sigmas = problem[2], problem[3], problem[-1]
    cost, residuals, A, g = _evaluate(problem, control, radii, True)
    assert np.all(np.isfinite(residuals)), "every edge has a residual: the tube lies in front of both cameras"

    params = np.concatenate([control.ravel(), radii])

    def residual_vector(p):
        return _evaluate(problem, p[:3 * COUNT].reshape(COUNT, 3), p[3 * COUNT:], False)[1]

    J = np.empty((len(residuals), len(params)))
    for k in range(len(params)):
        h = 1e-7
        up, down = params.copy(), params.copy()
        up[k] += h
        down[k] -= h
        J[:, k] = (residual_vector(up) - residual_vector(down)) / (2.0 * h)
    W = 1.0 / sigmas ** 2
    A_ref = J.T @ (W[:, None] * J)
    g_ref = J.T @ (W * residuals)

    assert cost == pytest.approx(float(np.sum((residuals / sigmas) ** 2)), rel=1e-12)
    np.testing.assert_array_equal(A, A.T)
    scale = np.max(np.abs(A_ref))
    np.testing.assert_allclose(A, A_ref, rtol=0, atol=1e-7 * scale)
    np.testing.assert_allclose(g, g_ref, rtol=0, atol=1e-7 * np.max(np.abs(g_ref)))
    # every control point and both radius bins are seen: no row of the system is left empty
    assert np.all(np.abs(np.diag(A)) > 0)
