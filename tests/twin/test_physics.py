"""Validation of the arm's physics against beam theory, and its behaviour under every pressure input.

The cantilever checks use the real arm (three sections, two rigid baseplates) held horizontally
(gravity perpendicular to its base) against an elastica solved here by shooting (tests/twin/elastica.py,
itself checked against closed forms below); the arc check uses one section under a pure end moment
without gravity.
"""

import dataclasses
import math
import re

import numpy as np
import pytest

from tests.twin.elastica import Piece, cantilever_tip
from twin.mjcf import STANDARD_GRAVITY_M_S2
from twin.params import ArmParams, PMAParams, section_length_ranges_m
from twin.physics import ArmSimulation, NotSettledWarning, SimulationError
from twin.shape import ArmShape

RAMP_CHANNELS = ("s1_a", "s2_a", "s3")  # the paper's experiment: these three ramped together


@pytest.fixture(scope="module")
def params() -> ArmParams:
    return ArmParams.load()


@pytest.fixture(scope="module")
def sim(params) -> ArmSimulation:
    return ArmSimulation(params)


@pytest.fixture
def arm(sim) -> ArmSimulation:
    sim.reset()
    return sim


def pressures(params: ArmParams, bar: float, channels=RAMP_CHANNELS) -> np.ndarray:
    return np.array([bar if c in channels else 0.0 for c in params.channels])


def rod_pieces(params: ArmParams, gravity: float) -> list[Piece]:
    """The arm as the oracle sees it: elastic sections and rigid, heavy baseplates."""
    pieces = []
    for k, section in enumerate(params.sections):
        pieces.append(Piece(section.length_m, section.EI_Nm2, section.mass_kg * gravity / section.length_m))
        if k + 1 < len(params.sections):
            plate = params.baseplate
            pieces.append(Piece(plate.thickness_m, math.inf, plate.mass_kg * gravity / plate.thickness_m))
    return pieces


def fit_circle(points: np.ndarray) -> tuple[float, float]:
    """Radius of the best circle through (N, 3) points lying in a plane, and the largest residual."""
    centred = points - points.mean(axis=0)
    e1, e2 = np.linalg.svd(centred)[2][:2]
    x, y = centred @ e1, centred @ e2
    a, b, c = np.linalg.lstsq(np.column_stack([x, y, np.ones_like(x)]), x**2 + y**2, rcond=None)[0]
    xc, yc = a / 2, b / 2
    radius = math.sqrt(c + xc**2 + yc**2)
    return radius, float(np.max(np.abs(np.hypot(x - xc, y - yc) - radius)))


# ----------------------------------------------------------------------------- the oracle itself
def test_oracle_matches_closed_forms():
    # uniform load, small deflection: q L^4 / (8 EI)
    _, w = cantilever_tip([Piece(1.0, 2.0, 3.0)], linear=True)
    assert w == pytest.approx(3.0 / 16, rel=1e-9)
    # tip load P L^2 / EI = 1, large deflection (Bisshopp & Drucker 1945): w/L = 0.30172, (L-u)/L = 0.05643
    u, w = cantilever_tip([Piece(1.0, 1.0, 0.0)], tip_load_N=1.0)
    assert w == pytest.approx(0.30172, abs=2e-5)
    assert 1 - u == pytest.approx(0.05643, abs=2e-5)
    # a rigid outer piece (length b) does not bend: the flexible part (a) carries the tip load P and the
    # moment P b, and the rigid part adds its rotation times b
    a, b, load = 0.5, 0.5, 1e-3
    u, w = cantilever_tip([Piece(a, 1.0, 0.0), Piece(b, math.inf, 0.0)], tip_load_N=load, linear=True)
    assert w == pytest.approx(load * (a**3 / 3 + b * a**2 / 2 + (a**2 / 2 + b * a) * b), rel=1e-9)


# ----------------------------------------------------------------------------- validation
def _horizontal_tip(params: ArmParams, gravity: float, tol_m_s: float) -> np.ndarray:
    # gravity along +x is the arm (along -z) held horizontally
    sim = ArmSimulation(params, gravity_world=(gravity, 0.0, 0.0))
    assert sim.settle(tol_m_s=tol_m_s, max_time_s=30.0)
    return sim.backbone()[-1]


