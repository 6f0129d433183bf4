"""``softarm study robustness``: issue 10's targets on a reduced set (12 frames per condition), the files
it writes, and the targets check itself.

The reduced set runs every condition of the study (the paper's ramp, 12 frames spread over it, both
modes on the same frames) and fails when a condition misses its target in default mode:
lab, dim, bright_warm, blur >= 95 % valid and RMSE <= 1.3x clean; occluded >= 80 % valid and
RMSE <= 2x clean; no false valid frame (valid while a point or the tip is more than 10 mm off) anywhere.
"""

import json
from types import SimpleNamespace

import pytest

from bench.config import load_bench_config
from bench.engines import EngineConfig
from bench.robustness import (
    COLUMNS,
    CONDITIONS,
    TARGETS,
    Condition,
    check_targets,
    parse_condition,
    robustness_command,
    robustness_study,
)
from bench.study_files import read_results

REDUCED_FRAMES = 12


@pytest.fixture(scope="module")
def reduced(tmp_path_factory):
    out = tmp_path_factory.mktemp("robustness")
    conditions = [parse_condition(c, 0) for c in CONDITIONS]
    result = robustness_study(load_bench_config(), conditions, REDUCED_FRAMES, out, EngineConfig("local", 2),
                              progress=False)
    return out, result


# Measured misses on this reduced set (seed 0), each xfail(strict) until fixed; measured 2026-12-02 once the
# coarse masks read the nearest raw pixels (OpenCV 5.0 read the other neighbour, and every figure before
# that date was measured on its misread masks; occluded's false valid frame went with them).
# The frames are 5 s apart, so each starts nearly cold; the ramp's last frames are the hard ones (the arm
# runs along the image rows past the second baseplate, so depth there rests on the apparent width).
# blur left this list in the twelfth session (2026-12-03), when the blur is measured and taken out of the
# images (estimator.deblur): 12/12 valid, no false valid, 1.72 mm = 1.19x clean; before, 10/12 (t = 37 s
# the base hidden, t = 58 s a tip that missed its outline), 2.39 mm = 1.65x.
KNOWN_MISSES: dict[str, str] = {}
# dim left this list in the twenty-sixth session (2026-12-06): its refused frame (t = 37 s, "only 252 mm of
# the 685 mm arm is visible") is searched cold; dim light leaves pinholes in the top section's coarse mask
# and its skeleton two loops without a free end, so no walk starts at the base. The left walks start at the
# first connector, the right one from the tip runs the whole arm, and the only pair whose first points share
# a row was the tip section alone. The walks from either end of the middle section, joined through it, and
# the right walk turned to start at the base now pair as the whole arm (estimator/arm_region.py:
# walked_and_turned, _fullest_match): 12/12 valid, no false valid, 1.36 mm = 1.06x clean (before: 11/12,
# 1.34 mm = 1.05x).
# Filling the pinholes was tried in the twenty-second session and cost elsewhere (benchmarks/MEASUREMENTS.md).
# occluded left this list in the twenty-third session (2026-12-05): t = 47.5 s, valid with its tip 10.5 mm
# off in depth, has a restart of the tip's depth that ends lower in cost 8-15 mm away and is refused
# (``BETTER_RESTART_TIP_M``): 10/12 valid (83 %), no false valid, 1.35 mm = 1.06x clean (before: 11/12
# with that frame, 1.57 mm = 1.23x).
# bright_warm left this list in the fourteenth session (2026-12-04): one ray of the right image's tip outline
# 4.8 px off (the rest 0.3 px RMS) no longer leaves that image's whole tip out (t = 53 s, refused as hidden
# before), and a connector the mask closed over is found in the image's colour (t = 58 s): 12/12, no false
# valid, 1.55 mm = 1.21x clean (before: 11/12, 1.42 mm = 0.98x of a clean 1.46 mm).


@pytest.mark.parametrize("condition", [
    pytest.param(c, marks=pytest.mark.xfail(strict=True, reason=KNOWN_MISSES[c])) if c in KNOWN_MISSES else c
    for c in CONDITIONS])
