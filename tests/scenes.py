"""Small synthetic stereo scenes with exact ground truth, drawn without OpenGL.

A tube (flat end caps, dark baseplates between sections) is meshed along a known backbone,
every facet is projected through the full camera model (distortion included) and filled in
depth order at 4x resolution, then averaged down: anti-aliased raw images like a real camera's.
Independent of the twin's renderer on purpose, so the two can check each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from estimator import StereoCalibration

ORANGE_BGR = np.array([20.0, 110.0, 245.0])
PLATE_BGR = np.array([60.0, 60.0, 60.0])
BACKGROUND_BGR = (200, 190, 180)
LIGHT_CAM = np.array([-0.3, -0.5, -1.0]) / np.linalg.norm([-0.3, -0.5, -1.0])  # towards the light
SUPERSAMPLE = 4


def zed_like_calibration() -> StereoCalibration:
    """A raw ZED-like pair: distortion, slightly different intrinsics, a few mrad of rotation."""
    K1 = np.array([[700.9, 0, 645.5], [0, 700.9, 361.2], [0, 0, 1]])
    K2 = np.array([[699.0, 0, 639.7], [0, 699.0, 364.9], [0, 0, 1]])
    R = cv2.Rodrigues(np.array([0.0061, 0.0068, -0.0019]))[0]
    return StereoCalibration(K1, [-0.176, 0.0266, 0.0004, -0.0003, 0.0], K2, [-0.175, 0.0267, -0.0002, 0.0003, 0.0],
                             R, [-0.12, 0.0003, -0.0002], (1280, 720))


def rectified_calibration() -> StereoCalibration:
    """An ideal rectified pair built from two projection matrices."""
    K = np.array([[700.0, 0, 640.0], [0, 700.0, 360.0], [0, 0, 1]])
    P1 = np.hstack([K, np.zeros((3, 1))])
    P2 = np.hstack([K, K @ np.array([[-0.12], [0.0], [0.0]])])
    return StereoCalibration.from_projection_matrices(P1, P2, (1280, 720))


@dataclass(frozen=True)
class Section:
    length_m: float
    curvature_per_m: float  # bending curvature
    plane_rad: float  # direction of bending around the local tangent
    twist_rad_per_m: float = 0.0


def backbone(sections: list[Section], base_cam: tuple[float, float, float], n: int = 400,
             tilt_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Piecewise constant-curvature backbone in the left camera frame, hanging down the image.

    Returns:
        points (n, 3) metres base -> tip, and the arc lengths (n,) at which sections end.
    """
    total = sum(s.length_m for s in sections)
    ds = total / (n - 1)
    # frame columns: normal1, normal2, tangent; tangent starts along +y (down the image), tilted toward -z.
    t0 = np.array([0.0, np.cos(tilt_rad), -np.sin(tilt_rad)])
    n1 = np.array([1.0, 0.0, 0.0])
    frame = np.column_stack([n1, np.cross(t0, n1), t0])
    point = np.array(base_cam, dtype=float)
    points = [point.copy()]
    ends = np.cumsum([s.length_m for s in sections])
    s = 0.0
    for _ in range(n - 1):
        sec = sections[min(int(np.searchsorted(ends, s + ds / 2)), len(sections) - 1)]
        k_local = sec.curvature_per_m * np.array([-np.sin(sec.plane_rad), np.cos(sec.plane_rad), 0.0])
        omega = k_local + np.array([0.0, 0.0, sec.twist_rad_per_m])
        rot = cv2.Rodrigues(omega * ds)[0]
        mid = frame @ cv2.Rodrigues(omega * ds / 2)[0]
        point = point + mid[:, 2] * ds
        frame = frame @ rot
        points.append(point.copy())
        s += ds
    return np.array(points), ends[:-1]


