"""The run folder: written frame by frame, read back exactly, tolerant of a killed run; run summaries."""

import json
import math

import numpy as np
import pytest

from bench.config import RecordingConfig
from bench.frame_record import record_problem
from bench.recording import FRAMES_FILE, SUMMARY_FILE, RunFolderError, RunWriter, jsonable, load_run, read_frames
from bench.scoring import DEPTH_UNIT_M, dequantize_depth, pooled_rmse, quantize_depth, summarize, summary_table
from tests.fakes import small_calibration


def noisy_pair(seed: int, shape=(48, 64, 3)):
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, shape, dtype=np.uint8), rng.integers(0, 256, shape, dtype=np.uint8)


def frame_record(index: int, rmse: float, valid: bool = True) -> dict:
    errors = {"rmse_mm": rmse, "rmse_x_mm": rmse / 2, "rmse_y_mm": rmse / 3, "rmse_z_mm": rmse, "max_mm": 2 * rmse,
              "tip_mm": rmse + 1, "base_mm": 1.0, "arc_rmse_mm": rmse, "length_error_mm": -1.0}
    points = [[0.0, 0.1 * k, 1.0] for k in range(3)] if valid else []
    uv = [[32.0, 10.0 + 10 * k] for k in range(3)] if valid else []
    return {"index": index, "t_s": 0.5 * index, "timestamp_s": 0.5 * index, "camera_index": index,
            "commanded_bar": {"s1_a": 0.05 * index}, "chamber_bar": None, "valid": valid,
            "reason": "" if valid else "no arm found in the left image",
            "points_m": points, "left_uv": uv, "right_uv": uv,
            "timings_ms": {"total": 50.0 + index, "segment": 10.0}, "misalignment_px": 0.5 if valid else None,
            "errors": errors if valid else None,
            "qprime": ({"x_mm": 1.0, "y_mm": 2.0, "z_mm": 20.0, "count": 3, "rmse_mm": math.sqrt(405)}
                       if valid else None),
            "qprime_m": [[0.0, 0.1 * k, 0.98] for k in range(3)] if valid else None,
            "gt_m": [[0.0, 0.0, 1.0], [0.0, 0.3, 1.0], [0.0, 0.6, 1.0]], "bench_ms": {"render": 5.0}}


@pytest.fixture
def written_run(tmp_path):
    folder = tmp_path / "run"
    writer = RunWriter(folder, RecordingConfig(png_compression=3))
    writer.write_calibration(small_calibration())
    writer.write_config({"backend": "sim", "estimators": {"main": {"mode": "default"}}})
    pairs = [noisy_pair(i) for i in range(4)]
    depth = np.full((48, 64), np.inf, np.float32)
    depth[10:20, 30:40] = 1.23456
    for i, (left, right) in enumerate(pairs):
        writer.submit(frame_record(i, 1.0 + i, valid=i != 2), left, right, quantize_depth(depth) if i == 0 else None)
    writer.finish({"frames": 4, "note": math.nan})
    return folder, pairs, depth


def test_round_trip_is_exact(written_run):
    folder, pairs, depth = written_run
    run = load_run(folder)
    assert run.complete and run.skipped_lines == 0 and len(run.frames) == 4
    assert [f.index for f in run.frames] == [0, 1, 2, 3]
    for record, (left, right) in zip(run.frames, pairs, strict=True):
        np.testing.assert_array_equal(run.image(record, "left"), left)  # PNG: lossless
        np.testing.assert_array_equal(run.image(record, "right"), right)
        assert record.write_ms >= 0
    back = run.depth(run.frames[0])
    assert back.dtype == np.float32 and np.all(np.isinf(back[:10]))
    np.testing.assert_allclose(back[10:20, 30:40], 1.2346, atol=1e-6)  # 0.1 mm steps
    assert run.depth(run.frames[1]) is None
    assert json.loads((folder / SUMMARY_FILE).read_text()) == {"frames": 4, "note": None}  # NaN as null: strict JSON
    # the keys the stored summary lacks are filled in from the frames; it agreed with them, so no note
    assert run.summary["note"] is None and run.summary["valid_frames"] == 3 and run.summary_note is None
    assert run.calibration.image_size == (64, 48)
    assert run.frames[2].main.valid is False and run.frames[2].main.errors is None


