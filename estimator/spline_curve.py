"""Cubic splines through, or fitted to, ordered samples of a curve: compiled, so that the 2D
refinement of both images can run on two threads at once.

The refinement smooths its chord midpoints several times a frame with small splines (a few dozen
coefficients). Built with SciPy, each one is a handful of Python-level calls holding the
interpreter lock, and the two images' refinements took turns: 2.7 ms of refinement on one thread
became 5.8 ms on two. Here they are plain compiled loops on the same B-spline basis as the tube's
axis (``estimator.bspline``).
"""

from __future__ import annotations

import numba
import numpy as np

from estimator.bspline import DEGREE, basis_into, basis_workspace


@numba.njit(cache=True, nogil=True)
def interpolating_spline(x, y):
    """Knots (n + 4,), coefficients (n, d) and whether they were found, of the cubic through ``y`` (n, d)
    at strictly increasing ``x`` (n >= 4), with not-a-knot ends (the third derivative continuous across
    the second and last-but-one samples)."""
    n = x.shape[0]
    knots = np.empty(n + DEGREE + 1)
    for j in range(DEGREE + 1):
        knots[j] = x[0]
        knots[n + j] = x[n - 1]
    for j in range(2, n - 2):
        knots[j + 2] = x[j]
    A = np.zeros((n, n))
    work, values, deriv = basis_workspace()
    for i in range(n):
        first = basis_into(knots, n, x[i], work, values, deriv)
        for j in range(DEGREE + 1):
            A[i, first + j] = values[j]
    coefficients, solved = _solve_banded(A, y)
    return knots, coefficients, solved


@numba.njit(cache=True, nogil=True)
def least_squares_spline(x, y, knots, weights=None):
    """Coefficients (count, d) of the cubic on ``knots`` (``count`` + 4, end knots repeated four times)
    nearest ``y`` (m, d) at ``x`` (sorted, non-decreasing) in the least-squares sense, each squared
    residual weighted by ``weights`` (m,) if given; and whether the fit is determined: False where
    the samples do not meet the Schoenberg-Whitney condition (some basis function has no sample of
    its own: too few distinct places, or a stretch of knots without samples), whose normal matrix
    is singular."""
    count = knots.shape[0] - DEGREE - 1
    d = y.shape[1]
    N = np.zeros((count, count))
    b = np.zeros((count, d))
    work, values, deriv = basis_workspace()
    for i in range(x.shape[0]):
        first = basis_into(knots, count, x[i], work, values, deriv)
        w = 1.0 if weights is None else weights[i]
        for p in range(DEGREE + 1):
            wp = w * values[p]
            for c in range(d):
                b[first + p, c] += wp * y[i, c]
            for q in range(DEGREE + 1):
                N[first + p, first + q] += wp * values[q]
    if not _schoenberg_whitney(x, knots, count, weights):
        return np.zeros((count, d)), False
    return _solve_banded(N, b)


@numba.njit(cache=True, nogil=True)
def _schoenberg_whitney(x, knots, count, weights):
    """Whether distinct samples of sorted ``x`` (with a positive weight, if weighted) can be matched one
    to each basis function, inside its support (the end samples may lie on the end knots): then,
    and only then, the least-squares normal matrix is positive definite (FITPACK's check ``fpchec``).
    Greedy, left to right: each basis function takes the first unused sample inside it."""
    j = 0
    last = -np.inf
    for i in range(x.shape[0]):
        if j == count:
            break
        xi = x[i]
        if xi <= last or (weights is not None and not weights[i] > 0.0):
            continue
        lo, hi = knots[j], knots[j + DEGREE + 1]
        if (xi > lo or (lo == knots[0] and xi >= lo)) and (xi < hi or (hi == knots[-1] and xi <= hi)):
            j += 1
            last = xi
    return j == count


@numba.njit(cache=True, nogil=True)
def _solve_banded(A, b):
    """(x, solved) with A x = b for a band matrix, by Gaussian elimination without pivoting (stable
    for B-spline collocation matrices, which are totally positive, and for the symmetric positive
    definite normal matrices: de Boor, A Practical Guide to Splines, ch. XIII). Not solved where a
    pivot vanishes. Written out rather than LAPACK's: a fraction of its compile time."""
    n = A.shape[0]
    d = b.shape[1]
    band = 0
    for i in range(n):
        for j in range(n):
            if A[i, j] != 0.0 and abs(i - j) > band:
                band = abs(i - j)
    U = A.copy()
    x = np.empty((n, d))
    for i in range(n):
        for c in range(d):
            x[i, c] = b[i, c]
    for k in range(n):
        pivot = U[k, k]
        scale = 0.0
        for j in range(n):
            scale = max(scale, abs(A[k, j]))
        if not (abs(pivot) > 1e-12 * scale and np.isfinite(pivot)):  # vanished, up to rounding
            return x, False
        for i in range(k + 1, min(n, k + band + 1)):
            f = U[i, k] / pivot
            if f == 0.0:
                continue
            for j in range(k, min(n, k + band + 1)):
                U[i, j] -= f * U[k, j]
            for c in range(d):
                x[i, c] -= f * x[k, c]
    for k in range(n - 1, -1, -1):
        for c in range(d):
            total = x[k, c]
            for j in range(k + 1, min(n, k + band + 1)):
                total -= U[k, j] * x[j, c]
            x[k, c] = total / U[k, k]
    return x, True


@numba.njit(cache=True, nogil=True)
def evaluate(knots, coefficients, at):
    """(values (m, d), first derivatives (m, d)) of a cubic spline at every ``at``; beyond the end
    knots, its end pieces continued."""
    count = coefficients.shape[0]
    d = coefficients.shape[1]
    m = at.shape[0]
    values = np.zeros((m, d))
    derivatives = np.zeros((m, d))
    work, v, dv = basis_workspace()
    for i in range(m):
        first = basis_into(knots, count, at[i], work, v, dv)
        for j in range(DEGREE + 1):
            for c in range(d):
                values[i, c] += v[j] * coefficients[first + j, c]
                derivatives[i, c] += dv[j] * coefficients[first + j, c]
    return values, derivatives
