"""A checkerboard calibration target the twin renders at chosen poses, in both raw images.

The board is geometry, not a texture: every square is its own quad (black or white) on one
plane, so its edges are as sharp as the anti-aliasing makes them and no texture filtering
blurs the corners. Images go through the same distortion, blur and noise as the arm's.

Board frame: x along the inner-corner columns, y along the rows, z out of the printed face
(towards the camera); the origin is the first inner corner, as ``BoardSpec.object_points``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from estimator.board_calibration import BoardSpec
from twin.render import Prop, StereoImages, StereoRenderer
from twin.rig import StereoRig

WHITE_RGB = (1.0, 1.0, 1.0)
BLACK_RGB = (0.06, 0.06, 0.06)


def _quads(rects: list[tuple[float, float, float, float]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axis-aligned rectangles (x0, y0, x1, y1) on z = 0 facing +z -> positions, normals, faces."""
    r = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
    x0, y0, x1, y1 = r.T
    z = np.zeros(len(r))
    corners = np.stack([np.column_stack([x0, y0, z]), np.column_stack([x1, y0, z]),
                        np.column_stack([x1, y1, z]), np.column_stack([x0, y1, z])], axis=1)
    positions = corners.reshape(-1, 3).astype(np.float32)
    normals = np.tile(np.array([0, 0, 1], np.float32), (len(positions), 1))
    base = 4 * np.arange(len(r))[:, None]
    faces = np.vstack([base + [0, 1, 2], base + [0, 2, 3]]).astype(np.uint32)
    return positions, normals, faces


def board_prop(board: BoardSpec, T_world_board: np.ndarray, margin_squares: float = 1.0) -> Prop:
    """The board as a renderable prop: (cols + 1) x (rows + 1) squares and a white margin.

    The square touching the first inner corner's (-x, -y) side is black.
    """
    sq = board.square_m
    black, white = [], []
    for i in range(board.inner_rows + 1):
        for j in range(board.inner_cols + 1):
            rect = ((j - 1) * sq, (i - 1) * sq, j * sq, i * sq)
            (black if (i + j) % 2 == 0 else white).append(rect)
    m = margin_squares * sq
    x0, y0 = -sq - m, -sq - m
    x1, y1 = board.inner_cols * sq + m, board.inner_rows * sq + m
    white += [(x0, y0, x1, -sq), (x0, board.inner_rows * sq, x1, y1),
              (x0, -sq, -sq, board.inner_rows * sq), (board.inner_cols * sq, -sq, x1, board.inner_rows * sq)]
    return Prop(parts=(_quads(black) + (BLACK_RGB,), _quads(white) + (WHITE_RGB,)),
                T_world_prop=np.asarray(T_world_board, dtype=np.float64))


def _rotation(rx: float, ry: float, rz: float) -> np.ndarray:
    return cv2.Rodrigues(np.array([rx, ry, rz], dtype=np.float64))[0]


def board_poses(rig: StereoRig, board: BoardSpec, n: int, *, seed: int = 0, margin_px: float = 25.0,
                distance_m: tuple[float, float] = (0.55, 1.0), max_tilt_deg: float = 40.0) -> list[np.ndarray]:
    """Poses (world frame, 4x4) of a hand-held board that calibrate well.

    The board centre visits a grid over the left image (corners and edges included, where the
    distortion is strongest), at a random distance, tilted up to ``max_tilt_deg`` about its two
    in-plane axes and rolled a little; every corner stays ``margin_px`` inside both raw images
    and the board faces both cameras.

    Raises:
        RuntimeError: no valid pose was found for a view (the board is too large for the image).
    """
    rng = np.random.default_rng(seed)
    calib = rig.calibration
    w, h = calib.image_size
    obj = board.object_points().astype(np.float64)
    centre = obj.mean(axis=0)
    # Visit image regions in a fixed order: a 4 x 3 grid of targets, then random ones.
    grid = [(u, v) for v in (0.22, 0.5, 0.78) for u in (0.2, 0.4, 0.6, 0.8)]
    order = [grid[i] for i in rng.permutation(len(grid))]
    poses = []
    for k in range(n):
        for _ in range(500):
            target = order[k] if k < len(order) else tuple(rng.uniform(0.15, 0.85, 2))
            jitter = rng.normal(0.0, 0.03, 2)
            u = (target[0] + jitter[0]) * w
            v = (target[1] + jitter[1]) * h
            ray = cv2.undistortPoints(np.array([[[u, v]]]), calib.K_left, calib.dist_left.reshape(1, -1))
            ray = np.append(ray.ravel(), 1.0)
            d = rng.uniform(*distance_m)
            tilt = math.radians(max_tilt_deg)
            R_cam_board = (_rotation(math.pi, 0.0, 0.0)  # board z towards the camera, x right
                           @ _rotation(rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt), rng.uniform(-0.35, 0.35)))
            t = ray * d - R_cam_board @ centre
            pts_l = obj @ R_cam_board.T + t
            ok = True
            for side in ("left", "right"):
                uv = calib.project(pts_l, side)
                if (uv.min() < margin_px or uv[:, 0].max() > w - 1 - margin_px
                        or uv[:, 1].max() > h - 1 - margin_px):
                    ok = False
            normal = R_cam_board[:, 2]
            for origin in (np.zeros(3), -calib.R.T @ calib.T):
                to_cam = origin - (t + R_cam_board @ centre)
                if np.dot(normal, to_cam) / np.linalg.norm(to_cam) < 0.35:
                    ok = False
            if ok:
                T_cam_board = np.eye(4)
                T_cam_board[:3, :3], T_cam_board[:3, 3] = R_cam_board, t
                poses.append(rig.T_world_cam_left @ T_cam_board)
                break
        else:
            raise RuntimeError(f"no valid board pose found for view {k}: the board may be too large for the image")
    return poses


def board_corners_left_camera(rig: StereoRig, board: BoardSpec, T_world_board: np.ndarray) -> np.ndarray:
    """(N, 3) true inner-corner positions in the left camera frame, metres (object-point order)."""
    obj = board.object_points().astype(np.float64)
    T = np.asarray(T_world_board, dtype=np.float64)
    return rig.world_to_left_camera(obj @ T[:3, :3].T + T[:3, 3])


def render_board_views(renderer: StereoRenderer, board: BoardSpec,
                       poses: Sequence[np.ndarray]) -> list[StereoImages]:
    """Render the board alone (no arm) at each pose: raw stereo pairs through the full sensor path."""
    return [renderer.render(None, depth=False, props=(board_prop(board, T),)) for T in poses]
