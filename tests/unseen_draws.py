"""The scenes of benchmarks/unseen_scenes.py in a test: the first frames of one condition of one sequence.

The benchmark draws random arms with tests/scenes.py (not the twin); a frame it found wrong is kept
as a test by drawing that sequence again up to it, the same frames, without the other conditions.
"""

from __future__ import annotations

import functools
import importlib.util
import sys
from pathlib import Path

import numpy as np

BENCHMARK = Path(__file__).resolve().parents[1] / "benchmarks" / "unseen_scenes.py"


@functools.cache
def _benchmark():
    spec = importlib.util.spec_from_file_location("unseen_scenes_benchmark", BENCHMARK)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def unseen_frames(seed: int, condition: str, upto: int, frames: int = 12) -> list[tuple[np.ndarray, ...]]:
    """(left, right, truth) of frames 0..``upto`` of the benchmark's sequence ``seed`` in ``condition``."""
    return _benchmark()._sequence(seed, frames, upto=upto, through=condition)[condition]


def unseen_calibration():
    """The ZED-like calibration the benchmark draws with."""
    return _benchmark()._scenes().zed_like_calibration()


def tracked(seed: int, condition: str, upto: int, frames: int = 12):
    """A default estimator run over frames 0..``upto`` of one sequence (``frames`` long, as the
    benchmark's ``--frames``): (estimator, [(result, truth)])."""
    from estimator import CenterlineEstimator

    estimator = CenterlineEstimator(unseen_calibration())
    drawn = unseen_frames(seed, condition, upto, frames)
    return estimator, [(estimator.estimate(left, right), truth) for left, right, truth in drawn]


def worst_mm(result, truth: np.ndarray) -> float:
    """A valid result's largest error against the true backbone, the tip's included (mm)."""
    from estimator.metrics import score_against_backbone

    score = score_against_backbone(result.points, truth)
    return max(score["max_mm"], score["tip_mm"])


def false_valid(pairs, bound_mm: float = 10.0) -> list[int]:
    """Indices of the (result, truth) pairs that came back valid more than ``bound_mm`` off."""
    return [i for i, (result, truth) in enumerate(pairs) if result.valid and worst_mm(result, truth) > bound_mm]
