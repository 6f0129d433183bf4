"""The live view (issue 15): ``softarm run --rrd``, ``--view web`` and ``softarm view`` make Rerun recordings,
and their content is read back with Rerun's own command line (``rerun rrd verify``, ``rerun rrd print``):
which entities, how many rows on each timeline, what a few rows hold.

Rerun's viewer tools collect usage data unless told not to: everything these tests start runs with
``CI=true`` (Rerun sends nothing where it is set) and a Rerun config of its own that says analytics are
disabled (``rerun analytics disable``), so nothing here depends on the machine's settings.
"""

from __future__ import annotations

import collections
import json
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bench.frame_record import EstimateRecord, FrameRecord
from bench.live_view import LiveView, ViewError, ViewTarget, check_target, view_command
from bench.recording import load_run
from bench.run import run_command
from tests.bench.rigkit import rig_config, run_args
from tests.fakes import small_calibration

REPO = Path(__file__).resolve().parents[2]
RERUN = [sys.executable, "-m", "rerun_cli"]  # the rerun-sdk wheel's CLI, whatever PATH says
PER_FRAME = ["/world/camera/left/image", "/world/camera/right/image", "/world/camera/left/centerline",
             "/world/camera/right/centerline", "/world/camera/left/bridged", "/world/camera/right/bridged",
             "/world/estimate/centerline", "/world/estimate/measured", "/world/estimate/bridged",
             "/world/estimate/invalid", "/plots/timing/total", "/plots/fps/estimator"]
CHANNELS = ["s1_a", "s1_b", "s1_c", "s1_d", "s2_a", "s2_b", "s3"]


# --- reading recordings with Rerun's CLI ----------------------------------------------------------------


