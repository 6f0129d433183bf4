"""Other experiment kinds on the twin: a quasi-static step and a seeded random sequence."""

import textwrap

import numpy as np
import pytest

from bench.config import DEFAULT_CONFIG, load_bench_config
from bench.recording import load_run
from bench.run import RunOptions, run_experiment


def config_file(folder, experiment: str):
    path = folder / "bench.toml"
    path.write_text(textwrap.dedent(f"""\
        [sim]
        twin = "{DEFAULT_CONFIG.parent / 'twin.toml'}"
        [experiment]
        """) + textwrap.dedent(experiment) + "[recording]\nlossless_frames = false\ndepth = false\n")
    return load_bench_config(path)


def test_quasi_static_step_settles_before_each_capture(tmp_path):
    config = config_file(tmp_path, """\
        kind = "step"
        channels = ["s2_a"]
        max_bar = 1.5
        step_at_s = 1.0
        duration_s = 2.0
        frames = 3
        quasi_static = true
        """)
    outcome = run_experiment(config, RunOptions(out=tmp_path / "run", report=False, progress=False))
    assert outcome.exit_code == 0
    run = load_run(tmp_path / "run")
    assert [f.commanded_bar["s2_a"] for f in run.frames] == [0.0, 1.5, 1.5]
    # the clock of the schedule stood still while the arm settled after the step: simulated time ran ahead
    ahead = [f.sim_time_s - f.t_s for f in run.frames]
    assert ahead[1] > ahead[0] + 0.05 and ahead[2] == pytest.approx(ahead[1], abs=1e-6)
    assert run.frames[1].chamber_bar["s2_a"] == pytest.approx(1.5, abs=1e-3)  # at rest: the chamber is there
    tip = [np.asarray(f.gt_m)[-1] for f in run.frames]
    assert np.linalg.norm(tip[1] - tip[0]) > 0.05 and np.linalg.norm(tip[2] - tip[1]) < 1e-3  # moved, then still
    assert run.frames[0].images["left"].endswith(".jpg") and run.frames[0].depth is None


def test_random_sequence_commands_the_seeded_levels(tmp_path):
    config = config_file(tmp_path, """\
        kind = "random"
        channels = ["s1_a", "s3"]
        max_bar = 2.0
        step_bar = 0.25
        hold_s = 0.5
        duration_s = 2.0
        frames = 5
        seed = 3
        """)
    outcome = run_experiment(config, RunOptions(out=tmp_path / "run", report=False, progress=False))
    assert outcome.exit_code == 0
    run = load_run(tmp_path / "run")
    levels = np.asarray(run.config["schedule"]["levels_bar"])
    for f, k in zip(run.frames, [0, 1, 2, 3, 3], strict=True):  # captures at 0, 0.5, 1, 1.5, 2 s
        assert [f.commanded_bar["s1_a"], f.commanded_bar["s3"]] == pytest.approx(levels[k])
    assert levels.max() > 0 and all(f.commanded_bar["s2_a"] == 0.0 for f in run.frames)


def test_per_section_sweep_drives_one_channel_at_a_time(tmp_path):
    config = config_file(tmp_path, """\
        kind = "sweep"
        channels = ["s1_a", "s2_a"]
        max_bar = 1.0
        step_bar = 0.5
        duration_s = 2.0
        frames = 5
        """)
    outcome = run_experiment(config, RunOptions(out=tmp_path / "run", report=False, progress=False))
    assert outcome.exit_code == 0
    run = load_run(tmp_path / "run")
    # s1_a rises and falls over the first second while s2_a holds 0; then s2_a does the same
    commanded = [(f.commanded_bar["s1_a"], f.commanded_bar["s2_a"]) for f in run.frames]
    assert commanded == [(0.0, 0.0), (1.0, 0.0), (0.0, 0.0), (0.0, 1.0), (0.0, 0.0)]
    tips = [np.asarray(f.gt_m)[-1] for f in run.frames]
    assert np.linalg.norm(tips[1] - tips[0]) > 0.01 and np.linalg.norm(tips[3] - tips[0]) > 0.01
    assert all(f.main.valid for f in run.frames)
