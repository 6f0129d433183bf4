"""The shipped model and configuration files: the arm (arm.toml), the stereo rig (camera.toml), the lab
scenes (scene.toml), the twin (twin.toml) and the bench configs (bench.toml; bench_rig.toml, the same on
the rig; bench_random.toml, random levels on every valve).

They are package data, installed with the wheel beside this file, so the code finds them wherever it
runs from (a checkout, ``pip install .``, another working directory) through ``importlib.resources``:

    from models import model_path
    model_path("bench.toml")      # Path to the installed file; relative paths inside it resolve against its folder
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def models_dir() -> Path:
    """The folder holding the model files (a real folder: the package is installed as files, not zipped).

    Raises:
        FileNotFoundError: the package is not installed as a folder of files.
    """
    folder = Path(str(files(__name__)))
    if not (folder / "twin.toml").is_file():
        raise FileNotFoundError(f"{folder}: the model files are missing (is softarm-twin installed as files, "
                                "not zipped?)")
    return folder


def model_path(name: str) -> Path:
    """The installed model file ``name`` (e.g. "twin.toml")."""
    return models_dir() / name
