"""The arm's MJCF, generated from its parameters in one function (after dm_control's ``swimmer._make_model``).

Design: each elastic section is a chain of ``n_links`` rigid capsules joined at the midpoints of
``n_links`` equal elements (the first joint sits half an element below the section's proximal plate,
the last half an element above its distal plate). Every joint point carries four joints lumping the
strain of one element of length ``l``: a slide along the axis (stiffness EA/l) and three hinges,
bending about x and y (EI/l) and twist about the axis (GJ/l). This is the midpoint rule for a
Kirchhoff rod: a uniform moment gives equal hinge angles M l / EI whose joint points lie on a
circle, a distributed load converges at second order in ``l``, and EI, GJ and EA stay independent
(ball joints would force GJ = EI). The rigid stretch between the last joint of a section and the
first of the next holds the 3D-printed baseplate, so plates stay flat and rigid. The slide at a
section's last joint also carries the section's final half element, so each section's axial
compliance L/EA sits between its own plates. Resolution: 10 links per section (nv = 120) matches
beam theory to ~0.1 % and runs ~19x real time on 2 cores (benchmarks/twin_physics.py, 2026-12-01).

Each PMA is a fixed tendon over its section's joints whose coefficients are the unit loads of that
PMA (bending moment direction, axial force per N m, twist per N m); the tendon is pulled by
actuators whose activation is the chamber pressure (``filterexact`` dynamics, the valve's first-order
lag, exact at any timestep) and whose control is the commanded pressure in bar. MuJoCo actuators
are affine in their activation, so a piecewise-linear pressure-to-moment table with K segments is
built from K actuators on the same tendon, one hinge function ``slope_change * max(0, p - p_knee)``
each (the force range clips the other side of the knee). All of them receive the same control and
have identical filters, so the first one (named after the channel) reports the chamber pressure.
Everything runs inside ``mj_step``; nothing is applied from Python between steps, so ``mj_step``
can batch many steps and the generated XML is a complete model on its own.

Joint damping is stiffness proportional (a damping time per section), the standard Rayleigh damping
of beam models and one number a lab fits from a step response. ``implicitfast`` integrates joint
damping implicitly, so every mode stiffer than the damping allows (axial, twist: up to ~3000 rad/s)
is overdamped and stable at 2 ms for any damping time above half the timestep, without small steps.
Measured on this model at 2 ms: RK4 diverges within 0.1 s; Euler (also implicit in joint damping)
is equivalent; MuJoCo 4's ``discrete`` integrator (implicit in stiffness too) holds but is not faster
and is marked experimental. Alternatives ruled out on the prototype: ball joints force GJ = EI,
spatial tendons through offset sites converge poorly with the link count, a ``flexcomp`` rod needs
forces from Python between steps. Known approximation: the x and y hinges compose in order, so
oblique bending (both PMAs' directions mixed) picks up a second-order error, 0.1 % at 86 deg.

The XML is generated when a simulation is built and never committed: ``models/arm.toml`` is the one
source of truth, so a lab that refits a number cannot end up with a stale model.
``python -m twin.mjcf [params.toml] > arm.xml`` writes it out for MuJoCo's viewer.

Names follow one scheme: bodies ``s1_link1`` .. ``s3_link10`` (base to tip), their joints
``s1_link1_stretch``, ``_bend_x``, ``_bend_y``, ``_twist``, geoms ``s1_link1_visual`` and
``s1_link1_collision``, plates ``base_mount``, ``plate1``, ``plate2``, tendons and first actuators
named by valve channel (``s1_a``), further table segments ``s1_a_seg1`` ...; keyframe ``home``.
Local frames: at rest every link frame is parallel to the world frame and the arm runs along local
-z, so a PMA's azimuth is the same in the file, in the rest pose and in the world.
"""

from __future__ import annotations

import math
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from twin.params import STANDARD_GRAVITY_M_S2, ArmParams, PMAParams

JOINT_SUFFIXES = ("stretch", "bend_x", "bend_y", "twist")
_FORCE_LIMIT = 1e9  # the open side of a hinge-function actuator's force range

ARM_RGBA = (0.95, 0.45, 0.1, 1.0)
PLATE_RGBA = (0.85, 0.85, 0.8, 1.0)


@dataclass(frozen=True)
class Piece:
    """A cylinder of the reference arm inside one link: elastic material of a section, or a plate.

    ``start_m``/``end_m`` are distances from the link's joint point along the arm (toward the tip).
    """

    kind: str  # "section" or "plate"
    index: int  # section index (0-based) or plate index (0-based, plate between sections i and i+1)
    start_m: float
    end_m: float
    radius_m: float
    mass_kg: float


