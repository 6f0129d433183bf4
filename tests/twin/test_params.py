"""The arm's parameter file: the default loads, and every malformed file names the file and the key."""

import dataclasses
import re

import numpy as np
import pytest

from twin.params import DEFAULT_PARAMS_PATH, ArmParams, ParamsFileError, PMAParams


@pytest.fixture(scope="module")
def text() -> str:
    return DEFAULT_PARAMS_PATH.read_text()


def test_default_file_describes_the_papers_arm():
    params = ArmParams.load()
    assert params.source == DEFAULT_PARAMS_PATH
    assert params.channels == ("s1_a", "s1_b", "s1_c", "s1_d", "s2_a", "s2_b", "s3")
    assert params.section_names == ("s1", "s2", "s3")
    assert params.total_length_m == pytest.approx(0.685, abs=1e-9)
    assert params.max_pressure_bar == 2.5
    assert all(0.02 <= s.radius_m <= 0.03 for s in params.sections)  # about 50 mm diameter
    kinds = [{p.kind for p in s.pmas} for s in params.sections]
    assert kinds == [{"contractile"}, {"extensile"}, {"extensile"}]
    assert [len(s.pmas) for s in params.sections] == [4, 2, 1]
    assert params.sections[2].pmas[0].helix_angle_deg != 0
    # section 2's PMAs bend in a plane orthogonal to section 1's first bend (s1_a)
    s1_a, s2_a = params.sections[0].pmas[0], params.sections[1].pmas[0]
    assert (s1_a.azimuth_deg - s2_a.azimuth_deg) % 180 == pytest.approx(90)


def test_moment_table_is_piecewise_linear_with_dead_zone_and_extrapolates():
    pma = PMAParams("x", "contractile", 0.0, 0.01, 0.0, (0.0, 0.5, 1.5), (0.0, 0.0, 2.0))
    assert pma.moment_at(0.25) == 0.0
    assert pma.moment_at(1.0) == pytest.approx(1.0)
    assert pma.moment_at(2.0) == pytest.approx(3.0)
    assert np.allclose(pma.moment_at(np.array([0.5, 1.5])), [0.0, 2.0])


def test_default_path_is_found_from_anywhere(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert ArmParams.load().channels[0] == "s1_a"


def _replace_in_section(text: str, section: int, old: str, new: str) -> str:
    """Replace the first ``old`` inside the n-th [[section]] table (0-based)."""
    parts = text.split("[[section]]")
    assert old in parts[section + 1], old
    parts[section + 1] = parts[section + 1].replace(old, new, 1)
    return "[[section]]".join(parts)


CASES = {
    "unknown key": (lambda t: t.replace("[arm]\n", "[arm]\ncolour = 3\n"), "arm.colour", "unknown key"),
    "unknown table": (lambda t: t + "\n[wheels]\ncount = 4\n", "wheels", "unknown key"),
    "missing key": (lambda t: _replace_in_section(t, 1, "EI_Nm2 = 0.35\n", ""), "section[1].EI_Nm2", "missing"),
    "missing table": (lambda t: re.sub(r"\[baseplate\][^\[]*", "", t), "baseplate", "missing"),
    "wrong type": (lambda t: _replace_in_section(t, 0, "EI_Nm2 = 0.60", 'EI_Nm2 = "stiff"'),
                   "section[0].EI_Nm2", "expected a number"),
    "boolean number": (lambda t: t.replace("max_pressure_bar = 2.5", "max_pressure_bar = true"),
                       "arm.max_pressure_bar", "expected a number"),
    "zero stiffness": (lambda t: _replace_in_section(t, 2, "GJ_Nm2 = 0.13", "GJ_Nm2 = 0.0"),
                       "section[2].GJ_Nm2", "positive"),
    "negative stiffness": (lambda t: _replace_in_section(t, 0, "EA_N = 3000.0", "EA_N = -3000.0"),
                           "section[0].EA_N", "positive"),
    "fractional links": (lambda t: _replace_in_section(t, 0, "n_links = 10", "n_links = 10.5"),
                         "section[0].n_links", "integer"),
    "unknown pma kind": (lambda t: _replace_in_section(t, 1, 'kind = "extensile"', 'kind = "telescopic"'),
                         "section[1].pma[0].kind", "contractile, extensile"),
    "decreasing table": (lambda t: _replace_in_section(t, 2, "pressure_bar = [0.0, 0.2, 1.0, 1.75, 2.5]",
                                                       "pressure_bar = [0.0, 1.0, 0.2, 1.75, 2.5]"),
                         "section[2].pma[0].pressure_bar", "increasing"),
    "short table": (lambda t: _replace_in_section(t, 2, "pressure_bar = [0.0, 0.2, 1.0, 1.75, 2.5]",
                                                  "pressure_bar = [0.0, 0.2, 1.0, 1.75, 2.0]"),
                    "section[2].pma[0].pressure_bar", "below max_pressure_bar"),
    "table lengths differ": (lambda t: _replace_in_section(t, 2, "moment_Nm = [0.0, 0.0, 0.52, 1.05, 1.45]",
                                                           "moment_Nm = [0.0, 0.52, 1.05, 1.45]"),
                             "section[2].pma[0].moment_Nm", "5 values"),
    "not an array": (lambda t: _replace_in_section(t, 2, "moment_Nm = [0.0, 0.0, 0.52, 1.05, 1.45]",
                                                   "moment_Nm = 1.45"),
                     "section[2].pma[0].moment_Nm", "array of numbers"),
    "duplicate channel": (lambda t: _replace_in_section(t, 1, 'channel = "s2_b"', 'channel = "s1_a"'),
                          "section[1].pma[1].channel", "used twice"),
    "no pma": (lambda t: t.split("[[section.pma]]\nchannel = \"s3\"")[0], "section[2].pma", "missing"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_malformed_file_names_file_and_key(tmp_path, text, case):
    mutate, key, reason = CASES[case]
    path = tmp_path / "arm.toml"
    path.write_text(mutate(text))
    with pytest.raises(ParamsFileError) as info:
        ArmParams.load(path)
    message = str(info.value)
    assert str(path) in message
    assert f"'{key}'" in message, message
    assert reason in message


def test_missing_and_non_toml_files_name_the_file(tmp_path):
    with pytest.raises(ParamsFileError, match=re.escape(str(tmp_path / "nope.toml")) + ": .*not found"):
        ArmParams.load(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[arm\nmax_pressure_bar = 2.5\n")
    with pytest.raises(ParamsFileError, match=re.escape(str(bad)) + ": not a TOML file"):
        ArmParams.load(bad)


def test_parameters_built_in_code_are_validated_too():
    params = ArmParams.load()
    with pytest.raises(ValueError, match="EI_Nm2: expected a positive number"):
        dataclasses.replace(params.sections[0], EI_Nm2=-1.0)
    with pytest.raises(ValueError, match="moment_Nm: .*starting with 0 at 0 bar"):
        dataclasses.replace(params.sections[0].pmas[0], moment_Nm=(0.1, 0.0, 1.35, 2.95, 4.3))
    with pytest.raises(ValueError, match="section: the arm needs at least one section"):
        dataclasses.replace(params, sections=())
