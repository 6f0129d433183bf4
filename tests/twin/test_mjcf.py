"""The MJCF generator: deterministic, one naming scheme, and a model MuJoCo accepts as it is.

The XML is generated at load time and never committed (models/arm.toml is the one source), so the
check is that the generator is a pure function of the parameters: the same document every time,
in this process and in a fresh one with a different hash seed.
"""

import hashlib
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest

from twin.mjcf import chain_layout, make_mjcf
from twin.params import ArmParams

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def params() -> ArmParams:
    return ArmParams.load()


def test_generator_is_deterministic_across_processes(params):
    xml = make_mjcf(params)
    assert make_mjcf(ArmParams.load()) == xml
    script = ("import hashlib, sys; from twin.mjcf import make_mjcf; from twin.params import ArmParams; "
              "sys.stdout.write(hashlib.sha256(make_mjcf(ArmParams.load()).encode()).hexdigest())")
    env = dict(os.environ, PYTHONHASHSEED="12345")
    other = subprocess.run([sys.executable, "-c", script], cwd=REPO, env=env, capture_output=True, text=True,
                           check=True).stdout
    assert other == hashlib.sha256(xml.encode()).hexdigest()


def test_no_committed_xml_can_go_stale():
    assert not list((REPO / "models").glob("arm*.xml")), "the arm's MJCF is generated, do not commit it"


def test_command_line_writes_the_model(tmp_path):
    out = subprocess.run([sys.executable, "-m", "twin.mjcf"], cwd=REPO, capture_output=True, text=True, check=True)
    assert out.stdout == make_mjcf(ArmParams.load())


def test_names_follow_one_scheme(params):
    model = mujoco.MjModel.from_xml_string(make_mjcf(params))
    bodies = [model.body(i).name for i in range(model.nbody)]
    expected_links = [f"s{k + 1}_link{j + 1}" for k, s in enumerate(params.sections) for j in range(s.n_links)]
    assert bodies == ["world", "base", *expected_links]
    joints = [model.joint(i).name for i in range(model.njnt)]
    assert joints == [f"{link}_{suffix}" for link in expected_links
                      for suffix in ("stretch", "bend_x", "bend_y", "twist")]
    assert [model.tendon(i).name for i in range(model.ntendon)] == list(params.channels)
    actuators = [model.actuator(i).name for i in range(model.nu)]
    for channel in params.channels:
        assert channel in actuators
        assert all(a == channel or a.startswith(f"{channel}_seg") for a in actuators
                   if model.tendon(model.actuator_trnid[model.actuator(a).id, 0]).name == channel)
    geoms = {model.geom(i).name for i in range(model.ngeom)}
    assert {"base_mount", "plate1", "plate2", "s1_link3_visual", "s3_link10_collision"} <= geoms
    assert model.key("home").id == 0
    assert model.site("tip").id == 0


def test_default_classes_separate_visual_and_collision_geoms(params):
    root = ET.fromstring(make_mjcf(params))
    classes = {c.get("class"): c for c in root.iter("default") if c.get("class")}
    assert {"arm", "visual", "collision", "plate"} <= set(classes)
    visual = classes["visual"].find("geom")
    collision = classes["collision"].find("geom")
    assert visual.get("contype") == visual.get("conaffinity") == "0"
    assert collision.get("contype") == "1" and collision.get("conaffinity") == "0"  # obstacles, never itself
    assert visual.get("group") != collision.get("group")
    for geom in root.find("worldbody").iter("geom"):
        assert geom.get("class") in {"visual", "collision", "plate"}, geom.get("name")


def test_model_mass_and_stiffness_come_from_the_parameters(params):
    model = mujoco.MjModel.from_xml_string(make_mjcf(params))
    moving = sum(model.body_mass[model.body(link.name).id] for link in chain_layout(params).links)
    first = params.sections[0]
    stub_mass = first.mass_kg / first.n_links / 2  # half an element is fixed to the base mount
    total = sum(s.mass_kg for s in params.sections) + params.baseplate.mass_kg * (len(params.sections) - 1)
    assert moving == pytest.approx(total - stub_mass, rel=1e-9)
    section = params.sections[1]
    element = section.length_m / section.n_links
    joint = model.joint("s2_link4_bend_x")
    assert model.jnt_stiffness[joint.id] == pytest.approx(section.EI_Nm2 / element)
    assert model.dof_damping[joint.dofadr[0]] == pytest.approx(section.damping_time_s * section.EI_Nm2 / element)
    assert model.jnt_stiffness[model.joint("s2_link4_twist").id] == pytest.approx(section.GJ_Nm2 / element)
    # a section's axial compliance adds up to L / EA over its slides
    compliance = sum(1 / model.jnt_stiffness[model.joint(f"s2_link{j + 1}_stretch").id]
                     for j in range(section.n_links))
    assert compliance == pytest.approx(section.length_m / section.EA_N)


def test_pma_actuators_reproduce_the_moment_table(params):
    model = mujoco.MjModel.from_xml_string(make_mjcf(params))
    data = mujoco.MjData(model)
    pma = params.sections[0].pmas[0]
    ids = [i for i in range(model.nu) if model.tendon(model.actuator_trnid[i, 0]).name == pma.channel]
    for bar in np.linspace(0, params.max_pressure_bar, 26):
        data.act[model.actuator_actadr[ids]] = bar
        mujoco.mj_forward(model, data)
        assert data.actuator_force[ids].sum() == pytest.approx(float(pma.moment_at(bar)), abs=1e-12)


def test_generator_rejects_bad_arguments(params):
    with pytest.raises(ValueError, match="timestep_s"):
        make_mjcf(params, timestep_s=0.0)
    with pytest.raises(ValueError, match="gravity_world"):
        make_mjcf(params, gravity_world=(0.0, float("nan"), -9.8))