@dataclass(frozen=True)
class Link:
    """One rigid link: from its joint point (the body origin) to the next joint point or the tip.

    Attributes:
        name: body name, ``s{section}_link{index}`` with 1-based section and index.
        section: 0-based section of its joint.
        s_joint_m: reference arc length of the joint point.
        span_m: rigid length to the next joint point (or to the tip).
        pieces: what the link is made of, for mass, inertia and geoms.
        axial_stiffness, axial_damping: N/m and N s/m of the slide joint, which lengthens the
            stretch from the previous joint point (or the base) to this one.
        bend_stiffness, bend_damping, twist_stiffness, twist_damping: N m/rad and N m s/rad of the hinges.
    """

    name: str
    section: int
    index: int
    s_joint_m: float
    span_m: float
    pieces: tuple[Piece, ...]
    axial_stiffness: float
    axial_damping: float
    bend_stiffness: float
    bend_damping: float
    twist_stiffness: float
    twist_damping: float

    @property
    def mass_kg(self) -> float:
        return sum(p.mass_kg for p in self.pieces)

    def inertia(self) -> tuple[float, np.ndarray]:
        """Centre of mass (distance from the joint point toward the tip) and diagonal inertia there."""
        masses = np.array([p.mass_kg for p in self.pieces])
        centres = np.array([(p.start_m + p.end_m) / 2 for p in self.pieces])
        lengths = np.array([p.end_m - p.start_m for p in self.pieces])
        radii = np.array([p.radius_m for p in self.pieces])
        com = float(masses @ centres / masses.sum())
        # solid cylinders along the axis, moved to the common centre of mass (parallel axes)
        transverse = masses * (3 * radii**2 + lengths**2) / 12 + masses * (centres - com) ** 2
        axial = masses * radii**2 / 2
        return com, np.array([transverse.sum(), transverse.sum(), axial.sum()])


@dataclass(frozen=True)
class ChainLayout:
    """Where everything sits along the arm at rest (reference arc length s, metres from the base).

    Attributes:
        links: base to tip.
        section_spans_m: (start, end) of each section's elastic part.
        plate_spans_m: (start, end) of each baseplate.
        stub_m: the first joint's distance from the base (the stretch fixed to the base mount).
        total_length_m: base to tip.
    """

    links: tuple[Link, ...]
    section_spans_m: tuple[tuple[float, float], ...]
    plate_spans_m: tuple[tuple[float, float], ...]
    stub_m: float
    total_length_m: float

    def section_links(self, section: int) -> tuple[Link, ...]:
        return tuple(link for link in self.links if link.section == section)


def chain_layout(params: ArmParams) -> ChainLayout:
    """Discretise the arm: joint points at element midpoints, plates inside the links that span them."""
    spans, plates = [], []
    s = 0.0
    for i, section in enumerate(params.sections):
        spans.append((s, s + section.length_m))
        s += section.length_m
        if i < len(params.sections) - 1:
            plates.append((s, s + params.baseplate.thickness_m))
            s += params.baseplate.thickness_m
    total = s

    joints = []  # (section, index, s)
    for i, (section, (a, _)) in enumerate(zip(params.sections, spans, strict=True)):
        element = section.length_m / section.n_links
        joints += [(i, j + 1, a + (j + 0.5) * element) for j in range(section.n_links)]

    def material(s0: float, s1: float) -> list[tuple[str, int, float, float]]:
        """The sections' and plates' parts of the reference arm in [s0, s1]."""
        out = []
        for i, (a, b) in enumerate(spans):
            if min(b, s1) > max(a, s0):
                out.append(("section", i, max(a, s0), min(b, s1)))
        for i, (a, b) in enumerate(plates):
            if min(b, s1) > max(a, s0):
                out.append(("plate", i, max(a, s0), min(b, s1)))
        return sorted(out, key=lambda part: part[2])

    links = []
    for n, (sec, index, s_joint) in enumerate(joints):
        s_next = joints[n + 1][2] if n + 1 < len(joints) else total
        pieces = []
        for kind, i, s0, s1 in material(s_joint, s_next):
            if kind == "section":
                sp = params.sections[i]
                pieces.append(Piece(kind, i, s0 - s_joint, s1 - s_joint, sp.radius_m,
                                    sp.mass_kg * (s1 - s0) / sp.length_m))
            else:
                pieces.append(Piece(kind, i, s0 - s_joint, s1 - s_joint, params.baseplate.radius_m,
                                    params.baseplate.mass_kg))
        # The slide lengthens the stretch from the previous joint point. It holds the compliance of its
        # own section's material there; the last one of a section also takes the section's final half
        # element (between it and the plate or tip), so every section's stretch is exact and stays
        # between its own plates.
        sp = params.sections[sec]
        element = sp.length_m / sp.n_links
        stretch = element / 2 if index == 1 else element
        if index == sp.n_links:
            stretch += element / 2
        axial = sp.EA_N / stretch
        links.append(Link(
            name=f"s{sec + 1}_link{index}", section=sec, index=index, s_joint_m=s_joint, span_m=s_next - s_joint,
            pieces=tuple(pieces),
            axial_stiffness=axial,
            axial_damping=sp.damping_time_s * axial,
            bend_stiffness=sp.EI_Nm2 / element,
            bend_damping=sp.damping_time_s * sp.EI_Nm2 / element,
            twist_stiffness=sp.GJ_Nm2 / element,
            twist_damping=sp.damping_time_s * sp.GJ_Nm2 / element,
        ))
    return ChainLayout(links=tuple(links), section_spans_m=tuple(spans), plate_spans_m=tuple(plates),
                       stub_m=joints[0][2], total_length_m=total)