def test_horizontal_cantilever_small_load_matches_euler_bernoulli(params):
    gravity = 0.02  # m/s^2: tip deflection ~0.1 % of the length, the linear regime
    tip = _horizontal_tip(params, gravity, tol_m_s=1e-8)
    _, w_ref = cantilever_tip(rod_pieces(params, gravity), linear=True)
    assert w_ref / params.total_length_m < 2e-3
    error = (tip[0] - w_ref) / w_ref
    assert abs(error) < 0.01, f"tip deflection {tip[0]:.6g} m vs Euler-Bernoulli {w_ref:.6g} m ({100 * error:+.3f} %)"
    assert abs(tip[1]) < 1e-9


def test_horizontal_cantilever_under_gravity_matches_elastica(params):
    tip = _horizontal_tip(params, STANDARD_GRAVITY_M_S2, tol_m_s=1e-6)
    u_ref, w_ref = cantilever_tip(rod_pieces(params, STANDARD_GRAVITY_M_S2))
    _, w_linear = cantilever_tip(rod_pieces(params, STANDARD_GRAVITY_M_S2), linear=True)
    assert (w_linear - w_ref) / w_ref > 0.05, "not a large deflection: the test would not tell elastica from EB"
    error = (tip[0] - w_ref) / w_ref
    assert abs(error) < 0.02, f"tip deflection {tip[0]:.5g} m vs elastica {w_ref:.5g} m ({100 * error:+.3f} %)"
    assert -tip[2] == pytest.approx(u_ref, rel=0.02)


@pytest.mark.parametrize("n_links", [10, 6])
def test_section_under_pure_end_moment_forms_arc_of_curvature_m_over_ei(params, n_links):
    section = params.sections[0]
    # one section, one PMA with a linear table; its huge moment arm makes the axial force negligible
    # (1e-3 N per N m), so the section carries a pure moment at every joint
    pma = PMAParams("m", "contractile", azimuth_deg=30.0, moment_arm_m=1e3, helix_angle_deg=0.0,
                    pressure_bar=(0.0, 2.5), moment_Nm=(0.0, 5.0))
    beam = dataclasses.replace(params, sections=(dataclasses.replace(section, pmas=(pma,), n_links=n_links),))
    sim = ArmSimulation(beam, gravity_world=(0.0, 0.0, 0.0))
    for bar in (0.5, 2.0):
        sim.command([bar])
        assert sim.settle(tol_m_s=1e-8)
        curvature_ref = float(pma.moment_at(bar)) / section.EI_Nm2
        radius, residual = fit_circle(sim.backbone(400))
        error = (1 / radius - curvature_ref) / curvature_ref
        assert abs(error) < 0.01, f"curvature {1 / radius:.5g} /m vs M/EI {curvature_ref:.5g} /m ({100 * error:+.3f} %)"
        assert residual < 1e-4 * radius, "the backbone is not an arc"
        # the total bend too (oblique bending composes x and y hinges: a second-order 0.1 % at 86 deg)
        assert sim.section_bend_deg()[0] == pytest.approx(math.degrees(curvature_ref * section.length_m), rel=0.005)


@pytest.mark.parametrize("channel", ["s1_a", "s1_b", "s1_c", "s1_d", "s2_a", "s2_b"])
def test_each_pma_bends_and_strains_its_section_as_its_table_says(params, channel):
    sim = ArmSimulation(params, gravity_world=(0.0, 0.0, 0.0))
    bar = 2.5
    sim.command(pressures(params, bar, (channel,)))
    assert sim.settle(tol_m_s=1e-7)
    k = next(i for i, s in enumerate(params.sections) if any(p.channel == channel for p in s.pmas))
    section = params.sections[k]
    pma = next(p for p in section.pmas if p.channel == channel)
    moment = float(pma.moment_at(bar))
    bend = sim.section_bend_deg()
    assert bend[k] == pytest.approx(math.degrees(moment * section.length_m / section.EI_Nm2), rel=0.01)
    assert np.all(np.delete(bend, k) < 1e-3), "without gravity the other sections stay straight"
    strain = (sim.section_lengths_m()[k] - section.length_m) / section.length_m
    expected = (1 if pma.kind == "extensile" else -1) * moment / pma.moment_arm_m / section.EA_N
    assert strain == pytest.approx(expected, rel=0.02)
    # a contractile PMA bends toward its side, an extensile one away from it (azimuth in the world frame)
    end = sim.section_end_points()[k] - (sim.section_end_points()[k - 1] if k else np.zeros(3))
    side = np.array([math.cos(math.radians(pma.azimuth_deg)), math.sin(math.radians(pma.azimuth_deg)), 0.0])
    assert np.sign(end @ side) == (1 if pma.kind == "contractile" else -1)


