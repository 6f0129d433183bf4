"""MuJoCo simulation of the arm: pressures in, backbone and surface geometry out.

``ArmSimulation`` owns one MuJoCo model generated from ``ArmParams`` (see ``twin.mjcf`` for the
discretisation and why it was chosen) and exposes named quantities only: commanded and chamber
pressures, the backbone, the shape with its plates, section end points and bending angles. Nothing
downstream should index ``qpos``.

Time advances in whole MuJoCo steps, many per call into MuJoCo (``mj_step(..., nstep)``); after each
batch the state is checked, and a MuJoCo warning, a NaN or a diverging state raises
``SimulationError`` naming the exact step (the batch is replayed step by step from a saved state to
find it, which costs nothing when all is well).
"""

from __future__ import annotations

import logging
import math
import os
import warnings
from collections.abc import Sequence

# The twin renders with pyrender, never through MuJoCo's own GL context. Left to choose one, MuJoCo
# imports glfw, whose import probes the GLFW library in a child Python process; a study's worker
# stopped while that probe ran left it to die on the closed pipe, printing a BrokenPipeError traceback
# on the study's stderr (tests/bench/test_studies.py, under load).
os.environ.setdefault("MUJOCO_GL", "disable")
import mujoco  # noqa: E402 - after MUJOCO_GL
import numpy as np

import hardware.errors
from twin.mjcf import STANDARD_GRAVITY_M_S2, chain_layout, make_mjcf
from twin.params import ArmParams
from twin.shape import ArmShape, Plate

_log = logging.getLogger(__name__)

_BATCH_STEPS = 100  # steps per call into MuJoCo between state checks
_MAX_JOINT_SPEED = 1e3  # rad/s or m/s: no soft arm moves like this; the integration has diverged
_SAMPLES_PER_SEGMENT = 12  # backbone: points per interpolated segment before arc-length resampling
_WARNING_NAMES = {int(w): w.name for w in (mujoco.mjtWarning.mjWARN_INERTIA, mujoco.mjtWarning.mjWARN_CONTACTFULL,
                                          mujoco.mjtWarning.mjWARN_CNSTRFULL, mujoco.mjtWarning.mjWARN_BADQPOS,
                                          mujoco.mjtWarning.mjWARN_BADQVEL, mujoco.mjtWarning.mjWARN_BADQACC,
                                          mujoco.mjtWarning.mjWARN_BADCTRL)}
_DOF_WARNINGS = {int(mujoco.mjtWarning.mjWARN_BADQPOS), int(mujoco.mjtWarning.mjWARN_BADQVEL),
                 int(mujoco.mjtWarning.mjWARN_BADQACC)}


def _route_mujoco_warnings() -> None:
    """Send MuJoCo's warning text to ``logging`` instead of stdout and ./MUJOCO_LOG.TXT.

    The simulation reports every warning as a ``SimulationError`` anyway; MuJoCo's own printing
    would litter the working directory. A handler someone else installed is left alone.
    """
    if mujoco.get_mju_user_warning() is None:
        mujoco.set_mju_user_warning(lambda message: _log.warning("MuJoCo: %s", message))


class SimulationError(hardware.errors.SimulationError):
    """The simulation produced a MuJoCo warning, a NaN or a diverging state (a device error of the twin).

    Attributes:
        step: 1-based index of the MuJoCo step (since the last reset) after which it was detected.
        time_s: simulated time at the end of that step.
    """

    def __init__(self, message: str, step: int, time_s: float) -> None:
        super().__init__(message)
        self.step = step
        self.time_s = time_s


class NotSettledWarning(UserWarning):
    """``ArmSimulation.settle`` reached its time limit before the arm came to rest."""


