"""``softarm calibrate`` on both backends: the twin's rendered boards, and the rig's code path fed
by a recording of a hand-held board (side-by-side images, as the ZED delivers them)."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.calibrate import calibrate_command
from estimator import StereoCalibration
from estimator.board_calibration import BoardSpec, compare_calibrations
from twin.checkerboard import board_poses, render_board_views
from twin.render import StereoRenderer
from twin.rig import StereoRig

REPO = Path(__file__).resolve().parents[2]


def _args(**kw) -> argparse.Namespace:
    return argparse.Namespace(**{"config": None, "backend": None, "out": None, "views": None, **kw})


def test_sim_calibration_recovers_the_twins_camera(tmp_path, capsys):
    out = tmp_path / "calib.toml"
    assert calibrate_command(_args(backend="sim", out=str(out), views=8)) == 0
    text = capsys.readouterr().out
    assert "focal within 0.5 %): met" in text and str(out) in text
    estimated = StereoCalibration.load(out)
    truth = StereoRig.load(REPO / "models" / "camera.toml").calibration
    diff = compare_calibrations(estimated, truth)
    assert abs(diff["baseline_mm"]) < 0.5
    assert max(abs(v) for k, v in diff.items() if k.endswith("_pct")) < 0.5  # fx, fy of both eyes
    rms = float(text.split("reprojection RMS: ")[1].split(" px")[0])
    assert rms < 0.3


def _rig_config(tmp_path: Path, source: Path, calibration: Path) -> Path:
    config = tmp_path / "bench.toml"
    config.write_text(f"""
backend = "rig"
[sim]
twin = "{REPO / 'models' / 'twin.toml'}"
[rig.camera]
source = "{source}"
calibration = "{calibration}"
resolution = "HD"
fps = 15
[rig.valves]
port = "loop://"
[rig.valves.channels]
s1_a = 0
""")
    return config


def test_rig_calibration_from_a_recording_of_a_hand_held_board(tmp_path, capsys):
    rig = StereoRig.load(REPO / "models" / "camera.toml")
    board = BoardSpec()
    poses = board_poses(rig, board, 10, seed=11)
    with StereoRenderer(rig, seed=2) as renderer:
        views = render_board_views(renderer, board, poses)
        empty = renderer.render(None, depth=False)
    folder = tmp_path / "recording"
    folder.mkdir()
    # A recording: the board comes and goes, and sometimes stands still (repeated frames).
    frames = [empty, views[0], views[0]] + views[1:] + [empty]
    for i, v in enumerate(frames):
        cv2.imwrite(str(folder / f"{i:04d}.png"), np.hstack([v.left, v.right]))
    reference = tmp_path / "factory.toml"
    rig.calibration.save(reference)
    out = tmp_path / "rig_calib.toml"
    code = calibrate_command(_args(config=str(_rig_config(tmp_path, folder, reference)), out=str(out), views=20))
    text = capsys.readouterr().out
    assert code == 0, text
    assert "views used: 10 of 10" in text  # the repeated frame and the empty ones were skipped
    diff = compare_calibrations(StereoCalibration.load(out), rig.calibration)
    assert abs(diff["baseline_mm"]) < 0.5 and abs(diff["fx_right_pct"]) < 0.5


def test_rig_calibration_without_enough_views_fails_cleanly(tmp_path, capsys):
    rig = StereoRig.load(REPO / "models" / "camera.toml")
    with StereoRenderer(rig) as renderer:
        empty = renderer.render(None, depth=False)
    folder = tmp_path / "recording"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i:04d}.png"), np.hstack([empty.left, empty.right]))
    reference = tmp_path / "factory.toml"
    rig.calibration.save(reference)
    out = tmp_path / "never.toml"
    assert calibrate_command(_args(config=str(_rig_config(tmp_path, folder, reference)), out=str(out))) == 1
    assert "0 views" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("views", [2])
def test_too_few_requested_views_is_a_usage_error(views, capsys):
    assert calibrate_command(_args(backend="sim", views=views)) == 2
    assert "at least 6" in capsys.readouterr().err


def test_sim_calibration_with_another_board(tmp_path, capsys):
    """A 7x5 board of 50 mm squares, as a lab might print it: the same workflow, the same targets."""
    out = tmp_path / "calib.toml"
    assert calibrate_command(_args(backend="sim", out=str(out), views=8, board="7x5", square_mm=50.0)) == 0
    text = capsys.readouterr().out
    assert "7x5 inner corners, 50 mm squares" in text and "): met" in text


def test_the_twin_workflow_fails_when_the_targets_are_missed(tmp_path, capsys, monkeypatch):
    """Told the board's squares are 2 % larger than printed, the recovered baseline is 2 % off: exit 1."""
    import bench.calibrate as command

    real = command.calibrate_stereo

    def mislabelled(images, board, image_size, **kw):
        return real(images, BoardSpec(board.inner_cols, board.inner_rows, board.square_m * 1.02), image_size, **kw)

    monkeypatch.setattr(command, "calibrate_stereo", mislabelled)
    out = tmp_path / "calib.toml"
    assert calibrate_command(_args(backend="sim", out=str(out), views=8)) == 1
    assert "NOT met" in capsys.readouterr().out


@pytest.mark.parametrize(("kw", "message"), [
    ({"board": "9"}, "--board 9: expected inner corners as COLSxROWS"),
    ({"board": "6x6"}, "columns and rows different"),
    ({"square_mm": 0.0}, "--square-mm 0: expected the printed square size"),
])
def test_a_bad_board_is_a_usage_error(kw, message, capsys):
    assert calibrate_command(_args(backend="sim", **kw)) == 2
    assert message in capsys.readouterr().err