def test_helical_pma_bends_and_twists_its_section(params):
    sim = ArmSimulation(params, gravity_world=(0.0, 0.0, 0.0))
    bar = 2.5
    sim.command(pressures(params, bar, ("s3",)))
    assert sim.settle(tol_m_s=1e-7)
    section = params.sections[2]
    (pma,) = section.pmas
    torque = float(pma.moment_at(bar)) * math.tan(math.radians(pma.helix_angle_deg))
    assert sim.section_twist_deg()[2] == pytest.approx(math.degrees(torque * section.length_m / section.GJ_Nm2),
                                                       rel=0.01)
    assert sim.section_bend_deg()[2] > 45
    assert np.all(np.abs(sim.section_twist_deg()[:2]) < 1e-6)
    # extensile: the section lengthens by its axial load over EA
    strain = (sim.section_lengths_m()[2] - section.length_m) / section.length_m
    assert pma.kind == "extensile"
    assert strain == pytest.approx(float(pma.moment_at(bar)) / pma.moment_arm_m / section.EA_N, rel=0.02)
    # bending while twisting makes a space curve: section 3 leaves its plane (a planar arc gives ~1e-6)
    distal = sim.backbone(400)[np.linspace(0, 1, 400) > 0.72]
    centred = distal - distal.mean(axis=0)
    assert np.linalg.svd(centred, compute_uv=False)[2] / np.linalg.norm(centred, axis=1).max() > 0.02


@pytest.mark.parametrize("variant", ["default", "coarse", "fine", "one_section"])
def test_every_model_steps_through_random_pressures_without_warnings(params, variant):
    model = {
        "default": params,
        "coarse": dataclasses.replace(params, sections=tuple(dataclasses.replace(s, n_links=4)
                                                               for s in params.sections)),
        "fine": dataclasses.replace(params, sections=tuple(dataclasses.replace(s, n_links=16)
                                                             for s in params.sections)),
        "one_section": dataclasses.replace(params, sections=params.sections[:1]),
    }[variant]
    sim = ArmSimulation(model)
    rng = np.random.default_rng(0)
    n = len(sim.channels)
    for i in range(40):
        if i % 10 == 9:  # abrupt extremes: every valve slammed open or shut
            target = np.full(n, sim.max_pressure_bar) if i % 20 == 9 else np.zeros(n)
        else:
            target = rng.uniform(0, sim.max_pressure_bar, n) * (rng.random(n) < 0.6)
        sim.command(target)
        sim.advance(float(rng.uniform(0.01, 0.25)))
    assert all(w.number == 0 for w in sim.data.warning), [w.number for w in sim.data.warning]
    shape = sim.shape()
    assert np.all(np.isfinite(shape.points_world))
    assert np.max(np.linalg.norm(shape.points_world, axis=1)) < 1.2 * model.total_length_m


def test_full_ramp_on_all_channels_is_stable(params, arm):
    # the paper's ramp (0 -> 2.5 bar in 0.05 bar steps) on every channel at once, 0.2 s per step
    for bar in np.arange(0.05, 2.5 + 1e-9, 0.05):
        arm.command(np.full(len(arm.channels), round(bar, 2)))
        arm.advance(0.2)
    assert arm.settle()
    assert all(w.number == 0 for w in arm.data.warning)
    lengths = arm.section_lengths_m()
    # opposed PMAs cancel their bending; section 1 shortens (contractile), sections 2 and 3 lengthen
    assert lengths[0] < params.sections[0].length_m * 0.95
    assert lengths[1] > params.sections[1].length_m * 1.05
    assert lengths[2] > params.sections[2].length_m * 1.05
    assert np.all(arm.section_bend_deg()[:2] < 5)
    # what an estimator is told each section can reach (between the plates' middles): the hanging
    # extensile sections, every PMA at the top of its table, reach their longest; the contractile one
    # lies within its range, held above its shortest by the arm's weight
    ranges = np.array(section_length_ranges_m(params))
    plates = params.baseplate.thickness_m * np.array([0.5, 1.0, 0.5])
    measured = lengths + plates
    assert np.all((ranges[:, 0] <= measured) & (measured <= ranges[:, 1] + 1e-4)), (ranges, measured)
    assert measured[1:] == pytest.approx(ranges[1:, 1], abs=1e-3)
    assert measured[0] < params.sections[0].length_m * 0.95 and measured[0] - ranges[0, 0] < 0.01


