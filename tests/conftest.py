"""Shared test settings: offscreen rendering on the CPU and paths to test data."""

import os
from pathlib import Path

import pytest

# Must be set before pyrender/PyOpenGL is imported anywhere in the test session.
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture(scope="session")
def zed_conf_dir() -> Path:
    """Real Stereolabs factory calibration files (see tests/data/zed/README.md)."""
    return DATA / "zed"
