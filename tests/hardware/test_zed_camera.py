"""ZedCamera on recorded side-by-side sources (the same class that opens the ZED over UVC)."""

import cv2
import numpy as np
import pytest

from hardware.errors import DeviceError, EndOfStreamError, NotConnectedError
from hardware.zed import ZedCamera, load_factory_calibration
from tests.fakes import side_by_side_frames, small_calibration, write_side_by_side_folder, write_side_by_side_video


@pytest.fixture
def calib():
    return small_calibration(64, 48)


@pytest.fixture
def frames(calib):
    return side_by_side_frames(calib, 5)


@pytest.mark.parametrize("kind", ["video", "images"])
def test_recording_is_split_into_left_and_right_with_index_and_time(tmp_path, calib, frames, kind):
    if kind == "video":
        source = write_side_by_side_video(tmp_path / "session.mkv", frames, fps=25.0)
    else:
        source = write_side_by_side_folder(tmp_path / "session", frames)
    with ZedCamera(source, calib, fps=25) as camera:
        assert camera.mode.frame_size == (128, 48) and camera.mode.kind == kind
        got = [camera.grab() for _ in frames]
        with pytest.raises(EndOfStreamError, match="after 5 frames"):
            camera.grab()
    for i, (frame, expected) in enumerate(zip(got, frames, strict=True)):
        assert frame.index == i
        assert frame.timestamp_s == pytest.approx(i / 25.0)
        assert frame.left.shape == frame.right.shape == (48, 64, 3)
        assert frame.left.flags.c_contiguous and frame.right.flags.c_contiguous
        np.testing.assert_array_equal(frame.left, expected[:, :64])  # lossless sources: exact pixels
        np.testing.assert_array_equal(frame.right, expected[:, 64:])


def test_loop_restarts_a_recording_with_increasing_time(tmp_path, calib, frames):
    folder = write_side_by_side_folder(tmp_path / "session", frames[:2])
    with ZedCamera(folder, calib, fps=10, loop=True) as camera:
        got = [camera.grab() for _ in range(5)]
    assert [f.index for f in got] == [0, 1, 2, 3, 4]
    assert np.all(np.diff([f.timestamp_s for f in got]) > 0)
    np.testing.assert_array_equal(got[2].left, got[0].left)


def test_frame_size_must_match_the_calibration_and_the_error_names_both(tmp_path, calib, frames):
    video = write_side_by_side_video(tmp_path / "session.mkv", frames)
    camera = ZedCamera(video, small_calibration(80, 48))
    with pytest.raises(DeviceError, match=r"frames are 128x48 but the calibration's image_size 80x48"):
        camera.connect()
    assert not camera.is_connected


def test_device_requests_a_zed_mode_that_fits_the_calibration(zed_conf_dir):
    hd = load_factory_calibration(zed_conf_dir / "SN1010.conf", "HD")
    with pytest.raises(ValueError, match=r"image_size \(1280, 720\) does not match the ZED VGA eye size"):
        ZedCamera(0, hd, resolution="VGA", fps=30)
    with pytest.raises(ValueError, match="offers 15, 30, 60 fps at HD"):
        ZedCamera(0, hd, resolution="HD", fps=100)


def test_a_missing_device_fails_clearly(zed_conf_dir):
    hd = load_factory_calibration(zed_conf_dir / "SN1010.conf", "HD")
    with pytest.raises(DeviceError, match="no such device"):
        ZedCamera("/dev/v4l/by-id/usb-no-such-zed-video-index0", hd).connect()
    camera = ZedCamera(63, hd)  # an index no test machine has
    with pytest.raises(DeviceError, match="could not open camera 63"):
        camera.connect()
    assert not camera.is_connected


def test_bad_sources_are_rejected_at_construction(tmp_path, calib):
    with pytest.raises(ValueError, match="does not exist"):
        ZedCamera(tmp_path / "nothing.mkv", calib)
    with pytest.raises(TypeError):
        ZedCamera(True, calib)
    (tmp_path / "empty").mkdir()
    with pytest.raises(DeviceError, match="has no images"):
        ZedCamera(tmp_path / "empty", calib).connect()
    (tmp_path / "broken.mkv").write_bytes(b"not a video")
    with pytest.raises(DeviceError, match="could not open video"):
        ZedCamera(tmp_path / "broken.mkv", calib).connect()


def test_grab_before_connect_and_after_close(tmp_path, calib, frames):
    camera = ZedCamera(write_side_by_side_folder(tmp_path / "s", frames), calib)
    with pytest.raises(NotConnectedError):
        camera.grab()
    camera.connect()
    camera.grab()
    camera.close()
    with pytest.raises(NotConnectedError):
        camera.grab()


def test_index_restarts_at_zero_on_reconnect(tmp_path, calib, frames):
    camera = ZedCamera(write_side_by_side_video(tmp_path / "s.mkv", frames), calib)
    for _ in range(2):
        with camera:
            assert [camera.grab().index for _ in range(3)] == [0, 1, 2]


def test_greyscale_images_become_three_channel_bgr(tmp_path, calib):
    folder = tmp_path / "grey"
    folder.mkdir()
    cv2.imwrite(str(folder / "0.png"), np.full((48, 128), 77, np.uint8))
    with ZedCamera(folder, calib) as camera:
        frame = camera.grab()
    assert frame.left.shape == (48, 64, 3) and np.all(frame.left == 77)
