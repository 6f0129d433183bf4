"""The renderer draws what the exposed calibration says (dm_control's testCameraMatrix, for a
distorted stereo pair): the ground-truth backbone projected with ``StereoRig.calibration`` lies on
the centre of the arm's silhouette in both raw images, for straight, bent and 3D shapes.

Also: the depth map, the HSV segmentation range, the fast (scissored) read-back against
pyrender's own, sensor noise and the tube geometry.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest

from twin.render import StereoRenderer, rotation_minimising_frames, tube_surface
from twin.rig import SensorModel, StereoRig
from twin.shape import ArmShape, Plate

REPO = Path(__file__).resolve().parents[2]
CAMERA_TOML = REPO / "models" / "camera.toml"
LENGTH_M, RADIUS_M = 0.685, 0.025


# --- hand-made arm shapes (world frame: z up, base at the origin, hanging along -z) ---------


def _shape(points: np.ndarray, radius_m: float = RADIUS_M) -> ArmShape:
    points = np.asarray(points, dtype=np.float64)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    plates = []
    for i in (0, int(np.searchsorted(s, 0.36 * s[-1])), int(np.searchsorted(s, 0.70 * s[-1]))):
        t = points[min(i + 1, len(s) - 1)] - points[max(i - 1, 0)]
        plates.append(Plate(points[i], t / np.linalg.norm(t), 0.04, 0.008))
    return ArmShape(points, s, np.full(len(s), radius_m), tuple(plates))


def hanging(n: int = 200) -> ArmShape:
    return _shape(np.column_stack([np.zeros(n), np.zeros(n), np.linspace(0.0, -LENGTH_M, n)]))


def arc(kappa_per_m: float = 2.5, direction=(1.0, 0.0), n: int = 200) -> ArmShape:
    """Constant curvature, starting downwards, bending towards ``direction`` (x, y) in the world."""
    theta = kappa_per_m * np.linspace(0.0, LENGTH_M, n)
    lateral = (1.0 - np.cos(theta)) / kappa_per_m
    dx, dy = np.asarray(direction) / np.linalg.norm(direction)
    return _shape(np.column_stack([lateral * dx, lateral * dy, -np.sin(theta) / kappa_per_m]))


def helix_like(n: int = 200) -> ArmShape:
    """A 3D curve with torsion: a widening spiral going down (it also moves in depth)."""
    s = np.linspace(0.0, LENGTH_M, n)
    phase = 2.0 * np.pi * 1.1 * s / LENGTH_M
    r = 0.13 * s / LENGTH_M
    return _shape(np.column_stack([r * np.sin(phase), -r * (1 - np.cos(phase)), -0.85 * s]))


SHAPES = {"hanging": hanging, "arc_x": arc, "arc_towards_camera": lambda: arc(2.0, (0.6, -1.0)),
          "helix": helix_like}


@pytest.fixture(scope="module")
def rig() -> StereoRig:
    return StereoRig.load(CAMERA_TOML)


@pytest.fixture(scope="module")
def renderer(rig):
    with StereoRenderer(rig, seed=1) as r:
        yield r


def _bare(shape: ArmShape) -> ArmShape:
    return ArmShape(shape.points_world, shape.s_m, shape.radius_m, ())


# --- the projection proof ------------------------------------------------------------------


def silhouette_offsets(image: np.ndarray, uv: np.ndarray, radius_px: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """Signed distance (px) from each projected backbone point to the centre of the arm's
    silhouette, measured along the projected curve's normal.

    The blue channel separates the orange arm (B ~ 30) from the grey-blue background (B ~ 190);
    each edge is where a cross-section crosses halfway between the background level and the
    arm level at the centre, located to sub-pixel precision on a bilinearly sampled profile.
    Points whose cross-section is not one clean arm interval (overlaps, ends) come back NaN.
    """
    blue = image[..., 0].astype(np.float32)
    background = float(np.median(blue[:20, :]))
    tangent = np.gradient(uv, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1)[:, None]
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    out = np.full(len(uv), np.nan)
    step = 0.05
    for i in np.flatnonzero(usable):
        half = 2.2 * radius_px[i] + 4.0
        offsets = np.arange(-half, half + step / 2, step)
        pts = uv[i] + offsets[:, None] * normal[i]
        profile = cv2.remap(blue, pts[:, 0].astype(np.float32).reshape(1, -1),
                            pts[:, 1].astype(np.float32).reshape(1, -1), cv2.INTER_LINEAR).ravel()
        inside = float(np.min(profile[np.abs(offsets) < 0.5 * radius_px[i]]))
        if background - inside < 80 or abs(profile[0] - background) > 15 or abs(profile[-1] - background) > 15:
            continue
        level = 0.5 * (background + inside)
        below = profile < level
        idx = np.flatnonzero(below)
        if len(idx) == 0 or np.any(np.diff(idx) != 1):
            continue  # not a single arm interval on this cross-section
        a, b = idx[0], idx[-1]
        # Linear interpolation of the crossing on each side.
        left = offsets[a - 1] + step * (profile[a - 1] - level) / (profile[a - 1] - profile[a])
        right = offsets[b] + step * (profile[b] - level) / (profile[b] - profile[b + 1])
        out[i] = 0.5 * (left + right)
    return out


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_projected_backbone_lies_on_the_silhouette_centre_in_both_raw_images(rig, renderer, name):
    shape = SHAPES[name]()
    images = renderer.render(shape)
    points_cam = rig.world_to_left_camera(shape.points_world)
    calib = rig.calibration
    # Where the plates (dark, wider) or the ends would disturb a cross-section, do not measure.
    near_plate = np.zeros(len(shape.s_m), bool)
    for plate in shape.plates:
        near_plate |= np.linalg.norm(shape.points_world - plate.center_world, axis=1) < 0.06
    ends = (shape.s_m < 0.03) | (shape.s_m > shape.s_m[-1] - 0.04)
    usable = ~near_plate & ~ends
    worst = {}
    for side, image in (("left", images.left), ("right", images.right)):
        uv = calib.project(points_cam, side)
        cam = points_cam if side == "left" else points_cam @ calib.R.T + calib.T
        radius_px = calib.K(side)[0, 0] * shape.radius_m / cam[:, 2]
        offsets = silhouette_offsets(image, uv, radius_px, usable)
        measured = np.isfinite(offsets)
        assert measured.sum() >= 0.5 * usable.sum(), f"{side}: too few clean cross-sections ({measured.sum()})"
        worst[side] = float(np.max(np.abs(offsets[measured])))
        assert worst[side] < 1.0, f"{name}, {side} image: backbone {worst[side]:.3f} px off the silhouette centre"
        # The bias must be far below the bound, not just under it.
        assert abs(float(np.mean(offsets[measured]))) < 0.25
    print(f"{name}: worst offset left {worst['left']:.3f} px, right {worst['right']:.3f} px")


def test_the_measurement_sees_a_wrong_calibration(rig, renderer):
    """The proof can fail: a principal point off by 2 px (or the half-pixel shift forgotten
    twice over) is detected."""
    shape = hanging()
    images = renderer.render(shape)
    points_cam = rig.world_to_left_camera(shape.points_world)
    uv = rig.calibration.project(points_cam, "left") + np.array([2.0, 0.0])
    usable = (shape.s_m > 0.05) & (shape.s_m < 0.2)
    offsets = silhouette_offsets(images.left, uv, np.full(len(uv), 17.0), usable)
    assert abs(np.nanmean(offsets)) == pytest.approx(2.0, abs=0.3)


# --- depth -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["hanging", "arc_towards_camera"])
def test_depth_at_the_projected_backbone_is_the_near_tube_surface(rig, renderer, name):
    shape = _bare(SHAPES[name]())
    images = renderer.render(shape)
    depth = images.depth_left_m
    assert depth.dtype == np.float32 and depth.shape == (rig.image_size[1], rig.image_size[0])
    points_cam = rig.world_to_left_camera(shape.points_world)
    uv = rig.calibration.project(points_cam, "left")
    keep = (shape.s_m > 0.03) & (shape.s_m < shape.s_m[-1] - 0.04)
    cols, rows = np.round(uv[keep]).astype(int).T
    measured = depth[rows, cols]
    # The ray through an axis point enters the (locally straight) tube r / sin(psi) before it,
    # psi the angle between the ray and the axis; z drops by that times the ray's z component.
    axis = np.gradient(points_cam, axis=0)[keep]
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    ray = points_cam[keep] / np.linalg.norm(points_cam[keep], axis=1)[:, None]
    sin_psi = np.linalg.norm(np.cross(ray, axis), axis=1)
    expected = points_cam[keep, 2] - shape.radius_m[keep] / sin_psi * ray[:, 2]
    assert np.all(np.isfinite(measured))
    # Rounding to the nearest pixel moves the sample up to half a pixel (~0.7 mm) off the axis,
    # more in depth where the tube points towards the camera.
    np.testing.assert_allclose(measured, expected, atol=3e-3)
    assert np.median(np.abs(measured - expected)) < 5e-4
    assert np.isinf(depth[5, 5]), "background depth is inf"


# --- colours -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["hanging", "arc_x", "helix"])
def test_the_whole_arm_surface_is_inside_the_estimator_hsv_range(renderer, name):
    """Lit and shaded arm pixels stay in H 5..25, S 100..255, V 50..255 (OpenCV units); only
    anti-aliased silhouette pixels may leave it; background and plates stay out of it."""
    lo, hi = (5, 100, 50), (25, 255, 255)
    shape = SHAPES[name]()
    images = renderer.render(_bare(shape))
    for image in (images.left, images.right):
        hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
        in_range = cv2.inRange(hsv, lo, hi) > 0
        arm = np.isfinite(images.depth_left_m).astype(np.uint8) if image is images.left else in_range.astype(np.uint8)
        interior = cv2.erode(arm, np.ones((5, 5), np.uint8)) > 0
        assert interior.sum() > 5000
        assert np.all(in_range[interior]), f"{np.count_nonzero(~in_range[interior])} interior arm pixels out of range"
        near = cv2.dilate(arm, np.ones((5, 5), np.uint8)) > 0
        assert not np.any(in_range & ~near), "background pixels fall in the arm's HSV range"
        v = hsv[..., 2][interior]
        assert v.max() - v.min() > 40, "the arm is shaded (lit and unlit sides differ)"
    # The plates (and the base mount) must not be segmented as arm.
    with_plates = renderer.render(shape)
    hsv = cv2.cvtColor(with_plates.left, cv2.COLOR_BGR2HSV)
    arm_only = cv2.inRange(cv2.cvtColor(images.left, cv2.COLOR_BGR2HSV), lo, hi) > 0
    near_arm = cv2.dilate(arm_only.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    extra = (cv2.inRange(hsv, lo, hi) > 0) & ~near_arm
    assert extra.sum() < 20


# --- read-back, sensor and geometry ------------------------------------------------------------


def test_fast_scissored_readback_matches_pyrenders_full_render(rig):
    quiet = SensorModel(noise_std_dn=0.0)
    shape = arc()
    with StereoRenderer(rig, sensor=quiet) as fast:
        assert fast._fast_readback
        a = fast.render(shape)
        fast.render(hanging())  # a different frame in between: the previous rectangle is restored
        a2 = fast.render(shape)
    with StereoRenderer(rig, sensor=quiet, fast_readback=False) as slow:
        assert not slow._fast_readback
        b = slow.render(shape)
    for x, y in ((a.left, b.left), (a.right, b.right), (a2.left, b.left)):
        assert np.abs(x.astype(int) - y.astype(int)).max() <= 1
    finite = np.isfinite(b.depth_left_m)
    assert np.array_equal(finite, np.isfinite(a.depth_left_m))
    np.testing.assert_allclose(a.depth_left_m[finite], b.depth_left_m[finite], atol=1e-4)


def test_lights_and_equally_distant_meshes_are_drawn_in_the_order_they_were_added():
    """pyrender iterates sets (memory order): a process's first renderer and a later one summed the
    lights in another order and drew a blurred frame's edge pixels a level apart."""
    from twin.render import _drawing_order, _gl, _ordered_scene_class

    pyrender, _ = _gl()
    scene = _ordered_scene_class(pyrender)()
    scene.main_camera_node = scene.add(pyrender.PerspectiveCamera(yfov=1.0), pose=np.eye(4))
    far = np.eye(4)
    far[2, 3] = -2.0
    triangle = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    meshes = [scene.add(pyrender.Mesh([pyrender.Primitive(positions=triangle)]), pose=far, name=f"part{k}")
              for k in range(12)]
    near = scene.add(pyrender.Mesh([pyrender.Primitive(positions=triangle)]), pose=np.eye(4), name="near")
    lights = [scene.add(pyrender.DirectionalLight(intensity=k + 1.0), pose=np.eye(4)) for k in range(6)]
    assert _drawing_order(scene) == meshes + [near]  # far before near, ties as added
    assert list(scene.light_nodes) == lights
    scene.remove_node(meshes[3])
    scene.remove_node(lights[0])
    assert _drawing_order(scene) == meshes[:3] + meshes[4:] + [near]
    assert list(scene.light_nodes) == lights[1:]


