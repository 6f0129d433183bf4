"""The ray engine on a local Ray of 2 CPUs (one module-scoped start and stop): episodes as Ray tasks,
retried once, failures reported, and the same robustness table as the local engine."""

import json

import pytest

ray = pytest.importorskip("ray")

from bench.config import load_bench_config  # noqa: E402
from bench.engines import EngineConfig, run_episodes  # noqa: E402
from bench.robustness import parse_condition, robustness_study  # noqa: E402
from bench.study_files import table_differences  # noqa: E402
from models import model_path  # noqa: E402
from tests.bench import episode_fns  # noqa: E402

RAY2 = EngineConfig("ray", workers=2)


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, logging_level="warning")
    yield
    ray.shutdown()


def test_episodes_run_as_ray_tasks_retried_once_and_reported(local_ray, tmp_path):
    specs = [{"x": x, "fail": x == 2, "marker": str(tmp_path / f"m{x}")} for x in range(4)]
    outcomes = run_episodes(episode_fns.always_fails, specs, RAY2, progress=False)
    assert [o.ok for o in outcomes] == [True, True, False, True]
    assert [o.result["value"] for o in outcomes if o.ok] == [0, 1, 9]
    assert outcomes[2].attempts == 2 and outcomes[2].error == "ValueError: episode 2 is broken"
    retried = run_episodes(episode_fns.fails_first_time, specs[:2], RAY2, progress=False)
    assert [(o.ok, o.attempts) for o in retried] == [(True, 2), (True, 2)]
    assert ray.is_initialized()  # a Ray the engine did not start is left running


def test_ray_and_local_engines_give_the_same_robustness_table(local_ray, tmp_path):
    """A short ramp (6 s, 3 frames) in two scenes, once on each engine."""
    config_file = tmp_path / "bench.toml"
    config_file.write_text(f'base = "{model_path("bench.toml")}"\n[experiment]\nduration_s = 6.0\n')
    config = load_bench_config(config_file)
    conditions = [parse_condition(c, 0) for c in ("clean", "lab")]
    runs = {}
    for name in ("local", "ray"):
        runs[name] = tmp_path / name
        robustness_study(config, conditions, 3, runs[name], EngineConfig(name, 2), progress=False)
    assert table_differences(runs["local"] / "results.csv", runs["ray"] / "results.csv") == []
    assert (runs["local"] / "frames.csv").read_text() == (runs["ray"] / "frames.csv").read_text()
    engines = [json.loads((runs[n] / "study.json").read_text())["engine"] for n in ("local", "ray")]
    assert engines[0] == {"name": "local", "workers": 2}
    assert engines[1]["name"] == "ray" and engines[1]["workers"] == 2 and engines[1]["ray_version"]
