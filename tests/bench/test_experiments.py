"""Experiments as pure schedules, and the bench config sections that describe them."""

import dataclasses
import textwrap
from pathlib import Path

import numpy as np
import pytest

from bench.config import DEFAULT_CONFIG, ConfigError, ExperimentConfig, load_bench_config
from bench.experiments import make_schedule, staircase

REPO = DEFAULT_CONFIG.parents[1]


def test_default_experiment_is_the_papers_bending_ramp():
    """Section 5.2: s1_a, s2_a, s3 from 0 to 2.5 bar in 0.05 bar steps over 58 s, 690 frames."""
    schedule = make_schedule(load_bench_config().experiment)
    assert schedule.channels == ("s1_a", "s2_a", "s3")
    np.testing.assert_allclose(schedule.levels_bar[:, 0], np.arange(51) * 0.05, atol=1e-9)
    assert np.all(schedule.levels_bar == schedule.levels_bar[:, :1])  # the three rise together
    assert schedule.duration_s == 58.0 and schedule.frames == 690
    np.testing.assert_allclose(np.diff(schedule.change_times_s), 58.0 / 51)  # equal holds
    assert schedule.capture_times_s[0] == 0.0 and schedule.capture_times_s[-1] == 58.0
    assert schedule.command_at(0.0) == {"s1_a": 0.0, "s2_a": 0.0, "s3": 0.0}
    assert schedule.command_at(58.0) == {"s1_a": 2.5, "s2_a": 2.5, "s3": 2.5}
    assert schedule.command_at(58.0 / 51 * 7 + 1e-6)["s3"] == pytest.approx(0.35, abs=1e-12)
    assert repr(float(schedule.levels_bar[7, 0])) == "0.35"  # rounded: no 0.35000000000000003 in the records


def test_frames_option_spreads_captures_over_the_same_experiment():
    config = load_bench_config().experiment
    full, quick = make_schedule(config), make_schedule(config, frames=20)
    np.testing.assert_array_equal(quick.levels_bar, full.levels_bar)
    np.testing.assert_allclose(quick.capture_times_s, np.linspace(0, 58, 20))
    with pytest.raises(ValueError, match="--frames: expected at least one frame, got 0"):
        make_schedule(config, frames=0)


def test_levels_are_piecewise_constant_between_changes():
    schedule = make_schedule(ExperimentConfig(max_bar=1.0, step_bar=0.25, duration_s=10.0, frames=5))
    np.testing.assert_allclose(schedule.change_times_s, [0, 2, 4, 6, 8])
    for t, level in [(0.0, 0.0), (1.99, 0.0), (2.0, 0.25), (5.0, 0.5), (9.99, 1.0), (10.0, 1.0)]:
        assert schedule.levels_at(t)[0] == pytest.approx(level), t


def test_staircase_keeps_the_maximum_off_the_grid():
    np.testing.assert_allclose(staircase(0.0, 1.0, 0.3), [0, 0.3, 0.6, 0.9, 1.0])
    np.testing.assert_allclose(staircase(0.5, 1.0, 0.25), [0.5, 0.75, 1.0])