def test_renderers_live_side_by_side_and_dropping_one_spares_the_others(rig):
    """pyrender's own clean-up terminates the process-wide EGL display; ours must not."""
    import gc

    shape = hanging()
    keep = StereoRenderer(rig, sensor=SensorModel(0.0))
    try:
        before = keep.render(shape, depth=False).left
        closed = StereoRenderer(rig)
        closed.render(shape)
        closed.close()
        closed.close()
        dropped = StereoRenderer(rig)
        dropped.render(shape)
        del dropped
        gc.collect()
        after = keep.render(shape, depth=False).left
        assert np.array_equal(before, after)
    finally:
        keep.close()


def test_sensor_noise_is_seeded_and_has_the_configured_spread(rig):
    shape = hanging()
    sensor = SensorModel(noise_std_dn=3.0)
    with StereoRenderer(rig, seed=7, sensor=sensor) as r1:
        a = r1.render(shape, depth=False)
        a_next = r1.render(shape, depth=False)
    with StereoRenderer(rig, seed=7, sensor=sensor) as r2:
        b = r2.render(shape, depth=False)
    with StereoRenderer(rig, sensor=SensorModel(noise_std_dn=0.0)) as r3:
        clean = r3.render(shape, depth=False)
    assert a.depth_left_m is None
    assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
    assert not np.array_equal(a.left, a_next.left)
    diff = a.left.astype(float) - clean.left.astype(float)
    assert np.std(diff[100:300, 100:400]) == pytest.approx(3.0, rel=0.1)
    assert abs(np.mean(diff[100:300, 100:400])) < 0.1


