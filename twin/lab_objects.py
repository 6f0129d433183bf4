"""Meshes of a lab scene: the wall, the floor, boxes, cables and blobs, with texture coordinates.

Pure geometry and textures (numpy, OpenCV): the renderer turns each :class:`Part` into an
OpenGL mesh. Texture coordinates are in units of the texture's tile, so wood grain and bricks
keep their real size on any object.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from twin.meshes import tube_surface
from twin.scene import BLOB_BUMP, Backdrop, LabScene, SceneObject, Surface, cable_curve
from twin.textures import procedural_texture, value_noise

TEXTURE_PX = 512  # texture tile of an object, pixels on a side
TILE_FEATURES = 16.0  # features per tile: a tile spans TILE_FEATURES * feature_m


@dataclass(frozen=True, eq=False)
class Part:
    """One mesh of the scene, in its object's frame.

    Attributes:
        positions, normals: (V, 3) float32, metres and unit vectors.
        faces: (F, 3) uint32, counter-clockwise seen from outside.
        rgb: display colour in 0..1 (the texture, if any, already carries it: then white).
        uv: (V, 2) float32 texture coordinates, or None.
        texture: (H, W, 3) uint8 display RGB, or None.
    """

    positions: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    rgb: tuple[float, float, float]
    uv: np.ndarray | None = None
    texture: np.ndarray | None = None


def _texture_for(surface: Surface, seed: int, shape=(TEXTURE_PX, TEXTURE_PX)) -> np.ndarray | None:
    if surface.texture is None:
        return None
    feature_px = shape[0] / TILE_FEATURES
    return procedural_texture(surface.texture, shape, surface.rgb, surface.contrast, feature_px, seed)


def _tile_m(surface: Surface) -> float:
    return TILE_FEATURES * surface.feature_m


def _part(positions, normals, faces, surface: Surface, uv=None, texture=None) -> Part:
    rgb = (1.0, 1.0, 1.0) if texture is not None else tuple(surface.rgb)
    return Part(np.asarray(positions, np.float32), np.asarray(normals, np.float32), np.asarray(faces, np.uint32),
                rgb, None if uv is None or texture is None else np.asarray(uv, np.float32), texture)


def box_part(size_m, surface: Surface, seed: int) -> Part:
    """A box centred on its frame's origin with full extents ``size_m``."""
    half = np.asarray(size_m, np.float64) / 2.0
    positions, normals, uvs, faces = [], [], [], []
    tile = _tile_m(surface)
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            u_axis, v_axis = [a for a in range(3) if a != axis]
            corners = []
            for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.zeros(3)
                p[axis] = sign * half[axis]
                p[u_axis] = du * half[u_axis]
                p[v_axis] = dv * half[v_axis]
                corners.append(p)
            corners = np.array(corners)
            # wind counter-clockwise seen from outside
            if np.dot(np.cross(corners[1] - corners[0], corners[2] - corners[0]), n) < 0:
                corners = corners[::-1]
            base = len(positions) * 4
            positions.append(corners)
            normals.append(np.repeat(n[None], 4, axis=0))
            uvs.append(np.column_stack([corners[:, u_axis], corners[:, v_axis]]) / tile)
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    texture = _texture_for(surface, seed)
    return _part(np.vstack(positions), np.vstack(normals), faces, surface, np.vstack(uvs), texture)


def blob_part(semi_axes_m, surface: Surface, seed: int, rings: int = 18, segments: int = 28) -> Part:
    """An irregular ellipsoid (a hand, a bag, a sponge): smooth radial bumps of about 15 %."""
    rng = np.random.default_rng(seed)
    theta = np.linspace(0.0, math.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * math.pi, segments + 1)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    bumps = 1.0 + BLOB_BUMP * value_noise((rings + 1, segments + 1), 6.0, rng, octaves=2)
    bumps[:, -1] = bumps[:, 0]  # the seam closes
    bumps[0, :], bumps[-1, :] = bumps[0].mean(), bumps[-1].mean()  # and so do the poles
    unit = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    positions = unit * bumps[..., None] * np.asarray(semi_axes_m)[None, None, :]
    # normals from the surface's parameter derivatives
    d_th = np.gradient(positions, axis=0)
    d_ph = np.gradient(positions, axis=1)
    normals = np.cross(d_th, d_ph)
    norm = np.linalg.norm(normals, axis=2, keepdims=True)
    normals = np.where(norm > 1e-12, normals / np.maximum(norm, 1e-12), unit)
    outward = np.sum(normals * unit, axis=2, keepdims=True) < 0
    normals = np.where(outward, -normals, normals)
    idx = np.arange((rings + 1) * (segments + 1)).reshape(rings + 1, segments + 1)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, d], 1), np.stack([a, d, b], 1)])
    faces = _outward(positions.reshape(-1, 3), faces)
    uv = np.column_stack([ph.ravel() / (2 * math.pi), th.ravel() / math.pi]) * 4.0
    texture = _texture_for(surface, seed)
    return _part(positions.reshape(-1, 3), normals.reshape(-1, 3), faces, surface, uv, texture)