def test_step_sweep_and_random_experiments():
    base = ExperimentConfig(channels=("s1_a", "s2_b"), max_bar=1.0, step_bar=0.5, duration_s=12.0, frames=7)
    step = make_schedule(dataclasses.replace(base, kind="step", step_at_s=3.0))
    np.testing.assert_allclose(step.change_times_s, [0, 3])
    np.testing.assert_allclose(step.levels_bar, [[0, 0], [1, 1]])

    sweep = make_schedule(dataclasses.replace(base, kind="sweep"))
    # each channel in turn goes 0 -> 0.5 -> 1 -> 0.5 -> 0 while the other holds the start level
    np.testing.assert_allclose(sweep.levels_bar[:, 0], [0, 0.5, 1, 0.5, 0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(sweep.levels_bar[:, 1], [0, 0, 0, 0, 0, 0, 0.5, 1, 0.5, 0])
    assert sweep.change_times_s[5] == pytest.approx(6.0)  # the second channel starts half way

    fine = dataclasses.replace(base, kind="random", step_bar=0.05, hold_s=0.5, seed=7)
    random = make_schedule(fine)
    again, other = make_schedule(fine), make_schedule(dataclasses.replace(fine, seed=8))
    np.testing.assert_array_equal(random.levels_bar, again.levels_bar)  # seeded
    assert not np.array_equal(random.levels_bar, other.levels_bar)
    assert len(random.change_times_s) == 24 and np.all(random.levels_bar[0] == 0)  # frame 0 at rest
    on_grid = random.levels_bar / 0.05
    np.testing.assert_allclose(on_grid, np.round(on_grid), atol=1e-6)
    assert random.levels_bar.min() >= 0 and random.levels_bar.max() <= 1.0
    assert len(np.unique(random.levels_bar)) > 8  # really random, not a constant


# --- config sections --------------------------------------------------------------------------


def test_default_config_sections():
    config = load_bench_config()
    assert config.experiment == ExperimentConfig()
    assert config.estimator_config().mode == "default"
    assert config.estimator_config(mode="paper").compensation == "nearest"  # the paper's preset follows the mode
    assert config.recording.root is None and config.recording.runs_root() == Path.cwd() / "runs"
    assert config.recording.lossless_frames and config.report.enabled


def test_rig_config_runs_the_same_experiment_on_the_rig():
    sim, rig = load_bench_config(), load_bench_config(REPO / "models" / "bench_rig.toml")
    assert rig.backend == "rig" and rig.rig is not None
    assert dataclasses.replace(rig.experiment, lead_in_s=0.0) == sim.experiment
    # the same estimator, told on the rig what the twin's arm file tells it on the twin (the connectors'
    # radius, that the arm hangs from a mount, what the sections can reach: rounded outwards)
    told = sim.estimator_config()
    assert dict(rig.estimator) == {**sim.estimator, "connector_radius_m": told.connector_radius_m,
                                   "base_mount": told.base_mount,
                                   "section_lengths_m": rig.estimator["section_lengths_m"]}
    assert np.allclose(rig.estimator["section_lengths_m"], told.section_lengths_m, atol=0.0011)
    assert rig.rig.valves == sim.rig.valves


def test_estimator_mode_override_keeps_the_files_other_keys(tmp_path):
    path = tmp_path / "bench.toml"
    path.write_text('[estimator]\nmode = "default"\ncompensation = "none"\nn_points = 25\n')
    config = load_bench_config(path)
    paper = config.estimator_config(mode="paper")
    assert (paper.mode, paper.compensation, paper.n_points, paper.som_input) == ("paper", "none", 25, "contour")


def test_a_key_of_another_kind_does_not_refuse_a_schedule(tmp_path):
    """The reported case: a 1 s ramp was refused over step_at_s (default 1 s), which only the step uses."""
    path = tmp_path / "bench.toml"
    path.write_text('[experiment]\nkind = "ramp"\nduration_s = 1.0\nframes = 10\n')
    assert load_bench_config(path).experiment.duration_s == 1.0


@pytest.mark.parametrize(("text", "message"), [
    ("[experiment]\nkind = \"ramps\"\n", r"\[experiment\] kind: expected one of 'ramp', 'step', 'sweep', 'random'"),
    ("[experiment]\nframs = 3\n", r"unknown key \[experiment\] frams; did you mean 'frames'\?"),
    ("[experiment]\nmax_bar = \"2.5\"\n", r"\[experiment\] max_bar: expected a number, got '2.5'"),
    ("[experiment]\nmax_bar = 0.0\n", r"\[experiment\] max_bar: expected 0 <= start_bar < max_bar"),
    ("[experiment]\nchannels = []\n", r"\[experiment\] channels: expected at least one valve name"),
    ("[experiment]\nchannels = [\"s3\", \"s3\"]\n", r"\[experiment\] channels: a valve is listed twice"),
    ("[experiment]\nstep_bar = 3.0\n", r"\[experiment\] step_bar: expected a step in \(0, max_bar - start_bar\]"),
    ("[experiment]\nframes = 0\n", r"\[experiment\] frames: expected at least one frame"),
    ("[experiment]\nkind = \"step\"\nduration_s = 1.0\nframes = 10\n", r"\[experiment\] step_at_s: expected a time"),
    ("[estimator]\nmdoe = \"paper\"\n", r"\[estimator\]: unknown key 'mdoe'"),
    ("[estimator]\nmode = \"fast\"\n", r"\[estimator\]: mode: expected one of"),
    ("[estimator]\nn_points = \"20\"\n", r"\[estimator\]: n_points: expected an integer"),
    ("[estimator]\nsom_alpha0 = \"0.2\"\n", r"\[estimator\]: som_alpha0: expected a number in \(0, 1\], got '0.2'"),
    ("[estimator]\nsom_alpha0 = true\n", r"\[estimator\]: som_alpha0: expected a number in \(0, 1\], got True"),
    ("[estimator]\narm_radius_m = inf\n", r"\[estimator\]: arm_radius_m: expected a positive number"),
    ("[recording]\npng_compression = 12\n", r"\[recording\] png_compression: expected a zlib level 0-9"),
    ("[recording]\nlossless = true\n", r"unknown key \[recording\] lossless; did you mean 'lossless_frames'\?"),
    ("[report]\nvideo_scale = 3\n", r"\[report\] video_scale: expected a factor in \[0.05, 1\]"),
])
def test_bad_sections_name_the_file_and_the_key(tmp_path, text, message):
    path = tmp_path / "bench.toml"
    path.write_text(textwrap.dedent(text))
    with pytest.raises(ConfigError, match=message) as error:
        load_bench_config(path)
    assert str(path) in str(error.value)
