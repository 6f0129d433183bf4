"""The CI regression: the paper's bending experiment on the twin with 20 frames, default and paper mode.

A change that degrades the estimator or the twin fails here. The targets are the figures the
estimator meets on these 20 frames with a margin (measured when they were set; see
``REGRESSION_TARGETS``). The same run also checks the run folder, the report and a replay.
"""

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from bench.config import MODELS, load_bench_config
from bench.recording import load_run
from bench.replay import replay, replay_command, replay_estimator_config
from bench.report import write_report
from bench.run import RunOptions, run_experiment

FRAMES = 20
# Targets of the regression, on the paper's ramp (58 s, 0 -> 2.5 bar) captured in 20 frames.
# Measured on 2026-11-22 and again on 2026-12-01 (unchanged): default mode 20/20 valid, RMSE 3.60 mm,
# per axis 1.24 / 1.06 / 3.21 mm, largest point error 23.2 mm, mean tip 8.4 mm, Q' 3.25 / 4.67 / 27.9 mm;
# paper mode 14/20 valid (the six frames where the arm forms a U come back invalid: the literal
# compensation matches the wrong branch and the estimate is implausibly long), median per-frame RMSE
# 26.0 mm, pooled 30.0 mm, per axis 6.7 / 6.5 / 28.5 mm.
REGRESSION_TARGETS = {
    "default": {"valid_fraction_min": 0.95, "rmse_mm_max": 5.0, "rmse_xyz_mm_max": (2.0, 2.0, 4.5), "max_mm_max": 35.0,
                "tip_mm_max": 12.0},
    # Q' sees the tube's surface, about one radius (25 mm) in front of the axis: its z error must show that
    # offset (and nothing much more); x and y stay small.
    "default_qprime": {"xy_mm_max": (5.0, 6.5), "z_mm_band": (15.0, 40.0)},
    # The paper mode is the reproduction baseline: valid on most frames, clearly worse than the default
    # mode, within this band; its floor catches a paper mode that stopped reproducing the paper.
    "paper": {"valid_fraction_min": 0.6, "median_rmse_mm_band": (10.0, 40.0), "rmse_mm_max": 45.0},
}


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sim") / "run"
    outcome = run_experiment(load_bench_config(), RunOptions(compare=True, frames=FRAMES, out=folder, progress=False))
    return outcome


def test_the_run_completes(sim_run):
    assert sim_run.exit_code == 0 and sim_run.stopped is None
    assert sim_run.summary["frames"] == FRAMES


def test_default_mode_meets_its_accuracy_targets(sim_run):
    s, t = json.loads((sim_run.folder / "summary.json").read_text()), REGRESSION_TARGETS["default"]
    figures = {k: s[k] for k in ("valid_frames", "rmse_mm", "rmse_xyz_mm", "max_mm", "tip_mm")}
    assert s["valid_fraction"] >= t["valid_fraction_min"], figures
    assert s["rmse_mm"] <= t["rmse_mm_max"], figures
    assert all(v <= limit for v, limit in zip(s["rmse_xyz_mm"], t["rmse_xyz_mm_max"], strict=True)), figures
    assert s["max_mm"] <= t["max_mm_max"], figures
    assert s["tip_mm"] <= t["tip_mm_max"], figures


def test_default_mode_against_the_papers_qprime(sim_run):
    s, t = sim_run.summary, REGRESSION_TARGETS["default_qprime"]
    x, y, z = s["qprime_rmse_xyz_mm"]
    assert s["qprime_frames"] == s["valid_frames"]
    assert x <= t["xy_mm_max"][0] and y <= t["xy_mm_max"][1], s["qprime_rmse_xyz_mm"]
    assert t["z_mm_band"][0] <= z <= t["z_mm_band"][1], s["qprime_rmse_xyz_mm"]


def test_paper_mode_stays_in_its_band(sim_run):
    s = json.loads((sim_run.folder / "summary.json").read_text())
    paper, t = s["paper"], REGRESSION_TARGETS["paper"]
    figures = {k: paper[k] for k in ("valid_frames", "rmse_mm", "median_rmse_mm", "rmse_xyz_mm")}
    assert paper["frames"] == FRAMES
    assert paper["valid_fraction"] >= t["valid_fraction_min"], figures
    low, high = t["median_rmse_mm_band"]
    assert low <= paper["median_rmse_mm"] <= high, figures
    assert paper["rmse_mm"] <= t["rmse_mm_max"], figures
    assert paper["median_rmse_mm"] > s["median_rmse_mm"], "the paper mode should not beat the default mode"


