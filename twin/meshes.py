"""Triangle meshes the twin renders: the arm's tube, rigid props, and poses of their frames.

Pure geometry (numpy): no OpenGL here, so meshes can be built and tested without a renderer.
Positions are metres; normals are unit and outward; faces wind counter-clockwise seen from
outside.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def rotation_minimising_frames(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tangents and rotation-minimising normal/binormal along a polyline (double reflection).

    Wang, Juettler, Zheng, Liu (2008), "Computation of rotation minimizing frames", algorithm 1.

    Args:
        points: (N, 3), N >= 2, consecutive points distinct.

    Returns:
        t, n, b: three (N, 3) arrays of unit vectors; (n, b, t) is right-handed at every point.
    """
    p = np.asarray(points, dtype=np.float64)
    seg = np.diff(p, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    if np.any(seg_len <= 1e-12):
        raise ValueError("points: consecutive backbone points coincide")
    seg /= seg_len[:, None]
    t = np.empty_like(p)
    t[0], t[-1] = seg[0], seg[-1]
    t[1:-1] = seg[1:] + seg[:-1]
    t /= np.linalg.norm(t, axis=1)[:, None]
    # First normal: the world axis least aligned with the first tangent, made perpendicular.
    a = np.eye(3)[np.argmin(np.abs(t[0]))]
    r = a - np.dot(a, t[0]) * t[0]
    r /= np.linalg.norm(r)
    n = np.empty_like(p)
    n[0] = r
    for i in range(len(p) - 1):
        v1 = p[i + 1] - p[i]
        c1 = float(v1 @ v1)
        r_l = n[i] - (2.0 / c1) * float(v1 @ n[i]) * v1
        t_l = t[i] - (2.0 / c1) * float(v1 @ t[i]) * v1
        v2 = t[i + 1] - t_l
        c2 = float(v2 @ v2)
        n[i + 1] = r_l if c2 < 1e-30 else r_l - (2.0 / c2) * float(v2 @ r_l) * v2
    # Remove round-off drift from orthogonality.
    n -= np.sum(n * t, axis=1)[:, None] * t
    n /= np.linalg.norm(n, axis=1)[:, None]
    b = np.cross(t, n)
    return t, n, b


def tube_surface(points: np.ndarray, radius: np.ndarray, sides: int,
                 caps: tuple[bool, bool] = (True, True)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smooth tube swept along a backbone, with flat end caps.

    Args:
        points: (N, 3) backbone, metres.
        radius: (N,) tube radius at each point, metres.
        sides: vertices around each ring.
        caps: whether to close the (start, end) of the tube with a flat disc.

    Returns:
        positions (V, 3) float32, normals (V, 3) float32 (outward, unit), faces (F, 3) uint32
        with counter-clockwise winding seen from outside.
    """
    p = np.asarray(points, dtype=np.float64)
    rad = np.asarray(radius, dtype=np.float64)
    t, n, b = rotation_minimising_frames(p)
    theta = np.linspace(0.0, 2.0 * math.pi, sides, endpoint=False)
    cos, sin = np.cos(theta), np.sin(theta)
    radial = cos[None, :, None] * n[:, None, :] + sin[None, :, None] * b[:, None, :]  # (N, S, 3)
    ring = p[:, None, :] + rad[:, None, None] * radial
    # The surface normal tilts against the tangent where the radius changes: n ~ radial - r'(s) t.
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    drds = np.gradient(rad, s) if len(p) > 2 else np.full(len(p), (rad[-1] - rad[0]) / s[-1])
    normal = radial - drds[:, None, None] * t[:, None, :]
    normal /= np.linalg.norm(normal, axis=2)[..., None]
    N, S = len(p), sides
    positions = [ring.reshape(-1, 3)]
    normals = [normal.reshape(-1, 3)]
    i = np.arange(N - 1)[:, None]
    j = np.arange(S)[None, :]
    a0 = i * S + j
    a1 = i * S + (j + 1) % S
    b0 = a0 + S
    b1 = a1 + S
    # (n, b, t) right-handed: going around by +theta and along +t, the quad (a0, a1, b1, b0)
    # has its outward normal along radial when wound a0 -> a1 -> b1.
    faces = [np.stack([a0, a1, b1], -1).reshape(-1, 3), np.stack([a0, b1, b0], -1).reshape(-1, 3)]
    count = N * S
    for end, keep in zip((0, N - 1), caps, strict=True):
        if not keep:
            continue
        outward = -t[end] if end == 0 else t[end]
        centre = count
        positions.append(np.vstack([p[end][None], ring[end]]))
        normals.append(np.repeat(outward[None], S + 1, axis=0))
        rim = centre + 1 + np.arange(S)
        nxt = centre + 1 + (np.arange(S) + 1) % S
        tri = np.stack([np.full(S, centre), nxt, rim], -1) if end == 0 else np.stack([np.full(S, centre), rim, nxt], -1)
        faces.append(tri)
        count += S + 1
    return (np.vstack(positions).astype(np.float32), np.vstack(normals).astype(np.float32),
            np.vstack(faces).astype(np.uint32))


def pose_with_z(z_axis: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """(4, 4) pose whose z axis points along ``z_axis`` and whose origin is ``origin`` (x, y arbitrary)."""
    z = np.asarray(z_axis, float) / np.linalg.norm(z_axis)
    a = np.eye(3)[np.argmin(np.abs(z))]
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = origin
    return T


@dataclass(frozen=True, eq=False)
class Prop:
    """An extra object in the scene (e.g. a calibration board): one or more triangle meshes.

    Attributes:
        parts: tuples (positions (V, 3), normals (V, 3), faces (F, 3), display RGB colour) in the
            prop's own frame, metres.
        T_world_prop: (4, 4) pose of the prop in the world.
    """

    parts: tuple[tuple[np.ndarray, np.ndarray, np.ndarray, tuple[float, float, float]], ...]
    T_world_prop: np.ndarray