def test_blur_and_exposure_gain_change_the_image(rig):
    shape = hanging()
    with StereoRenderer(rig, sensor=SensorModel(0.0, blur_sigma_px=2.0, exposure_gain=0.5)) as r:
        dim = r.render(shape, depth=False).left
    with StereoRenderer(rig, sensor=SensorModel(0.0)) as r:
        plain = r.render(shape, depth=False).left
    assert np.mean(dim[:50, :50]) == pytest.approx(0.5 * np.mean(plain[:50, :50]), abs=1.0)
    # Blur spreads the arm's edges: fewer steep steps between neighbouring pixels.
    def steep(image):
        return np.count_nonzero(np.abs(np.diff(image[..., 0].astype(int), axis=1)) > 20)

    assert steep(dim) < 0.2 * steep(plain)


def test_rotation_minimising_frames_do_not_twist_about_a_planar_curve():
    shape = arc(3.0, (1.0, 0.0))
    t, n, b = rotation_minimising_frames(shape.points_world)
    assert np.allclose(np.sum(t * n, 1), 0, atol=1e-9) and np.allclose(np.linalg.norm(n, axis=1), 1)
    # For a planar curve the RMF binormal keeps a constant angle to the plane's normal.
    assert np.allclose(np.abs(b @ np.array([0.0, 1.0, 0.0])), abs(b[0, 1]), atol=1e-6)


