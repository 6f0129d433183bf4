"""One frame path and compact, exact twin runs.

Every part of the bench builds a frame's record with ``bench.process.process`` and reads it as a
``FrameRecord``; no module reaches into another's private names; the capture loop does not ask which
backend it has. The twin's frames are stored as their noise-free render (the difference from the
static scene, cropped) with the noise seed, and ``Run.image`` rebuilds the captured images bit for bit,
so ``softarm replay`` reproduces every estimate exactly.
"""

import ast
import json
import textwrap
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bench.config import DEFAULT_CONFIG, load_bench_config
from bench.frame_record import EstimateRecord, FrameRecord, RecordError
from bench.process import Capture, process
from bench.recording import add_patch, difference_patch, load_run
from bench.replay import replay_command
from bench.run import RunOptions, run_experiment
from bench.scoring import dequantize_depth, quantize_depth
from estimator import CenterlineEstimator, EstimateResult
from hardware.interfaces import StereoFrame
from tests.fakes import small_calibration

BENCH = Path(__file__).resolve().parents[2] / "bench"

# --- the frame record ------------------------------------------------------------------------


def _result(n: int = 4) -> EstimateResult:
    points = np.column_stack([np.zeros(n), np.linspace(-0.3, 0.3, n), np.full(n, 1.0)]) + 1.23456789e-8
    uv = np.column_stack([np.full(n, 32.0004), np.linspace(10, 40, n)])
    return EstimateResult(points, True, "", uv, uv + [2.0, 0.0], {"total": 12.34567, "tube": 3.0},
                          misalignment_px=0.123456, flags=("length",), measured=np.array([True, True, False, True]),
                          point_std_m=np.array([1e-4, 2e-4, 3e-3, 1e-4]), radius_m=0.0125, radius_source="configured",
                          points_unsmoothed=points[:3])


def test_an_estimate_keeps_the_estimators_newer_fields_rounded_as_written():
    record = EstimateRecord.from_result(_result(), {"errors": None, "qprime": None, "qprime_m": None})
    assert record.flags == ("length",) and record.measured.tolist() == [True, True, False, True]
    np.testing.assert_array_equal(record.point_std_m, [1e-4, 2e-4, 3e-3, 1e-4])
    assert record.radius_m == 0.0125 and record.radius_source == "configured"
    assert record.points_m[0, 1] == -0.3 and record.timings_ms["total"] == 12.346 and record.misalignment_px == 0.1235
    assert record.points_unsmoothed_m.shape == (3, 3)
    again = EstimateRecord.from_json(json.loads(json.dumps(record.to_json())))
    assert again.to_json() == record.to_json()
    paper_mode = EstimateRecord.from_result(EstimateResult(np.zeros((0, 3)), False, "no arm", np.zeros((0, 2)),
                                                           np.zeros((0, 2)), {"total": 1.0}))
    assert paper_mode.radius_m is None and paper_mode.radius_source == "" and len(paper_mode.measured) == 0


def test_process_builds_the_record_every_command_writes():
    calibration = small_calibration()

    class Fixed:
        config = SimpleNamespace(mode="paper")

        def estimate(self, left, right):
            return _result()

    frame = StereoFrame(np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64, 3), np.uint8), 1.5, 7)
    gt = np.column_stack([np.zeros(50), np.linspace(-0.3, 0.3, 50), np.full(50, 1.0)])
    capture = Capture(index=3, t_s=1.25, frame=frame, commanded_bar={"s1_a": 0.5}, gt_m=gt,
                      timings_ms={"render": 20.0})
    record = process(capture, {"main": Fixed(), "paper": Fixed()}, calibration)
    assert (record.index, record.t_s, record.timestamp_s, record.camera_index) == (3, 1.25, 1.5, 7)
    assert record.main.errors["rmse_mm"] >= 0 and record.paper.mode == "paper" and record.main.mode is None
    assert {"render", "estimate_main", "score_main", "estimate_paper", "score_paper"} == set(record.bench_ms)
    line = json.loads(json.dumps(record.to_json()))
    assert line["measured"] == [True, True, False, True] and line["radius_source"] == "configured"
    assert FrameRecord.from_json(line).to_json() == line
    with pytest.raises(ValueError, match="expected 'main' and optionally 'paper'"):
        process(capture, {"paper": Fixed()}, calibration)


