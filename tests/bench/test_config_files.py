"""The config files and where things go: one reader and one error type for every file, a rig config
holding only what differs (``base``), clamp_tolerance reaching the valve banks, ``softarm --version``,
runs under the working directory and ``runs/latest``."""

import os
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

import bench.recording
from bench.cli import main
from bench.config import MODELS, ConfigError, load_bench_config
from bench.factory import serial_valves
from bench.recording import LATEST, point_latest, resolve_run_folder
from bench.rig_check import rig_command
from estimator.calibration import CalibrationFileError
from estimator.config_file import ConfigFileError, TableReader, integer
from tests.hardware.polling import wait_until
from twin.params import ArmParams, ParamsFileError
from twin.twin import TwinConfig

# --- one reader, one error type -------------------------------------------------------------


def test_every_file_raises_the_one_config_error(tmp_path):
    import twin.rig

    assert twin.rig.ConfigFileError is ConfigFileError and ConfigError is ConfigFileError
    assert issubclass(CalibrationFileError, ConfigFileError) and issubclass(ParamsFileError, ConfigFileError)
    broken = tmp_path / "broken.toml"
    broken.write_text("[x\n")
    loaders = [load_bench_config, TwinConfig.load, twin.rig.StereoRig.load, ArmParams.load,
               lambda p: __import__("estimator").StereoCalibration.load(p)]
    for load in loaders:
        with pytest.raises(ConfigFileError, match=rf"{broken}: not a TOML .*file: not valid TOML"):
            load(broken)


def test_the_reader_names_the_file_and_the_key_and_suggests_the_closest_key(tmp_path):
    path = tmp_path / "x.toml"
    reader = TableReader(path, {"render": {"sed": 1, "tube_sides": 4.5}})
    render = reader.sub("render")
    with pytest.raises(ConfigFileError, match=rf"^{path}: key \[render\] tube_sides: expected an integer, got 4.5$"):
        render.take("tube_sides", integer(8, 512))
    render.take("seed", integer(0, 9), 0)
    with pytest.raises(ConfigFileError, match=rf"^{path}: unknown key \[render\] sed; did you mean 'seed'\?"):
        render.done()
    with pytest.raises(ConfigFileError, match=rf"^{path}: missing table \[physics\]$"):
        reader.sub("physics")
    dotted = TableReader(path, {"section": [{"n": 1}]}, dotted=True)
    (section,) = dotted.tables("section")
    with pytest.raises(ConfigFileError, match=rf"^{path}: missing key 'section\[0\].m'$"):
        section.take("m", integer(0, 9))


# --- bench_rig.toml: what differs from bench.toml, nothing else -------------------------------------------


def test_the_rig_config_holds_only_what_differs_from_bench_toml():
    data = tomllib.loads((MODELS / "bench_rig.toml").read_text())
    # (the connectors' radius, the mount: on the twin the estimator reads them from the arm file, on the
    # rig from here)
    assert data == {"base": "bench.toml", "backend": "rig", "experiment": {"lead_in_s": 2.0},
                    "estimator": {"connector_radius_m": 0.032, "base_mount": True,
                                  "section_lengths_m": [[0.148, 0.230], [0.231, 0.280], [0.223, 0.251]]}}
    sim, rig = load_bench_config(), load_bench_config(MODELS / "bench_rig.toml")
    assert rig.rig == sim.rig and rig.recording == sim.recording and rig.report == sim.report


def test_the_random_config_drives_every_valve_and_changes_nothing_else():
    """bench_random.toml: the shapes the ramp never reaches (sections bent different ways), on the same
    twin, estimator and limits."""
    data = tomllib.loads((MODELS / "bench_random.toml").read_text())
    assert set(data) == {"base", "experiment"} and data["base"] == "bench.toml"
    sim, other = load_bench_config(), load_bench_config(MODELS / "bench_random.toml")
    assert other.experiment.kind == "random" and set(other.experiment.channels) == set(sim.rig.valves.channels)
    assert other.experiment.max_bar <= sim.rig.valves.max_pressure_bar
    assert (other.backend, other.sim, other.estimator, other.rig) == (sim.backend, sim.sim, sim.estimator, sim.rig)


