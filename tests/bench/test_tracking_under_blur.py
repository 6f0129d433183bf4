"""The estimator tracks a blurred arm from frame to frame, as it does a focused one (the twin's blur
preset: a camera shake of 9 px along the rows over a brick wall, and the arm's own motion)."""

from contextlib import closing

import pytest

from bench.config import load_bench_config
from bench.episodes import _captures, sequence_spec
from estimator import CenterlineEstimator


@pytest.fixture(scope="module")
def still_frames():
    """One frame of the paper's ramp per preset (t = 0: the arm hanging still), rendered by the twin."""
    config = load_bench_config()
    out = {}
    for preset in ("lab", "blur"):
        spec = sequence_spec(config, frames=1, preset=preset, scene_seed=0, estimators={"main": {}})
        calibration, captures = _captures(spec)
        with closing(captures):
            out[preset] = calibration, next(captures).frame
    return out


@pytest.mark.parametrize("preset", ["lab", "blur"])
def test_a_still_arm_is_tracked_blurred_or_not(still_frames, preset, monkeypatch):
    """The corridor around the last frame's arm is held to the arm's area in that frame's coarse gate,
    read from the raw image as the corridor's own is. Held to the fine mask's area instead, from the
    deblurred crop, the twin's blurred arm kept 0.72-0.75 of it where 0.8 is asked: it was never
    tracked, and every blurred frame searched for the arm afresh (the blur ramp: 56 -> 59 of 60 valid
    once tracked, false valid 2 -> 0)."""
    calibration, frame = still_frames[preset]
    estimator = CenterlineEstimator(calibration, load_bench_config().estimator_config(mode="default"))
    kept = {}
    original = CenterlineEstimator._keep_tracked_side

    def recording(self, side, gate, min_area):
        kept[side] = original(self, side, gate, min_area)
        return kept[side]

    monkeypatch.setattr(CenterlineEstimator, "_keep_tracked_side", recording)
    for _ in range(3):
        result = estimator.estimate(frame.left, frame.right)
        assert result.valid, result.reason
    assert set(kept) == {"left", "right"}
    assert all(mask is not None and mask.any() for mask in kept.values()), "the arm was searched for afresh"