def test_tube_surface_is_closed_and_points_outwards():
    shape = helix_like()
    positions, normals, faces = tube_surface(shape.points_world, shape.radius_m, 32)
    import trimesh

    mesh = trimesh.Trimesh(positions, faces, process=True)
    assert mesh.is_watertight and mesh.volume > 0
    assert mesh.volume == pytest.approx(np.pi * RADIUS_M**2 * shape.length_m, rel=0.01)
    # Vertex normals agree with the face winding.
    a, b, c = (positions[faces[:, k]] for k in range(3))
    face_normals = np.cross(b - a, c - a)
    assert np.mean(np.sum(face_normals * normals[faces[:, 0]], 1) > 0) > 0.99


def test_a_missing_egl_stack_names_the_packages_to_install():
    """In a fresh interpreter whose dynamic loader cannot find libEGL/libGL, creating a renderer
    fails with RenderBackendError naming the Debian packages."""
    script = textwrap.dedent(f"""
        import ctypes
        real_init = ctypes.CDLL.__init__
        def init(self, name, *args, **kwargs):
            if name and any(lib in str(name) for lib in ("EGL", "libGL", "libOpenGL")):
                raise OSError(f"{{name}}: cannot open shared object file: No such file or directory")
            real_init(self, name, *args, **kwargs)
        ctypes.CDLL.__init__ = init
        from twin.render import RenderBackendError, StereoRenderer
        from twin.rig import StereoRig
        try:
            StereoRenderer(StereoRig.load({str(CAMERA_TOML)!r}))
        except RenderBackendError as e:
            print("RenderBackendError:", e)
    """)
    result = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert "RenderBackendError:" in result.stdout, result.stdout + result.stderr
    assert "libegl1" in result.stdout and "libgl1-mesa-dri" in result.stdout


def test_the_matte_shader_ships_with_the_package_and_rendering_writes_no_temporary_folder(rig, tmp_path,
                                                                                         monkeypatch):
    """pyrender reads shaders from files. Written to a temporary folder per process, the shader outlived
    every worker process of a study (their exit skips ``atexit``): 27 folders left in /tmp in one day.
    It is package data now, and the wheel is told to ship it."""
    import tempfile
    import tomllib
    from importlib.resources import files

    from twin import render

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "*.frag" in project["package-data"]["twin"]
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # any folder made through tempfile lands here
    render._matte_shader_file.cache_clear()  # as in a fresh worker process
    with StereoRenderer(rig, seed=1) as fresh:
        images = fresh.render(hanging())
    assert images.left.std() > 5 and images.right.std() > 5  # the arm was drawn with the shader
    shader = Path(render._matte_shader_file())
    assert shader == Path(str(files("twin") / "matte.frag")) and shader.read_text().startswith("#version 330")
    assert list(tmp_path.iterdir()) == []
