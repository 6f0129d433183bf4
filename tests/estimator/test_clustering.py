"""The clustering baselines of section 4.3 with known answers: Algorithm 2 and Algorithm 3."""

import numpy as np
import pytest

from estimator.clustering import competitive_learning, kmeans_plus_plus, order_greedy


def test_competitive_learning_moves_only_the_winner_by_alpha():
    """Algorithm 2, line 8: W_j* += alpha (P_k - W_j*); every other node stays where it was."""
    init = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    point = np.array([[12.0, 4.0]])
    nodes = competitive_learning(point, init, epochs=1, alpha=0.25)
    np.testing.assert_array_equal(nodes[[0, 2]], init[[0, 2]])
    np.testing.assert_allclose(nodes[1], init[1] + 0.25 * (point[0] - init[1]))
    # repeated presentations converge geometrically on the point: (1 - alpha)^epochs of the gap remains
    nodes = competitive_learning(point, init, epochs=10, alpha=0.25)
    np.testing.assert_allclose(nodes[1], point[0] + 0.75**10 * (init[1] - point[0]))


def test_competitive_learning_settles_on_cluster_means_it_is_started_in():
    rng = np.random.default_rng(0)
    means = np.array([[0.0, 0.0], [100.0, 0.0]])
    points = np.vstack([m + rng.normal(0, 2.0, (200, 2)) for m in means])
    nodes = competitive_learning(points, means + 20.0, epochs=15, alpha=0.05)
    # a constant learning rate leaves the nodes jittering around the means (the paper's critique)
    assert np.max(np.linalg.norm(nodes - means, axis=1)) < 2.0


def test_kmeans_plus_plus_seeds_far_apart_and_finds_the_cluster_means():
    """D^2 seeding picks each new centre with probability proportional to its squared distance,
    so three tight, distant clusters each get one seed; Lloyd steps then land on the means."""
    rng = np.random.default_rng(1)
    means = np.array([[0.0, 0.0], [300.0, 0.0], [0.0, 300.0]])
    points = np.vstack([m + rng.normal(0, 3.0, (100, 2)) for m in means])
    for seed in range(20):
        centres = kmeans_plus_plus(points, 3, seed=seed)
        nearest = np.argmin(np.linalg.norm(centres[:, None] - means[None], axis=2), axis=1)
        assert sorted(nearest) == [0, 1, 2], seed
        truth = np.array([points[100 * k:100 * (k + 1)].mean(0) for k in nearest])
        np.testing.assert_allclose(centres, truth, atol=1e-9)


def test_kmeans_plus_plus_with_more_centres_than_distinct_points():
    points = np.array([[1.0, 1.0], [1.0, 1.0], [5.0, 5.0]])
    centres = kmeans_plus_plus(points, 20)
    assert centres.shape == (2, 2)
    assert {tuple(c) for c in centres} == {(1.0, 1.0), (5.0, 5.0)}


def test_greedy_order_walks_nearest_neighbours_from_the_start():
    chain = np.column_stack([np.zeros(6), np.arange(6.0) * 10])
    shuffled = chain[[3, 0, 5, 1, 4, 2]]
    np.testing.assert_array_equal(order_greedy(shuffled, np.array([0.0, -5.0])), chain)
    np.testing.assert_array_equal(order_greedy(shuffled, np.array([0.0, 80.0])), chain[::-1])


@pytest.mark.parametrize("fn", [lambda p: competitive_learning(p, np.zeros((3, 2))), lambda p: kmeans_plus_plus(p, 3)])
def test_results_are_finite_on_degenerate_input(fn):
    points = np.full((10, 2), 7.0)
    assert np.all(np.isfinite(fn(points)))
