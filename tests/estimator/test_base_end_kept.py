"""An untracked chain starts from where the last frame's base was, not from the end nearest the top.

benchmarks/unseen_scenes.py ``--frames 6``, seed 118 (drawn by ``tests.scenes``, not the twin), dim:
the arm curls up until its tip is higher in the image than its base (there is no mount and no
configured ``base_pixel``). Frame 4 was refused, tracking let go, and frame 5's chain was started
from the end nearest the top edge: its tip. Every point lay on the arm (RMSE 1.0 mm), but base and
tip were swapped, and the frame came back valid with its tip 560 mm off.
"""

from __future__ import annotations

import numpy as np

from tests.unseen_draws import tracked


def test_a_tip_curled_above_its_base_keeps_its_ends():
    """Frame 5 comes back valid with its base at the base and its tip at the tip (each within 10 mm)."""
    _, results = tracked(118, "dim", 5, frames=6)
    assert not results[4][0].valid  # tracking let go here
    result, truth = results[5]
    assert result.valid, result.reason
    assert np.linalg.norm(result.points[0] - truth[0]) < 0.01
    assert np.linalg.norm(result.points[-1] - truth[-1]) < 0.01
