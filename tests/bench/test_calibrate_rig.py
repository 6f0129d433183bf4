"""``softarm calibrate --backend rig`` when the camera is missing or fails, and bad ``--views``: a clear
message naming the config file and ``[rig.camera] source``, a non-zero exit, no traceback, no file."""

import argparse
from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.calibrate import calibrate_command
from tests.fakes import side_by_side_frames, small_calibration


def rig_config(folder: Path, source: str) -> Path:
    """A rig config whose camera replays ``source`` with a 64x48 calibration (the valves are never opened)."""
    folder.mkdir(parents=True, exist_ok=True)
    small_calibration().save(folder / "calib.toml")
    path = folder / "bench.toml"
    path.write_text(f'backend = "rig"\n[rig.camera]\nsource = "{source}"\ncalibration = "calib.toml"\nfps = 30\n'
                    '[rig.valves]\nport = "loop://"\n[rig.valves.channels]\ns1_a = 0\n')
    return path


def args(config: Path | None = None, **kw) -> argparse.Namespace:
    return argparse.Namespace(**{"config": None if config is None else str(config), "backend": None,
                                 "out": None, "views": None, **kw})


def test_a_missing_camera_is_named_by_its_key(tmp_path, capsys):
    config = rig_config(tmp_path, "gone.mkv")
    out = tmp_path / "calib_out.toml"
    assert calibrate_command(args(config, out=str(out))) == 1
    err = capsys.readouterr().err
    assert f"{config.resolve()} [rig.camera] source: '{tmp_path.resolve() / 'gone.mkv'}' does not exist" in err
    assert not out.exists()


def test_a_camera_that_cannot_be_opened_is_named_by_its_key(tmp_path, capsys):
    (tmp_path / "notes.mkv").write_text("not a video")
    config = rig_config(tmp_path, "notes.mkv")
    assert calibrate_command(args(config, out=str(tmp_path / "c.toml"))) == 1
    assert f"{config.resolve()} [rig.camera] source: could not open video" in capsys.readouterr().err


def test_a_camera_that_fails_mid_way_is_named_by_its_key(tmp_path, capsys):
    folder = tmp_path / "recording"
    folder.mkdir()
    good, = side_by_side_frames(small_calibration(), 1)
    cv2.imwrite(str(folder / "0000.png"), good)
    cv2.imwrite(str(folder / "0001.png"), np.zeros((40, 100, 3), np.uint8))  # a frame of another size
    config = rig_config(tmp_path, "recording")
    out = tmp_path / "c.toml"
    assert calibrate_command(args(config, out=str(out))) == 1
    err = capsys.readouterr().err
    assert f"{config.resolve()} [rig.camera] source: " in err and f"{folder / '0001.png'} is 100x40" in err
    assert "stopped after 1 frame (0 views)" in err and not out.exists()


@pytest.mark.parametrize("views", [0, -3])
def test_non_positive_views_are_refused(tmp_path, capsys, views):
    config = rig_config(tmp_path, "gone.mkv")
    assert calibrate_command(args(config, views=views)) == 2
    err = capsys.readouterr().err
    assert f"--views {views}: expected a positive number of board views" in err
    assert "does not exist" not in err  # refused before the camera is opened


def test_calibrating_only_the_camera_needs_no_valve_section(tmp_path, capsys):
    """It used to demand [rig.valves] port: the config failed to load before the camera was tried."""
    folder = tmp_path / "rig"
    folder.mkdir()
    small_calibration().save(folder / "calib.toml")
    config = folder / "bench.toml"
    config.write_text('backend = "rig"\n[rig.camera]\nsource = "gone.mkv"\ncalibration = "calib.toml"\nfps = 30\n')
    assert calibrate_command(args(config, out=str(tmp_path / "c.toml"))) == 1  # the camera's fault, not the config's
    err = capsys.readouterr().err
    assert f"{config.resolve()} [rig.camera] source: " in err and "does not exist" in err
    assert "rig.valves" not in err


def test_a_recording_without_a_calibration_is_opened_at_its_own_size(tmp_path, capsys):
    """With no calibration file yet, the stand-in used to open the camera takes the recording's size (here
    2 x 64x48), not the HD mode's, so the recording is read; it shows no board, so nothing is calibrated."""
    from tests.fakes import write_side_by_side_video

    config = rig_config(tmp_path, "session.mkv").read_text().replace('calibration = "calib.toml"',
                                                                     'calibration = "not_yet.toml"')
    (tmp_path / "bench.toml").write_text(config)
    write_side_by_side_video(tmp_path / "session.mkv", side_by_side_frames(small_calibration(), 8))
    out = tmp_path / "c.toml"
    assert calibrate_command(args(tmp_path / "bench.toml", out=str(out))) == 1
    captured = capsys.readouterr()
    assert "no usable calibration to compare with" in captured.out
    assert "frames seen: 8" in captured.err and "128x48" not in captured.err
    assert not out.exists()