def test_every_frame_is_recorded_with_truth_scores_and_images(sim_run):
    run = load_run(sim_run.folder)
    assert run.complete and [f.index for f in run.frames] == list(range(FRAMES))
    assert run.skipped == [] and run.summary_note is None  # every line a valid record; summary.json agrees
    schedule = run.config["schedule"]
    np.testing.assert_allclose([f.t_s for f in run.frames], np.linspace(0, 58, FRAMES), atol=1e-6)
    # t = 51.9 s (4.0 mm off at most) is refused since the twenty-third session: a restart of its tip's
    # depth ends lower in cost with the tip 11 mm away (BETTER_RESTART_TIP_M); every other frame is valid.
    assert [round(f.t_s, 1) for f in run.frames if not f.main.valid] in ([], [51.9])
    for f in run.frames:
        assert len(f.gt_m) >= 100 and np.asarray(f.gt_m).shape[1] == 3
        m = f.main
        assert {"rectify", "segment", "total"} <= set(m.timings_ms)
        if m.valid:
            assert len(m.points_m) == 20 and len(m.left_uv) == 20 and len(m.right_uv) == 20
            assert m.errors["rmse_mm"] > 0 and m.qprime["count"] > 0
        else:  # recorded with its reason, no points and no scores; the rest of the record as any frame's
            assert m.reason and len(m.points_m) == 0 and m.errors is None and m.qprime is None
        assert f.paper.mode == "paper" and f.paper.errors is not None
        assert set(f.commanded_bar) == set(run.config["valves"]["channels"])
        # the commanded pressures are the schedule's at that time; the chambers follow with the valve lag
        k = int(np.searchsorted(schedule["change_times_s"], f.t_s + 1e-9, side="right")) - 1
        for channel, level in zip(schedule["channels"], schedule["levels_bar"][k], strict=True):
            assert f.commanded_bar[channel] == pytest.approx(level)
            assert f.chamber_bar[channel] == pytest.approx(level, abs=0.03)
        assert f.commanded_bar["s1_b"] == 0.0
        left = run.image(f, "left")
        assert left is not None and left.shape == (720, 1280, 3) and run.lossless(f)
        assert run.depth(f) is not None
    # the backbone's base stays put and the tip moves as the pressure rises
    first, last = np.asarray(run.frames[0].gt_m), np.asarray(run.frames[-1].gt_m)
    assert np.linalg.norm(first[0] - last[0]) < 0.005 and np.linalg.norm(first[-1] - last[-1]) > 0.2
    assert (sim_run.folder / "calibration.toml").is_file() and (sim_run.folder / "bench.toml").is_file()


def test_report_files_exist_and_are_not_empty(sim_run):
    report = sim_run.folder / "report"
    for name in ("fig12_axis_error.png", "fig13_fps.png", "fig10c_centerlines_3d.png", "fig10ab_overlay.png",
                 "fig11_qprime.png", "overlay.mp4", "summary.md", "compensation.json"):
        assert (report / name).is_file() and (report / name).stat().st_size > 1000, name
    text = (report / "summary.md").read_text()
    assert "2.9178 / 2.3287 / 5.5122" in text and "5.5/680 = 0.81 %" in text and "with compensation" in text
    compensation = json.loads((report / "compensation.json").read_text())
    assert len(compensation["frames"]) == FRAMES  # fewer frames than [report] compensation_frames: all of them


def test_report_runs_again_on_the_folder(sim_run, capsys):
    from bench.report import report_command

    (sim_run.folder / "report" / "summary.md").unlink()
    assert report_command(SimpleNamespace(run_dir=str(sim_run.folder))) == 0
    assert (sim_run.folder / "report" / "summary.md").stat().st_size > 1000


