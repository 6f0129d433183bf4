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


def test_an_image_of_another_size_in_a_folder_is_named_by_its_file(tmp_path, calib):
    """Reported: "frame 3 is 2400x720", a count from 0 the user had to map to frame_00003.png."""
    folder = tmp_path / "session"
    folder.mkdir()
    for k, width in enumerate((128, 128, 120)):
        cv2.imwrite(str(folder / f"frame_{k:05d}.png"), np.full((48, width, 3), 77, np.uint8))
    with ZedCamera(folder, calib) as camera:
        camera.grab(), camera.grab()
        with pytest.raises(DeviceError, match=rf"{folder / 'frame_00002.png'} is 120x48, expected 128x48"):
            camera.grab()


class FakeUVC:
    """Stands in for ``cv2.VideoCapture`` on a V4L2 device: records what is requested and reads
    back what the 'hardware' granted, so the mode checks of the real driver run unchanged."""

    opened: list = []

    def __init__(self, target, backend, *, grants=None, frames=3):
        self.target, self.backend, self.requests = target, backend, {}
        self.grants = grants or {}
        self.frames = frames
        self.released = False
        FakeUVC.opened.append(self)

    def isOpened(self):
        return True

    def set(self, prop, value):
        self.requests[prop] = value
        return True

    def get(self, prop):
        return self.grants.get(prop, self.requests.get(prop, 0.0))

    def read(self):
        if self.frames == 0:
            return False, None
        self.frames -= 1
        w, h = int(self.get(cv2.CAP_PROP_FRAME_WIDTH)), int(self.get(cv2.CAP_PROP_FRAME_HEIGHT))
        frame = np.zeros((h, w, 3), np.uint8)
        frame[:, w // 2:] = 255  # the right eye is white
        return True, frame

    def getBackendName(self):
        return "V4L2"

    def release(self):
        self.released = True


@pytest.fixture
def fake_uvc(monkeypatch):
    """Install FakeUVC; returns a function setting what the next device grants."""
    grants = {}
    FakeUVC.opened = []
    monkeypatch.setattr("hardware.zed.cv2.VideoCapture", lambda target, backend: FakeUVC(target, backend,
                                                                                       grants=dict(grants)))
    return grants


def test_device_is_asked_for_the_zed_mode_and_split(zed_conf_dir, fake_uvc):
    hd = load_factory_calibration(zed_conf_dir / "SN1010.conf", "HD")
    with ZedCamera(0, hd, resolution="HD", fps=60) as camera:
        device = FakeUVC.opened[-1]
        assert device.requests[cv2.CAP_PROP_FRAME_WIDTH] == 2560 and device.requests[cv2.CAP_PROP_FRAME_HEIGHT] == 720
        assert device.requests[cv2.CAP_PROP_FPS] == 60
        assert device.requests[cv2.CAP_PROP_FOURCC] == cv2.VideoWriter_fourcc(*"YUYV")
        assert camera.mode.frame_size == (2560, 720) and camera.mode.fps == 60 and camera.mode.pixel_format == "YUYV"
        first, second = camera.grab(), camera.grab()
        assert first.left.shape == first.right.shape == (720, 1280, 3)
        assert first.left.max() == 0 and first.right.min() == 255  # left eye first, then right
        assert second.timestamp_s >= first.timestamp_s and (first.index, second.index) == (0, 1)
        camera.grab()
        with pytest.raises(DeviceError, match="stopped delivering frames"):
            camera.grab()
    assert device.released


@pytest.mark.parametrize(("grants", "message"), [
    ({cv2.CAP_PROP_FRAME_WIDTH: 1344, cv2.CAP_PROP_FRAME_HEIGHT: 376},
     "fell back to 1344x376 instead of 2560x720 at 60 fps.*USB 3"),
    ({cv2.CAP_PROP_FPS: 30.0}, "fell back to 30 fps instead of 2560x720 at 60 fps"),
    ({cv2.CAP_PROP_FOURCC: float(cv2.VideoWriter_fourcc(*"MJPG"))}, "streams MJPG instead of YUYV"),
])
def test_a_device_that_falls_back_to_another_mode_is_refused(zed_conf_dir, fake_uvc, grants, message):
    fake_uvc.update(grants)
    camera = ZedCamera(0, load_factory_calibration(zed_conf_dir / "SN1010.conf", "HD"), resolution="HD", fps=60)
    with pytest.raises(DeviceError, match=message):
        camera.connect()
    assert not camera.is_connected and FakeUVC.opened[-1].released


def test_a_by_id_link_opens_the_device_it_points_at(tmp_path, zed_conf_dir, fake_uvc, monkeypatch):
    """/dev/v4l/by-id/... names the same camera whatever port it is on; the driver opens its target."""
    target = tmp_path / "video7"
    target.write_text("")
    link = tmp_path / "usb-Stereolabs_ZED-video-index0"
    link.symlink_to(target)
    monkeypatch.setattr("hardware.zed._classify", lambda source: ("device", str(source)))
    with ZedCamera(str(link), load_factory_calibration(zed_conf_dir / "SN1010.conf", "HD"), fps=30):
        assert FakeUVC.opened[-1].target == str(target)
