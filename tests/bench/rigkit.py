"""Helpers for the rig-backend tests: a drawn arm seen by a small calibrated stereo pair, and rig configs
pointing at a side-by-side recording of it and at the valve-board emulator (fixtures in ``conftest.py``)."""

import textwrap
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np

from tests.fakes import ARM_CHANNELS
from tests.scenes import render_scene

WIDTH, HEIGHT = 320, 240


def arm_polyline_m() -> np.ndarray:
    """A gently bent 0.6 m arm 1 m in front of the left camera (left camera frame)."""
    s = np.linspace(0.0, 1.0, 60)
    return np.column_stack([0.03 * np.sin(2.5 * s), -0.3 + 0.6 * s, np.full_like(s, 1.0)])


def draw_pair(calibration, points_m):
    """Left and right views of a tube of 25 mm radius along ``points_m``, and the left depth in mm.

    The tube is rendered as the estimator models an arm (``tests.scenes.render_scene``: a round tube
    with flat ends). Drawn as a thick line with round caps, its ends came out 19-21 mm off, and since
    a tip that misses its outline is refused (2026-12-03) such a frame is invalid, as it should be."""
    scene = render_scene(calibration, points_m, radius=0.025)
    depth = np.zeros((HEIGHT, WIDTH), np.uint16)
    uv = calibration.project(points_m, "left")
    thickness = int(round(2 * 0.025 * calibration.K("left")[0, 0] / 1.0))
    pts = np.round(uv * 16).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(depth, [pts], False, 1000, thickness, cv2.LINE_8, shift=4)
    return scene.left, scene.right, depth


def rig_config(folder: Path, port: str, *, duration_s=1.2, frames=6, max_bar=0.5, step_bar=0.1,
               channels='["s1_a", "s2_a", "s3"]', calibration="calib.toml", extra="", valves_max=2.5,
               loop="true", kind="ramp", experiment_extra="") -> Path:
    """A rig config in ``folder``; ``extra`` adds ``[report]`` keys, ``experiment_extra`` ``[experiment]`` keys."""
    path = folder / "bench_rig.toml"
    path.write_text(textwrap.dedent(f"""\
        backend = "rig"

        [experiment]
        kind = "{kind}"
        channels = {channels}
        max_bar = {max_bar}
        step_bar = {step_bar}
        duration_s = {duration_s}
        frames = {frames}
        {experiment_extra}
        [estimator]
        mode = "default"
        base_mount = true  # as models/bench_rig.toml: at 320 x 240 a free base's end is 9-11 mm uncertain

        [report]
        selected_frames = 4
        compensation_frames = 3
        {extra}
        [rig.camera]
        source = "session.mkv"
        calibration = "{calibration}"
        fps = 30
        loop = {loop}

        [rig.depth]
        source = "depth"
        scale_m = 0.001

        [rig.valves]
        port = "{port}"
        max_pressure_bar = {valves_max}
        reply_timeout_s = 0.25  # the emulator shares this process's GIL with the estimator

        [rig.valves.channels]
        """) + "\n".join(f"{name} = {i}" for i, name in enumerate(ARM_CHANNELS)) + "\n")
    return path


def run_args(config: Path, out: Path, **kw) -> SimpleNamespace:
    values = {"config": str(config), "backend": None, "mode": None, "compare": False, "frames": None,
              "out": str(out), "no_report": False}
    values.update(kw)
    return SimpleNamespace(**values)