def test_replay_reproduces_the_recorded_scores(sim_run, tmp_path):
    run = load_run(sim_run.folder)
    summary = replay(run, replay_estimator_config(run), tmp_path / "replay")
    again = load_run(tmp_path / "replay")
    assert summary["frames"] == FRAMES and again.complete
    for recorded, replayed in zip(run.frames, again.frames, strict=True):
        assert replayed.main.valid == recorded.main.valid
        np.testing.assert_array_equal(replayed.main.points_m, recorded.main.points_m)  # bit-identical
        assert replayed.main.to_json()["points_m"] == recorded.main.to_json()["points_m"]
        assert replayed.main.errors == recorded.main.errors
        assert replayed.main.qprime == recorded.main.qprime
    for key in ("rmse_mm", "rmse_xyz_mm", "max_mm", "tip_mm", "qprime_rmse_xyz_mm"):
        assert summary[key] == run.summary[key]
    assert again.image(again.frames[0], "left") is not None  # points at the original frames


def test_replay_command_in_another_mode(sim_run, tmp_path, capsys):
    args = SimpleNamespace(run_dir=str(sim_run.folder), mode="paper", centerline=None, out=str(tmp_path / "paper"))
    assert replay_command(args) == 0
    replayed = load_run(tmp_path / "paper")
    assert replayed.config["estimators"]["main"]["mode"] == "paper"
    # the paper mode replayed on the recorded frames is the paper mode the run compared
    assert replayed.summary["rmse_mm"] == pytest.approx(load_run(sim_run.folder).summary["paper"]["rmse_mm"])
    assert "replayed 20 frames" in capsys.readouterr().out
    report = write_report(tmp_path / "paper", options={"video": False, "compensation_frames": 0})
    assert (report / "fig12_axis_error.png").is_file() and not (report / "overlay.mp4").exists()


def test_a_replay_with_another_centerline_stage_says_which(sim_run, tmp_path, capsys):
    """The reported case: a replay with --centerline skeleton recorded and reported only "mode: paper"."""
    args = SimpleNamespace(run_dir=str(sim_run.folder), mode="paper", centerline="skeleton",
                           out=str(tmp_path / "skeleton"))
    assert replay_command(args) == 0
    replayed = load_run(tmp_path / "skeleton")
    assert replayed.summary["mode"] == "paper" and replayed.summary["centerline"] == "skeleton"
    report = write_report(tmp_path / "skeleton", options={"video": False, "compensation_frames": 0})
    text = (report / "summary.md").read_text()
    assert "estimator mode: **paper**, 2D centerline: **skeleton**" in text
    # a replay names the run it replayed, and claims no capture loop (reported: "loop fps" on a replay)
    assert f"- a replay of the run {sim_run.folder.resolve()}" in text and "loop fps" not in text


def test_the_run_folder_says_which_scene_and_which_arm_the_twin_showed(sim_run):
    """The reported case: a run in a custom lab scene recorded neither its preset nor its seed, and the
    estimator's arm came from its defaults, not from the twin's arm."""
    config = json.loads((sim_run.folder / "config.json").read_text())
    assert config["scene"] == {"preset": "clean", "seed": 0, "description": config["scene"]["description"],
                               "file": str(MODELS / "scene.toml")}
    main = config["estimators"]["main"]
    assert main["arm_length_m"] == pytest.approx(0.685) and main["arm_radius_m"] == pytest.approx(0.02435, abs=1e-5)
    report = write_report(sim_run.folder, options={"video": False, "compensation_frames": 0})
    text = (report / "summary.md").read_text()
    assert "- twin scene: **clean** (seed 0, " in text
    # the Q' note reads the run's own radius, and claims nothing of the paper's Q' it cannot show (reported)
    assert "(the tube's radius here: 24 mm)" in text and "in the paper as here" not in text


def test_the_run_times_its_parts(sim_run):
    bench_s = sim_run.summary["bench_s"]
    assert {"physics", "render", "estimate", "record_thread"} <= set(bench_s)
    assert all(v >= 0 and math.isfinite(v) for v in bench_s.values())
    assert bench_s["render"] > 0 and bench_s["estimate"] > 0


def test_the_disk_estimate_printed_before_a_run_matches_what_it_wrote(sim_run):
    """The estimate `softarm run` prints (and asks --yes above 2 GB on) against the bytes of this run."""
    from bench.config import RecordingConfig
    from bench.recording import frame_bytes

    written = sum(p.stat().st_size for p in (sim_run.folder / "frames").iterdir())
    written += (sim_run.folder / "frames.jsonl").stat().st_size
    estimate = FRAMES * frame_bytes(RecordingConfig(), (1280, 720), depth=True, compare=True, noise_free=True)
    assert 0.8 <= written / estimate <= 1.25, (written, estimate)