def test_every_line_is_on_disk_before_the_next_frame_is_taken(tmp_path):
    writer = RunWriter(tmp_path / "run", RecordingConfig())
    left, right = noisy_pair(0)
    writer.submit(frame_record(0, 1.0), left, right)
    writer.submit(frame_record(1, 1.0), left, right)  # waits for frame 0
    lines = (tmp_path / "run" / FRAMES_FILE).read_text().splitlines()
    assert len(lines) >= 1 and json.loads(lines[0])["index"] == 0
    assert (tmp_path / "run" / "frames" / "000000_left.png").is_file()
    writer.close()
    assert len((tmp_path / "run" / FRAMES_FILE).read_text().splitlines()) == 2
    assert not list((tmp_path / "run" / "frames").glob("*.tmp*"))  # written under temporary names, renamed


def test_a_killed_run_loads_without_its_cut_short_last_line(written_run):
    folder, _, _ = written_run
    (folder / SUMMARY_FILE).unlink()
    with open(folder / FRAMES_FILE, "a") as f:
        f.write('{"index": 4, "t_s": 2.0, "points_m": [[0.1, 0.2')  # SIGKILL mid-line
    run = load_run(folder)
    assert not run.complete and run.skipped_lines == 1 and len(run.frames) == 4
    assert run.summary["stopped"] == "killed (no summary.json)"
    assert run.summary["frames"] == 4 and run.summary["valid_frames"] == 3


def test_an_unreadable_summary_is_recomputed_from_the_frames(written_run):
    folder, _, _ = written_run
    (folder / SUMMARY_FILE).write_text('{"frames": 4, "rmse_')  # cut short (a full disk, an editor)
    run = load_run(folder)
    assert not run.complete and len(run.frames) == 4
    assert run.summary["stopped"].startswith("summary.json unreadable")
    assert run.summary["frames"] == 4 and run.summary["valid_frames"] == 3


def test_jpeg_frames_are_marked_lossy(tmp_path):
    writer = RunWriter(tmp_path / "run", RecordingConfig(lossless_frames=False))
    writer.write_config({})
    left, right = noisy_pair(1)
    writer.submit(frame_record(0, 1.0), left, right)
    writer.finish({})
    run = load_run(tmp_path / "run")
    assert run.frames[0].images["left"].endswith(".jpg") and not run.lossless(run.frames[0])
    assert run.image(run.frames[0], "left").shape == left.shape


def test_not_a_run_folder_and_no_overwrite(tmp_path, written_run):
    with pytest.raises(RunFolderError, match="not a run folder"):
        load_run(tmp_path)
    folder, _, _ = written_run
    with pytest.raises(RunFolderError, match="already holds a run"):
        RunWriter(folder, RecordingConfig())
    started = tmp_path / "started"  # killed between config.json and frames.jsonl: still not overwritten
    started.mkdir()
    (started / "config.json").write_text("{}")
    with pytest.raises(RunFolderError, match=r"already holds a run \(config.json\)"):
        RunWriter(started, RecordingConfig())


