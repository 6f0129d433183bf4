"""EstimatorConfig: presets per mode and errors that name the key."""

import math

import pytest

from estimator import EstimatorConfig


def test_modes_fill_their_presets():
    paper = EstimatorConfig(mode="paper")
    assert (paper.som_input, paper.som_schedule, paper.compensation, paper.smoothing_degree, paper.roi) == (
        "contour", "online", "nearest", 6, False)
    assert (paper.n_points, paper.som_radius, paper.som_alpha0, paper.som_epochs) == (20, 2, 0.2, 15)  # Table 1
    default = EstimatorConfig()
    assert default.medial_refinement and default.extend_ends and default.compensation == "windowed"


def test_overrides_survive_and_replace_follows_mode():
    cfg = EstimatorConfig(mode="paper", compensation="windowed")
    assert cfg.compensation == "windowed"
    assert cfg.replace(mode="default").som_schedule == "batch"
    assert cfg.replace(n_points=30).n_points == 30


@pytest.mark.parametrize(
    ("values", "key"),
    [
        ({"mode": "fast"}, "mode"),
        ({"centerline": "hough"}, "centerline"),
        ({"hsv_low": (5, 100)}, "hsv_low"),
        ({"hsv_high": (200, 255, 255)}, "hsv_high"),
        ({"median_ksize": 4}, "median_ksize"),
        ({"n_points": 2}, "n_points"),
        ({"som_alpha0": 0.0}, "som_alpha0"),
        ({"som_time": "iteration"}, "som_time"),
        ({"arm_radius_m": -1.0}, "arm_radius_m"),
        ({"base_pixel": (1.0,)}, "base_pixel"),
        ({"roi": "yes"}, "roi"),
        # the wrong type (a TOML string, a boolean) or no finite value: a ValueError naming the key, not a
        # TypeError from comparing, an OpenCV error at the first frame, or a radius of inf mm (reported cases)
        ({"som_alpha0": "0.2"}, "som_alpha0"),
        ({"som_alpha0": True}, "som_alpha0"),
        ({"arm_radius_m": "0.025"}, "arm_radius_m"),
        ({"arm_radius_m": math.inf}, "arm_radius_m"),
        ({"max_gap_widths": "2"}, "max_gap_widths"),
        ({"max_width_ratio": math.nan}, "max_width_ratio"),
        ({"arm_length_m": "0.685"}, "arm_length_m"),
        ({"hsv_low": 5}, "hsv_low"),
        ({"canny_high": "x"}, "canny_high"),
        ({"canny_low": -50}, "canny_low"),
        ({"base_pixel": (math.nan, 1.0)}, "base_pixel"),
        ({"base_pixel": 3.0}, "base_pixel"),
    ],
)
def test_bad_values_name_the_key(values, key):
    with pytest.raises(ValueError, match=f"^{key}: expected"):
        EstimatorConfig(**values)


def test_numpy_numbers_are_numbers_and_canny_takes_either_order():
    """numpy scalars pass as before the finite-number checks; a reversed Canny pair is OpenCV's to sort."""
    import numpy as np

    cfg = EstimatorConfig(arm_radius_m=np.float32(0.025), som_alpha0=np.float64(0.2), canny_low=np.int64(120),
                          canny_high=100)
    assert cfg.arm_radius_m == np.float32(0.025) and cfg.canny_low == 120


def test_from_dict_names_the_source_and_unknown_keys():
    cfg = EstimatorConfig.from_dict({"mode": "paper", "hsv_low": [0, 90, 40]}, source="bench.toml [estimator]")
    assert cfg.hsv_low == (0, 90, 40)
    with pytest.raises(ValueError, match=r"bench.toml \[estimator\]: unknown key 'alpha'"):
        EstimatorConfig.from_dict({"alpha": 0.3}, source="bench.toml [estimator]")
    with pytest.raises(ValueError, match=r"bench.toml \[estimator\]: n_points: expected"):
        EstimatorConfig.from_dict({"n_points": "twenty"}, source="bench.toml [estimator]")
