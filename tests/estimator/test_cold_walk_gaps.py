"""The cold search's walk along the arm crosses an occluder next to a baseplate, and a slanted baseplate.

A dark cable crossing the arm just before a baseplate leaves a piece of the tube about as long as it
is wide between the two; thinning leaves that piece no skeleton branch, so the walk met one gap made
of both cuts and the piece (over three widths where each cut was under one), stopped, and the
section beyond was lost in one image: "only 444 mm of the 685 mm arm is visible", or "the left one
is 67 % as long as the other" (benchmarks/unseen_scenes.py, occluded: seeds 12, 39 and 45, the
first frames of each). A baseplate seen at an angle cuts the tube on a slant, and thinning retracts
the skeleton's ends there far more than the half width a square cut costs: the gap between the ends
was 3.3 widths where the mask's was a third of one (seed 50, dim, frame 9). The scenes are
drawn by ``tests.scenes``, not the twin.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import estimator.skeleton as skeleton
from estimator.arm_region import trace_tubes
from tests.unseen_draws import tracked, worst_mm


def _cut_tube() -> np.ndarray:
    """A coarse mask of a vertical tube 9 px wide, cut by a cable (rows 78-83) and a baseplate (93-97):
    a top piece, a piece as long as it is wide, and the rest; rounded as the coarse masks are."""
    mask = np.zeros((170, 300), np.uint8)
    mask[55:78, 196:205] = 255
    mask[84:93, 196:205] = 255
    mask[98:150, 196:205] = 255
    return cv2.morphologyEx(mask, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7)))


def _longest(traces) -> float:
    return max((trace.length for trace in traces), default=0.0)


def test_the_walk_from_the_top_steps_over_a_piece_as_long_as_wide():
    traces = trace_tubes(_cut_tube(), None, 9)
    first = traces[0]
    assert first.path[0][1] < 65 and first.path[-1][1] > 140  # from the top piece to the bottom one


def test_without_the_stepping_stone_the_top_piece_is_left_out(monkeypatch):
    monkeypatch.setattr(skeleton, "STONE_HALF", np.inf)
    traces = trace_tubes(_cut_tube(), None, 9)
    assert all(trace.path[0][1] > 95 and trace.path[-1][1] > 95 for trace in traces)  # only the bottom piece


def test_a_speck_is_not_a_stepping_stone():
    mask = np.zeros((60, 60), np.uint8)
    mask[10:50, 10:19] = 255  # a tube piece (its skeleton is a branch)
    mask[30, 40] = 255  # a one-pixel speck
    points, adjacency = skeleton._neighbours(skeleton.thin(mask))
    branches = [b for b in skeleton._branches(points, adjacency) if len(b) >= 2]
    _, _, with_stones, added = skeleton.with_stepping_stones(mask, points, adjacency, branches, 4.5)
    assert added == set() and len(with_stones) == len(branches)


def test_a_piece_without_a_branch_gets_one_through_its_centre():
    mask = np.zeros((60, 60), np.uint8)
    cv2.circle(mask, (30, 30), 4, 255, -1)
    points, adjacency = skeleton._neighbours(skeleton.thin(mask))
    branches = [b for b in skeleton._branches(points, adjacency) if len(b) >= 2]
    new_points, new_adjacency, with_stones, added = skeleton.with_stepping_stones(mask, points, adjacency, branches,
                                                                                4.0)
    assert len(added) == 1
    stone = with_stones[next(iter(added))]
    assert np.allclose(new_points[stone].mean(axis=0), (30.0, 30.0), atol=0.5)
    assert all(new_adjacency[i] == [] for i in stone)  # reached and left only across gaps


def test_end_reaches_measure_the_mask_beyond_a_skeleton_end():
    mask = np.zeros((40, 80), np.uint8)
    mask[16:25, 5:70] = 255  # a horizontal tube 9 px wide
    points, adjacency = skeleton._neighbours(skeleton.thin(mask))
    branches = [b for b in skeleton._branches(points, adjacency) if len(b) >= 2]
    reaches = skeleton.end_reaches(mask, points, branches, adjacency, span=8, min_length=9.0)
    ends = {int(points[i][0]): reach for i, reach in reaches.items()}
    # the skeleton ends short of the tube's square ends: what is left is about the half width
    assert len(ends) == 2 and all(abs(reach - (69 - u if u > 40 else u - 5)) <= 1.0 for u, reach in ends.items())


def test_a_blob_is_not_credited_with_its_reach():
    """A ball's skeleton is short and retracts far from its ends; credited, it drew the walk from a
    blurred tip onto a skin-coloured ball past it (tests/estimator/test_lab_scenes.py, c_bend, blur)."""
    mask = np.zeros((60, 60), np.uint8)
    cv2.ellipse(mask, (30, 30), (5, 8), 0, 0, 360, 255, -1)
    points, adjacency = skeleton._neighbours(skeleton.thin(mask))
    branches = [b for b in skeleton._branches(points, adjacency) if len(b) >= 2]
    assert branches and skeleton.end_reaches(mask, points, branches, adjacency, span=8, min_length=9.0) == {}


COLD_STARTS = [(39, "occluded", 0), (45, "occluded", 0), (12, "occluded", 0)]


@pytest.mark.parametrize(("seed", "condition", "frame"), COLD_STARTS)
def test_an_arm_cut_by_a_cable_next_to_a_baseplate_is_found_whole(seed, condition, frame):
    _, results = tracked(seed, condition, frame)
    result, truth = results[frame]
    assert result.valid, result.reason
    assert worst_mm(result, truth) < 5.0  # 1.3-1.8 mm; refused before as a section short


def test_a_slanted_baseplate_does_not_end_the_walk():
    _, results = tracked(50, "dim", 9)
    result, truth = results[9]
    assert result.valid, result.reason  # refused before: "the right one is 63 % as long as the other"
    assert worst_mm(result, truth) < 5.0


def test_without_the_reaches_the_slanted_baseplate_ends_it(monkeypatch):
    monkeypatch.setattr(skeleton, "end_reaches", lambda *args, **kwargs: {})
    _, results = tracked(50, "dim", 9)
    assert not results[9][0].valid