def test_every_condition_meets_its_targets_in_default_mode(reduced, condition):
    _, result = reduced
    problems = result["targets"][condition]
    table = "\n".join(result["headline"])
    assert not problems, f"{condition} below its targets: {problems}\n{table}"


# What each known miss still reaches (valid frames, at most so many false valid, RMSE ratio to clean):
# a strict xfail passes however far a condition falls, so these hold the rest of its figures. The sixth
# session's length bound on the noisy pre-fit curve halved blur's valid frames (11/12 -> 6/12) under
# the xfail, unseen until the stored frames were re-run. The eighth session traded blur's 11 valid
# with 1 false valid for 9 with none (a tip that misses its outline is refused); the ninth session's
# connectors took bright_warm's false valid away and blur to 10 valid; blur meets its targets since the twelfth.
# The fourteenth session's connectors took clean's RMSE on this set 1.46 -> 1.28 mm and left dim's at
# 1.37 mm: its ratio rose 0.94 -> 1.07x, its floor with it. The fifteenth session's cap model (a point
# beyond the end is the rim's, not a silhouette line's) took occluded's t = 58 s from 11.3 to 5.4 mm off;
# t = 47.5 s went 7.2 -> 10.5 mm and t = 31.6 s is refused (10 mm along the arm), so its floor is 11 valid.
# Over all the stored and validation sequences that change took valid 1,086 -> 1,092 and false valid 14 -> 8.
KNOWN_MISS_FLOORS: dict[str, tuple[int, int, float]] = {}  # dim met its targets in the 26th


@pytest.mark.parametrize("condition", sorted(KNOWN_MISS_FLOORS))
def test_a_known_miss_does_not_fall_further(reduced, condition):
    _, result = reduced
    rows = {r["condition"]: r for r in result["rows"] if r["mode"] == "default"}
    row, clean = rows[condition], rows["clean"]
    valid, false_valid, ratio = KNOWN_MISS_FLOORS[condition]
    table = "\n".join(result["headline"])
    assert row["valid"] >= valid and row["false_valid"] <= false_valid, table
    assert row["rmse_mm"] <= ratio * clean["rmse_mm"], table


def test_the_study_writes_one_row_per_condition_and_mode_and_its_record(reduced):
    out, result = reduced
    rows = read_results(out / "results.csv")
    assert list(rows[0]) == list(COLUMNS)
    assert [(r["condition"], r["mode"]) for r in rows] == [(c, m) for c in CONDITIONS for m in ("default", "paper")]
    assert all(r["frames"] == str(REDUCED_FRAMES) and r["error"] == "" for r in rows)
    study = json.loads((out / "study.json").read_text())
    assert study["study"] == "robustness" and study["engine"] == {"name": "local", "workers": 2}
    assert study["episodes"] == len(CONDITIONS) and study["completed"] == len(CONDITIONS) and study["failed"] == []
    assert study["episodes_per_s"] > 0 and study["versions"]["mujoco"]
    assert set(study["seeds"]["scenes"]) == set(CONDITIONS)
    assert set(study["targets"]) == set(CONDITIONS)
    assert (out / "robustness.png").stat().st_size > 20_000
    frames = (out / "frames.csv").read_text().splitlines()
    assert len(frames) == 1 + len(CONDITIONS) * 2 * REDUCED_FRAMES


def test_a_frame_far_from_the_last_is_estimated_as_a_first_frame_is(tmp_path):
    """The reported case: ``--frames 2`` puts the second frame 58 s after the first, and the SOM started
    from the first frame's chain crossed itself there ("self-overlap"), while the same image estimated
    cold is valid. A chain the last frame led astray is started over from the image alone."""
    result = robustness_study(load_bench_config(), [parse_condition("clean", 0)], 2, tmp_path,
                              EngineConfig("local", 1), progress=False)
    default = next(r for r in result["rows"] if r["mode"] == "default")
    assert default["valid"] == 2 and default["false_valid"] == 0, read_results(tmp_path / "frames.csv")