def test_paper_ramp_gives_a_visible_3d_shape_that_does_not_fold_in_the_camera(params, arm):
    camera = np.array([0.0, -1.0, -params.total_length_m / 2])  # ~1 m in front, looking along +y
    horizontal, worst_gap = 0.0, np.inf
    for bar in np.arange(0.05, 2.5 + 1e-9, 0.05):
        arm.command(pressures(params, round(bar, 2)))
        arm.advance(0.5)
        shape = arm.shape()
        points = shape.points_world
        horizontal = max(horizontal, float(np.abs(points[:, :2]).max()))
        # pinhole projection; parts of the tube far apart along the arm must stay apart in the image
        depth = points[:, 1] - camera[1]
        uv = (points[:, [0, 2]] - camera[[0, 2]]) / depth[:, None]
        width = 2 * shape.radius_m / depth
        apart = np.abs(shape.s_m[:, None] - shape.s_m[None]) > 0.15
        gap = np.linalg.norm(uv[:, None] - uv[None], axis=2) / np.maximum(width[:, None], width[None])
        worst_gap = min(worst_gap, float(gap[apart].min()))
    assert arm.settle()
    bend = arm.section_bend_deg()
    assert np.all((bend > 60) & (bend < 120)), bend
    assert horizontal < 0.45
    assert worst_gap > 1.0, "the silhouette folds over itself"
    tip = arm.backbone()[-1]
    assert tip[0] > 0.2 and tip[1] > 0.1, "s1_a bends away from the camera (+y), s2_a to its right (+x)"


@pytest.mark.parametrize("channel", ["s1_a", "s2_a", "s3"])
def test_each_section_bends_a_lot_against_gravity_at_full_pressure(params, arm, channel):
    arm.command(pressures(params, params.max_pressure_bar, (channel,)))
    assert arm.settle()
    k = int(channel[1]) - 1
    assert 60 < arm.section_bend_deg()[k] < 120


# ----------------------------------------------------------------------------- failure is loud
def test_absurd_timestep_raises_simulation_error_naming_the_step(params):
    sim = ArmSimulation(params, timestep_s=0.5)  # above twice the damping time: implicit damping cannot hold it
    sim.command(np.full(len(sim.channels), 2.0))
    with pytest.raises(SimulationError) as info:
        sim.advance(60.0)
    error = info.value
    assert re.search(rf"at step {error.step} \(t = {error.time_s:.4f} s", str(error))
    assert 1 <= error.step < 120


def test_nan_raises_simulation_error_at_the_step_it_enters(arm):
    arm.advance(0.1)  # 50 steps
    arm.data.qvel[7] = np.nan
    with pytest.raises(SimulationError, match=r"at step 51 \(t = 0\.1020 s") as info:
        arm.advance(0.5)
    assert info.value.step == 51
    arm.reset()
    arm.advance(0.1)  # usable again after a reset
    assert np.all(np.isfinite(arm.backbone()))


@pytest.mark.parametrize("bad, message", [
    (np.nan, "channel s2_a: pressure nan is not finite"),
    (-0.1, r"channel s2_a: -0.1 bar is outside \[0, 2.5\] bar"),
    (2.6, r"channel s2_a: 2.6 bar is outside \[0, 2.5\] bar"),
])
def test_command_rechecks_pressures_and_names_the_channel(arm, bad, message):
    values = np.zeros(len(arm.channels))
    values[arm.channels.index("s2_a")] = bad
    with pytest.raises(ValueError, match=message):
        arm.command(values)
    with pytest.raises(ValueError, match="expected 7 pressures"):
        arm.command(np.zeros(3))
    assert np.all(arm.commanded_bar == 0)


