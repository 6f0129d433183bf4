"""Paper mode on the twin's ramp where it was worst: the tip running along the rows, 34-40 s.

The twin's dark baseplates are about as wide in the images as a 5 px closing: closing the mask
bridged a plate in one view and not in the other, the two contours were traced in different
orders, and the two SOMs leaned differently (up to 5 px of disparity near the tip, about 100 mm
of depth there). The paper preset only opens the mask ("remove isolated pixels"), so every plate
cuts both views alike. All 690 frames: 8.6 mm against 13.3 mm with the closing (issue 12's
target: 12 mm).
"""

import os

import numpy as np
import pytest

from estimator import CenterlineEstimator, EstimatorConfig
from estimator.metrics import score_against_backbone

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

RAMP_S = 58.0  # the paper's experiment: s1_a, s2_a and s3 from 0 to 2.5 bar in 58 s


@pytest.fixture(scope="module")
def ramp_window():
    """Frames every 2 s up to 34 s (the warm start's history), then every 0.25 s to 40 s."""
    from twin import Twin
    from twin.twin import DEFAULT_CONFIG, TwinConfig

    twin = Twin(TwinConfig.load(DEFAULT_CONFIG))
    times = [*np.arange(0.0, 34.0, 2.0), *np.arange(34.0, 40.01, 0.25)]
    frames, now = [], 0.0
    try:
        for t in times:
            while now < t - 1e-9:
                step = min(0.5, t - now)
                bar = 2.5 * min((now + step) / RAMP_S, 1.0)
                twin.valves.set_pressures({"s1_a": bar, "s2_a": bar, "s3": bar})
                twin.advance(step)
                now += step
            frame = twin.camera.grab()
            frames.append((t, frame.left, frame.right, twin.backbone()))
        return twin.camera.calibration, frames
    finally:
        twin.close()


def window_rmse(ramp_window, config: EstimatorConfig) -> float:
    calibration, frames = ramp_window
    estimator = CenterlineEstimator(calibration, config)
    errors = []
    for t, left, right, truth in frames:
        result = estimator.estimate(left, right)
        assert result.valid, f"t = {t:.2f} s: {result.reason}"  # the paper mode reports every frame
        if t >= 34.0:
            errors.append(score_against_backbone(result.points, truth)["rmse_mm"])
    return float(np.sqrt(np.mean(np.square(errors))))


def test_paper_preset_holds_where_the_tip_runs_along_the_rows(ramp_window):
    """Measured: 8.9 mm over the window with the preset, 19.6 mm with a 5 px closing."""
    preset = window_rmse(ramp_window, EstimatorConfig(mode="paper"))
    closed = window_rmse(ramp_window, EstimatorConfig(mode="paper", close_ksize=5))
    assert preset <= 12.0
    assert preset <= 0.6 * closed
