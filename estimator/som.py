"""1-D self-organising map that turns 2D arm pixels into an ordered chain of centre points.

Algorithm 1 of the paper (online SOM) is compiled with numba; a pure-numpy version of the same
arithmetic stays as the reference for cross-checks and as the paper-speed baseline. The batch
SOM is the default mode's refinement: deterministic and free of the online jitter.

Choices where the paper is ambiguous (all configurable through ``EstimatorConfig``; the README's
table of the paper's ambiguities gives the measured effect of each):
- t in alpha(t) = alpha0 / (1 + t / lambda) counts presentations (``time="sample"``, the paper
  preset): alpha falls from 0.2 to about 0.01 within the first pass over the contour, so the
  nodes settle instead of tracking the last few samples. ``time="epoch"`` counts passes: alpha
  only falls to about 0.1, each node stays a moving average of its last ~10 samples and jitters
  by a couple of pixels, which is most of the paper mode's depth error under that reading.
- Neighbourhood radius N(t) = N (1 - t / lambda) (Remark 1: the neighbourhood shrinks); nodes with
  |j - j*| <= ceil(N(t)) move, weighted by the Gaussian eta(r) = exp(-r^2 / (2 sigma^2)) whose
  width is tied to N: sigma = N / 2 unless given, so a larger N pulls more neighbours along
  (Fig 5c). The width does not shrink with N(t): a Gaussian narrowed to winner-take-all lets
  the chain zig-zag between the two edges of the arm on contour input (a lower quantization
  error than the centre line), which is not what the paper's figures show.
- Presentation order: ``order="given"`` presents the points in the order given, every epoch
  (Algorithm 1's "for each P_k": the contour's traversal order; deterministic, the paper
  preset); ``order="shuffled"`` draws a seeded permutation per epoch after sorting the points,
  so the result does not depend on the order in which the points were given.
- ``shrink=False`` keeps the radius N fixed instead of shrinking it.
"""

from __future__ import annotations

import math

import numba
import numpy as np

ORDERS = ("shuffled", "given")


def presentation_order(points: np.ndarray, epochs: int, seed: int, order: str = "shuffled") -> np.ndarray:
    """(epochs, K) int64 indices into ``points``: a seeded shuffle of the sorted points per epoch,
    or (``order="given"``) the points as given, every epoch."""
    points = np.asarray(points, dtype=np.float64)
    if order == "given":
        return np.tile(np.arange(len(points), dtype=np.int64), (epochs, 1))
    if order != "shuffled":
        raise ValueError(f"order: expected one of {ORDERS}, got {order!r}")
    canonical = np.lexsort((points[:, 1], points[:, 0]))
    rng = np.random.default_rng(seed)
    return np.stack([canonical[rng.permutation(len(points))] for _ in range(epochs)]).astype(np.int64)


def linear_init(points: np.ndarray, n: int) -> np.ndarray:
    """n nodes evenly spaced along the principal axis of the points, spanning their extent.

    Node 0 is the end with the smaller image row (nearer the top edge), so a hanging arm starts
    ordered base first.

    Args:
        points: (K, 2) pixels.
        n: number of nodes.

    Returns:
        (n, 2) float64 node positions.
    """
    points = np.asarray(points, dtype=np.float64)
    mean = points.mean(axis=0)
    centred = points - mean
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    axis = vt[0]
    if axis[1] < 0 or (axis[1] == 0 and axis[0] < 0):
        axis = -axis  # point down the image: node 0 at the top
    proj = centred @ axis
    return mean + np.linspace(proj.min(), proj.max(), n)[:, None] * axis


def _schedule(epoch: int, index: int, count: int, epochs: int, alpha0: float, lam: float, radius: float,
              sigma0: float, per_sample: bool, shrinking: bool) -> tuple[float, int, float]:
    """Learning rate, integer reach and Gaussian width for one update (shared by both versions)."""
    t = epoch * count + index if per_sample else epoch
    alpha = alpha0 / (1.0 + t / lam)
    shrink = 1.0 - epoch / epochs if shrinking else 1.0
    reach = max(1, math.ceil(radius * shrink - 1e-12))
    return alpha, reach, sigma0


_schedule_jit = numba.njit(cache=True)(_schedule)


@numba.njit(cache=True, inline="always")
def winner(px, py, nodes):
    """Index of the node nearest to (px, py): eqs. (1)-(2), the winner neuron j*."""
    best = 0
    best_d = np.inf
    for j in range(nodes.shape[0]):
        dx = px - nodes[j, 0]
        dy = py - nodes[j, 1]
        d = dx * dx + dy * dy
        if d < best_d:
            best_d = d
            best = j
    return best


@numba.njit(cache=True, nogil=True)
def _som_online_compiled(points, nodes, order, alpha0, lam, radius, sigma0, per_sample, shrinking):
    n = nodes.shape[0]
    epochs, count = order.shape
    for e in range(epochs):
        for i in range(count):
            k = order[e, i]
            px = points[k, 0]
            py = points[k, 1]
            best = winner(px, py, nodes)
            alpha, reach, sigma = _schedule_jit(e, i, count, epochs, alpha0, lam, radius, sigma0, per_sample,
                                                shrinking)
            lo = max(0, best - reach)
            hi = min(n - 1, best + reach)
            for j in range(lo, hi + 1):  # eq. (3) over the winning neighbourhood
                r = j - best
                eta = math.exp(-(r * r) / (2.0 * sigma * sigma))
                nodes[j, 0] += eta * alpha * (px - nodes[j, 0])
                nodes[j, 1] += eta * alpha * (py - nodes[j, 1])
    return nodes