def test_settle_warns_and_returns_false_when_not_at_rest_in_time(params, arm):
    arm.command(pressures(params, 2.5))
    with pytest.warns(NotSettledWarning, match="not at rest"):
        assert arm.settle(max_time_s=0.1) is False
    # checking more often than once a step still advances (one step per check)
    with pytest.warns(NotSettledWarning):
        assert arm.settle(max_time_s=0.01, check_every_s=1e-4) is False
    assert arm.time_s == pytest.approx(0.1 + 0.01, abs=arm.timestep_s)


def test_settle_does_not_mistake_a_still_start_for_rest(params, arm):
    # at t = 0 nothing moves yet, but the pressurised arm is far from equilibrium
    arm.command(pressures(params, 2.5))
    assert arm.settle()
    assert arm.time_s > 1.0
    assert arm.section_bend_deg()[0] > 60


# ----------------------------------------------------------------------------- state and geometry
def test_valve_lag_is_first_order(params, arm):
    tau = params.valve_time_constant_s
    arm.command(pressures(params, 2.0))
    arm.advance(tau)
    chamber = arm.chamber_bar[arm.channels.index("s1_a")]
    assert chamber == pytest.approx(2.0 * (1 - math.exp(-1)), rel=1e-6)
    assert arm.commanded_bar[arm.channels.index("s1_a")] == 2.0
    assert arm.chamber_bar[arm.channels.index("s1_b")] == 0.0


def test_time_and_reset(params, arm):
    arm.command(pressures(params, 1.0))
    arm.advance(0.3013)  # rounded to whole 2 ms steps
    assert arm.time_s == pytest.approx(0.302)
    arm.reset()
    assert arm.time_s == 0.0
    assert np.all(arm.commanded_bar == 0) and np.all(arm.chamber_bar == 0)
    straight = np.column_stack([np.zeros(200), np.zeros(200), -np.linspace(0, params.total_length_m, 200)])
    assert np.allclose(arm.backbone(), straight, atol=1e-12)


def test_backbone_is_base_to_tip_through_the_base_and_even_in_arc_length(params, arm):
    arm.command(pressures(params, 2.0))
    arm.advance(1.0)
    points = arm.backbone(150)
    assert points.shape == (150, 3)
    assert np.array_equal(points[0], np.zeros(3))
    assert np.allclose(points[-1], arm.tip_position(), atol=1e-12)
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    assert steps.max() / steps.min() < 1.01
    # smooth: the direction turns gradually (no kinks at the joints)
    directions = np.diff(points, axis=0) / steps[:, None]
    turn = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", directions[:-1], directions[1:]), -1, 1)))
    assert turn.max() < 3.0
    # leaves the base along -z, and runs through the section ends
    assert directions[0] @ np.array([0, 0, -1.0]) > 0.9999
    ends = arm.section_end_points()
    assert np.min(np.linalg.norm(arm.backbone(2000)[:, None] - ends[None], axis=2), axis=0).max() < 1e-3


def test_shape_has_radii_and_plates_posed_on_the_backbone(params, arm):
    arm.command(pressures(params, 2.0))
    arm.advance(1.0)
    shape = arm.shape()
    assert isinstance(shape, ArmShape)
    assert shape.s_m[0] == 0.0 and np.all(np.diff(shape.s_m) > 0)
    assert set(np.round(shape.radius_m, 6)) == {s.radius_m for s in params.sections}
    assert shape.radius_m[0] == params.sections[0].radius_m and shape.radius_m[-1] == params.sections[-1].radius_m
    mount, *plates = shape.plates
    assert len(plates) == len(params.sections) - 1
    assert np.allclose(mount.center_world, [0, 0, params.base_mount.thickness_m / 2])
    assert np.allclose(mount.normal_world, [0, 0, -1])
    dense = arm.backbone(4000)
    tangents = np.gradient(dense, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    for plate in plates:
        nearest = int(np.argmin(np.linalg.norm(dense - plate.center_world, axis=1)))
        assert np.linalg.norm(dense[nearest] - plate.center_world) < 1e-3
        assert plate.normal_world @ tangents[nearest] > 0.999
        assert plate.radius_m == params.baseplate.radius_m
