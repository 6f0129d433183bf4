"""``softarm study sweep --grid FILE.toml``: the grid file, the search, and a small sweep on a short ramp."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

from bench.config import load_bench_config
from bench.engines import EngineConfig
from bench.study_files import read_results
from bench.sweep import Range, load_grid, rank, score_settings, sweep_command, sweep_study
from estimator.config_file import ConfigFileError
from models import model_path


def _grid(tmp_path, text: str):
    path = tmp_path / "grid.toml"
    path.write_text(text)
    return path


GRID = """
[sweep]
frames = 3
[scenes]
presets = ["clean", "lab"]
[estimator]
tube_fit = [true, false]
"""


def test_a_grid_runs_every_setting_on_every_scene_and_ranks_them(tmp_path):
    config_file = tmp_path / "bench.toml"
    config_file.write_text(f'base = "{model_path("bench.toml")}"\n[experiment]\nduration_s = 6.0\n')
    config = load_bench_config(config_file)
    grid = load_grid(_grid(tmp_path, GRID))
    out = tmp_path / "sweep"
    result = sweep_study(config, grid, out, EngineConfig("local", 2), progress=False)
    rows = read_results(out / "results.csv")
    assert [(r["preset"], r["tube_fit"]) for r in rows] == [("clean", "true"), ("clean", "false"), ("lab", "true"),
                                                            ("lab", "false")]
    assert list(rows[0])[:5] == ["episode", "setting", "tube_fit", "preset", "scene_seed"]
    assert all(r["frames"] == "3" and r["error"] == "" for r in rows)
    study = json.loads((out / "study.json").read_text())
    assert study["study"] == "sweep" and study["engine"]["name"] == "local" and study["episodes"] == 4
    assert study["episodes_per_s"] > 0 and study["configuration"]["search"] == "grid"
    assert study["best"] == result["ranking"][0] and len(study["ranking"]) == 2
    assert (out / "sweep.png").stat().st_size > 10_000


def test_ranking_puts_settings_that_meet_min_valid_first(tmp_path):
    grid = load_grid(_grid(tmp_path, GRID))
    rows = [{"setting": 0, "valid_fraction": 1.0, "false_valid": 0, "rmse_mm": 2.0, "error": ""},
            {"setting": 1, "valid_fraction": 0.5, "false_valid": 0, "rmse_mm": 1.0, "error": ""}]
    ranked = rank(score_settings(rows, [{"tube_fit": True}, {"tube_fit": False}], grid), grid)
    assert [s["setting"] for s in ranked] == [0, 1]  # the lower RMSE is valid half the time: it ranks second
    rows[1]["valid_fraction"] = 1.0
    rows[1]["false_valid"] = 1
    ranked = rank(score_settings(rows, [{"tube_fit": True}, {"tube_fit": False}], grid), grid)
    assert [s["setting"] for s in ranked] == [0, 1] and not ranked[1]["eligible"]


def test_a_random_search_draws_the_same_settings_from_the_same_seed(tmp_path):
    text = """
[sweep]
search = "random"
samples = 20
seed = 3
[scenes]
presets = ["lab"]
[estimator]
som_alpha0 = { min = 0.05, max = 0.5, log = true }
n_points = { min = 12, max = 30, integer = true }
tube_fit = [true, false]
"""
    grid = load_grid(_grid(tmp_path, text))
    assert grid.parameters["som_alpha0"] == Range(0.05, 0.5, log=True)
    a, b = grid.settings(), grid.settings()
    assert a == b and len(a) == 20
    alphas = np.array([s["som_alpha0"] for s in a])
    assert np.all((alphas >= 0.05) & (alphas <= 0.5))
    assert all(isinstance(s["n_points"], int) and 12 <= s["n_points"] <= 30 for s in a)
    assert {s["tube_fit"] for s in a} == {True, False}


@pytest.mark.parametrize(("text", "message"), [
    ('[sweep]\n[scenes]\npresets = ["lab"]\n[estimator]\nsom_alfa0 = [0.1]\n', "unknown key [estimator] som_alfa0"),
    ('[sweep]\n[scenes]\npresets = ["lab"]\n[estimator]\nsom_alpha0 = { min = 0.1, max = 0.2 }\n',
     'key [estimator] som_alpha0: a range { min, max } needs search = "random"'),
    ('[sweep]\n[scenes]\npresets = ["lab"]\n[estimator]\nn_points = [20, -3]\n', "key [estimator] n_points: -3"),
    ('[sweep]\nsearch = "bayes"\n[scenes]\npresets = ["lab"]\n[estimator]\ntube_fit = [true]\n', "[sweep] search"),
    ('[sweep]\n[scenes]\npresets = []\n[estimator]\ntube_fit = [true]\n', "[scenes] presets"),
    ('[sweep]\n[scenes]\npresets = ["lab"]\n[estimator]\n', "no parameter to sweep"),
])
def test_a_bad_grid_file_names_the_file_and_the_key(tmp_path, text, message):
    path = _grid(tmp_path, text)
    with pytest.raises(ConfigFileError) as error:
        load_grid(path)
    assert str(error.value).startswith(str(path)) and message in str(error.value)


def test_the_command_refuses_a_bad_grid_before_running_anything(tmp_path, capsys):
    path = _grid(tmp_path, '[sweep]\n[scenes]\npresets = ["lab"]\n[estimator]\nsom_alfa0 = [0.1]\n')
    out = tmp_path / "out"
    assert sweep_command(SimpleNamespace(which="sweep", grid=str(path), out=str(out), frames=None)) == 2
    assert "som_alfa0" in capsys.readouterr().err and not out.exists()
    assert sweep_command(SimpleNamespace(which="sweep", grid=None, out=str(out))) == 2
    assert "--grid FILE.toml is required" in capsys.readouterr().err
    # a preset the scene file lacks is the grid's typo: named there, and said before anything runs
    path = _grid(tmp_path, '[sweep]\n[scenes]\npresets = ["lab", "nosuch"]\n[estimator]\nsom_alpha0 = [0.1]\n')
    assert sweep_command(SimpleNamespace(which="sweep", grid=str(path), out=str(out), frames=None)) == 2
    err = capsys.readouterr().err
    assert f"{path} [scenes] presets: 'nosuch': " in err and "unknown preset 'nosuch'" in err and not out.exists()
