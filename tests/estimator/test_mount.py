"""The mount learner (estimator.mount): the base point and direction from the first trusted fits."""

from dataclasses import dataclass

import numpy as np
import pytest

from estimator.mount import DISAGREE_FRAMES, LEARN_FRAMES, MountLearner


@dataclass
class Fit:
    """What the learner reads of a tube fit."""

    control: np.ndarray
    rms_px: float = 0.2
    inliers: float = 0.98


def fit_at(base, direction=(0.0, 1.0, 0.0), rms_px=0.2, inliers=0.98) -> Fit:
    base = np.asarray(base, np.float64)
    direction = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    control = base + np.outer(np.arange(6) * 0.04, direction)
    return Fit(control, rms_px, inliers)


BASE = np.array([0.01, -0.34, 0.98])


def test_median_of_the_first_trusted_frames_becomes_the_prior():
    rng = np.random.default_rng(0)
    learner = MountLearner()
    points = BASE + rng.normal(0.0, 0.001, (LEARN_FRAMES, 3))
    points[2] += [0.02, 0.0, 0.0]  # one frame far off: the median ignores it
    directions = np.array([0.0, 1.0, 0.0]) + rng.normal(0.0, 0.01, (LEARN_FRAMES, 3))
    for k in range(LEARN_FRAMES):
        assert learner.prior is None
        learner.observe(fit_at(points[k], directions[k]))
    point, direction = learner.prior
    np.testing.assert_allclose(point, np.median(points, axis=0), atol=1e-12)
    assert np.linalg.norm(direction) == pytest.approx(1.0)
    assert direction @ [0.0, 1.0, 0.0] > 0.999


def test_untrusted_fits_are_ignored():
    learner = MountLearner()
    for _ in range(LEARN_FRAMES):
        learner.observe(fit_at(BASE + [0.05, 0.0, 0.0], rms_px=0.9))  # edges off the tube
        learner.observe(fit_at(BASE + [0.05, 0.0, 0.0], inliers=0.7))  # many edges not on it
    assert learner.frames == 0 and learner.prior is None
    for _ in range(LEARN_FRAMES):
        learner.observe(fit_at(BASE))
    np.testing.assert_allclose(learner.prior[0], BASE)


def _learned() -> MountLearner:
    learner = MountLearner()
    for _ in range(LEARN_FRAMES):
        learner.observe(fit_at(BASE))
    assert learner.prior is not None
    return learner


def test_repeated_disagreement_drops_the_prior():
    """The camera was bumped: five frames in a row a centimetre away and the prior is forgotten."""
    learner = _learned()
    for _ in range(DISAGREE_FRAMES - 1):
        learner.observe(fit_at(BASE + [0.01, 0.0, 0.0]))
        assert learner.prior is not None
    learner.observe(fit_at(BASE + [0.01, 0.0, 0.0]))
    assert learner.prior is None and learner.frames == 0
    # and it learns the new place
    for _ in range(LEARN_FRAMES):
        learner.observe(fit_at(BASE + [0.01, 0.0, 0.0]))
    np.testing.assert_allclose(learner.prior[0], BASE + [0.01, 0.0, 0.0])


def test_disagreement_must_be_in_a_row():
    learner = _learned()
    for _ in range(3):
        for _ in range(DISAGREE_FRAMES - 1):
            learner.observe(fit_at(BASE + [0.01, 0.0, 0.0]))
        learner.observe(fit_at(BASE + [0.001, 0.0, 0.0]))  # one agreeing frame resets the count
    np.testing.assert_allclose(learner.prior[0], BASE)


def test_reset_forgets():
    learner = _learned()
    learner.reset()
    assert learner.prior is None and learner.frames == 0