def test_read_frames_skips_and_names_every_line_that_is_not_a_frame(tmp_path):
    """A partial record such as {"index": 10} (a KeyError 't_s' in the report before), a wrong type, a
    repeated index and a cut-short last line: each skipped, by line number and why; blank lines ignored."""
    path = tmp_path / FRAMES_FILE
    lines = [json.dumps(frame_record(0, 1.0)), "", "[1, 2]", "not json", json.dumps(frame_record(1, 1.0)),
             '{"index": 10}', json.dumps({**frame_record(2, 1.0), "points_m": "x"}),
             json.dumps({**frame_record(3, 1.0), "errors": {"rmse_mm": 1.0}}), json.dumps(frame_record(1, 9.0)),
             json.dumps({**frame_record(4, 1.0), "index": True}), json.dumps(frame_record(5, 1.0))[:40]]
    path.write_text("\n".join(lines))  # no end of line after the last: cut short by a kill
    records, skipped = read_frames(path)
    assert [r.index for r in records] == [0, 1] and records[1].main.errors["rmse_mm"] == 1.0  # the first index 1
    assert [str(s) for s in skipped] == [
        "line 3: not a frame record: expected a JSON object, got [1, 2] (a list)",
        "line 4: not JSON (Expecting value: line 1 column 1 (char 0))",
        "line 6: not a frame record: missing key 't_s'",
        "line 7: not a frame record: points_m: expected a list of [x, y, z], got 'x' (a string)",
        "line 8: not a frame record: errors: missing key 'rmse_x_mm'",
        "line 9: index 1 again (first on line 5); the first is kept",
        "line 10: not a frame record: index: expected an integer >= 0, got True (a boolean)",
        "line 11: cut short (no end of line: the run was killed while writing it)",
    ]


def test_every_record_the_run_writes_passes_the_schema(written_run):
    folder, _, _ = written_run
    run = load_run(folder)
    assert len(run.frames) == 4 and run.skipped == []
    assert all(record_problem(f.to_json()) is None for f in run.frames)
    first = run.frames[0].to_json()
    assert record_problem({**first, "paper": {**first, "mode": "paper"}}) is None
    assert record_problem({**first, "paper": {**first, "mode": "paper", "valid": "yes"}}) == (
        "paper: valid: expected true or false, got 'yes' (a string)")


# --- scoring --------------------------------------------------------------------------------


def test_depth_quantization_round_trip():
    depth = np.array([[np.inf, 0.0, -1.0, np.nan], [0.00004, 1.00004, 6.5535, 7.0]], np.float32)
    units = quantize_depth(depth)
    assert units.dtype == np.uint16
    np.testing.assert_array_equal(units, [[0, 0, 0, 0], [0, 10000, 65535, 0]])
    back = dequantize_depth(units)
    assert np.isinf(back[0]).all() and back[1, 1] == pytest.approx(1.0)
    assert DEPTH_UNIT_M == 1e-4


def test_summary_pools_frames_like_table_2():
    records = [frame_record(i, rmse) for i, rmse in enumerate([1.0, 2.0, 3.0])] + [frame_record(3, 9.0, valid=False)]
    s = summarize(records)
    assert s["frames"] == 4 and s["valid_frames"] == 3 and s["scored_frames"] == 3
    assert s["rmse_mm"] == pytest.approx(math.sqrt((1 + 4 + 9) / 3))
    assert s["rmse_xyz_mm"][0] == pytest.approx(math.sqrt((0.25 + 1 + 2.25) / 3))
    assert s["max_mm"] == 6.0 and s["tip_mm"] == pytest.approx(3.0) and s["tip_max_mm"] == 4.0
    assert s["qprime_rmse_xyz_mm"] == pytest.approx([1.0, 2.0, 20.0])
    assert s["fps"] == pytest.approx(1000 / 51.5)  # the median frame
    assert s["arm_length_mm"] == pytest.approx(600.0)
    assert s["max_axis_rmse_mm"] == s["rmse_xyz_mm"][2]
    assert s["invalid_reasons"] == {"no arm found in the left image": 1}
    assert pooled_rmse([3.0, None, math.nan, 4.0]) == pytest.approx(math.sqrt(12.5))
    lines = summary_table(s, markdown=True)
    assert any("2.9178 / 2.3287 / 5.5122" in line for line in lines)
    assert any("5.5/680 = 0.81 %" in line for line in lines)
    assert json.loads(json.dumps(jsonable(s)))  # strict JSON


def test_summary_of_nothing_scored_says_so():
    records = [frame_record(0, 1.0, valid=False)]
    s = summarize(records)
    assert s["valid_frames"] == 0 and math.isnan(s["rmse_mm"]) and math.isnan(s["max_axis_rmse_mm"])
    assert any("n/a" in line for line in summary_table(s))