def _frames(points: np.ndarray) -> np.ndarray:
    """Rotation-minimising frames (N, 3, 3) with columns (n1, n2, tangent)."""
    tangents = np.gradient(points, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    ref = np.array([1.0, 0.0, 0.0]) if abs(tangents[0, 0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    n1 = ref - tangents[0] * (ref @ tangents[0])
    frames = []
    for t in tangents:
        n1 = n1 - t * (n1 @ t)
        n1 /= np.linalg.norm(n1)
        frames.append(np.column_stack([n1, np.cross(t, n1), t]))
    return np.array(frames)


def _tube_facets(points, radius, plate_s, s, sides=20, plate_radius=0.034, plate_thickness=0.008):
    """Quads (M, 4, 3) with colours (M, 3): tube wall, end caps and plate discs."""
    frames = _frames(points)
    angles = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    circle = np.stack([np.cos(angles), np.sin(angles), np.zeros(sides)], 1)
    rings = points[:, None, :] + radius * np.einsum("nij,kj->nki", frames, circle)
    quads, colours = [], []
    in_plate = np.zeros(len(points), dtype=bool)
    for sp in plate_s:
        in_plate |= np.abs(s - sp) <= plate_thickness / 2
    for i in range(len(points) - 1):
        colour = PLATE_BGR if (in_plate[i] or in_plate[i + 1]) else ORANGE_BGR
        for k in range(sides):
            k2 = (k + 1) % sides
            quads.append([rings[i, k], rings[i, k2], rings[i + 1, k2], rings[i + 1, k]])
            colours.append(colour)
    for i in (0, len(points) - 1):  # flat caps as fans of quads
        for k in range(sides):
            k2 = (k + 1) % sides
            quads.append([points[i], rings[i, k], rings[i, k2], points[i]])
            colours.append(ORANGE_BGR)
    for sp in plate_s:  # plate discs wider than the tube
        i = int(np.argmin(np.abs(s - sp)))
        f = frames[i]
        top = points[i] + f[:, 2] * plate_thickness / 2
        bottom = points[i] - f[:, 2] * plate_thickness / 2
        rim = plate_radius * np.einsum("ij,kj->ki", f, circle)
        for k in range(sides):
            k2 = (k + 1) % sides
            quads.append([top + rim[k], top + rim[k2], bottom + rim[k2], bottom + rim[k]])
            quads.append([top, top + rim[k], top + rim[k2], top])
            quads.append([bottom, bottom + rim[k], bottom + rim[k2], bottom])
            colours.extend([PLATE_BGR] * 3)
    return np.array(quads), np.array(colours)


def render_view(calib: StereoCalibration, side: str, quads: np.ndarray, colours: np.ndarray) -> np.ndarray:
    """Raw BGR image of the facets seen by one camera (painter's algorithm, supersampled)."""
    w, h = calib.image_size
    flat = quads.reshape(-1, 3)
    cam = flat if side == "left" else flat @ calib.R.T + calib.T
    uv = calib.project(flat, side).reshape(len(quads), 4, 2)
    depth = cam[:, 2].reshape(len(quads), 4).mean(1)
    centre = cam.reshape(len(quads), 4, 3).mean(1)
    normal = np.cross(quads[:, 2] - quads[:, 0], quads[:, 3] - quads[:, 1])
    if side == "right":
        normal = normal @ calib.R.T
    normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-12
    facing = np.sign(-np.einsum("ij,ij->i", normal, centre))  # flip back faces to face the camera
    lambert = np.clip(np.einsum("ij,j->i", normal * facing[:, None], LIGHT_CAM), 0, 1)
    shade = 0.55 + 0.45 * lambert
    big = np.empty((h * SUPERSAMPLE, w * SUPERSAMPLE, 3), np.uint8)
    big[:] = BACKGROUND_BGR
    shift = 4
    scale = SUPERSAMPLE * (1 << shift)
    for i in np.argsort(-depth):
        poly = np.round((uv[i] + 0.5) * scale - (1 << shift) / 2).astype(np.int32)
        colour = tuple(float(c) for c in np.clip(colours[i] * shade[i], 0, 255))
        cv2.fillConvexPoly(big, poly, colour, lineType=cv2.LINE_8, shift=shift)
    return cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)


@dataclass(frozen=True)
class Scene:
    left: np.ndarray
    right: np.ndarray
    gt_points: np.ndarray  # (N, 3) left camera frame, base -> tip
    calibration: StereoCalibration


def render_scene(calib: StereoCalibration, points: np.ndarray, plate_s=(), radius: float = 0.025,
                 noise_std: float = 2.0, seed: int = 0) -> Scene:
    """Render a tube along ``points`` (left camera frame) into both raw images."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    # Mesh at ~6 mm rings: fine enough that facets do not show in the silhouette.
    count = max(int(s[-1] / 0.006), 20)
    dense = np.column_stack([np.interp(np.linspace(0, s[-1], count), s, points[:, k]) for k in range(3)])
    dense_s = np.linspace(0, s[-1], count)
    quads, colours = _tube_facets(dense, radius, plate_s, dense_s)
    rng = np.random.default_rng(seed)
    images = []
    for side in ("left", "right"):
        image = render_view(calib, side, quads, colours).astype(np.float64)
        image += rng.normal(0, noise_std, image.shape)
        images.append(np.clip(image, 0, 255).astype(np.uint8))
    return Scene(images[0], images[1], points, calib)


def standard_shapes() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Named backbones of a 685 mm arm 0.9 to 1.1 m away: (points, section-joint arc lengths).

    The kinds of shapes the paper's arm takes: hanging straight, bending in the image plane,
    bending towards the camera, three sections in different planes with a twisting tip.
    """
    L = (0.235, 0.23, 0.22)
    return {
        "straight": backbone([Section(sum(L), 0.0, 0.0)], (0.0, -0.34, 1.0)),
        "c_bend": backbone([Section(L[0], 1.2, 0.0), Section(L[1], 1.8, 0.0), Section(L[2], 2.0, 0.0)],
                           (-0.05, -0.36, 0.98)),
        "towards_camera": backbone([Section(L[0], 1.0, 1.57), Section(L[1], 1.2, 1.2), Section(L[2], 1.2, 0.8)],
                                   (0.02, -0.36, 1.08)),
        "three_d": backbone([Section(L[0], 1.6, 0.0), Section(L[1], 2.2, 1.57), Section(L[2], 2.2, 1.0, 3.0)],
                            (-0.08, -0.34, 1.0)),
        "s_curve": backbone([Section(L[0], 2.0, 0.0), Section(L[1], 2.6, 3.14), Section(L[2], 1.5, 0.5)],
                            (-0.02, -0.34, 0.95), tilt_rad=0.15),
    }


def u_shapes() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Shapes beyond the paper's experiment: the arm curls until it crosses image rows twice."""
    L = (0.235, 0.23, 0.22)
    return {
        "hook": backbone([Section(L[0], 2.4, 0.0), Section(L[1], 3.0, 0.2), Section(L[2], 3.0, 0.6)],
                         (-0.14, -0.40, 1.0)),
        "curl": backbone([Section(L[0], 1.0, 0.0), Section(L[1], 7.0, 0.0), Section(L[2], 7.0, 0.3)],
                         (0.0, -0.34, 1.0)),
    }


def folded_shape() -> tuple[np.ndarray, np.ndarray]:
    """The tip folds back up in front of the arm: its silhouette overlaps the arm's."""
    L = (0.235, 0.23, 0.22)
    return backbone([Section(L[0], 0.5, 0.0), Section(L[1], 6.5, 1.57), Section(L[2], 6.0, 1.57)], (0.0, -0.34, 1.0))
