"""Shared test settings: offscreen rendering on the CPU and paths to shared data."""

import os
from pathlib import Path

import pytest

# Must be set before pyrender/PyOpenGL is imported anywhere in the test session.
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture(scope="session")
def zed_conf_dir() -> Path:
    """The real Stereolabs factory files shipped beside the repository."""
    path = SHARED / "data" / "zed"
    if not path.is_dir():
        pytest.fail(f"shared test data not found at {path}: CI checks out ../shared beside the repository")
    return path
