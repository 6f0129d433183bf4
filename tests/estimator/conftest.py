"""Rendered scenes shared by the estimator tests (drawn once per test worker)."""

import numpy as np
import pytest

from tests.scenes import Section, backbone, rectified_calibration, render_scene, standard_shapes, zed_like_calibration


@pytest.fixture(scope="session")
def zed_calibration():
    return zed_like_calibration()


@pytest.fixture(scope="session")
def cold_scenes():
    """Every standard shape through the raw ZED-like pair and through an ideal rectified pair."""
    scenes = {}
    for label, calib in (("raw", zed_like_calibration()), ("rectified", rectified_calibration())):
        for name, (points, joints) in standard_shapes().items():
            scenes[f"{label}/{name}"] = render_scene(calib, points, joints, seed=len(scenes))
    return scenes


@pytest.fixture(scope="session")
def bending_sequence():
    """30 frames of a smooth 3D bending motion from hanging straight to a twisted three-section bend."""
    calib = zed_like_calibration()
    L = (0.235, 0.23, 0.22)
    frames = []
    for i, a in enumerate(np.linspace(0.0, 1.0, 30)):
        points, joints = backbone([Section(L[0], 1.6 * a, 0.0), Section(L[1], 2.4 * a, 1.57),
                                   Section(L[2], 2.6 * a, 1.0, 3.0 * a)], (-0.05, -0.34, 1.0))
        frames.append(render_scene(calib, points, joints, seed=100 + i))
    return frames