def test_a_record_with_a_wrong_new_field_is_refused_by_name():
    record = process(Capture(index=0, t_s=0.0, frame=StereoFrame(np.zeros((8, 8, 3), np.uint8),
                                                                  np.zeros((8, 8, 3), np.uint8), 0.0, 0),
                             commanded_bar={}), {"main": _Failing()}, None).to_json()
    assert record["valid"] is False and record["reason"] == "estimator error: RuntimeError: boom"
    for key, value, why in [("measured", [1], "measured: [0]: expected true or false, got 1 (an integer)"),
                            ("radius_m", "big", "radius_m: expected a number, got 'big' (a string)"),
                            ("clean", {"seed": 0}, "clean: missing key 'index'")]:
        with pytest.raises(RecordError, match=f"^{__import__('re').escape(why)}$"):
            FrameRecord.from_json({**record, key: value})
    version_1 = {k: v for k, v in record.items() if k not in ("flags", "measured", "point_std_m", "radius_m",
                                                              "radius_source")}
    assert FrameRecord.from_json(version_1).main.flags == ()  # an older run still reads


class _Failing:
    config = SimpleNamespace(mode="default")

    def estimate(self, left, right):
        raise RuntimeError("boom")

    def reset(self):
        pass


# --- one path, no private names, no backend checks in the loop ---------------------------------


def test_no_bench_module_imports_another_modules_private_names():
    for path in sorted(BENCH.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("bench."):
                private = [a.name for a in node.names if a.name.startswith("_")]
                assert not private, f"{path.name} imports {private} from {node.module}"


def test_every_command_builds_records_with_process():
    users = {path.name for path in BENCH.glob("*.py") if "process(" in path.read_text()}
    assert {"run.py", "replay.py", "report.py", "studies.py"} <= users
    for name in ("run.py", "replay.py", "report.py", "studies.py", "scoring.py"):
        text = (BENCH / name).read_text()
        assert "estimate_fields" not in text and "_Capture" not in text, name


def test_the_capture_loop_never_asks_which_backend_it_has():
    for name in ("capture.py", "process.py"):
        tree = ast.parse((BENCH / name).read_text())
        words = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)} | {
            n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)}
        assert not words & {"backend", "twin", "sim", "rig", "SimulationError"}, name
    run = (BENCH / "run.py").read_text()
    loop = run[run.index("def _run_loop"):run.index("def _add_timings")]
    assert "backend" not in loop and "twin" not in loop


# --- the twin's frames: stored noise-free, rebuilt exactly ---------------------------------------


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_a_difference_patch_is_lossless_and_cropped(dtype):
    rng = np.random.default_rng(0)
    shape = (40, 60, 3) if dtype == np.uint8 else (40, 60)
    top = np.iinfo(dtype).max
    background = rng.integers(0, top, shape, dtype=dtype, endpoint=True)
    image = background.copy()
    image[10:14, 20:31] = rng.integers(0, top, image[10:14, 20:31].shape, dtype=dtype, endpoint=True)
    image[12, 25] = np.subtract(background[12, 25], 1, dtype=dtype)  # wraps round where the background is 0
    image[12, 26] = 0
    background[12, 26] = top  # a difference that wraps round
    patch, origin = difference_patch(image, background)
    assert patch.dtype == dtype and patch.shape[:2] == (4, 11) and origin == (20, 10)
    np.testing.assert_array_equal(add_patch(background, patch, origin), image)
    empty, at = difference_patch(background, background)
    assert empty.shape[:2] == (1, 1) and at == (0, 0)
    np.testing.assert_array_equal(add_patch(background, empty, at), background)
    with pytest.raises(ValueError, match="does not fit"):
        add_patch(background, patch, (55, 38))


def _short_config(folder: Path, frames: int, preset: str = "clean") -> Path:
    models = DEFAULT_CONFIG.parent
    twin = folder / "twin.toml"
    twin.write_text((models / "twin.toml").read_text().replace('arm = "arm.toml"', f'arm = "{models / "arm.toml"}"')
                    .replace('camera = "camera.toml"', f'camera = "{models / "camera.toml"}"')
                    .replace('scenes = "scene.toml"', f'scenes = "{models / "scene.toml"}"')
                    .replace('preset = "clean"', f'preset = "{preset}"'))
    path = folder / "bench.toml"
    path.write_text(textwrap.dedent(f"""\
        [sim]
        twin = "{twin}"
        [experiment]
        max_bar = 2.5
        duration_s = 58.0
        frames = {frames}
        """))
    return path


