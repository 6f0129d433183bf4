"""Small synthetic stereo scenes with exact ground truth, drawn without OpenGL.

A tube (flat end caps, dark baseplates between sections) is meshed along a known backbone,
every facet is projected through the full camera model (distortion included) and filled in
depth order at 4x resolution, then averaged down: anti-aliased raw images like a real camera's.
Independent of the twin's renderer on purpose, so the two can check each other.

Lab scenes (``Lab``, ``render_lab_scenes``) put the same tube in front of a textured wall, with
wooden, skin-coloured and yellow things beside it, a dark cable in front of it, dim or warm
light and horizontal motion blur. Everything but the tube is a flat layer parallel to the left
image plane at its own depth; each pixel's ray (distortion and the right eye's pose included) is
cut with that plane and the layer's pattern is evaluated there, so both eyes see the wall and
the distractors at the disparity of their depth, as a camera would.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

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


def render_view(calib: StereoCalibration, side: str, quads: np.ndarray, colours: np.ndarray,
                background=BACKGROUND_BGR) -> np.ndarray:
    """Raw BGR image of the facets seen by one camera (painter's algorithm, supersampled)."""
    w, h = calib.image_size
    return cv2.resize(_raster(calib, side, quads, colours, background), (w, h), interpolation=cv2.INTER_AREA)


def _raster(calib: StereoCalibration, side: str, quads: np.ndarray, colours: np.ndarray, background) -> np.ndarray:
    """The facets filled in depth order at SUPERSAMPLE times the image's resolution (uint8 BGR)."""
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
    big[:] = background
    shift = 4
    scale = SUPERSAMPLE * (1 << shift)
    for i in np.argsort(-depth):
        poly = np.round((uv[i] + 0.5) * scale - (1 << shift) / 2).astype(np.int32)
        colour = tuple(float(c) for c in np.clip(colours[i] * shade[i], 0, 255))
        cv2.fillConvexPoly(big, poly, colour, lineType=cv2.LINE_8, shift=shift)
    return big


@dataclass(frozen=True)
class Scene:
    left: np.ndarray
    right: np.ndarray
    gt_points: np.ndarray  # (N, 3) left camera frame, base -> tip
    calibration: StereoCalibration


def render_scene(calib: StereoCalibration, points: np.ndarray, plate_s=(), radius: float = 0.025,
                 noise_std: float = 2.0, seed: int = 0, lab: Lab | None = None, sides: int = 20) -> Scene:
    """Render a tube along ``points`` (left camera frame) into both raw images; with ``lab``, in
    that lab scene (its own noise) instead of before the uniform backdrop.

    The tube is a prism of ``sides`` faces: seen across, a 20-sided one is on average 0.6 % narrower
    than its radius says (between cos(pi / 20) and 1 of it, by how its faces turn to the eye), which
    the estimator's width cue reads as depth (0.2-1.5 mm further at 0.92 m, measured on a straight tube).
    Tests of depth to a fraction of a millimetre render a rounder tube."""
    if lab is not None:
        return compose_lab(calib, points, tube_layers(calib, points, plate_s, radius), lab, seed)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    # Mesh at ~6 mm rings: fine enough that facets do not show in the silhouette.
    count = max(int(s[-1] / 0.006), 20)
    dense = np.column_stack([np.interp(np.linspace(0, s[-1], count), s, points[:, k]) for k in range(3)])
    dense_s = np.linspace(0, s[-1], count)
    quads, colours = _tube_facets(dense, radius, plate_s, dense_s, sides=sides)
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


# --- lab scenes -----------------------------------------------------------------------------

WOOD_BGR = np.array([70.0, 125.0, 180.0])
SKIN_BGR = np.array([122.0, 152.0, 212.0])
YELLOW_BGR = np.array([40.0, 200.0, 225.0])
DARK_BGR = np.array([34.0, 34.0, 38.0])
BRICK_BGR = np.array([150.0, 160.0, 190.0])  # painted bricks: below the arm's saturation until warm light
MORTAR_BGR = np.array([185.0, 188.0, 190.0])


@dataclass(frozen=True)
class Layer:
    """A flat thing parallel to the left image plane: ``paint(X, Y, pixel_m)`` gives its colour
    (..., 3) and coverage (...) at left-camera coordinates X, Y (metres) on the plane z = ``z_m``;
    ``pixel_m`` is a pixel's footprint there, for anti-aliased outlines."""

    z_m: float
    paint: Callable[[np.ndarray, np.ndarray, float], tuple[np.ndarray, np.ndarray]]
    extent_m: tuple[float, float, float, float] | None = None  # (x0, x1, y0, y1) it stays within; None: everywhere


@dataclass(frozen=True)
class Lab:
    """What surrounds the tube in a lab scene.

    Attributes:
        wall: "bricks" (painted bricks), "plaster" or None (the uniform backdrop).
        wall_z_m: depth of the wall (a plane parallel to the image).
        distractors: a wooden shelf board and box, a skin-coloured object and a thin yellow cable
            beside the arm.
        occluder_width_m: a dark cable this wide crossing in front of the arm's middle (0: none).
        light: scales every colour (dim light below 1, over-exposure above).
        tint_bgr: per-channel factors of the light's colour (warm light: more red, less blue).
        motion_blur_px: length of a horizontal box blur over the whole image (a fast pan), odd.
        noise_std: Gaussian pixel noise, digital numbers.
    """

    wall: str | None = "bricks"
    wall_z_m: float = 2.0
    distractors: bool = True
    occluder_width_m: float = 0.0
    light: float = 1.0
    tint_bgr: tuple[float, float, float] = (1.0, 1.0, 1.0)
    motion_blur_px: int = 0
    noise_std: float = 2.0
    extra: tuple[Layer, ...] = field(default=())


LAB_CONDITIONS = {
    "lab": Lab(),
    "dim": Lab(light=0.45, noise_std=3.0),
    "warm": Lab(light=1.15, tint_bgr=(0.72, 0.95, 1.15)),
    "blur": Lab(motion_blur_px=9),
    "occluded": Lab(occluder_width_m=0.012),
}


def _smooth_box(X, Y, x0, x1, y0, y1, pixel_m):
    """Anti-aliased coverage of an axis-aligned rectangle (a pixel-wide ramp across its outline)."""
    inside = np.minimum(np.minimum(X - x0, x1 - X), np.minimum(Y - y0, y1 - Y))
    return np.clip(0.5 + inside / pixel_m, 0.0, 1.0)


def _polyline_distance(X, Y, points):
    best = np.full(X.shape, np.inf)
    for (ax, ay), (bx, by) in zip(points[:-1], points[1:], strict=True):
        dx, dy = bx - ax, by - ay
        t = np.clip(((X - ax) * dx + (Y - ay) * dy) / (dx * dx + dy * dy), 0.0, 1.0)
        best = np.minimum(best, np.hypot(X - ax - t * dx, Y - ay - t * dy))
    return best


def _hash_tint(i, j, spread):
    """A repeatable factor in [1 - spread, 1 + spread] per integer cell (i, j)."""
    h = np.sin(i * 12.9898 + j * 78.233) * 43758.5453
    return 1.0 + spread * (2.0 * (h - np.floor(h)) - 1.0)


def wall_layer(kind: str, z_m: float) -> Layer:
    """A wall filling the view: painted bricks (courses of 75 mm, 10 mm mortar) or mottled plaster."""

    def paint(X, Y, pixel_m):
        mottle = 1.0 + 0.05 * np.sin(X / 0.031) * np.sin(Y / 0.023) + 0.03 * np.sin((X + 2 * Y) / 0.007)
        if kind == "plaster":
            colour = np.array([175.0, 180.0, 186.0]) * mottle[..., None]
        elif kind == "bricks":
            course = np.floor(Y / 0.075)
            along = X + 0.11 * (course % 2)
            brick = np.floor(along / 0.22)
            mortar = ((Y - course * 0.075) < 0.010) | ((along - brick * 0.22) < 0.010)
            tint = _hash_tint(course, brick, 0.08) * mottle
            colour = np.where(mortar[..., None], MORTAR_BGR, BRICK_BGR * tint[..., None])
        else:
            raise ValueError(f"wall: expected 'bricks' or 'plaster', got {kind!r}")
        return colour, np.ones(X.shape)

    return Layer(z_m, paint)


def box_layer(z_m: float, x_m: tuple[float, float], y_m: tuple[float, float], bgr: np.ndarray,
              grain_m: float = 0.0) -> Layer:
    """A rectangle (a shelf board, the front of a box), wood-grained when ``grain_m`` > 0."""

    def paint(X, Y, pixel_m):
        colour = np.broadcast_to(bgr, X.shape + (3,)).astype(np.float64)
        if grain_m > 0:
            grain = 1.0 + 0.12 * np.sin(2 * np.pi * Y / grain_m + 3.0 * np.sin(2 * np.pi * X / 0.17))
            colour = colour * grain[..., None]
        return colour, _smooth_box(X, Y, *x_m, *y_m, pixel_m)

    return Layer(z_m, paint, (x_m[0], x_m[1], y_m[0], y_m[1]))


def blob_layer(z_m: float, centre_m: tuple[float, float], axes_m: tuple[float, float], bgr: np.ndarray) -> Layer:
    """An ellipse, shaded darker towards its rim (a rounded, hand-sized object)."""

    def paint(X, Y, pixel_m):
        r = np.hypot((X - centre_m[0]) / axes_m[0], (Y - centre_m[1]) / axes_m[1])
        coverage = np.clip(0.5 + (1.0 - r) * min(axes_m) / pixel_m, 0.0, 1.0)
        shade = 1.0 - 0.25 * np.clip(r, 0.0, 1.0) ** 2
        return bgr * shade[..., None], coverage

    a, b = axes_m
    return Layer(z_m, paint, (centre_m[0] - a, centre_m[0] + a, centre_m[1] - b, centre_m[1] + b))


def cable_layer(z_m: float, points_m: np.ndarray, width_m: float, bgr: np.ndarray) -> Layer:
    """A cable of ``width_m`` along a polyline (X, Y), shaded across like a cylinder."""
    points_m = np.asarray(points_m, np.float64)

    def paint(X, Y, pixel_m):
        d = _polyline_distance(X, Y, points_m)
        coverage = np.clip(0.5 + (0.5 * width_m - d) / pixel_m, 0.0, 1.0)
        shade = 1.0 - 0.35 * np.clip(d / (0.5 * width_m), 0.0, 1.0) ** 2
        return bgr * shade[..., None], coverage

    lo, hi = points_m.min(axis=0) - width_m, points_m.max(axis=0) + width_m
    return Layer(z_m, paint, (lo[0], hi[0], lo[1], hi[1]))


def lab_layers(lab: Lab, points: np.ndarray) -> tuple[list[Layer], list[Layer]]:
    """(behind the arm, in front of it) for a tube along ``points`` (left camera frame)."""
    behind, front = [], []
    if lab.wall is not None:
        behind.append(wall_layer(lab.wall, lab.wall_z_m))
    if lab.distractors:
        base = points[0]
        behind += [
            # a shelf board to the right, clear of the arm
            box_layer(1.5, (0.42, 1.40), (0.02, 0.075), WOOD_BGR, grain_m=0.011),
            # a wooden box, low on the left
            box_layer(1.6, (-1.35, -0.72), (0.24, 0.62), WOOD_BGR * 1.08, grain_m=0.017),
            # a hand-sized skin-coloured object on the right
            blob_layer(1.25, (0.52, 0.30), (0.045, 0.07), SKIN_BGR),
            # a thin yellow cable hanging a hand's width beside the arm's base
            cable_layer(float(base[2]) + 0.04, np.array([[base[0] - 0.13, -0.60], [base[0] - 0.125, -0.25],
                                                         [base[0] - 0.145, 0.0], [base[0] - 0.135, 0.12]]),
                        0.007, YELLOW_BGR),
        ]
    if lab.occluder_width_m > 0:
        # A dark cable in front of the arm, crossing it at 40 % of its length, slightly sloping.
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        p = np.array([np.interp(0.4 * arc[-1], arc, points[:, k]) for k in range(3)])
        z = 0.75
        x, y = p[0] * z / p[2], p[1] * z / p[2]
        front.append(cable_layer(z, np.array([[x - 1.0, y - 0.12], [x + 1.0, y + 0.12]]), lab.occluder_width_m,
                                 DARK_BGR))
    behind += [layer for layer in lab.extra if layer.z_m > float(np.max(points[:, 2]))]
    front += [layer for layer in lab.extra if layer.z_m <= float(np.max(points[:, 2]))]
    return sorted(behind, key=lambda layer: -layer.z_m), sorted(front, key=lambda layer: -layer.z_m)


@functools.lru_cache(maxsize=4)
def _rays(calib: StereoCalibration, side: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Each raw pixel's ray in the left camera frame: (origin (3,), directions (H, W, 3), focal)."""
    w, h = calib.image_size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    K, dist = calib.K(side), calib.dist(side)
    xy = cv2.undistortPoints(np.stack([u, v], -1).reshape(-1, 1, 2), K, dist.reshape(1, -1)).reshape(h, w, 2)
    d = np.concatenate([xy, np.ones((h, w, 1))], axis=2)
    if side == "left":
        return np.zeros(3), d, float(K[0, 0])
    return -calib.R.T @ calib.T, d @ calib.R, float(K[0, 0])  # x_right = R x_left + T


def paint_layers(calib: StereoCalibration, side: str, layers: list[Layer], image: np.ndarray) -> np.ndarray:
    """``image`` (H, W, 3 float) with the layers painted over it, far to near."""
    origin, d, focal = _rays(calib, side)
    image = image.copy()
    for layer in layers:
        lam = (layer.z_m - origin[2]) / d[..., 2]
        X, Y = origin[0] + lam * d[..., 0], origin[1] + lam * d[..., 1]
        pixel_m = layer.z_m / focal
        if layer.extent_m is None:
            colour, coverage = layer.paint(X, Y, pixel_m)
            image += coverage[..., None] * (colour - image)
            continue
        x0, x1, y0, y1 = layer.extent_m
        near = ((np.abs(X - 0.5 * (x0 + x1)) < 0.5 * (x1 - x0) + pixel_m)
                & (np.abs(Y - 0.5 * (y0 + y1)) < 0.5 * (y1 - y0) + pixel_m))
        colour, coverage = layer.paint(X[near], Y[near], pixel_m)
        image[near] += coverage[..., None] * (colour - image[near])
    return image


def tube_layers(calib: StereoCalibration, points: np.ndarray, plate_s=(), radius: float = 0.025):
    """Per eye, the tube alone: (premultiplied colour (H, W, 3) float, coverage (H, W) in [0, 1])."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    count = max(int(s[-1] / 0.006), 20)
    dense = np.column_stack([np.interp(np.linspace(0, s[-1], count), s, points[:, k]) for k in range(3)])
    quads, colours = _tube_facets(dense, radius, plate_s, np.linspace(0, s[-1], count))
    w, h = calib.image_size
    out = {}
    for side in ("left", "right"):
        big = _raster(calib, side, quads, colours, (0, 0, 0))  # every facet's colour has all channels > 0
        covered = (big[..., 0] > 0).view(np.uint8) * np.uint8(255)
        colour = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA).astype(np.float64)
        coverage = cv2.resize(covered, (w, h), interpolation=cv2.INTER_AREA).astype(np.float64) / 255.0
        out[side] = (colour, coverage)
    return out


def compose_lab(calib: StereoCalibration, points: np.ndarray, layers: dict, lab: Lab, seed: int = 0,
                backdrops: dict | None = None) -> Scene:
    """A lab scene from the tube's layers (``tube_layers``): wall and distractors, the tube, what
    is in front of it, the light, the blur, the noise. ``backdrops`` caches what is behind the
    tube across conditions that share it."""
    behind, front = lab_layers(lab, points)
    backdrops = {} if backdrops is None else backdrops
    rng = np.random.default_rng(seed)
    w, h = calib.image_size
    images = []
    for side in ("left", "right"):
        key = (side, lab.wall, lab.wall_z_m, lab.distractors, lab.extra)
        if key not in backdrops:
            plain = np.empty((h, w, 3))
            plain[:] = BACKGROUND_BGR
            backdrops[key] = paint_layers(calib, side, behind, plain)
        colour, coverage = layers[side]
        image = colour + (1.0 - coverage[..., None]) * backdrops[key]
        image = paint_layers(calib, side, front, image)
        image *= lab.light * np.asarray(lab.tint_bgr, np.float64)
        np.clip(image, 0, 255, out=image)  # the sensor saturates before the blur of a pan mixes pixels
        if lab.motion_blur_px > 1:
            image = cv2.blur(image, (int(lab.motion_blur_px), 1), borderType=cv2.BORDER_REPLICATE)
        image += rng.standard_normal(image.shape, dtype=np.float32) * lab.noise_std
        images.append(np.clip(np.round(image), 0, 255).astype(np.uint8))
    return Scene(images[0], images[1], points, calib)


def render_lab_scenes(calib: StereoCalibration, points: np.ndarray, plate_s=(), conditions: dict | None = None,
                      radius: float = 0.025, seed: int = 0) -> dict[str, Scene]:
    """One tube in several lab conditions (name -> ``Lab``; default ``LAB_CONDITIONS``), rasterised once."""
    layers = tube_layers(calib, points, plate_s, radius)
    conditions = LAB_CONDITIONS if conditions is None else conditions
    backdrops: dict = {}
    return {name: compose_lab(calib, points, layers, lab, seed + k, backdrops)
            for k, (name, lab) in enumerate(conditions.items())}