class ArmSimulation:
    """The arm in MuJoCo, driven by chamber pressures.

    Args:
        params: the arm (``ArmParams.load()`` for ``models/arm.toml``).
        timestep_s: integration step; 2 ms holds the validation and runs > 10x real time.
        gravity_world: (3,) m/s^2 in the world frame; tilt it to emulate a base mount held
            horizontally (how a lab identifies EI), or zero it.

    Raises:
        ValueError: a non-positive timestep or a malformed gravity vector.
    """

    def __init__(self, params: ArmParams, timestep_s: float = 0.002,
                 gravity_world: Sequence[float] = (0.0, 0.0, -STANDARD_GRAVITY_M_S2)) -> None:
        _route_mujoco_warnings()
        self.params = params
        self._layout = chain_layout(params)
        self._model = mujoco.MjModel.from_xml_string(
            make_mjcf(params, timestep_s=timestep_s, gravity_world=tuple(gravity_world)))
        self._data = mujoco.MjData(self._model)
        m = self._model
        self._channels = params.channels
        # all actuators of a channel (one per table segment) get the same control; the first reports the chamber
        self._actuators = [
            np.array([i for i in range(m.nu) if m.tendon(m.actuator_trnid[i, 0]).name == channel])
            for channel in self._channels]
        self._chamber_act = np.array([m.actuator_actadr[ids[0]] for ids in self._actuators])
        self._bodies = np.array([m.body(link.name).id for link in self._layout.links])
        self._home = m.key("home").id
        self._tip = m.site("tip").id
        self._state_spec = mujoco.mjtState.mjSTATE_INTEGRATION
        self._saved = np.empty(mujoco.mj_stateSize(m, self._state_spec))
        self._commanded = np.zeros(len(self._channels))
        self._steps = 0
        # constant geometry for the backbone
        links = self._layout.links
        self._span = np.array([link.span_m for link in links])
        self._s_joint = np.array([link.s_joint_m for link in links])
        self._section_of = np.array([link.section for link in links])
        self._twist_qpos = np.array([m.jnt_qposadr[m.joint(f"{link.name}_twist").id] for link in links])
        self._plate_links, self._plate_offsets = [], []
        for n, link in enumerate(links):
            for piece in link.pieces:
                if piece.kind == "plate":
                    self._plate_links.append(n)
                    self._plate_offsets.append((piece.start_m, piece.end_m))
        radii = [s.radius_m for s in params.sections]
        mids = [(a + b) / 2 for a, b in self._layout.plate_spans_m]
        self._radius_breaks, self._radii = np.array(mids), np.array(radii)
        self.reset()

    # ------------------------------------------------------------------ inputs and state
    @property
    def channels(self) -> tuple[str, ...]:
        return self._channels

    @property
    def max_pressure_bar(self) -> float:
        return self.params.max_pressure_bar

    @property
    def timestep_s(self) -> float:
        return float(self._model.opt.timestep)

    @property
    def time_s(self) -> float:
        """Simulated seconds since the last reset (whole steps times the timestep, no drift)."""
        return self._steps * self.timestep_s

    @property
    def commanded_bar(self) -> np.ndarray:
        """(n_channels,) last commanded pressures, channel order."""
        return self._commanded.copy()

    @property
    def chamber_bar(self) -> np.ndarray:
        """(n_channels,) chamber pressures now, lagging the commands by the valve time constant."""
        return self._data.act[self._chamber_act].copy()

    @property
    def model(self) -> mujoco.MjModel:
        """The MuJoCo model, for viewers and diagnostics (use the named accessors for geometry)."""
        return self._model

    @property
    def data(self) -> mujoco.MjData:
        """The MuJoCo data, for viewers and diagnostics (use the named accessors for geometry)."""
        return self._data

    def command(self, pressures_bar: Sequence[float] | np.ndarray) -> None:
        """Set the valve set-points, one per channel in ``channels`` order, in bar.

        Raises:
            ValueError: wrong count, or a value that is not finite or outside [0, max_pressure_bar];
                the message names the channel.
        """
        values = np.asarray(pressures_bar, dtype=float)
        if values.shape != (len(self._channels),):
            raise ValueError(f"expected {len(self._channels)} pressures in channel order "
                             f"({', '.join(self._channels)}), got shape {values.shape}")
        for name, bar in zip(self._channels, values, strict=True):
            if not math.isfinite(bar):
                raise ValueError(f"channel {name}: pressure {bar} is not finite")
            if not 0 <= bar <= self.max_pressure_bar:
                raise ValueError(f"channel {name}: {bar} bar is outside [0, {self.max_pressure_bar}] bar")
        for ids, bar in zip(self._actuators, values, strict=True):
            self._data.ctrl[ids] = bar
        self._commanded = values.copy()

    def reset(self) -> None:
        """Back to the ``home`` keyframe: straight, unstrained, vented, t = 0 (gravity then stretches it)."""
        mujoco.mj_resetDataKeyframe(self._model, self._data, self._home)
        mujoco.mj_forward(self._model, self._data)
        self._commanded = np.zeros(len(self._channels))
        self._steps = 0

    # ------------------------------------------------------------------ time
    def advance(self, duration_s: float) -> None:
        """Simulate ``duration_s`` seconds (rounded to whole timesteps) with the current commands.

        Raises:
            ValueError: a negative or non-finite duration.
            SimulationError: a MuJoCo warning, NaN or diverging state; names the step. Call
                ``reset()`` before using the simulation again.
        """
        if not (math.isfinite(duration_s) and duration_s >= 0):
            raise ValueError(f"duration_s: expected a finite number >= 0, got {duration_s!r}")
        remaining = round(duration_s / self.timestep_s)
        while remaining > 0:
            n = min(remaining, _BATCH_STEPS)
            self._run(n)
            remaining -= n
        # mj_step leaves the derived quantities (xpos, xmat, cvel) one step behind qpos: refresh the
        # ones the accessors use (the full mj_forward would refactor the mass matrix for nothing)
        m, d = self._model, self._data
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)

    def settle(self, tol_m_s: float = 1e-4, tol_bar: float = 1e-3, max_time_s: float = 30.0,
               check_every_s: float = 0.05) -> bool:
        """Advance until the arm is static: every joint point and the tip slower than ``tol_m_s`` (now and
        on average over the last ``check_every_s``) and every chamber within ``tol_bar`` of its command.

        Not settling is not an error (the shape is still the true one at that instant): it warns
        with ``NotSettledWarning`` and returns False, so a caller that needs rest can insist.

        Returns:
            True when the arm came to rest within ``max_time_s`` of simulated time.

        Raises:
            ValueError: a tolerance or time that is not a positive number.
            SimulationError: as in ``advance``.
        """
        for name, value in (("tol_m_s", tol_m_s), ("tol_bar", tol_bar), ("max_time_s", max_time_s),
                            ("check_every_s", check_every_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a positive number, got {value!r}")
        start_step = self._steps
        limit_steps = math.ceil(max_time_s / self.timestep_s - 1e-9)
        interval_s = max(1, round(check_every_s / self.timestep_s)) * self.timestep_s  # at least one step
        while True:
            before = self._tracked_points()
            self.advance(interval_s)
            # both the speed now and the mean speed over the interval: a turning point of a swing
            # has no speed but has moved
            mean_speed = float(np.max(np.linalg.norm(self._tracked_points() - before, axis=1))) / interval_s
            speed = max(mean_speed, self._max_point_speed())
            if speed < tol_m_s and np.all(np.abs(self.chamber_bar - self._commanded) < tol_bar):
                return True
            if self._steps - start_step >= limit_steps:
                warnings.warn(f"arm not at rest after {max_time_s} s of simulated time (t = {self.time_s:.3f} s, "
                              f"fastest point {speed:.2e} m/s)", NotSettledWarning, stacklevel=2)
                return False

    def _run(self, n: int) -> None:
        m, d = self._model, self._data
        mujoco.mj_getState(m, d, self._saved, self._state_spec)
        counts = self._warning_counts()
        mujoco.mj_step(m, d, nstep=n)
        if self._problem(counts) is None:
            self._steps += n
            return
        # replay the batch one step at a time to name the step where it went wrong
        mujoco.mj_setState(m, d, self._saved, self._state_spec)
        for k in range(1, n + 1):
            counts = self._warning_counts()
            mujoco.mj_step(m, d)
            problem = self._problem(counts)
            if problem is not None:
                step = self._steps + k
                time_s = step * m.opt.timestep
                raise SimulationError(f"simulation failed at step {step} (t = {time_s:.4f} s, "
                                      f"timestep {m.opt.timestep:g} s): {problem}", step, time_s)
        step = self._steps + n  # not reproduced step by step (should not happen): name the batch's end
        raise SimulationError(f"simulation failed by step {step} (t = {step * m.opt.timestep:.4f} s): "
                              f"{self._problem(np.zeros_like(counts))}", step, step * m.opt.timestep)

    def _warning_counts(self) -> np.ndarray:
        return self._data.warning.number.copy()  # a view; iterating the stat objects costs 60 us

    def _problem(self, counts_before: np.ndarray) -> str | None:
        d, m = self._data, self._model
        new = np.flatnonzero(self._warning_counts() > counts_before)
        if len(new):
            parts = []
            for w in new:
                info = int(d.warning.lastinfo[w])
                where = f" (dof {info}: joint {m.joint(m.dof_jntid[info]).name})" \
                    if w in _DOF_WARNINGS and 0 <= info < m.nv else f" (info {info})"
                parts.append(f"MuJoCo warning {_WARNING_NAMES.get(int(w), w)}{where}")
            return "; ".join(parts)
        for name in ("qpos", "qvel", "act"):
            values = getattr(d, name)
            if not np.all(np.isfinite(values)):
                i = int(np.flatnonzero(~np.isfinite(values))[0])
                return f"{name}[{i}] is {values[i]}"
        fastest = int(np.argmax(np.abs(d.qvel)))
        if abs(d.qvel[fastest]) > _MAX_JOINT_SPEED:
            return (f"diverging: joint {m.joint(m.dof_jntid[fastest]).name} moves at {d.qvel[fastest]:.3g} "
                    f"(limit {_MAX_JOINT_SPEED:g} rad/s or m/s); is the timestep too large?")
        return None

    def _tracked_points(self) -> np.ndarray:
        """(n_links + 1, 3) the joint points and the tip."""
        return np.vstack([self._data.xpos[self._bodies], self.tip_position()])

    def _max_point_speed(self) -> float:
        """Fastest linear speed of a joint point or the tip, m/s."""
        velocity = np.empty(6)
        fastest = 0.0
        objects = [(mujoco.mjtObj.mjOBJ_BODY, body) for body in self._bodies] + [(mujoco.mjtObj.mjOBJ_SITE, self._tip)]
        for kind, index in objects:
            mujoco.mj_objectVelocity(self._model, self._data, kind, index, velocity, 0)
            fastest = max(fastest, float(np.linalg.norm(velocity[3:])))
        return fastest

    # ------------------------------------------------------------------ geometry
    def _axes(self) -> np.ndarray:
        """(n_links, 3) unit direction of each link toward the tip (its local -z)."""
        return -self._data.xmat[self._bodies].reshape(-1, 3, 3)[:, :, 2]

    def _nodes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Backbone nodes with unit tangents (K, 3), (K, 3) and reference arc lengths (K,).

        The chain lumps each element's bending into the joint at its middle, so the rod's element
        boundaries are the links' midpoints, where the rod's tangent is the link's axis. The nodes are
        those points (the plates' faces for a link carrying a plate, which keeps plates straight), the
        base point and the tip; between two nodes the rod turns by one joint's angle.
        """
        points = self._data.xpos[self._bodies]
        axes = self._axes()
        s_joint = self._s_joint
        node_p, node_t, node_s = [np.zeros(3)], [np.array([0.0, 0.0, -1.0])], [0.0]
        plates = dict(zip(self._plate_links, self._plate_offsets, strict=True))
        last = len(points) - 1
        for n in range(len(points)):
            if n in plates:
                for offset in plates[n]:
                    node_p.append(points[n] + offset * axes[n])
                    node_t.append(axes[n])
                    node_s.append(s_joint[n] + offset)
            elif n == last:
                node_p.append(points[n] + self._span[n] * axes[n])
                node_t.append(axes[n])
                node_s.append(self._layout.total_length_m)
            else:
                node_p.append((points[n] + points[n + 1]) / 2)
                node_t.append(axes[n])
                node_s.append(s_joint[n] + self._span[n] / 2)
        return np.array(node_p), np.array(node_t), np.array(node_s)

    def _dense(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The backbone sampled densely: positions (M, 3), arc length (M,), reference arc length (M,)."""
        p, t, s_ref = self._nodes()
        p0, p1, t0, t1 = p[:-1], p[1:], t[:-1], t[1:]
        chord = np.linalg.norm(p1 - p0, axis=1)
        # Hermite tangent length that makes the cubic follow the circular arc through both nodes
        half = 0.5 * np.arccos(np.clip(np.einsum("ij,ij->i", t0, t1), -1.0, 1.0))
        ratio = np.where(half > 1e-6, 2 * np.tan(half / 2) / np.where(half > 1e-6, np.sin(half), 1.0), 1.0)
        scale = (chord * ratio)[:, None, None]
        u = np.linspace(0.0, 1.0, _SAMPLES_PER_SEGMENT, endpoint=False)[None, :, None]
        h00, h10, h01, h11 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2
        curve = h00 * p0[:, None] + h10 * scale * t0[:, None] + h01 * p1[:, None] + h11 * scale * t1[:, None]
        curve = np.vstack([curve.reshape(-1, 3), p[-1:]])
        s_dense_ref = np.concatenate([(s_ref[:-1, None] + u[0, :, 0] * np.diff(s_ref)[:, None]).ravel(), s_ref[-1:]])
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
        return curve, arc, s_dense_ref

    def backbone(self, n_points: int = 200) -> np.ndarray:
        """The backbone now: (n_points, 3) metres, world frame, base -> tip, evenly spaced in arc length.

        A C1 curve through the base point (exactly), every joint point and the tip, with tangents from
        the link frames (cubic Hermite segments), resampled by arc length.
        """
        return self._resample(n_points)[0]

    def shape(self, n_points: int = 200) -> ArmShape:
        """The backbone with its arc length, tube radius per point and plates (base mount first)."""
        points, s, s_ref = self._resample(n_points)
        radius = self._radii[np.searchsorted(self._radius_breaks, s_ref, side="right")]
        return ArmShape(points_world=points, s_m=s, radius_m=radius, plates=self.plates())

    def plates(self) -> tuple[Plate, ...]:
        """The base mount and the baseplates, posed on the backbone."""
        mount, plate = self.params.base_mount, self.params.baseplate
        out = [Plate(center_world=np.array([0.0, 0.0, mount.thickness_m / 2]), normal_world=np.array([0.0, 0.0, -1.0]),
                     radius_m=mount.radius_m, thickness_m=mount.thickness_m)]
        points, axes = self._data.xpos[self._bodies], self._axes()
        for n, (start, end) in zip(self._plate_links, self._plate_offsets, strict=True):
            out.append(Plate(center_world=points[n] + (start + end) / 2 * axes[n], normal_world=axes[n].copy(),
                             radius_m=plate.radius_m, thickness_m=plate.thickness_m))
        return tuple(out)

    def _resample(self, n_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if isinstance(n_points, bool) or not isinstance(n_points, int | np.integer) or n_points < 2:
            raise ValueError(f"n_points: expected an integer >= 2, got {n_points!r}")
        curve, arc, s_ref = self._dense()
        s = np.linspace(0.0, arc[-1], n_points)
        points = np.column_stack([np.interp(s, arc, curve[:, k]) for k in range(3)])
        points[0], points[-1] = curve[0], curve[-1]
        return points, s, np.interp(s, arc, s_ref)

    def tip_position(self) -> np.ndarray:
        """(3,) metres, world frame."""
        return self._data.site_xpos[self._tip].copy()

    def section_end_points(self) -> np.ndarray:
        """(n_sections, 3) metres: the distal end of each section's elastic part (a plate's face, or the tip)."""
        p, _, s_ref = self._nodes()
        ends = [b for _, b in self._layout.section_spans_m]
        return np.array([p[np.flatnonzero(np.isclose(s_ref, b, rtol=0, atol=1e-9))[0]] for b in ends])

    def section_bend_deg(self) -> np.ndarray:
        """(n_sections,) angle between each section's tangents at its proximal and distal ends, degrees."""
        proximal, distal = self._section_end_axes()
        return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", proximal, distal), -1.0, 1.0)))

    def section_twist_deg(self) -> np.ndarray:
        """(n_sections,) material twist of each section: the cross-sections' rotation about the backbone
        accumulated from its proximal to its distal end (the sum of its twist joints), degrees."""
        twist = self._data.qpos[self._twist_qpos]
        return np.degrees(np.array([twist[self._section_of == k].sum() for k in range(len(self.params.sections))]))

    def section_lengths_m(self) -> np.ndarray:
        """(n_sections,) current length of each section's elastic part (the chain through its joints)."""
        p, _, s_ref = self._nodes()
        joints = self._data.xpos[self._bodies]
        out = []
        for k, (a, b) in enumerate(self._layout.section_spans_m):
            ends = [p[np.flatnonzero(np.isclose(s_ref, x, rtol=0, atol=1e-9))[0]] for x in (a, b)]
            chain = np.vstack([ends[0], joints[self._section_of == k], ends[1]])
            out.append(float(np.linalg.norm(np.diff(chain, axis=0), axis=1).sum()))
        return np.array(out)

    def _section_end_axes(self) -> tuple[np.ndarray, np.ndarray]:
        axes = self._axes()
        proximal, distal = [], []
        for k in range(len(self.params.sections)):
            ids = [n for n, link in enumerate(self._layout.links) if link.section == k]
            proximal.append(axes[ids[0] - 1] if ids[0] > 0 else np.array([0.0, 0.0, -1.0]))
            distal.append(axes[ids[-1]])
        return np.array(proximal), np.array(distal)