def som_online(points: np.ndarray, init: np.ndarray, *, epochs: int = 15, alpha0: float = 0.2, lam: float = 15.0,
               radius: int = 2, sigma0: float | None = None, seed: int = 0, time: str = "epoch",
               compiled: bool = True, order: str = "shuffled", shrink: bool = True) -> np.ndarray:
    """Train the online SOM of Algorithm 1 from ``init`` (linear init or the previous frame).

    Args:
        points: (K, 2) input pixels (contour or mask).
        init: (n, 2) initial nodes.
        epochs: training rounds (lambda of Table 1 when equal to ``lam``).
        alpha0, lam: learning rate alpha(t) = alpha0 / (1 + t / lam).
        radius: neighbourhood radius N at t = 0.
        sigma0: Gaussian neighbourhood width, node units; None ties it to the radius: N / 2.
        seed: presentation order seed.
        time: "epoch" or "sample", what t counts.
        compiled: numba (True) or the numpy reference (False).
        order: "shuffled" (seeded, independent of the input order) or "given" (as given).
        shrink: shrink the neighbourhood radius over the epochs (Remark 1) or keep it at N.

    Returns:
        (n, 2) trained nodes, in the order of ``init``.
    """
    points = _check_points(points)
    nodes = np.array(init, dtype=np.float64, copy=True)
    if nodes.ndim != 2 or nodes.shape[1] != 2 or len(nodes) < 2:
        raise ValueError(f"init: expected (n, 2) nodes with n >= 2, got {nodes.shape}")
    if time not in ("epoch", "sample"):
        raise ValueError(f"time: expected 'epoch' or 'sample', got {time!r}")
    sigma = neighbourhood_width(radius, sigma0)
    sequence = presentation_order(points, epochs, seed, order)
    args = (float(alpha0), float(lam), float(radius), sigma, time == "sample", bool(shrink))
    if compiled:
        return _som_online_compiled(points, nodes, sequence, *args)
    return _som_online_reference(points, nodes, sequence, *args)


def neighbourhood_width(radius: float, sigma: float | None = None) -> float:
    """The Gaussian's width in node units: ``sigma`` when given, else N / 2 (tied to the radius, so
    N = 2 gives the classic width 1 and a larger N pulls more neighbours along)."""
    if sigma is None:
        if radius <= 0:
            raise ValueError(f"radius: expected a positive neighbourhood radius N, got {radius!r}")
        return 0.5 * float(radius)
    if not sigma > 0:
        raise ValueError(f"sigma0: expected a positive width in node units, got {sigma!r}")
    return float(sigma)


def _som_online_reference(points, nodes, order, alpha0, lam, radius, sigma0, per_sample, shrinking):
    """The same arithmetic as the compiled loop, vectorised over nodes with numpy."""
    n = len(nodes)
    epochs, count = order.shape
    index = np.arange(n)
    for e in range(epochs):
        for i in range(count):
            p = points[order[e, i]]
            best = int(np.argmin(((p - nodes) ** 2).sum(axis=1)))
            alpha, reach, sigma = _schedule(e, i, count, epochs, alpha0, lam, radius, sigma0, per_sample, shrinking)
            near = np.abs(index - best) <= reach
            r = (index[near] - best).astype(np.float64)
            eta = np.exp(-(r * r) / (2.0 * sigma * sigma))
            nodes[near] += (eta * alpha)[:, None] * (p - nodes[near])
    return nodes


@numba.njit(cache=True, nogil=True)
def _som_batch_compiled(points, nodes, iterations, sigma_start, sigma_end):
    n = nodes.shape[0]
    count = points.shape[0]
    sums = np.zeros((n, 2))
    hits = np.zeros(n)
    for it in range(iterations):
        frac = it / max(iterations - 1, 1)
        sigma = sigma_start * (sigma_end / sigma_start) ** frac
        sums[:] = 0.0
        hits[:] = 0.0
        for k in range(count):
            best = winner(points[k, 0], points[k, 1], nodes)
            sums[best, 0] += points[k, 0]
            sums[best, 1] += points[k, 1]
            hits[best] += 1.0
        reach = int(math.ceil(3.0 * sigma))
        for j in range(n):
            wx = 0.0
            wy = 0.0
            wsum = 0.0
            for i in range(max(0, j - reach), min(n, j + reach + 1)):
                h = math.exp(-((i - j) ** 2) / (2.0 * sigma * sigma))
                wx += h * sums[i, 0]
                wy += h * sums[i, 1]
                wsum += h * hits[i]
            if wsum > 1e-9:
                nodes[j, 0] = wx / wsum
                nodes[j, 1] = wy / wsum
    return nodes


def som_batch(points: np.ndarray, init: np.ndarray, *, iterations: int = 6, sigma_start: float = 1.5,
              sigma_end: float = 0.5) -> np.ndarray:
    """Batch SOM: each node moves to the neighbourhood-weighted mean of the points it wins.

    Deterministic and independent of point order; the neighbourhood width shrinks geometrically
    from ``sigma_start`` to ``sigma_end`` (node units), which keeps the chain ordered while the
    nodes settle on the centre of the region they cover.

    Args:
        points: (K, 2) pixels.
        init: (n, 2) nodes, already ordered (e.g. the previous frame's).

    Returns:
        (n, 2) refined nodes in the order of ``init``.
    """
    points = _check_points(points)
    nodes = np.array(init, dtype=np.float64, copy=True)
    if iterations <= 0:
        return nodes
    return _som_batch_compiled(points, nodes, int(iterations), float(sigma_start), float(sigma_end))


def _check_points(points: np.ndarray) -> np.ndarray:
    points = np.ascontiguousarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) == 0:
        raise ValueError(f"points: expected (K, 2) pixels with K >= 1, got {points.shape}")
    return points
