"""The arm's physical parameters, loaded from one TOML file in ``models/`` (default ``models/arm.toml``).

Every number a lab fits to its own arm lives in that file, with the unit in the key name; the MJCF
generator (``twin.mjcf``) and the simulation (``twin.physics``) read nothing else. The dataclasses
are frozen and validate themselves, so a parameter set built in code (``dataclasses.replace``) is
checked like one read from a file; the loader adds the file and the key to every message.

Frames: each section's azimuths are measured in the arm's rest frame, which is the world frame
(x, y horizontal, z up; the arm hangs along -z): azimuth 0 deg points along +x, 90 deg along +y.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path

import numpy as np

from estimator.config_file import ConfigFileError, TableReader, is_number, read_toml

# models/ is package data (importlib.resources finds it in a checkout and in an installed wheel alike).
DEFAULT_PARAMS_PATH = Path(str(files("models") / "arm.toml"))

PMA_KINDS = ("contractile", "extensile")
STANDARD_GRAVITY_M_S2 = 9.80665  # the twin's gravity (twin.mjcf), and the weight the sections carry
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


class ParamsFileError(ConfigFileError):
    """A parameter file is missing, unreadable, or has a bad key; the message names both."""


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name}: expected a positive number, got {value!r}")


def _finite(name: str, value: float) -> None:
    if not math.isfinite(value):
        raise ValueError(f"{name}: expected a finite number, got {value!r}")


@dataclass(frozen=True)
class PMAParams:
    """One pneumatic muscle actuator (PMA) and its pressure-to-load law.

    The PMA is one force along the section at ``moment_arm_m`` from the centreline. The table gives
    the bending moment it puts on its section as a function of chamber pressure (piecewise linear,
    extrapolated with the last slope); the axial force and the twist torque follow from the same
    force: axial = moment / moment_arm (shortens a contractile, lengthens an extensile section),
    twist = moment * tan(helix_angle).

    Attributes:
        channel: valve channel name, e.g. ``s1_a``.
        kind: ``contractile`` (bends toward its side, shortens) or ``extensile`` (bends away, lengthens).
        azimuth_deg: where the PMA sits around the section, in the rest frame (0 = +x, 90 = +y).
        moment_arm_m: distance of the PMA's line of force from the centreline.
        helix_angle_deg: winding angle of a helical PMA (0 for straight ones); positive twists the
            section right-handedly about its base-to-tip direction.
        pressure_bar: table abscissa, strictly increasing, starting at 0 and reaching the maximum pressure.
        moment_Nm: bending moment at each tabulated pressure; 0 at 0 bar, never negative.
    """

    channel: str
    kind: str
    azimuth_deg: float
    moment_arm_m: float
    helix_angle_deg: float
    pressure_bar: tuple[float, ...]
    moment_Nm: tuple[float, ...]  # noqa: N815 (the file's key, unit in the name)

    def __post_init__(self) -> None:
        if not _NAME.match(self.channel):
            raise ValueError(f"channel: expected a name like 's1_a' (letters, digits, '_'), got {self.channel!r}")
        if self.kind not in PMA_KINDS:
            raise ValueError(f"kind: expected one of {', '.join(PMA_KINDS)}, got {self.kind!r}")
        _finite("azimuth_deg", self.azimuth_deg)
        _positive("moment_arm_m", self.moment_arm_m)
        if not (math.isfinite(self.helix_angle_deg) and abs(self.helix_angle_deg) < 80):
            raise ValueError(f"helix_angle_deg: expected a number in (-80, 80), got {self.helix_angle_deg!r}")
        p, m = np.asarray(self.pressure_bar, float), np.asarray(self.moment_Nm, float)
        if p.ndim != 1 or len(p) < 2 or not np.all(np.isfinite(p)):
            raise ValueError(f"pressure_bar: expected at least two finite numbers, got {self.pressure_bar!r}")
        if p[0] != 0 or np.any(np.diff(p) <= 0):
            raise ValueError(f"pressure_bar: expected a strictly increasing table starting at 0, "
                             f"got {self.pressure_bar!r}")
        if m.shape != p.shape:
            raise ValueError(f"moment_Nm: expected {len(p)} values (one per pressure_bar entry), got {len(m)}")
        if not np.all(np.isfinite(m)) or np.any(m < 0) or m[0] != 0:
            raise ValueError(f"moment_Nm: expected finite values >= 0 starting with 0 at 0 bar, got {self.moment_Nm!r}")

    @property
    def slopes_Nm_per_bar(self) -> np.ndarray:
        """(K-1,) slope of each table segment."""
        return np.diff(self.moment_Nm) / np.diff(self.pressure_bar)

    def moment_at(self, pressure_bar: float | np.ndarray) -> np.ndarray:
        """Bending moment in N m at a chamber pressure in bar (extrapolated with the last slope)."""
        p = np.asarray(pressure_bar, dtype=float)
        table = np.interp(p, self.pressure_bar, self.moment_Nm)
        beyond = self.moment_Nm[-1] + self.slopes_Nm_per_bar[-1] * (p - self.pressure_bar[-1])
        return np.where(p > self.pressure_bar[-1], beyond, table)


@dataclass(frozen=True)
class SectionParams:
    """One elastic section between two plates, treated as a Kirchhoff rod.

    Attributes:
        length_m: length of the elastic part at rest (plates excluded).
        radius_m: outer radius (the rendered tube, the collision capsules).
        mass_kg: mass of the elastic part, PMAs included, spread evenly along it.
        EI_Nm2, GJ_Nm2, EA_N: bending, torsional and axial stiffness.
        damping_time_s: stiffness-proportional damping: every joint's damping is this time times its stiffness.
        n_links: rigid links the section is discretised into (the model's resolution).
        pmas: the section's actuators.
    """

    length_m: float
    radius_m: float
    mass_kg: float
    EI_Nm2: float
    GJ_Nm2: float
    EA_N: float
    damping_time_s: float
    n_links: int
    pmas: tuple[PMAParams, ...]

    def __post_init__(self) -> None:
        for name in ("length_m", "radius_m", "mass_kg", "EI_Nm2", "GJ_Nm2", "EA_N", "damping_time_s"):
            _positive(name, getattr(self, name))
        if isinstance(self.n_links, bool) or not isinstance(self.n_links, int) or not 2 <= self.n_links <= 200:
            raise ValueError(f"n_links: expected an integer in [2, 200], got {self.n_links!r}")
        if not self.pmas:
            raise ValueError("pma: a section needs at least one PMA")
        if self.radius_m >= self.length_m / 2:
            raise ValueError(f"radius_m: {self.radius_m} m is not small against the length {self.length_m} m")


@dataclass(frozen=True)
class BaseMountParams:
    """The fixed disc the arm hangs from; its lower face is the world origin (s = 0)."""

    radius_m: float
    thickness_m: float

    def __post_init__(self) -> None:
        for name in ("radius_m", "thickness_m"):
            _positive(name, getattr(self, name))


@dataclass(frozen=True)
class PlateParams:
    """A rigid 3D-printed baseplate between two sections (part of the arm's length)."""

    radius_m: float
    thickness_m: float
    mass_kg: float

    def __post_init__(self) -> None:
        for name in ("radius_m", "thickness_m", "mass_kg"):
            _positive(name, getattr(self, name))


@dataclass(frozen=True)
class ArmParams:
    """The whole arm: sections from base to tip, joined by identical baseplates, hanging from a base mount.

    Attributes:
        max_pressure_bar: highest gauge pressure any channel accepts.
        valve_time_constant_s: first-order lag from commanded to chamber pressure.
        base_mount: the fixed disc above the arm (its lower face is the world origin, s = 0).
        baseplate: the disc between two consecutive sections (rigid, part of the arm's length).
        sections: base to tip; section i (from 1) is named ``s{i}``.
        source: the file the parameters came from, if any (for messages).
    """

    max_pressure_bar: float
    valve_time_constant_s: float
    base_mount: BaseMountParams
    baseplate: PlateParams
    sections: tuple[SectionParams, ...]
    source: Path | None = None

    def __post_init__(self) -> None:
        _positive("max_pressure_bar", self.max_pressure_bar)
        _positive("valve_time_constant_s", self.valve_time_constant_s)
        if not self.sections:
            raise ValueError("section: the arm needs at least one section")
        seen: set[str] = set()
        for i, section in enumerate(self.sections):
            for j, pma in enumerate(section.pmas):
                if pma.channel in seen:
                    raise ValueError(f"section[{i}].pma[{j}].channel: {pma.channel!r} is used twice")
                seen.add(pma.channel)
                if pma.pressure_bar[-1] < self.max_pressure_bar:
                    raise ValueError(f"section[{i}].pma[{j}].pressure_bar: the table ends at {pma.pressure_bar[-1]} "
                                     f"bar, below max_pressure_bar = {self.max_pressure_bar} bar")

    @property
    def channels(self) -> tuple[str, ...]:
        """Valve channels in section order, then in file order within a section."""
        return tuple(pma.channel for section in self.sections for pma in section.pmas)

    @property
    def section_names(self) -> tuple[str, ...]:
        return tuple(f"s{i + 1}" for i in range(len(self.sections)))

    @property
    def total_length_m(self) -> float:
        """Arc length from the base (s = 0) to the tip at rest: sections plus baseplates."""
        return sum(s.length_m for s in self.sections) + (len(self.sections) - 1) * self.baseplate.thickness_m

    @classmethod
    def load(cls, path: str | Path | None = None) -> ArmParams:
        """Read and validate a parameter file (default ``models/arm.toml`` of this repository).

        Raises:
            ParamsFileError: the file is missing or not TOML, a key is unknown or missing, a value has
                the wrong type or an invalid value; the message names the file and the key.
        """
        path = Path(path) if path is not None else DEFAULT_PARAMS_PATH
        # Arrays of tables ([[section]], [[section.pma]]): keys are named by their dotted path.
        top = TableReader(path, read_toml(path, "", ParamsFileError), dotted=True, error=ParamsFileError)
        top.only(("arm", "base_mount", "baseplate", "section"))
        arm = top.sub("arm")
        base_mount = _build(BaseMountParams, top.sub("base_mount"), top, radius_m=float, thickness_m=float)
        baseplate = _build(PlateParams, top.sub("baseplate"), top, radius_m=float, thickness_m=float, mass_kg=float)
        sections = tuple(_section(reader, top) for reader in
                         top.tables("section", what="one [[section]] table per section, base to tip"))
        return _build(cls, arm, top, max_pressure_bar=float, valve_time_constant_s=float,
                      extra={"base_mount": base_mount, "baseplate": baseplate, "sections": sections, "source": path})


def _number(value) -> float:
    if not is_number(value):
        raise TypeError(f"expected a number, got {value!r}")
    return float(value)


def _integer(value) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"expected an integer, got {value!r}")
    return value


def _string(value) -> str:
    if not isinstance(value, str):
        raise TypeError(f"expected a string, got {value!r}")
    return value


def _numbers(value) -> tuple[float, ...]:
    if not isinstance(value, list) or not all(is_number(v) for v in value):
        raise TypeError(f"expected an array of numbers, got {value!r}")
    return tuple(float(v) for v in value)


# What each field of a parameter table holds, as a converter of the shared reader.
_KINDS = {float: _number, int: _integer, str: _string, tuple: _numbers}


def _build(cls, reader: TableReader, top: TableReader, extra: dict | None = None, **kinds):
    """``cls`` from one table: its keys are exactly ``kinds`` (plus ``pma`` for a section), checked by type,
    then by the dataclass, whose message is turned into the file's key."""
    extra = extra or {}
    reader.only(set(kinds) | ({"pma"} if "pmas" in extra else set()))
    values = {key: reader.take(key, _KINDS[kind]) for key, kind in kinds.items()}
    try:
        return cls(**values, **extra)
    except ValueError as e:
        # __post_init__ messages start with the field, or with a nested key such as section[1].pma[0].channel
        field, _, reason = str(e).partition(": ")
        if field.startswith("section[") or field == "section":
            raise top.error(field, reason) from e
        if field in kinds or field == "pma":
            raise reader.error(field, reason) from e
        raise reader.fail(f"table {reader.name()}: {e}") from e


def _section(reader: TableReader, top: TableReader) -> SectionParams:
    pmas = tuple(_build(PMAParams, pma, top, channel=str, kind=str, azimuth_deg=float, moment_arm_m=float,
                        helix_angle_deg=float, pressure_bar=tuple, moment_Nm=tuple)
                 for pma in reader.tables("pma", what="one [[section.pma]] table per PMA"))
    return _build(SectionParams, reader, top, extra={"pmas": pmas}, length_m=float, radius_m=float, mass_kg=float,
                  EI_Nm2=float, GJ_Nm2=float, EA_N=float, damping_time_s=float, n_links=int)


def twin_arm_file(twin_toml: str | Path) -> Path:
    """The arm parameter file a ``twin.toml`` names (its ``arm`` key), without loading the twin.

    Raises:
        ConfigFileError: the twin file is missing or not TOML, or names no arm file that exists.
    """
    from estimator.config_file import file_in

    path = Path(twin_toml)
    return TableReader(path, read_toml(path, "twin")).take("arm", file_in(path.parent))


def tube_of(arm: ArmParams) -> tuple[float, float]:
    """(length, radius) in metres of the one tube an estimator assumes for this arm: the arm's length
    at rest, and its sections' radii averaged over their lengths."""
    sections = sum(s.length_m for s in arm.sections)
    return arm.total_length_m, sum(s.radius_m * s.length_m for s in arm.sections) / sections


def section_length_ranges_m(arm: ArmParams,
                            gravity_mps2: float = STANDARD_GRAVITY_M_S2) -> tuple[tuple[float, float], ...]:
    """(min, max) length of each section as an estimator measures it between connectors: from the
    mount's face to the first baseplate's middle, between baseplates' middles, from the last one's
    middle to the tip.

    The elastic part stretches by axial force / EA: every contractile PMA of the section at the
    highest pressure (its force, moment / moment_arm, shortens it) or every extensile one (lengthens
    it), plus or minus the weight of the arm beyond it (hanging or held upside down). Plates are rigid.
    """
    out = []
    count = len(arm.sections)
    masses = [s.mass_kg for s in arm.sections]
    for i, section in enumerate(arm.sections):
        forces = {kind: sum(float(p.moment_at(arm.max_pressure_bar)) / p.moment_arm_m
                            for p in section.pmas if p.kind == kind) for kind in PMA_KINDS}
        beyond = 0.5 * masses[i] + sum(masses[i + 1:]) + (count - 1 - i) * arm.baseplate.mass_kg
        weight = beyond * gravity_mps2
        shortest = section.length_m * (1.0 - (forces["contractile"] + weight) / section.EA_N)
        longest = section.length_m * (1.0 + (forces["extensile"] + weight) / section.EA_N)
        plates = arm.baseplate.thickness_m * (0.5 * (i > 0) + 0.5 * (i < count - 1))
        out.append((max(shortest, 0.0) + plates, longest + plates))
    return tuple(out)