def rerun_cli(env: dict, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    result = subprocess.run([*RERUN, *args], env=env, capture_output=True, text=True, timeout=300)
    if check:
        assert result.returncode == 0, f"rerun {' '.join(args)}: {result.stderr[-2000:]}"
    return result


def recording_rows(path: Path, env: dict) -> dict[str, dict[str, int]]:
    """Entity path -> {"rows": all its rows, "static": rows on no timeline, <timeline>: rows on it}, from
    ``rerun rrd print -vv``; the blueprint's entities (on the "blueprint" timeline) are left out."""
    printed = rerun_cli(env, "rrd", "print", "-vv", str(path)).stdout
    rows: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    chunk = None
    for line in printed.splitlines():
        match = re.match(r"Chunk\(\S+\) with (\d+) rows \(.*?\) - (/\S*) - ", line)
        if match:
            if chunk is not None and not chunk[2]:
                rows[chunk[0]]["static"] += chunk[1]
            chunk = (match.group(2), int(match.group(1)), set())
            rows[chunk[0]]["rows"] += chunk[1]
            continue
        if chunk is not None:
            for name in re.findall(r"index_name: (\w+)", line):
                if name not in chunk[2]:
                    chunk[2].add(name)
                    rows[chunk[0]][name] += chunk[1]
    if chunk is not None and not chunk[2]:
        rows[chunk[0]]["static"] += chunk[1]
    return {path: dict(counts) for path, counts in rows.items() if "blueprint" not in counts}


def has_blueprint(path: Path, env: dict) -> bool:
    printed = rerun_cli(env, "rrd", "print", str(path)).stdout
    return "BlueprintActivationCommand" in printed and re.search(r" - /viewport - ", printed) is not None


def entity_data(path: Path, entity: str, env: dict) -> str:
    """The rows of one entity as ``rerun rrd print -vvv`` shows them (values included)."""
    return rerun_cli(env, "rrd", "print", "-vvv", "--entity", entity, str(path)).stdout


# --- fixtures -------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rerun_env(tmp_path_factory):
    """The environment for every process these tests start (and this one, for the module's duration):
    CI set, and a Rerun config with analytics disabled."""
    home = tmp_path_factory.mktemp("rerun_home")
    values = {"CI": "true", "XDG_CONFIG_HOME": str(home / "config"), "XDG_DATA_HOME": str(home / "data")}
    with pytest.MonkeyPatch.context() as mp:
        for key, value in values.items():
            mp.setenv(key, value)
        env = dict(os.environ)
        rerun_cli(env, "analytics", "disable")
        yield env


@pytest.fixture(scope="module")
def twin_run(tmp_path_factory, rerun_env):
    """``softarm run --frames 10 --rrd FILE`` on the twin, as a user types it."""
    folder = tmp_path_factory.mktemp("twin_run")
    rrd, out = folder / "live.rrd", folder / "run"
    result = subprocess.run([sys.executable, "-m", "bench.cli", "run", "--frames", "10", "--rrd", str(rrd), "--out",
                             str(out), "--no-report"], cwd=folder, env=rerun_env, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    return SimpleNamespace(folder=out, rrd=rrd, stdout=result.stdout, run=load_run(out))


def test_analytics_are_disabled_for_everything_the_tests_start(rerun_env):
    config = json.loads(rerun_cli(rerun_env, "analytics", "config").stdout)
    assert config["analytics_enabled"] is False
    assert Path(config["config_file_path"]).is_relative_to(rerun_env["XDG_CONFIG_HOME"])
    assert rerun_env["CI"] == "true"  # Rerun's own rule: no analytics where CI is set (CI runs set it too)


# --- softarm run --rrd on the twin ----------------------------------------------------------------------


def test_run_rrd_records_every_frame_on_both_timelines(twin_run, rerun_env):
    rerun_cli(rerun_env, "rrd", "verify", str(twin_run.rrd))
    assert f"rerun {twin_run.rrd}" in twin_run.stdout  # says how to open it
    rows = recording_rows(twin_run.rrd, rerun_env)
    frames = twin_run.run.frames
    assert len(frames) == 10
    for entity in [*PER_FRAME, "/world/truth/backbone", "/plots/pressure/commanded", "/plots/pressure/chamber"]:
        assert rows.get(entity, {}).get("frame") == 10, (entity, rows.get(entity))
        assert rows[entity]["t_s"] == 10, entity
    assert rows["/plots/pressure/commanded"]["static"] == 1  # the series' names, a series per channel
    last = frames[-1].commanded_bar
    assert re.search(r"\[" + r", ".join(f"{last[c]:g}" for c in CHANNELS) + r"\]",
                     entity_data(twin_run.rrd, "/plots/pressure/commanded", rerun_env).replace(".0,", ",")
                     .replace(".0]", "]"))
    scored = sum(1 for f in frames if f.main.errors is not None)
    assert scored >= 5
    for entity in ("/plots/error/rmse_mm", "/plots/error/tip_mm"):
        assert rows[entity]["frame"] == rows[entity]["t_s"] == scored, entity
    invalid = sum(1 for f in frames if not f.main.valid)
    assert rows.get("/log/invalid", {}).get("frame", 0) == invalid
    # the cameras and the world's axes are static; the summary comes once, at the last frame
    assert rows["/world"] == {"rows": 1, "static": 1}
    assert rows["/world/camera/left"] == {"rows": 1, "static": 1}  # its Pinhole
    assert rows["/world/camera/right"] == {"rows": 2, "static": 2}  # its pose and its Pinhole
    assert rows["/summary"]["frame"] == 1
    summary = entity_data(twin_run.rrd, "/summary", rerun_env)
    assert re.search(rf"row_\w+\s+┆ {frames[-1].index}\s+┆", summary), summary  # at the last frame
    assert "text/markdown" in summary and f"{len(frames) - invalid}/{len(frames)} valid frames" in summary
    assert has_blueprint(twin_run.rrd, rerun_env)


def test_run_rrd_images_are_jpeg_and_the_camera_is_calibrated(twin_run, rerun_env):
    images = entity_data(twin_run.rrd, "/world/camera/left/image", rerun_env)
    assert images.count("image/jpeg") >= 10
    pinhole = entity_data(twin_run.rrd, "/world/camera/left", rerun_env)
    K = twin_run.run.calibration.K("left")
    width, height = twin_run.run.calibration.image_size
    # image_from_camera is stored column-major: fx, 0, 0, 0, fy, 0, cx, cy, 1
    assert f"[[{K[0, 0]:g}, 0.0, 0.0, 0.0, {K[1, 1]:g}, 0.0, {K[0, 2]:g}, {K[1, 2]:g}, 1.0]]" in pinhole, pinhole
    assert f"[[{width:.1f}, {height:.1f}]]" in pinhole
    size = twin_run.rrd.stat().st_size
    assert size < 10 * 400e3  # ~60 kB a frame with two JPEG images: not raw pixels (2.8 MB a pair)


def test_view_of_the_run_folder_makes_the_same_recording(twin_run, rerun_env, tmp_path):
    rrd = tmp_path / "view.rrd"
    result = subprocess.run([sys.executable, "-m", "bench.cli", "view", str(twin_run.folder), "--rrd", str(rrd)],
                            cwd=tmp_path, env=rerun_env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    rerun_cli(rerun_env, "rrd", "verify", str(rrd))
    live, replayed = recording_rows(twin_run.rrd, rerun_env), recording_rows(rrd, rerun_env)
    assert set(replayed) == set(live)
    for entity, counts in live.items():
        assert replayed[entity] == counts, entity
    assert has_blueprint(rrd, rerun_env)
    # the twin's images come back as the estimator saw them (noise drawn again): the same JPEG bytes
    assert entity_data(rrd, "/world/camera/left/image", rerun_env).count("image/jpeg") >= 10


# --- the viewer: web, no display, no rerun-sdk ------------------------------------------------------------


def _lines(stream, out: queue.Queue) -> None:
    for line in stream:
        out.put(line)
    out.put(None)


def _wait_for(lines: queue.Queue, pattern: str, seen: list[str], timeout_s: float = 300.0) -> re.Match:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=1.0)
        except queue.Empty:
            continue
        if line is None:
            break
        seen.append(line)
        match = re.search(pattern, line)
        if match:
            return match
    raise AssertionError(f"never printed {pattern!r}:\n{''.join(seen)}")


def test_view_web_serves_the_viewer_and_prints_its_url_until_ctrl_c(rerun_env, tmp_path):
    rrd, out = tmp_path / "web.rrd", tmp_path / "run"
    child = subprocess.Popen([sys.executable, "-m", "bench.cli", "run", "--frames", "3", "--view", "web", "--rrd",
                              str(rrd), "--out", str(out), "--no-report"], cwd=tmp_path, env=rerun_env,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=_lines, args=(child.stdout, lines), daemon=True).start()
    seen: list[str] = []
    try:
        url = _wait_for(lines, r"web viewer is at (http://127\.0\.0\.1:(\d+)\?url=rerun%2Bhttp%3A%2F%2F127\.0\.0\.1"
                               r"%3A(\d+)%2Fproxy)", seen)
        with urllib.request.urlopen(url.group(1), timeout=30) as page:  # loopback only
            assert page.status == 200 and b"<html" in page.read(4096).lower()
        _wait_for(lines, r"keeps serving the recording at http://127\.0\.0\.1", seen)  # the run ended; still up
        with urllib.request.urlopen(f"http://127.0.0.1:{url.group(2)}/", timeout=30) as page:
            assert page.status == 200
        child.send_signal(signal.SIGINT)
        assert child.wait(timeout=60) == 0, "".join(seen)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait(timeout=30)
    rerun_cli(rerun_env, "rrd", "verify", str(rrd))
    assert recording_rows(rrd, rerun_env)["/world/estimate/centerline"]["frame"] == 3
    assert len(load_run(out).frames) == 3


class _CtrlCAtFlush:
    """A terminal whose user presses Ctrl-C the moment a line about serving reaches it."""

    def __init__(self) -> None:
        self.text = ""

    def write(self, text: str) -> int:
        self.text += text
        return len(text)

    def flush(self) -> None:
        if "keeps serving" in self.text and "stopped" not in self.text:
            raise KeyboardInterrupt


def test_ctrl_c_right_after_the_serving_line_stops_the_viewer_cleanly(rerun_env, tmp_path):
    """CI once pressed Ctrl-C as soon as it read the line, and the run died of a KeyboardInterrupt raised
    before the wait had begun (exit -2, not 0): the line is now printed inside the wait's guard."""
    view = LiveView(ViewTarget(rrd=tmp_path / "x.rrd"))
    try:
        view.url = "http://127.0.0.1:9/?url=test"
        out = _CtrlCAtFlush()
        view.serve_until_interrupted(out=out)  # returns: the interrupt is the way to stop it
        assert "keeps serving" in out.text and "web viewer stopped" in out.text
    finally:
        view.url = None
        view.close()


def test_view_without_a_display_fails_at_once_and_says_what_to_use(rerun_env, tmp_path):
    env = {k: v for k, v in rerun_env.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    out = tmp_path / "run"
    result = subprocess.run([sys.executable, "-m", "bench.cli", "run", "--view", "--frames", "2", "--out", str(out)],
                            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert "needs a display" in result.stderr and "--view web" in result.stderr and "--rrd FILE" in result.stderr
    assert "nothing was moved" in result.stderr and not out.exists()
    # softarm view without --rrd opens the viewer: the same answer
    result = subprocess.run([sys.executable, "-m", "bench.cli", "view", str(tmp_path / "none")], cwd=tmp_path,
                            env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "none: no such folder" in result.stderr  # a bad RUN is named first


def test_view_of_a_run_without_a_display_says_what_to_use(twin_run, rerun_env, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert view_command(SimpleNamespace(run_dir=str(twin_run.folder), rrd=None, web=False)) == 1
    err = capsys.readouterr().err
    assert "needs a display" in err and "--view web" in err


def test_view_to_a_file_that_cannot_be_written_says_so_without_a_traceback(twin_run, rerun_env, capsys):
    assert view_command(SimpleNamespace(run_dir=str(twin_run.folder), rrd="/proc/softarm-view-test.rrd",
                                        web=False)) == 1
    err = capsys.readouterr().err
    assert "--rrd /proc/softarm-view-test.rrd: cannot be written" in err and "Traceback" not in err


def test_without_rerun_sdk_the_view_says_how_to_install_it(tmp_path, rerun_env):
    blocked = ("import sys; sys.modules['rerun'] = None; from bench.cli import main; "
               f"sys.exit(main(['run', '--rrd', 'x.rrd', '--frames', '2', '--out', {str(tmp_path / 'run')!r}]))")
    result = subprocess.run([sys.executable, "-c", blocked], cwd=tmp_path, env=rerun_env, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    assert "pip install 'softarm-twin[view]'" in result.stderr and "nothing was moved" in result.stderr
    # the core path never imports it
    core = ("import sys; import bench.cli, bench.run, bench.replay, bench.report; "
            "sys.exit(1 if 'rerun' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", core], cwd=tmp_path, env=rerun_env, timeout=120).returncode == 0


def test_a_bad_rrd_path_is_refused_before_anything_moves(tmp_path, capsys):
    with pytest.raises(ViewError, match="does not exist"):
        check_target(ViewTarget(rrd=tmp_path / "missing" / "x.rrd"))
    with pytest.raises(ViewError, match="is a folder"):
        check_target(ViewTarget(rrd=tmp_path))
    # a folder that is there but takes no new file (as root, only a special file system refuses)
    with pytest.raises(ViewError, match="cannot be written"):
        check_target(ViewTarget(rrd=Path("/proc/softarm-view-test.rrd")))
    check_target(ViewTarget(rrd=tmp_path / "ok.rrd"))  # a writable path passes and is not left behind
    assert not (tmp_path / "ok.rrd").exists()
    # a FIFO would block the check's open; a link to nothing would be replaced by a file (reviewed)
    os.mkfifo(tmp_path / "pipe.rrd")
    with pytest.raises(ViewError, match="not a regular file"):
        check_target(ViewTarget(rrd=tmp_path / "pipe.rrd"))
    (tmp_path / "dangling.rrd").symlink_to(tmp_path / "nowhere" / "x.rrd")
    with pytest.raises(ViewError, match="a link to nothing"):
        check_target(ViewTarget(rrd=tmp_path / "dangling.rrd"))
    assert (tmp_path / "dangling.rrd").is_symlink()
    args = SimpleNamespace(config=None, backend=None, mode=None, compare=False, frames=2, out=str(tmp_path / "run"),
                           no_report=True, yes=False, view=None, rrd=str(tmp_path / "missing" / "x.rrd"))
    assert run_command(args) == 2
    assert "nothing was moved" in capsys.readouterr().err and not (tmp_path / "run").exists()


# --- the logger: beside the loop, bridged and invalid points apart ----------------------------------------


def _estimate(points, measured, valid=True, reason=""):
    points = np.asarray(points, float)
    uv = points[:, :2] * 100 + 20 if len(points) else np.zeros((0, 2))
    return EstimateRecord(valid=valid, reason=reason, points_m=points, left_uv=uv, right_uv=uv - [3, 0],
                          timings_ms={"segment": 2.0, "total": 8.0}, measured=np.asarray(measured, bool))


def _record(index, estimate):
    return FrameRecord(index=index, t_s=0.5 * index, timestamp_s=0.5 * index, camera_index=index,
                       commanded_bar={"s1_a": 0.1 * index}, chamber_bar=None, bench_ms={}, main=estimate)


def test_submit_never_waits_for_a_slow_logger_and_the_frames_keep_their_3d(tmp_path, rerun_env, monkeypatch):
    import bench.live_view as live_view

    release = threading.Event()
    encoding = threading.Event()
    original = live_view._jpeg

    def stuck(image):
        encoding.set()
        assert release.wait(timeout=60)
        return original(image)

    monkeypatch.setattr(live_view, "_jpeg", stuck)
    rrd = tmp_path / "slow.rrd"
    view = LiveView(ViewTarget(rrd=rrd), max_pending_images=1)
    calibration = small_calibration(64, 48)
    view.start(calibration, channels=["s1_a"], name="slow")
    image = np.zeros((48, 64, 3), np.uint8)
    points = [[0.0, 0.0, 1.0], [0.0, 0.1, 1.0], [0.0, 0.2, 1.0]]
    view.submit(_record(0, _estimate(points, [True] * 3)), image, image)
    assert encoding.wait(timeout=60)  # the logger is stuck in the first frame's images
    for i in range(1, 5):  # these return although the logger cannot take anything: their images are left out
        view.submit(_record(i, _estimate(points, [True] * 3)), image, image)
    assert not release.is_set() and view.skipped_images == 4
    release.set()
    view.finish({"backend": "sim", "frames": 5, "valid_frames": 5})
    view.close()
    assert view.error is None and view.frames == 5
    rows = recording_rows(rrd, rerun_env)
    assert rows["/world/camera/left/image"]["frame"] == 1 and rows["/world/camera/right/image"]["frame"] == 1
    assert rows["/world/estimate/centerline"]["frame"] == 5 and rows["/plots/pressure/commanded"]["frame"] == 5


def test_bridged_points_and_invalid_frames_are_drawn_apart(tmp_path, rerun_env):
    rrd = tmp_path / "apart.rrd"
    view = LiveView(ViewTarget(rrd=rrd))
    view.start(small_calibration(64, 48), channels=["s1_a"], name="apart")
    points = [[0.0625, 0.0, 1.0], [0.0625, 0.125, 1.0], [0.375, 0.25, 1.0]]
    view.submit(_record(0, _estimate(points, [True, True, False])))  # the tip bridged
    view.submit(_record(1, _estimate(np.zeros((0, 3)), [], valid=False, reason="no arm found in the left image")))
    view.submit(_record(2, _estimate([*points[:2], [0.5, 0.25, 1.0]], [True, True, True])))
    view.finish(None)
    view.close()
    rows = recording_rows(rrd, rerun_env)
    for entity in ("/world/estimate/centerline", "/world/estimate/measured", "/world/estimate/bridged",
                   "/world/estimate/invalid", "/world/camera/left/centerline"):
        assert rows[entity]["frame"] == 3, entity
    bridged = entity_data(rrd, "/world/estimate/bridged", rerun_env)
    measured = entity_data(rrd, "/world/estimate/measured", rerun_env)
    assert "0.375" in bridged and "0.375" not in measured  # the bridged tip only among the bridged
    assert "0.0625" in measured and "0.0625" not in bridged
    invalid = entity_data(rrd, "/world/estimate/invalid", rerun_env)
    assert "frame 1 invalid" in invalid and "no arm found in the left image" in invalid  # the last valid one, named
    assert "Clear:is_recursive" in entity_data(rrd, "/world/estimate/centerline", rerun_env)  # frame 1 shows none
    assert rows["/log/invalid"]["frame"] == 1


# --- the rig ----------------------------------------------------------------------------------------------


def test_rig_run_and_its_view_record_the_same_without_truth(rig_folder, board, rerun_env, tmp_path):
    out, rrd = rig_folder / "run", tmp_path / "rig.rrd"
    assert run_command(run_args(rig_config(rig_folder, board.port), out, rrd=str(rrd), view=None,
                                no_report=True)) == 0
    run = load_run(out)
    rows = recording_rows(rrd, rerun_env)
    frames = len(run.frames)
    assert frames >= 4
    assert rows["/world/camera/left/image"]["frame"] == frames and rows["/world/estimate/centerline"]["t_s"] == frames
    assert not any(e.startswith(("/world/truth", "/plots/error", "/plots/pressure/chamber")) for e in rows)
    assert rows["/plots/pressure/commanded"]["frame"] == frames and rows["/summary"]["frame"] == 1
    replayed = tmp_path / "rig_view.rrd"
    assert view_command(SimpleNamespace(run_dir=str(out), rrd=str(replayed), web=False)) == 0
    assert recording_rows(replayed, rerun_env) == rows
