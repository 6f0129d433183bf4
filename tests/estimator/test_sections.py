"""The sections' lengths between the connectors located on the fitted axis (estimator/sections.py)."""

import numpy as np
import pytest

from estimator.config import EstimatorConfig
from estimator.sections import SLACK_M, section_length_problem

# The twin's arm (models/arm.toml through twin.params.section_length_ranges_m, rounded): a contractile
# first section, two extensile ones.
RANGES = ((0.148, 0.230), (0.231, 0.280), (0.223, 0.251))


@pytest.mark.parametrize("arcs, length", [
    ((0.200, 0.458), 0.690),  # both connectors, every section within its range
    ((0.150, 0.385), 0.610),  # all three at their shortest
    ((0.230, 0.510), 0.761),  # all three at their longest
    ((0.200,), 0.690),  # one connector: the first
    ((0.458,), 0.690),  # one connector: the second
    ((0.247,), 0.724),  # the 6 s ramp's last frame: a band at a sharp bend placed 17 mm past what section 1 reaches
])
def test_lengths_the_arm_can_have_pass(arcs, length):
    assert section_length_problem(np.array(arcs), length, RANGES) is None


def test_a_last_section_hidden_end_on_is_named():
    # bright_warm's random sequence, t = 28.5 s: the fitted tube 82 mm short, every shown point right
    problem = section_length_problem(np.array([0.192, 0.459]), 0.623, RANGES)
    assert problem is not None
    assert problem.startswith("section 3 measures 164 mm from the second connector to the tip")
    assert "223-251 mm" in problem and "section_lengths_m" in problem and "end-on" in problem


def test_one_connector_is_taken_for_the_one_that_fits():
    # at 0.46 m it can only be the second: then the last stretch, 0.16 m, is too short for section 3
    problem = section_length_problem(np.array([0.460]), 0.620, RANGES)
    assert problem is not None and "section 3 measures 160 mm from the second connector" in problem
    # at 0.20 m the first: sections 2-3 together from there
    problem = section_length_problem(np.array([0.200]), 0.560, RANGES)
    assert problem is not None and problem.startswith("sections 2-3 measure 360 mm from the first connector to the tip")


def test_a_first_section_too_long_blames_a_connector_not_a_hidden_tip():
    problem = section_length_problem(np.array([0.300, 0.530]), 0.760, RANGES)
    assert problem is not None and problem.startswith("section 1 measures 300 mm from the base")
    assert "a connector mistaken" in problem


def test_slack_and_what_cannot_be_told():
    # just inside the slack passes, just beyond it does not
    assert section_length_problem(np.array([0.200, 0.458]), 0.458 + 0.223 - SLACK_M + 0.001, RANGES) is None
    assert section_length_problem(np.array([0.200, 0.458]), 0.458 + 0.223 - SLACK_M - 0.001, RANGES) is not None
    # no connector, or more than the arm has: nothing said
    assert section_length_problem(np.zeros(0), 0.3, RANGES) is None
    assert section_length_problem(np.array([0.1, 0.2, 0.3]), 0.3, RANGES) is None


def test_the_config_key_is_checked():
    cfg = EstimatorConfig(connector_radius_m=0.032, section_lengths_m=[[0.148, 0.23], [0.231, 0.28], [0.223, 0.251]])
    assert cfg.section_lengths_m == RANGES
    assert EstimatorConfig().section_lengths_m is None
    for bad in ([[0.1, 0.2]], [[0.2, 0.1], [0.1, 0.2]], [[0.1, "a"], [0.1, 0.2]], [[0.1, 0.2, 0.3], [0.1, 0.2]],
                [[0.0, 0.2], [0.1, 0.2]], [[0.1, float("nan")], [0.1, 0.2]], "0.2", 0.2):
        with pytest.raises(ValueError, match="section_lengths_m"):
            EstimatorConfig(connector_radius_m=0.032, section_lengths_m=bad)
    with pytest.raises(ValueError, match="section_lengths_m: expected connector_radius_m as well"):
        EstimatorConfig(section_lengths_m=RANGES)