def test_a_base_is_merged_table_by_table_and_keeps_its_own_relative_paths(tmp_path):
    (tmp_path / "lab").mkdir()
    base = tmp_path / "lab" / "base.toml"
    base.write_text('[sim]\ntwin = "my_twin.toml"\n[experiment]\nframes = 12\nmax_bar = 1.0\n'
                    '[rig.camera]\nsource = "session"\ncalibration = "calib.toml"\n')
    mine = tmp_path / "mine.toml"
    mine.write_text('base = "lab/base.toml"\n[experiment]\nframes = 7\n[rig.camera]\nfps = 30\n')
    config = load_bench_config(mine)
    assert config.path == mine.resolve()
    assert (config.experiment.frames, config.experiment.max_bar) == (7, 1.0)
    assert config.sim.twin == tmp_path / "lab" / "my_twin.toml"  # the base's path, against the base's folder
    assert config.rig.camera.source == tmp_path / "lab" / "session" and config.rig.camera.fps == 30


def test_a_channel_map_replaces_its_bases_whole(tmp_path):
    """Reported: a file mapping two valves kept the base's seven too, and the clash named this file for a valve
    it never wrote ("s1_a and s1_b both use board channel 1"). Other tables still merge key by key."""
    mine = tmp_path / "mine.toml"
    mine.write_text(f'base = "{MODELS / "bench_rig.toml"}"\n[rig.valves]\nmax_pressure_bar = 2.0\n'
                    '[rig.valves.channels]\ns1_a = 0\nvalve_b = 1\n')
    valves = load_bench_config(mine).rig.valves
    assert dict(valves.channels) == {"s1_a": 0, "valve_b": 1} and valves.max_pressure_bar == 2.0
    assert valves.port == load_bench_config(MODELS / "bench_rig.toml").rig.valves.port  # the rest merged


def test_a_bad_base_is_named_by_the_file_that_holds_the_error(tmp_path):
    base = tmp_path / "base.toml"
    base.write_text("[experiment]\nframs = 3\n")
    mine = tmp_path / "mine.toml"
    mine.write_text('base = "base.toml"\n')
    with pytest.raises(ConfigError, match=rf"^{base}: unknown key \[experiment\] frams; did you mean 'frames'"):
        load_bench_config(mine)
    mine.write_text('base = "nowhere.toml"\n')
    with pytest.raises(ConfigError, match=rf"^{mine}: key base: .*nowhere.toml: config file not found"):
        load_bench_config(mine)
    base.write_text('base = "mine.toml"\n')
    mine.write_text('base = "base.toml"\n')
    with pytest.raises(ConfigError, match=r"key base: .*mine.toml leads back to this file \(a cycle: "):
        load_bench_config(mine)
    mine.write_text("base = 3\n")
    with pytest.raises(ConfigError, match=r"key base: expected the config file this one changes, got 3"):
        load_bench_config(mine)


# --- clamp_tolerance reaches the valve banks ------------------------------------------------------


def test_clamp_tolerance_of_rig_valves_reaches_the_serial_bank(tmp_path):
    path = tmp_path / "bench.toml"
    path.write_text('[rig.camera]\nsource = 0\ncalibration = "x.conf"\nfps = 30\n'
                    '[rig.valves]\nport = "loop://"\nclamp = true\nclamp_tolerance = 0.3\n')
    valves_config = load_bench_config(path).rig.valves
    assert valves_config.clamp_tolerance == 0.3
    assert serial_valves(valves_config).clamp_tolerance_bar == pytest.approx(0.3 * 2.5)
    assert load_bench_config().rig.valves.clamp_tolerance == 0.1  # bench.toml writes the default
    path.write_text(path.read_text().replace("0.3", "0.9"))
    with pytest.raises(ConfigError, match=r"\[rig.valves\] clamp_tolerance: expected a fraction of max_pressure_bar "
                                          r"in \[0, 0.5\], got 0.9"):
        load_bench_config(path)