def _outward(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Flip faces whose winding points inwards (normal towards the centroid)."""
    p = positions[faces]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    centre = positions.mean(axis=0)
    inward = np.sum(normal * (p.mean(axis=1) - centre), axis=1) < 0
    faces = faces.copy()
    faces[inward] = faces[inward][:, ::-1]
    return faces


def cable_part(points_m, radius_m: float, surface: Surface, seed: int, sides: int = 12) -> Part:
    """A cable: a tube of ``radius_m`` along a smooth curve through ``points_m``."""
    curve = cable_curve(points_m)
    at = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
    positions, normals, faces = tube_surface(curve, np.full(len(curve), radius_m), sides)
    texture = _texture_for(surface, seed)
    uv = None
    if texture is not None:
        ring = np.repeat(at, sides) / _tile_m(surface)
        around = np.tile(np.arange(sides) / sides, len(at))
        uv = np.column_stack([ring, around])
        uv = np.vstack([uv, np.zeros((len(positions) - len(uv), 2))])
    return _part(positions, normals, faces, surface, uv, texture)


def object_parts(obj: SceneObject, seed: int) -> list[Part]:
    """The meshes of one scene object in its own frame."""
    if obj.kind == "box":
        return [box_part(obj.size_m, obj.surface, seed)]
    if obj.kind == "blob":
        return [blob_part(obj.size_m, obj.surface, seed)]
    return [cable_part(obj.points_m, obj.radius_m, obj.surface, seed)]


def backdrop_parts(backdrop: Backdrop, seed: int, px_per_m: float = 400.0) -> list[Part]:
    """The wall (facing the camera, -y) and the floor (facing up), in world coordinates."""
    width, height = backdrop.size_m
    cx, cz = backdrop.centre_xz_m
    y = backdrop.wall_y_m
    corners = np.array([[cx - width / 2, y, cz - height / 2], [cx + width / 2, y, cz - height / 2],
                        [cx + width / 2, y, cz + height / 2], [cx - width / 2, y, cz + height / 2]])
    normals = np.tile([0.0, -1.0, 0.0], (4, 1))
    faces = [[0, 1, 2], [0, 2, 3]]  # counter-clockwise seen from the camera (x right, z up)
    # pyrender uploads a texture bottom row first (OpenGL's order), so v = 1 is the image's top row.
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    surface = backdrop.surface
    if backdrop.kind == "image":
        texture = cv2.cvtColor(cv2.imread(str(backdrop.image), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    elif backdrop.kind == "procedural":
        # One scale both ways (a size limit must not stretch the bricks), capped by the texture limits.
        px_per_m = min(px_per_m, 2048 / height, 4096 / width)
        shape = (max(int(round(height * px_per_m)), 2), max(int(round(width * px_per_m)), 2))
        feature_px = surface.feature_m * px_per_m
        texture = procedural_texture(surface.texture, shape, surface.rgb, surface.contrast, feature_px, seed)
    else:
        texture = None
    parts = [_part(corners, normals, faces, surface, uv, texture)]
    if backdrop.floor_z_m is not None and backdrop.floor is not None:
        z = backdrop.floor_z_m
        depth = y + 1.5  # from the wall to behind the camera
        floor = np.array([[cx - width / 2, y, z], [cx + width / 2, y, z], [cx + width / 2, y - depth, z],
                          [cx - width / 2, y - depth, z]])
        fuv = np.column_stack([floor[:, 0], floor[:, 1]]) / _tile_m(backdrop.floor)
        parts.append(_part(floor, np.tile([0.0, 0.0, 1.0], (4, 1)), [[0, 2, 1], [0, 3, 2]], backdrop.floor, fuv,
                           _texture_for(backdrop.floor, seed + 1)))
    return parts


def scene_parts(scene: LabScene) -> tuple[list[Part], list[tuple[SceneObject, list[Part]]],
                                          list[tuple[SceneObject, list[Part]]]]:
    """(static world parts, static objects with their parts, moving objects with their parts)."""
    world = [] if scene.backdrop is None else backdrop_parts(scene.backdrop, scene.seed)
    static, moving = [], []
    for i, obj in enumerate(scene.objects):
        entry = (obj, object_parts(obj, scene.seed * 1000 + i + 1))
        (moving if obj.moving else static).append(entry)
    return world, static, moving
