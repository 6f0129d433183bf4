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
