"""Where the arm leaves its mount, learned from the first trusted frames.

The mount is rigid and the camera does not move, so the point where the arm first shows below
its mount and the direction it leaves in are the same in every frame. While the first section
is straight they are measured well; once it bends (and the mount's own image hides part of
the tube's end), the images alone place the base a few millimetres off. The median of the first
trusted frames becomes a prior for the later ones.

Bounded: if later frames keep disagreeing with the learned base (the camera was bumped), it is
forgotten and learned again.
"""

from __future__ import annotations

import numpy as np

LEARN_FRAMES = 8  # trusted frames whose median becomes the prior
TRUST_RMS_PX = 0.5  # a fit this close to its edges is trusted
DISAGREE_M = 0.006  # a base this far from the prior counts as disagreement
DISAGREE_FRAMES = 5  # this many in a row and the prior is dropped


class MountLearner:
    """Learns the base point and direction of the arm (rectified left camera frame)."""

    def __init__(self) -> None:
        self._points: list[np.ndarray] = []
        self._directions: list[np.ndarray] = []
        self.prior: tuple[np.ndarray, np.ndarray] | None = None
        self._disagreements = 0

    @property
    def frames(self) -> int:
        return len(self._points)

    def reset(self) -> None:
        self.__init__()

    def observe(self, fit) -> None:
        """Take one fit's base (only from trusted fits, only until the prior is set)."""
        point = fit.control[0].copy()
        chord = fit.control[1] - fit.control[0]
        direction = chord / max(float(np.linalg.norm(chord)), 1e-12)
        if self.prior is not None:
            far = float(np.linalg.norm(point - self.prior[0])) > DISAGREE_M
            self._disagreements = self._disagreements + 1 if far else 0
            if self._disagreements >= DISAGREE_FRAMES:
                self.reset()
            return
        if fit.rms_px > TRUST_RMS_PX or fit.inliers < 0.9:
            return
        self._points.append(point)
        self._directions.append(direction)
        if len(self._points) >= LEARN_FRAMES:
            mean_direction = np.median(np.array(self._directions), axis=0)
            self.prior = (np.median(np.array(self._points), axis=0),
                          mean_direction / np.linalg.norm(mean_direction))