def test_clamp_tolerance_of_twin_toml_reaches_the_sim_bank(tmp_path):
    for name in ("twin.toml", "arm.toml", "camera.toml", "scene.toml"):
        (tmp_path / name).write_text((MODELS / name).read_text())
    path = tmp_path / "twin.toml"
    path.write_text(path.read_text().replace("clamp = false", "clamp = true").replace("clamp_tolerance = 0.1",
                                                                                      "clamp_tolerance = 0.2"))
    config = TwinConfig.load(path)
    assert config.clamp_pressures and config.clamp_tolerance == 0.2
    from twin import Twin

    twin = Twin.from_config(path)  # the twin builds its own bank from the file (not this test)
    try:
        assert twin.valves.clamp_tolerance_bar == pytest.approx(0.2 * twin.sim.max_pressure_bar)
    finally:
        twin.close()
    path.write_text(path.read_text().replace("clamp_tolerance = 0.2", "clamp_tolerance = 2"))
    with pytest.raises(ConfigFileError, match=r"key \[valves\] clamp_tolerance: expected a number in \[0.0, 0.5\]"):
        TwinConfig.load(path)


# --- rig check: the board's line-noise count -----------------------------------------------------------


def test_rig_check_prints_the_boards_unreadable_frames(tmp_path, zed_conf_dir, board, capsys):
    import numpy as np
    import serial

    from tests.bench.test_factory import write_config
    from tests.fakes import write_side_by_side_video

    write_side_by_side_video(tmp_path / "zed.mkv", [np.full((720, 2560, 3), 90, np.uint8)] * 2)
    path = write_config(tmp_path, backend="sim", port=board.port, source="zed.mkv",
                        calibration=str(zed_conf_dir / "SN1010.conf"))
    with serial.Serial(board.port, timeout=0.1) as line:  # line noise: three lines the board cannot read
        line.write(b"%%noise\n#garbled 12\n~~\n")
        line.flush()
        wait_until(lambda: board.unreadable_frames >= 3, timeout_s=5.0)
        time.sleep(0.1)
        line.reset_input_buffer()
    assert rig_command(type("Args", (), {"config": str(path)})()) == 0
    out = capsys.readouterr().out
    assert f"unreadable frames (line noise) since the board started: {board.unreadable_frames}" in out, out
    # the recording is grey: said before a run finds no arm in any frame (reported)
    assert "warning: the frame has no colour" in out
    assert board.unreadable_frames >= 3


# --- softarm --version, runs/ and runs/latest ----------------------------------------------------------


def test_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"softarm {version('softarm-twin')}"


def test_latest_points_to_the_newest_run_and_falls_back_to_a_text_file(tmp_path, monkeypatch):
    runs = tmp_path / "runs"
    first, second = runs / "2026-01-01_000000", runs / "2026-01-01_000001"
    for folder in (first, second):
        folder.mkdir(parents=True)
    point_latest(first)
    assert (runs / LATEST).is_symlink() and os.readlink(runs / LATEST) == first.name  # relative: the folder can move
    point_latest(second)
    assert resolve_run_folder(runs / LATEST) == second and (runs / LATEST / ".").resolve() == second.resolve()

    def no_links(*args, **kwargs):
        raise OSError("symbolic links are not supported here")

    monkeypatch.setattr(bench.recording.os, "symlink", no_links)
    point_latest(first)
    latest = runs / LATEST
    assert latest.is_file() and not latest.is_symlink() and latest.read_text().strip() == first.name
    assert resolve_run_folder(latest) == first
    assert not list(runs.glob(".latest*"))  # no temporary left behind


def test_runs_go_under_the_working_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    root = load_bench_config().recording.runs_root()
    assert root == tmp_path / "runs" and Path.cwd() == tmp_path