def _rows(**changes):
    """A passing study: clean at 1.0 mm, every other condition within its targets."""
    rows = []
    for name in CONDITIONS:
        row = {"condition": name, "preset": name, "mode": "default", "frames": 20, "valid": 20, "valid_fraction": 1.0,
               "false_valid": 0, "rmse_mm": 1.0, "error": ""}
        row.update(changes.get(name, {}))
        rows.append(row)
        rows.append({**row, "mode": "paper", "false_valid": 20, "rmse_mm": 50.0})  # the paper mode is not held
    return rows


def test_targets_pass_a_study_that_meets_them():
    assert check_targets(_rows()) == {name: [] for name in CONDITIONS}


@pytest.mark.parametrize(("condition", "change", "expected"), [
    ("lab", {"valid": 18, "valid_fraction": 0.9}, "18/20 valid (90 %), target 95%"),
    ("dim", {"rmse_mm": 1.31}, "RMSE 1.31 mm = 1.31x clean (1.00 mm), target <= 1.3x"),
    ("occluded", {"valid": 15, "valid_fraction": 0.75}, "15/20 valid (75 %), target 80%"),
    ("occluded", {"rmse_mm": 2.1}, "target <= 2x"),
    ("clean", {"false_valid": 1}, "1 false valid frame(s)"),
    ("random", {"false_valid": 2}, "2 false valid frame(s)"),
    ("blur", {"error": "RuntimeError: boom"}, "the episode failed: RuntimeError: boom"),
])
def test_targets_name_each_miss(condition, change, expected):
    problems = check_targets(_rows(**{condition: change}))
    assert any(expected in p for p in problems[condition]), problems[condition]
    assert all(not p for name, p in problems.items() if name != condition)


def test_occluded_may_lose_a_fifth_of_its_frames_but_lab_may_not():
    assert TARGETS["occluded"].valid == 0.80 and TARGETS["lab"].valid == 0.95
    rows = _rows(occluded={"valid": 16, "valid_fraction": 0.8, "rmse_mm": 2.0})
    assert check_targets(rows)["occluded"] == []


def test_ratio_targets_need_the_clean_condition_in_the_same_study():
    rows = [r for r in _rows() if r["condition"] != "clean"]
    assert "no RMSE of the 'clean' condition" in check_targets(rows)["lab"][0]


def test_conditions_parse_preset_and_seed():
    assert parse_condition("lab", 4) == Condition("lab", "lab", 4)
    assert parse_condition("random:7", 0) == Condition("random:7", "random", 7)
    for bad in ("random:x", ":3", "random:-1"):
        with pytest.raises(ValueError, match="--conditions"):
            parse_condition(bad, 0)


def test_an_unknown_condition_names_the_scene_files_presets(tmp_path, capsys):
    """Refused as a bad option is (exit 2, as softarm run answers an unknown preset), before anything runs."""
    args = SimpleNamespace(which="robustness", config=None, frames=2, out=str(tmp_path / "s"), conditions=["lab",
                           "fog"], engine="local", workers=1, ray_address=None)
    assert robustness_command(args) == 2
    said = capsys.readouterr()
    assert "unknown preset 'fog'" in said.err and "bright_warm" in said.err and said.out == ""
    assert not (tmp_path / "s").exists()


def test_a_condition_given_twice_is_refused(tmp_path, capsys):
    """Reported: it ran twice and study.json, keyed by condition, kept one of the two."""
    args = SimpleNamespace(which="robustness", config=None, frames=2, out=str(tmp_path / "s"),
                           conditions=["clean", "lab", "clean"], engine="local", workers=1, ray_address=None)
    assert robustness_command(args) == 2
    assert "--conditions: clean given more than once" in capsys.readouterr().err and not (tmp_path / "s").exists()


@pytest.mark.parametrize("frames", [0, 1001])
def test_frames_out_of_range_are_refused(tmp_path, capsys, frames):
    args = SimpleNamespace(which="robustness", config=None, frames=frames, out=str(tmp_path / "s"))
    assert robustness_command(args) == 2
    assert f"--frames {frames}: expected 1 to 1000 frames per condition" in capsys.readouterr().err
