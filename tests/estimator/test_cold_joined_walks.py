"""The cold search's traces from the other end: walks joined through a piece between two gaps, and
traces reversed to start at their end nearer the base.

The twin's dim frame at t = 37 s (tests/bench/test_robustness.py) was refused as "only 252 mm of the
685 mm arm is visible": pinholes left the top section's skeleton loops without a free end, so no walk
started at the base. The left walks started at the first connector and ran to the tip; the right walk
from the tip ran the whole arm, but it started at the tip, so only the tip section alone paired by row.
Joined through the middle section and turned to start at the base, both traces pair as the whole arm.
They only extend a match the walked traces found (``_fullest_match``) and must end on one row too: a
joined walk that ran past the tip into the next thing (the lab scenes' blurred C bend) is not taken.
"""

from __future__ import annotations

import cv2
import numpy as np

from estimator.arm_region import Trace, _ends_on_one_row, _joined_walks, trace_tubes, walked_and_turned


def test_two_walks_from_either_end_of_a_piece_are_joined_through_it():
    branches = [[0, 1, 2], [10, 11], [3, 4, 5]]
    walks = {(0, True): [0, 1, 2, 3, 4, 5], (0, False): [2, 1, 0, 10, 11]}
    assert _joined_walks(walks, branches) == [[11, 10, 0, 1, 2, 3, 4, 5]]


def test_a_walk_that_ends_with_its_piece_is_not_joined():
    branches = [[0, 1, 2], [3, 4, 5]]
    assert _joined_walks({(0, True): [0, 1, 2, 3, 4, 5], (0, False): [2, 1, 0]}, branches) == []
    assert _joined_walks({(0, True): [0, 1, 2, 3, 4, 5]}, branches) == []


def _two_pieces() -> np.ndarray:
    """A coarse mask of a vertical tube 13 px wide, cut once (rows 100-102)."""
    mask = np.zeros((170, 300), np.uint8)
    mask[40:100, 194:207] = 255
    mask[103:150, 194:207] = 255
    return cv2.morphologyEx(mask, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7)))


def test_a_trace_walked_from_the_bottom_is_turned_to_start_at_the_top():
    walked, turned = walked_and_turned(_two_pieces(), None, 9)
    from_bottom = [t for t in walked if t.path[0][1] > t.path[-1][1]]
    assert from_bottom and turned  # the walk from the lowest end is one of the walked
    for trace in turned:
        assert trace.path[0][1] < trace.path[-1][1]
    assert any(np.array_equal(t.path, from_bottom[0].path[::-1]) for t in turned)


def test_trace_tubes_gives_the_walked_traces_only():
    walked, turned = walked_and_turned(_two_pieces(), None, 9)
    plain = trace_tubes(_two_pieces(), None, 9)
    assert turned
    assert [t.path.tolist() for t in plain] == [t.path.tolist() for t in walked]


def _vertical(top: float, bottom: float, u: float = 200.0, half: float = 4.8) -> Trace:
    v = np.arange(top, bottom + 1.0)
    return Trace(np.column_stack([np.full(len(v), u), v]), half, 1.0, np.full(len(v), half))


def test_a_pair_ending_rows_apart_does_not_end_on_one_row():
    assert _ends_on_one_row(_vertical(62, 127), _vertical(64, 126, u=180.0))
    # the blurred C bend's joined walk: ran on 10 rows past the other image's tip (1.5 half widths: 7.2)
    assert not _ends_on_one_row(_vertical(61, 165), _vertical(60, 155, u=180.0))