def test_the_wheel_ships_the_models_and_nothing_finds_them_by_the_checkout():
    """`pip install .` must work from any folder: models/ is a package whose TOML files are package data,
    read through importlib.resources, never through the checkout's layout (``parents[1] / "models"``)."""
    from importlib.resources import files

    repo = Path(__file__).resolve().parents[2]
    project = tomllib.loads((repo / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "models" in project["packages"]["find"]["include"] and project["package-data"]["models"] == ["*.toml"]
    shipped = sorted(p.name for p in (repo / "models").glob("*.toml"))
    assert {"arm.toml", "bench.toml", "bench_rig.toml", "camera.toml", "scene.toml", "twin.toml"} <= set(shipped)
    assert all((files("models") / name).is_file() for name in shipped)
    for package in ("estimator", "hardware", "twin", "bench"):
        for path in (repo / package).rglob("*.py"):
            text = path.read_text()
            assert '"models"' not in text.replace('files("models")', ""), f"{path} finds models/ by the checkout"


def test_on_the_twin_the_estimator_is_told_the_twins_arm(tmp_path):
    """The reported case: a shorter, thinner arm in a copy of arm.toml, and every frame invalid ("only 373 mm
    of the 685 mm arm is visible", "the width of a 25 mm radius") until [estimator] was edited by hand."""
    import shutil

    for name in ("twin.toml", "arm.toml", "camera.toml", "scene.toml"):
        shutil.copy(MODELS / name, tmp_path / name)
    arm = (tmp_path / "arm.toml").read_text()
    for old, new in (("length_m = 0.225", "length_m = 0.12"), ("length_m = 0.224", "length_m = 0.12"),
                     ("length_m = 0.220", "length_m = 0.11"), ("radius_m = 0.026", "radius_m = 0.015"),
                     ("radius_m = 0.025", "radius_m = 0.014"), ("radius_m = 0.022", "radius_m = 0.013")):
        assert old in arm, old
        arm = arm.replace(old, new)
    (tmp_path / "arm.toml").write_text(arm)
    bench = tmp_path / "bench.toml"
    bench.write_text('[sim]\ntwin = "twin.toml"\n')
    estimator = load_bench_config(bench).estimator_config()
    assert estimator.arm_length_m == pytest.approx(0.12 + 0.12 + 0.11 + 2 * 0.008)
    assert estimator.arm_radius_m == pytest.approx((0.12 * 0.015 + 0.12 * 0.014 + 0.11 * 0.013) / 0.35)
    # what [estimator] says wins; the rig's arm is the user's to describe, the twin's arm does not apply
    bench.write_text('[sim]\ntwin = "twin.toml"\n\n[estimator]\narm_radius_m = 0.02\n')
    assert load_bench_config(bench).estimator_config().arm_radius_m == 0.02
    shipped = load_bench_config().estimator_config()
    assert (shipped.arm_length_m, round(shipped.arm_radius_m, 4)) == (0.685, 0.0243)
    assert shipped.connector_radius_m == 0.032  # its baseplates, stereo features between sections
    assert shipped.base_mount  # it hangs from its base mount
    rig = load_bench_config(MODELS / "bench_rig.toml").estimator_config()
    assert rig.arm_radius_m == 0.025 and rig.connector_radius_m == 0.032  # the rig file's own [estimator]
    assert rig.base_mount
    assert load_bench_config(bench).estimator_config().connector_radius_m == 0.032
    # what each section can reach, from the arm file's physics; the rig file's ranges hold the twin's
    twin_ranges = np.array(shipped.section_lengths_m)
    assert twin_ranges.shape == (3, 2) and np.all(twin_ranges[:, 0] < twin_ranges[:, 1])
    assert np.all(np.array(rig.section_lengths_m)[:, 0] <= twin_ranges[:, 0] + 1e-9)
    assert np.all(np.array(rig.section_lengths_m)[:, 1] >= twin_ranges[:, 1] - 1e-9)

