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
import tomllib
import typing
from dataclasses import dataclass
from pathlib import Path

import numpy as np

DEFAULT_PARAMS_PATH = Path(__file__).resolve().parents[1] / "models" / "arm.toml"

PMA_KINDS = ("contractile", "extensile")
_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


class ParamsFileError(ValueError):
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
        try:
            data = tomllib.loads(path.read_text())
        except FileNotFoundError as e:
            raise ParamsFileError(f"{path}: arm parameter file not found") from e
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise ParamsFileError(f"{path}: not a TOML file ({e})") from e
        reader = _Reader(path)
        arm = reader.table(data, "arm", "")
        top_keys = {"arm", "base_mount", "baseplate", "section"}
        reader.no_unknown(data, top_keys, "")
        sections_raw = data.get("section")
        if not isinstance(sections_raw, list) or not sections_raw:
            raise ParamsFileError(f"{path}: missing key 'section' (one [[section]] table per section, base to tip)")
        sections = tuple(reader.section(raw, f"section[{i}]") for i, raw in enumerate(sections_raw))
        return reader.build(cls, arm, "arm", max_pressure_bar=float, valve_time_constant_s=float,
                            extra={"base_mount": reader.build(BaseMountParams, reader.table(data, "base_mount", ""),
                                                              "base_mount", radius_m=float, thickness_m=float),
                                   "baseplate": reader.plate(data, "baseplate"),
                                   "sections": sections, "source": path})


class _Reader:
    """Turns TOML tables into the dataclasses above, naming the file and key in every error."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, key: str, reason: str) -> typing.NoReturn:
        raise ParamsFileError(f"{self.path}: key '{key}': {reason}")

    def table(self, data: dict, name: str, where: str) -> dict:
        key = f"{where}.{name}" if where else name
        if name not in data:
            raise ParamsFileError(f"{self.path}: missing key '{key}'")
        if not isinstance(data[name], dict):
            self.fail(key, f"expected a table, got {type(data[name]).__name__}")
        return data[name]

    def no_unknown(self, table: dict, allowed: set[str], where: str) -> None:
        for key in table:
            if key not in allowed:
                self.fail(f"{where}.{key}" if where else key,
                          f"unknown key; expected one of {', '.join(sorted(allowed))}")

    def value(self, table: dict, key: str, kind: type, where: str):
        full = f"{where}.{key}"
        if key not in table:
            raise ParamsFileError(f"{self.path}: missing key '{full}'")
        value = table[key]
        if kind is float:
            if isinstance(value, bool) or not isinstance(value, int | float):
                self.fail(full, f"expected a number, got {value!r}")
            return float(value)
        if kind is int:
            if isinstance(value, bool) or not isinstance(value, int):
                self.fail(full, f"expected an integer, got {value!r}")
            return value
        if kind is str:
            if not isinstance(value, str):
                self.fail(full, f"expected a string, got {value!r}")
            return value
        # tuple of floats
        if not isinstance(value, list) or not all(isinstance(v, int | float) and not isinstance(v, bool)
                                                  for v in value):
            self.fail(full, f"expected an array of numbers, got {value!r}")
        return tuple(float(v) for v in value)

    def build(self, cls, table: dict, where: str, extra: dict | None = None, **kinds):
        extra = extra or {}
        self.no_unknown(table, set(kinds) | ({"pma"} if "pmas" in extra else set()), where)
        values = {key: self.value(table, key, kind, where) for key, kind in kinds.items()}
        try:
            return cls(**values, **extra)
        except ValueError as e:
            # __post_init__ messages start with the field, or with a nested key such as section[1].pma[0].channel
            field, _, reason = str(e).partition(": ")
            if field.startswith("section[") or field == "section":
                self.fail(field, reason)
            if field in kinds or field == "pma":
                self.fail(f"{where}.{field}", reason)
            raise ParamsFileError(f"{self.path}: table '{where}': {e}") from e

    def plate(self, data: dict, name: str) -> PlateParams:
        return self.build(PlateParams, self.table(data, name, ""), name,
                          radius_m=float, thickness_m=float, mass_kg=float)

    def section(self, raw, where: str) -> SectionParams:
        if not isinstance(raw, dict):
            self.fail(where, "expected a table")
        pmas_raw = raw.get("pma")
        if not isinstance(pmas_raw, list) or not pmas_raw:
            raise ParamsFileError(f"{self.path}: missing key '{where}.pma' (one [[section.pma]] table per PMA)")
        pmas = tuple(
            self.build(PMAParams, p if isinstance(p, dict) else self.fail(f"{where}.pma[{j}]", "expected a table"),
                       f"{where}.pma[{j}]", channel=str, kind=str, azimuth_deg=float, moment_arm_m=float,
                       helix_angle_deg=float, pressure_bar=tuple, moment_Nm=tuple)
            for j, p in enumerate(pmas_raw))
        return self.build(SectionParams, raw, where, extra={"pmas": pmas},
                          length_m=float, radius_m=float, mass_kg=float, EI_Nm2=float, GJ_Nm2=float, EA_N=float,
                          damping_time_s=float, n_links=int)