def pma_unit_loads(pma: PMAParams, section: int, link: Link) -> dict[str, float]:
    """Generalised load per N m of bending moment that a PMA of ``section`` puts on one link's joints.

    Bending: a contractile PMA at azimuth phi pulls its side together and bends toward it, a moment
    about (sin phi, -cos phi, 0) for an arm along -z; an extensile one pushes and bends away. The
    same force shortens (contractile) or lengthens (extensile) its section by moment / moment_arm and,
    wound at the helix angle, twists it by moment * tan(helix). All act on the section's own joints.
    """
    if link.section != section:
        return {}
    phi = math.radians(pma.azimuth_deg)
    sign = 1.0 if pma.kind == "contractile" else -1.0
    return {"stretch": -sign / pma.moment_arm_m, "bend_x": sign * math.sin(phi), "bend_y": -sign * math.cos(phi),
            "twist": math.tan(math.radians(pma.helix_angle_deg))}


def _num(x: float) -> str:
    """Shortest text that reads back as the same double: the model holds the parameters exactly."""
    text = repr(float(x))
    text = text[:-2] if text.endswith(".0") else text
    return "0" if text == "-0" else text


def _vec(values) -> str:
    return " ".join(_num(float(v)) for v in values)


def make_mjcf(params: ArmParams, *, timestep_s: float = 0.002,
              gravity_world: tuple[float, float, float] = (0.0, 0.0, -STANDARD_GRAVITY_M_S2)) -> str:
    """Generate the arm's MJCF from its parameters.

    Args:
        params: the arm.
        timestep_s: integration step.
        gravity_world: (3,) m/s^2; tilt it to emulate a base held horizontally (EI identification).

    Returns:
        The MJCF document as a string; identical inputs give an identical string.
    """
    if not (math.isfinite(timestep_s) and timestep_s > 0):
        raise ValueError(f"timestep_s: expected a positive number, got {timestep_s!r}")
    gravity = np.asarray(gravity_world, dtype=float)
    if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
        raise ValueError(f"gravity_world: expected 3 finite numbers, got {gravity_world!r}")
    layout = chain_layout(params)

    root = ET.Element("mujoco", model="softarm")
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    option = ET.SubElement(root, "option", timestep=_num(timestep_s), integrator="implicitfast",
                           gravity=_vec(gravity))
    # the arm never touches itself; collision geoms (contype 1, conaffinity 0) are there for obstacles a
    # scene may add, which then also enables the contact flag.
    # autoreset off: a bad state stays in mjData for the error message instead of silently resetting.
    ET.SubElement(option, "flag", contact="disable", autoreset="disable")

    default = ET.SubElement(root, "default")
    arm = ET.SubElement(default, "default", {"class": "arm"})
    ET.SubElement(arm, "joint", limited="false")
    visual = ET.SubElement(arm, "default", {"class": "visual"})
    ET.SubElement(visual, "geom", type="capsule", contype="0", conaffinity="0", group="1", density="0",
                  rgba=_vec(ARM_RGBA))
    plate = ET.SubElement(arm, "default", {"class": "plate"})
    ET.SubElement(plate, "geom", type="cylinder", contype="0", conaffinity="0", group="1", density="0",
                  rgba=_vec(PLATE_RGBA))
    collision = ET.SubElement(arm, "default", {"class": "collision"})
    ET.SubElement(collision, "geom", type="capsule", contype="1", conaffinity="0", group="3", density="0")

    world = ET.SubElement(root, "worldbody")
    ET.SubElement(world, "light", name="top", pos="0 -0.5 1", dir="0 0.5 -1", directional="true")
    base = ET.SubElement(world, "body", name="base", childclass="arm")
    mount = params.base_mount
    ET.SubElement(base, "geom", name="base_mount", attrib={"class": "plate"},
                  size=_vec((mount.radius_m, mount.thickness_m / 2)), pos=_vec((0, 0, mount.thickness_m / 2)))
    ET.SubElement(base, "geom", name="base_stub_visual", attrib={"class": "visual"},
                  fromto=_vec((0, 0, 0, 0, 0, -layout.stub_m)), size=_num(params.sections[0].radius_m))

    parent, previous = base, None
    for link in layout.links:
        pos = (0.0, 0.0, -(link.s_joint_m - previous.s_joint_m) if previous else -link.s_joint_m)
        body = ET.SubElement(parent, "body", name=link.name, pos=_vec(pos))
        com, inertia = link.inertia()
        ET.SubElement(body, "inertial", pos=_vec((0, 0, -com)), mass=_num(link.mass_kg), diaginertia=_vec(inertia))
        ET.SubElement(body, "joint", name=f"{link.name}_stretch", type="slide", axis="0 0 -1",
                      stiffness=_num(link.axial_stiffness), damping=_num(link.axial_damping))
        for suffix, axis in (("bend_x", "1 0 0"), ("bend_y", "0 1 0")):
            ET.SubElement(body, "joint", name=f"{link.name}_{suffix}", type="hinge", axis=axis,
                          stiffness=_num(link.bend_stiffness), damping=_num(link.bend_damping))
        ET.SubElement(body, "joint", name=f"{link.name}_twist", type="hinge", axis="0 0 -1",
                      stiffness=_num(link.twist_stiffness), damping=_num(link.twist_damping))
        for n, piece in enumerate(p for p in link.pieces if p.kind == "section"):
            ET.SubElement(body, "geom", name=f"{link.name}_visual" + (f"{n}" if n else ""),
                          attrib={"class": "visual"}, size=_num(piece.radius_m),
                          fromto=_vec((0, 0, -piece.start_m, 0, 0, -piece.end_m)))
        for piece in (p for p in link.pieces if p.kind == "plate"):
            ET.SubElement(body, "geom", name=f"plate{piece.index + 1}", attrib={"class": "plate"},
                          size=_vec((piece.radius_m, (piece.end_m - piece.start_m) / 2)),
                          pos=_vec((0, 0, -(piece.start_m + piece.end_m) / 2)))
        ET.SubElement(body, "geom", name=f"{link.name}_collision", attrib={"class": "collision"},
                      size=_num(params.sections[link.section].radius_m),
                      fromto=_vec((0, 0, 0, 0, 0, -link.span_m)))
        parent, previous = body, link
    ET.SubElement(parent, "site", name="tip", pos=_vec((0, 0, -previous.span_m)), size="0.005")

    tendons = ET.SubElement(root, "tendon")
    actuators = ET.SubElement(root, "actuator")
    for s, section in enumerate(params.sections):
        for pma in section.pmas:
            fixed = ET.SubElement(tendons, "fixed", name=pma.channel)
            for link in layout.links:
                loads = pma_unit_loads(pma, s, link)
                for suffix in JOINT_SUFFIXES:
                    if abs(loads.get(suffix, 0.0)) > 1e-12:  # cos(90 deg) is 6e-17, not 0
                        ET.SubElement(fixed, "joint", joint=f"{link.name}_{suffix}", coef=_num(loads[suffix]))
            # moment(p) = sum_k dslope_k * max(0, p - p_k): one actuator per knee of the table.
            slopes = pma.slopes_Nm_per_bar
            changes = np.diff(slopes, prepend=0.0)
            for k, (knee, change) in enumerate(zip(pma.pressure_bar[:-1], changes, strict=True)):
                if k > 0 and change == 0.0:
                    continue
                force_range = (0.0, _FORCE_LIMIT) if change >= 0 else (-_FORCE_LIMIT, 0.0)
                ET.SubElement(actuators, "general", name=pma.channel if k == 0 else f"{pma.channel}_seg{k}",
                              tendon=pma.channel, dyntype="filterexact",
                              dynprm=_num(params.valve_time_constant_s), gaintype="fixed", gainprm=_num(change),
                              biastype="affine", biasprm=_vec((-change * knee, 0, 0)),
                              ctrlrange=_vec((0, params.max_pressure_bar)), forcerange=_vec(force_range))

    keyframe = ET.SubElement(root, "keyframe")
    ET.SubElement(keyframe, "key", name="home")  # straight and unstrained, valves vented, t = 0
    ET.indent(root)
    return ET.tostring(root, encoding="unicode") + "\n"


if __name__ == "__main__":
    sys.stdout.write(make_mjcf(ArmParams.load(sys.argv[1] if len(sys.argv) > 1 else None)))