@pytest.mark.parametrize("preset", ["clean", "lab"])
def test_the_twins_recorded_frames_are_the_captured_frames_bit_for_bit(tmp_path, monkeypatch, preset):
    from twin.camera import SimStereoCamera

    grabbed = []
    original = SimStereoCamera.grab

    def keep(self):
        frame = original(self)
        grabbed.append((frame.left.copy(), frame.right.copy(), self.depth_left()))
        return frame

    monkeypatch.setattr(SimStereoCamera, "grab", keep)
    config = load_bench_config(_short_config(tmp_path, 4, preset))
    outcome = run_experiment(config, RunOptions(out=tmp_path / "run", report=False, progress=False))
    assert outcome.exit_code == 0
    run = load_run(tmp_path / "run")
    assert len(run.frames) == len(grabbed) == 4 and run.config["sensor"]["read_noise_dn"] > 0
    for record, (left, right, depth) in zip(run.frames, grabbed, strict=True):
        assert record.clean["index"] == record.camera_index and record.images["left"].endswith(".png")
        np.testing.assert_array_equal(run.image(record, "left"), left)
        np.testing.assert_array_equal(run.image(record, "right"), right)
        assert not np.array_equal(run.clean_image(record, "left"), left)  # stored before the noise
        np.testing.assert_array_equal(run.depth(record), dequantize_depth(quantize_depth(depth)))
    # the twin's frames take a few tens of kilobytes (the noisy pair took 2.2 MB)
    per_frame = sum(p.stat().st_size for p in (tmp_path / "run" / "frames").glob("0*")) / len(run.frames)
    assert per_frame < 100_000, per_frame


def test_softarm_replay_gives_bit_identical_estimates(tmp_path, monkeypatch, capsys):
    config = load_bench_config(_short_config(tmp_path, 6))
    run_experiment(config, RunOptions(out=tmp_path / "run", report=False, progress=False))
    monkeypatch.chdir(tmp_path)
    assert replay_command(SimpleNamespace(run_dir=str(tmp_path / "run"), mode=None, centerline=None, out=None)) == 0
    replays = sorted((tmp_path / "runs").glob("replay_*"))
    assert len(replays) == 1 and (tmp_path / "runs" / "latest").resolve() == replays[0].resolve()
    recorded, replayed = load_run(tmp_path / "run"), load_run(tmp_path / "runs" / "latest")
    assert len(replayed.frames) == len(recorded.frames) == 6
    for a, b in zip(recorded.frames, replayed.frames, strict=True):
        one, other = a.main.to_json(), b.main.to_json()
        for key in ("timings_ms",):  # the only thing a replay may change: how long it took
            one.pop(key), other.pop(key)
        assert one == other
        np.testing.assert_array_equal(a.main.points_m, b.main.points_m)
    # the replay's records point at the original frames: its report draws them
    np.testing.assert_array_equal(replayed.image(replayed.frames[2], "left"),
                                  recorded.image(recorded.frames[2], "left"))


def test_a_new_estimator_on_the_recorded_frames_sees_the_captured_images(tmp_path):
    """The report's re-runs and the studies feed ``process`` the frames ``Run.image`` rebuilds: a fresh
    estimator on them gives what the run's estimator gave (it started cold too)."""
    config = load_bench_config(_short_config(tmp_path, 2))
    run_experiment(config, RunOptions(out=tmp_path / "run", report=False, progress=False))
    run = load_run(tmp_path / "run")
    estimator = CenterlineEstimator(run.calibration, config.estimator_config())
    for record in run.frames:
        units, unit_m = run.depth_units(record)
        capture = Capture(index=record.index, t_s=record.t_s,
                          frame=StereoFrame(run.image(record, "left"), run.image(record, "right"), record.timestamp_s,
                                            record.camera_index),
                          commanded_bar=record.commanded_bar, gt_m=record.gt_m, depth_units=units, depth_unit_m=unit_m)
        again = process(capture, {"main": estimator}, run.calibration)
        np.testing.assert_array_equal(again.main.points_m, record.main.points_m)
        assert again.main.errors == record.main.errors and again.main.qprime == record.main.qprime


# --- estimating beside the loop ----------------------------------------------------------------


def test_the_worker_handles_items_in_order_beside_the_producer_and_hands_back_its_error():
    import threading

    from bench.worker import FrameWorker

    seen, threads = [], set()
    gate = threading.Event()

    def handle(item):
        gate.wait(10)
        threads.add(threading.current_thread().name)
        seen.append(item)

    with FrameWorker(handle, depth=2, name="estimate-record") as worker:
        for item in range(3):  # one in hand, two queued: the producer goes on while the first is handled
            worker.put(item)
        assert seen == []
        gate.set()
        for item in range(3, 6):
            worker.put(item)
        worker.finish()
    assert seen == list(range(6)) and threads == {"estimate-record"}

    def fail_on_two(item):
        if item == 2:
            raise OSError(28, "No space left on device")
        seen.append(item)

    seen.clear()
    worker = FrameWorker(fail_on_two, depth=1)
    with pytest.raises(OSError, match="No space left"):
        for item in range(50):
            worker.put(item)
    worker.close()
    assert seen == [0, 1]  # nothing after the failure is handled
    worker.finish()  # the error was handed over once; closing again is harmless
    with pytest.raises(ValueError, match="depth"):
        FrameWorker(handle, depth=0)
