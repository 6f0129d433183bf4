"""The paper's clustering baselines (section 4.3): competitive learning and K-Means++.

Neither keeps an order between centres: competitive learning starts from an ordered linear
initialisation, but with winner-take-all updates nodes overtake each other; K-Means++ centres
have no order at all. The 2D stage orders both by a greedy nearest-neighbour walk from the base
(``order_greedy``), which is what a user of these baselines has to add (and where they fail on
bent shapes).
"""

from __future__ import annotations

import numba
import numpy as np

from estimator.som import presentation_order, winner


@numba.njit(cache=True, nogil=True)
def _competitive(points, nodes, order, alpha):
    epochs, count = order.shape
    for e in range(epochs):
        for i in range(count):
            k = order[e, i]
            best = winner(points[k, 0], points[k, 1], nodes)
            # Algorithm 2, line 8: winner takes all.
            nodes[best, 0] += alpha * (points[k, 0] - nodes[best, 0])
            nodes[best, 1] += alpha * (points[k, 1] - nodes[best, 1])
    return nodes


def competitive_learning(points: np.ndarray, init: np.ndarray, *, epochs: int = 15, alpha: float = 0.2,
                         seed: int = 0, order: str = "shuffled") -> np.ndarray:
    """Algorithm 2: online winner-take-all updates with a constant learning rate.

    Args:
        points: (K, 2) pixels.
        init: (n, 2) initial nodes (linear initialisation or the previous frame).
        epochs: training rounds; alpha: learning rate in (0, 1).
        seed, order: presentation order, as for ``som_online``.

    Returns:
        (n, 2) nodes, indexed like ``init`` (winner-take-all does not keep them in order).
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    nodes = np.array(init, dtype=np.float64, copy=True)
    return _competitive(points, nodes, presentation_order(points, epochs, seed, order), float(alpha))


def kmeans_plus_plus(points: np.ndarray, n: int, *, iterations: int = 15, seed: int = 0) -> np.ndarray:
    """Algorithm 3: K-Means++ seeding (D^2 roulette) followed by ``iterations`` Lloyd steps.

    Returns:
        (n, 2) unordered centres (fewer if there are fewer distinct points).
    """
    points = np.asarray(points, dtype=np.float64)
    rng = np.random.default_rng(seed)
    n = min(n, len(np.unique(points, axis=0)))
    centres = np.empty((n, 2))
    centres[0] = points[rng.integers(len(points))]
    nearest = ((points - centres[0]) ** 2).sum(1)
    for j in range(1, n):
        total = nearest.sum()
        # Roulette wheel: probability proportional to the squared distance to the nearest centre.
        pick = int(np.searchsorted(np.cumsum(nearest), rng.random() * total)) if total > 0 else 0
        centres[j] = points[min(pick, len(points) - 1)]
        nearest = np.minimum(nearest, ((points - centres[j]) ** 2).sum(1))
    for _ in range(iterations):
        labels = np.argmin(((points[:, None, :] - centres[None]) ** 2).sum(2), axis=1)
        for j in range(n):
            members = points[labels == j]
            if len(members):
                centres[j] = members.mean(0)
    return centres


def order_greedy(centres: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Order unordered centres by walking to the nearest unvisited one, from the one nearest ``start``."""
    remaining = list(range(len(centres)))
    current = int(np.argmin(np.linalg.norm(centres - start, axis=1)))
    order = [current]
    remaining.remove(current)
    while remaining:
        d = np.linalg.norm(centres[remaining] - centres[current], axis=1)
        current = remaining.pop(int(np.argmin(d)))
        order.append(current)
    return centres[order]
