"""Offscreen stereo rendering of the arm: raw (distorted, noisy) images like a real ZED.

Each eye is rendered by pyrender (OpenGL through EGL, on the CPU with Mesa llvmpipe) as an
ideal pinhole camera on a canvas large enough to hold every raw pixel's ray; lens distortion
is then applied by ``cv2.remap`` with maps computed once (for every raw pixel, where its ray
lands on the ideal canvas, from ``cv2.undistortPoints``), followed by optical blur, exposure
gain and sensor noise. The same :class:`~estimator.StereoCalibration` that builds the maps is
the one the twin exposes, so projecting with it finds what was drawn.

Surfaces are matte (Lambert + ambient, a small shader of our own instead of pyrender's PBR):
linear colour = base colour x (ambient + directional x cos(angle to the light)), written with
gamma 1/2.2, so a fully lit surface shows the configured display colour.

Conventions: OpenCV pixel centres are at integer coordinates; OpenGL's are at i + 0.5, so the
pinhole principal point handed to pyrender is the OpenCV one plus half a pixel. The ideal canvas
is read bottom-up (OpenGL's row order) and the maps absorb the flip. Colours are handed to
OpenGL in BGR order (the lights are white, so channels never mix) and the images come out BGR.
"""

from __future__ import annotations

import functools
import importlib.resources
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # must precede the first import of PyOpenGL

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from twin.lab_objects import Part, scene_parts  # noqa: E402
from twin.meshes import Prop, pose_with_z, rotation_minimising_frames, tube_surface  # noqa: E402, F401
from twin.rig import SensorModel, StereoRig  # noqa: E402
from twin.scene import LabScene, SceneObject, clean_scene, temperature_rgb  # noqa: E402
from twin.sensor import CameraEffects, SensorSimulator, frame_generator  # noqa: E402
from twin.shape import ArmShape, Plate  # noqa: E402

_SIDES = ("left", "right")
_ZNEAR_M, _ZFAR_M = 0.02, 20.0
_CANVAS_MARGIN_PX = 3
MOTION_STEP_PX = 0.5  # motion blur: the largest step between two sub-frames of an exposure (canvas pixels)
# undistortPoints iterates; its default 5 iterations leave ~0.1 px at the corners of a ZED.
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12)
_GAMMA = 2.2  # the fragment shader writes colour ** (1 / 2.2)
_SAMPLES = 4  # pyrender's multisampled framebuffer: 4 samples per pixel
_PIECE_PX = 96  # a moving object's drawn rectangles: pieces this long along its box's longer side
_RECT_COST_PX = 8000  # a drawn rectangle's own cost (copy-in, resolve, read-back) in pixels, on llvmpipe
_DIELECTRIC_F0 = 0.04  # pyrender's own PBR shader: diffuse colour = base * (1 - 0.04)

# A matte (Lambert + ambient) fragment shader in place of pyrender's PBR one: no specular term,
# so shading only scales a colour and hue and saturation stay exactly those of the material
# (the estimator segments by HSV); it also halves the per-eye time on a CPU rasteriser.
# Uniform and input names are pyrender's (mesh.vert feeds it; unused uniforms are skipped).
# The shader ships beside this module (package data): pyrender reads shaders from files, and a
# file written to a temporary folder per process outlived every worker process, whose exit skips
# ``atexit`` (27 folders left in /tmp by one day's studies).
_MATTE_SHADER = "matte.frag"


@functools.cache
def _matte_shader_file() -> str:
    """The matte fragment shader's path in the installed package."""
    path = importlib.resources.files("twin") / _MATTE_SHADER
    if not path.is_file():
        raise FileNotFoundError(f"the twin's matte shader {_MATTE_SHADER} is missing from the installed package "
                                f"(looked in {path}): reinstall softarm-twin")
    return str(path)


def _matte_program_cache(pyrender):
    class MatteShaderCache(pyrender.shader_program.ShaderProgramCache):
        def get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
            if fragment_shader == "mesh.frag":
                fragment_shader = _matte_shader_file()
            return super().get_program(vertex_shader, fragment_shader, geometry_shader, defines)

    return MatteShaderCache()


@functools.cache
def _ordered_scene_class(pyrender):
    """pyrender's scene, numbering its nodes in the order they are added and handing out its lights
    in that order.

    pyrender keeps nodes in sets, which iterate in the order of memory addresses: the order the
    lights were bound in (the shader sums them in that order) and the order of meshes at the same
    distance (the parts of one object share its pose) differed from one renderer to the next, so a
    process's first renderer and a later one drew edge pixels a level apart (measured on blurred
    frames). With this scene and ``_drawing_order`` a scene draws the same pixels in any process.
    """

    class OrderedScene(pyrender.Scene):
        def __init__(self, *args, **kwargs):
            self.serials: dict = {}  # node -> when it was added
            super().__init__(*args, **kwargs)

        def add_node(self, node, parent_node=None):
            self.serials.setdefault(node, len(self.serials))
            return super().add_node(node, parent_node)

        def remove_node(self, node):
            super().remove_node(node)
            self.serials.pop(node, None)

        @property
        def light_nodes(self):
            return sorted(super().light_nodes, key=self.serials.__getitem__)

    return OrderedScene


def _drawing_order(scene) -> list:
    """The mesh nodes as pyrender draws them: opaque before transparent, far before near (pyrender's
    rule), and nodes at the same distance in the order they were added (``_ordered_scene_class``)."""
    eye = scene.get_pose(scene.main_camera_node)[:3, 3]
    return sorted(scene.mesh_nodes, key=lambda n: (
        bool(n.mesh.is_transparent), -float(np.linalg.norm(scene.get_pose(n)[:3, 3] - eye)), scene.serials[n]))


EGL_HINT = ("install the EGL and Mesa OpenGL runtime, e.g. on Debian/Ubuntu "
            "`apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libopengl0` (Mesa's llvmpipe "
            "renders on the CPU), and keep PYOPENGL_PLATFORM=egl (set by twin before pyrender is imported)")


class RenderBackendError(RuntimeError):
    """Offscreen OpenGL rendering is not available; the message names what to install."""


def _gl():
    """Import pyrender and PyOpenGL's GL functions, translating a missing GL stack."""
    if os.environ.get("PYOPENGL_PLATFORM") != "egl":
        raise RenderBackendError(
            f"PYOPENGL_PLATFORM is {os.environ.get('PYOPENGL_PLATFORM')!r}; the twin renders offscreen through "
            "EGL: set PYOPENGL_PLATFORM=egl before anything imports pyrender or OpenGL")
    try:
        import pyrender
        from OpenGL import GL
    except Exception as e:  # ImportError, OSError from ctypes, AttributeError from PyOpenGL's loader
        raise RenderBackendError(f"cannot load OpenGL through EGL ({type(e).__name__}: {e}); {EGL_HINT}") from e
    return pyrender, GL


@dataclass(frozen=True, eq=False)
class StereoImages:
    """One rendered raw stereo pair.

    Attributes:
        left, right: (H, W, 3) uint8 BGR raw images (distorted, blurred, noisy as configured).
        depth_left_m: (H, W) float32, metres along the left optical axis (camera z) of the
            surface seen at each RAW left pixel; ``inf`` where only background is seen.
            ``None`` when depth was not requested.
        clean_left, clean_right: the same images before the sensor noise and the YUYV transport
            (after distortion, blur, vignetting and gain): ``left`` is
            ``sensor.noisy(clean_left, frame_generator(seed, frame_index, "left"))``, bit for bit.
        frame_index: the frame's number in the renderer's noise sequence.
    """

    left: np.ndarray
    right: np.ndarray
    depth_left_m: np.ndarray | None
    clean_left: np.ndarray | None = None
    clean_right: np.ndarray | None = None
    frame_index: int = 0


@dataclass(frozen=True, eq=False)
class _Eye:
    K_canvas: np.ndarray  # 3x3 ideal pinhole of the canvas, OpenCV conventions (top-down rows)
    map1: np.ndarray  # fixed-point remap maps: raw pixel -> bottom-up canvas position
    map2: np.ndarray
    # The canvas pixel nearest each raw pixel (CV_16SC2, used without a second map) for the depth buffer:
    # OpenCV 5.0 rounded the fixed-point pair the wrong way under INTER_NEAREST (fixed in 5.1).
    nearest: np.ndarray
    residual_px: float  # worst round-trip error of the maps (raw -> ray -> raw), pixels


def _eye_rays(K: np.ndarray, dist: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) normalised undistorted coordinates x/z, y/z of the ray through every raw pixel
    (read-only arrays, cached per camera: renderers of the same rig share them)."""
    return _eye_rays_cached(np.asarray(K, np.float64).tobytes(), np.asarray(dist, np.float64).tobytes(),
                            tuple(size))


@functools.lru_cache(maxsize=8)
def _eye_rays_cached(K_bytes: bytes, dist_bytes: bytes, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    K = np.frombuffer(K_bytes, np.float64).reshape(3, 3)
    dist = np.frombuffer(dist_bytes, np.float64)
    w, h = size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    raw = np.stack([u.ravel(), v.ravel()], axis=1)
    xy = cv2.undistortPoints(raw.reshape(-1, 1, 2), K, dist.reshape(1, -1), criteria=_UNDISTORT_CRITERIA)
    xy = xy.reshape(h, w, 2)
    x, y = np.ascontiguousarray(xy[..., 0]), np.ascontiguousarray(xy[..., 1])
    x.setflags(write=False)
    y.setflags(write=False)
    return x, y


def _keep_egl_display(platform) -> None:
    """Make a pyrender EGL platform release only its own context.

    pyrender's ``delete_context`` (called by ``OffscreenRenderer.delete`` and by its ``__del__``
    when a renderer is garbage-collected) calls ``eglTerminate`` on the process-wide EGL display,
    which kills every other renderer's context in the process (two twins, a twin and a
    calibration renderer). Destroying just this context is enough.
    """
    if not all(hasattr(platform, a) for a in ("_egl_display", "_egl_context", "delete_context")):
        return

    def delete_context() -> None:
        from OpenGL import EGL

        display, context = platform._egl_display, platform._egl_context
        platform._egl_display = platform._egl_context = None
        if display is not None and context is not None:
            EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
            EGL.eglDestroyContext(display, context)

    platform.delete_context = delete_context


def _linear(rgb_display: Sequence[float]) -> np.ndarray:
    """Display RGB -> linear BGR for pyrender's shader (which writes linear ** (1 / 2.2))."""
    return np.asarray(rgb_display, dtype=np.float64)[::-1] ** _GAMMA


class StereoRenderer:
    """Render raw stereo pairs of an :class:`ArmShape` (and optional props) seen by a :class:`StereoRig`.

    One OpenGL context, scene and canvas are reused. The static part of a lab scene (the wall,
    the floor, objects that do not move) is rendered once per eye and its multisamples kept; per
    frame the rectangles around the arm, the props and the moving objects get those samples back
    and only what moves is drawn over them, so a cluttered scene costs little more than an empty
    one and the pixels are those of drawing everything.

    Args:
        rig: the cameras, their calibration, pose and the default appearance.
        seed: seed of the sensor noise: frame k's noise is drawn from (seed, k) alone
            (``twin.sensor.frame_generator``), so frames are reproducible for a given seed and a
            recorded frame's noise can be drawn again from its noise-free image.
        tube_sides: vertices around the tube (48 keeps the polygon within 0.05 px of a circle).
        sensor: overrides ``rig.sensor`` (e.g. noise-free renders for measurements).
        fast_readback: draw and read only the rectangles holding what moves and read depth
            only where needed; ``False`` uses pyrender's own full read-back (slower,
            kept as a reference and a fallback).
        scene: what surrounds the arm (:class:`twin.scene.LabScene`); None is the clean scene
            (camera.toml's uniform background, lights and sensor).
        effects: overrides the camera effects the scene and the sensor give.

    Raises:
        RenderBackendError: no offscreen OpenGL (EGL) is available; the message names the
            system packages to install.
    """

    def __init__(self, rig: StereoRig, *, seed: int = 0, tube_sides: int = 48,
                 sensor: SensorModel | None = None, fast_readback: bool = True, scene: LabScene | None = None,
                 effects: CameraEffects | None = None) -> None:
        if tube_sides < 8:
            raise ValueError(f"tube_sides: expected at least 8, got {tube_sides}")
        self.rig = rig
        self.scene = scene if scene is not None else clean_scene()
        self.sensor = rig.sensor if sensor is None else sensor
        self.effects = effects if effects is not None else self.scene.effects(self.sensor)
        self.tube_sides = int(tube_sides)
        self.seed = int(seed)
        self._rng = np.random.default_rng(seed)
        self._next_frame = 0
        self._background: dict[str, np.ndarray] = {}
        self.timings_s: dict[str, float] = {}
        self._pyrender, self._GL = _gl()
        pyrender = self._pyrender
        calib = rig.calibration

        # --- distortion maps and the ideal canvas (once) ---------------------------------
        per_eye = {}
        lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
        for side in _SIDES:
            K = calib.K(side)
            x, y = _eye_rays(K, calib.dist(side), calib.image_size)
            per_eye[side] = (x, y)
            u = K[0, 0] * x + K[0, 1] * y + K[0, 2]
            v = K[1, 1] * y + K[1, 2]
            lo = np.minimum(lo, [u.min() - K[0, 2], v.min() - K[1, 2]])
            hi = np.maximum(hi, [u.max() - K[0, 2], v.max() - K[1, 2]])
        self._eyes: dict[str, _Eye] = {}
        self._canvas_size = (0, 0)
        self._build_canvas(per_eye, lo, hi)
        self._sensors = {side: SensorSimulator(self.effects, calib.K(side), calib.image_size, self._rng)
                         for side in _SIDES}

        # --- the scene --------------------------------------------------------------------
        look = rig.appearance
        backdrop = self.scene.backdrop
        background = look.background_rgb if backdrop is None else backdrop.surface.rgb
        ambient, lights = self._lights()
        self._scene = _ordered_scene_class(pyrender)(bg_color=np.append(np.asarray(background)[::-1], 1.0),
                                                     ambient_light=ambient)
        self._camera_nodes = {}
        for side in _SIDES:
            K = self._eyes[side].K_canvas
            camera = pyrender.IntrinsicsCamera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2] + 0.5, cy=K[1, 2] + 0.5,
                                               znear=_ZNEAR_M, zfar=_ZFAR_M)
            self._camera_nodes[side] = self._scene.add(camera, pose=rig.T_world_cam_gl(side), name=f"cam_{side}")
        self._lights_gl = []
        for colour_bgr, intensity, direction in lights:
            light = pyrender.DirectionalLight(color=colour_bgr, intensity=intensity)
            self._scene.add(light, pose=pose_with_z(-np.asarray(direction), np.zeros(3)))
            self._lights_gl.append(light)
        self._arm_material = self._material(look.arm_rgb)
        self._plate_material = self._material(look.plate_rgb)
        self._tube_node = None
        self._plate_nodes: list = []
        self._plate_key: tuple | None = None
        self._prop_nodes: list = []
        self._arm_vertices: list[np.ndarray] = []
        self._prop_vertices: list[np.ndarray] = []
        world, static, moving = scene_parts(self.scene)
        static_parts = []  # (node, its vertices in the world)
        for part in world:
            static_parts.append((self._scene.add(self._part_mesh(part), name="backdrop"), part.positions))
        for obj, parts in static:
            T = obj.T_world(0.0)
            for part in parts:
                node = self._scene.add(self._part_mesh(part), pose=T, name=obj.name)
                static_parts.append((node, part.positions.astype(np.float64) @ T[:3, :3].T + T[:3, 3]))
        self._moving: list[tuple[SceneObject, list, list[np.ndarray]]] = []
        self._moving_faces: list[list[np.ndarray]] = []
        for obj, parts in moving:
            nodes = [self._scene.add(self._part_mesh(part), pose=obj.T_world(0.0), name=obj.name) for part in parts]
            self._moving.append((obj, nodes, [part.positions.astype(np.float64) for part in parts]))
            self._moving_faces.append([np.asarray(part.faces, np.int64) for part in parts])
        try:
            self._renderer = pyrender.OffscreenRenderer(*self._canvas_size)
        except Exception as e:  # EGL missing devices/drivers surface as many exception types
            raise RenderBackendError(f"cannot create an offscreen EGL context ({type(e).__name__}: {e}); "
                                     f"{EGL_HINT}") from e
        _keep_egl_display(self._renderer._platform)
        if hasattr(self._renderer._renderer, "_sorted_mesh_nodes"):
            self._renderer._renderer._sorted_mesh_nodes = _drawing_order
        # Linear light = base * (ambient + directional * cos); see twin/matte.frag.
        if hasattr(self._renderer._renderer, "_program_cache"):
            self._renderer._renderer._program_cache = _matte_program_cache(pyrender)
        else:  # pyrender's PBR shader: its Lambert term is radiance * 0.96 * cos / pi
            for light in self._lights_gl:
                light.intensity = light.intensity * math.pi / (1.0 - _DIELECTRIC_F0)
        # A drawn rectangle starts from the static scene's samples: these are never drawn again.
        self._static_nodes = [node for node, _ in static_parts]
        self._fast_readback = fast_readback and all(
            hasattr(self._renderer._renderer, a) for a in ("_main_fb", "_main_fb_ms", "_read_main_framebuffer"))
        if self._fast_readback:
            self._want_depth = True
            self._rects = [(0, 0, *self._canvas_size)]
            self._static_samples: dict[str, int] = {}
            self._raw_boxes: dict[str, list] = {side: [] for side in _SIDES}
            self._renderer._renderer._read_main_framebuffer = self._read_framebuffer
            self._render_static()

    def _lights(self) -> tuple[np.ndarray, list[tuple[np.ndarray, float, np.ndarray]]]:
        """Ambient colour and (colour, intensity, direction) of each light, colours in BGR order."""
        lighting = self.scene.lighting
        if lighting is None:
            look = self.rig.appearance
            return np.full(3, look.ambient), [(np.ones(3), look.directional,
                                               np.asarray(look.light_direction_world, float))]
        ambient = lighting.ambient * temperature_rgb(lighting.ambient_temperature_k)[::-1]
        lights = [(temperature_rgb(light.temperature_k)[::-1], light.intensity,
                   np.asarray(light.direction_world, float)) for light in lighting.lights]
        return ambient, lights

    def _render_static(self) -> None:
        """Render the static scene once per eye: the canvas, the raw image and the left depth behind
        everything that moves; per frame only the rectangle around what moves is drawn again."""
        self._set_arm(None)
        self._show_moving(False)
        self._canvas = {}
        self._static_canvas = {}
        for side in _SIDES:
            self._scene.main_camera_node = self._camera_nodes[side]
            [(colour, zbuf)] = self._renderer.render(self._scene)
            self._canvas[side] = [colour.copy(), zbuf.copy(), None]  # colour, depth, the last frame's rects
            self._static_canvas[side] = (colour.copy(), zbuf.copy())
            self._keep_static_samples(side)
        self._show_moving(True)
        self._static_raw = {}
        self._static_done = {}
        for side in _SIDES:
            eye = self._eyes[side]
            raw = cv2.remap(self._static_canvas[side][0], eye.map1, eye.map2, cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REPLICATE)
            self._static_raw[side] = raw
            self._static_done[side] = None if self.effects.legacy else self._sensors[side].static(raw)
        eye = self._eyes["left"]
        zbuf = cv2.remap(self._static_canvas["left"][1], eye.nearest, None, cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_REPLICATE)
        self._static_depth = _gl_depth_to_metres(zbuf)

    # --- set-up helpers ------------------------------------------------------------------------

    def _build_canvas(self, per_eye: dict, lo: np.ndarray, hi: np.ndarray) -> None:
        """One canvas size for both eyes, each eye's principal point placed to cover its rays."""
        calib = self.rig.calibration
        m = _CANVAS_MARGIN_PX
        width = int(math.ceil(hi[0] - lo[0])) + 2 * m + 1
        height = int(math.ceil(hi[1] - lo[1])) + 2 * m + 1
        width += (-width) % 4  # GL_RGB rows stay 4-byte aligned
        self._canvas_size = (width, height)
        for side in _SIDES:
            K = calib.K(side)
            x, y = per_eye[side]
            K_canvas = K.copy()
            K_canvas[0, 2] = -math.floor(lo[0]) + m  # lo is relative to the principal point
            K_canvas[1, 2] = -math.floor(lo[1]) + m
            u = (K_canvas[0, 0] * x + K_canvas[0, 1] * y + K_canvas[0, 2]).astype(np.float32)
            v = (K_canvas[1, 1] * y + K_canvas[1, 2]).astype(np.float32)
            v_up = (height - 1) - v  # the canvas is read bottom-up
            map1, map2 = cv2.convertMaps(u, v_up, cv2.CV_16SC2)
            nearest = np.stack([np.round(u), np.round(v_up)], axis=-1).clip(-32768, 32767).astype(np.int16)
            # Check the inversion with OpenCV's forward model on every 4th row and column and
            # the borders (projectPoints on all 0.9 M pixels would take a second per eye).
            w, h = calib.image_size
            cols = np.unique(np.r_[np.arange(0, w, 4), w - 1])
            rows = np.unique(np.r_[np.arange(0, h, 4), h - 1])
            sub = np.ix_(rows, cols)
            rays = np.column_stack([x[sub].ravel(), y[sub].ravel(), np.ones(x[sub].size)])
            back, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, calib.dist(side).reshape(1, -1))
            grid = np.stack(np.meshgrid(cols, rows), -1).reshape(-1, 2)
            residual = float(np.max(np.abs(back.reshape(-1, 2) - grid)))
            if residual > 1e-3:
                raise ValueError(f"{side} camera: the distortion cannot be inverted over the image "
                                 f"(round-trip error {residual:.3g} px); check its dist coefficients")
            self._eyes[side] = _Eye(K_canvas, map1, map2, nearest, residual)

    def _material(self, rgb_display):
        return self._pyrender.MetallicRoughnessMaterial(
            baseColorFactor=np.append(_linear(rgb_display), 1.0), metallicFactor=0.0, roughnessFactor=1.0)

    def _mesh(self, positions, normals, faces, material, uv=None):
        pyrender = self._pyrender
        primitive = pyrender.Primitive(positions=positions, normals=normals, indices=faces, texcoord_0=uv,
                                       material=material, mode=pyrender.constants.GLTF.TRIANGLES)
        return pyrender.Mesh([primitive])

    def _part_mesh(self, part: Part):
        """A scene part as a mesh; textures are uploaded in BGR order like every other colour."""
        pyrender = self._pyrender
        texture = None
        if part.texture is not None:
            texture = pyrender.Texture(source=np.ascontiguousarray(part.texture[..., ::-1]), source_channels="RGB")
        material = pyrender.MetallicRoughnessMaterial(baseColorFactor=np.append(_linear(part.rgb), 1.0),
                                                      baseColorTexture=texture, metallicFactor=0.0,
                                                      roughnessFactor=1.0)
        return self._mesh(part.positions, part.normals, part.faces, material,
                          part.uv if texture is not None else None)

    @property
    def canvas_size(self) -> tuple[int, int]:
        """(width, height) of the ideal pinhole canvas each eye is rendered on."""
        return self._canvas_size

    def canvas_K(self, side: str) -> np.ndarray:
        """3x3 pinhole matrix of one eye's ideal canvas (OpenCV conventions, top-down rows)."""
        return self._eyes[side].K_canvas.copy()

    # --- per-frame scene updates ----------------------------------------------------------------

    def _arm_geometry(self, shape: ArmShape):
        """The tube mesh and the plate poses of one arm shape (built before anything is drawn, so
        the drawn rectangle can cover every sub-frame of a motion-blurred exposure)."""
        tube = tube_surface(shape.points_world, shape.radius_m, self.tube_sides)
        poses = [pose_with_z(plate.normal_world, plate.center_world) for plate in shape.plates]
        return shape, tube, poses

    def _set_arm(self, shape: ArmShape | None, geometry=None) -> None:
        scene = self._scene
        if self._tube_node is not None:
            scene.remove_node(self._tube_node)
            self._tube_node = None
        self._arm_vertices = []
        if shape is None:
            for node in self._plate_nodes:
                node.mesh.is_visible = False
            return
        _, (positions, normals, faces), poses = geometry if geometry is not None else self._arm_geometry(shape)
        # Posed at its own centroid, not at the world origin where the base plate sits: pyrender sorts
        # nodes by distance and leaves ties to a set's order, which differed between renderers.
        centroid = positions.mean(axis=0)
        pose = np.eye(4)
        pose[:3, 3] = centroid
        self._tube_node = scene.add(self._mesh(positions - centroid.astype(np.float32), normals, faces,
                                               self._arm_material), pose=pose, name="arm")
        self._arm_vertices = [positions.astype(np.float64)]
        key = tuple((round(p.radius_m, 9), round(p.thickness_m, 9)) for p in shape.plates)
        if key != self._plate_key:
            for node in self._plate_nodes:
                scene.remove_node(node)
            self._plate_nodes = []
            for plate in shape.plates:
                h = plate.thickness_m / 2.0
                disc = tube_surface(np.array([[0, 0, -h], [0, 0, h]]), np.full(2, plate.radius_m), self.tube_sides)
                self._plate_nodes.append(scene.add(self._mesh(*disc, self._plate_material), name="plate"))
            self._plate_key = key
        for node, pose in zip(self._plate_nodes, poses, strict=True):
            node.mesh.is_visible = True
            scene.set_pose(node, pose)
            local = node.mesh.primitives[0].positions.astype(np.float64)
            self._arm_vertices.append(local @ pose[:3, :3].T + pose[:3, 3])

    def _show_moving(self, visible: bool) -> None:
        for _, nodes, _ in self._moving:
            for node in nodes:
                node.mesh.is_visible = visible

    def _moving_vertices(self, t_s: float) -> list[np.ndarray]:
        out = []
        for obj, _, locals_ in self._moving:
            T = obj.T_world(t_s)
            out += [local @ T[:3, :3].T + T[:3, 3] for local in locals_]
        return out

    def _moving_vertices_by_object(self, t_s: float) -> list[list[np.ndarray]]:
        out = []
        for obj, _, locals_ in self._moving:
            T = obj.T_world(t_s)
            out.append([local @ T[:3, :3].T + T[:3, 3] for local in locals_])
        return out

    def _set_moving(self, t_s: float) -> None:
        for obj, nodes, _ in self._moving:
            T = obj.T_world(t_s)
            for node in nodes:
                self._scene.set_pose(node, T)

    def _set_props(self, props: Sequence[Prop]) -> None:
        for node in self._prop_nodes:
            self._scene.remove_node(node)
        self._prop_nodes = []
        self._prop_vertices = []
        for prop in props:
            pose = np.asarray(prop.T_world_prop, float)
            for positions, normals, faces, rgb in prop.parts:
                mesh = self._mesh(np.asarray(positions, np.float32), np.asarray(normals, np.float32),
                                  np.asarray(faces, np.uint32), self._material(rgb))
                self._prop_nodes.append(self._scene.add(mesh, pose=pose))
                self._prop_vertices.append(np.asarray(positions, np.float64) @ pose[:3, :3].T + pose[:3, 3])

    # --- rendering --------------------------------------------------------------------------------

    def _read_framebuffer(self, scene, flags):
        """Replacement for pyrender's read-back: each drawn rectangle's colour, and raw depth only when
        asked, no flips or conversions (the remap maps absorb the bottom-up row order)."""
        GL = self._GL
        r = self._renderer._renderer
        out = []
        for x, y, w, h in self._rects:  # bottom-up GL window coordinates
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, r._main_fb_ms)
            GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, r._main_fb)
            GL.glBlitFramebuffer(x, y, x + w, y + h, x, y, x + w, y + h, GL.GL_COLOR_BUFFER_BIT, GL.GL_LINEAR)
            if self._want_depth:
                GL.glBlitFramebuffer(x, y, x + w, y + h, x, y, x + w, y + h, GL.GL_DEPTH_BUFFER_BIT, GL.GL_NEAREST)
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, r._main_fb)
            GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
            colour = np.frombuffer(GL.glReadPixels(x, y, w, h, GL.GL_RGB, GL.GL_UNSIGNED_BYTE),
                                   dtype=np.uint8).reshape(h, w, 3)
            depth = None
            if self._want_depth:
                depth = np.frombuffer(GL.glReadPixels(x, y, w, h, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT),
                                      dtype=np.float32).reshape(h, w)
            out.append((colour, depth))
        return out

    def _drawn_rect(self, side: str, vertices: list[np.ndarray]) -> tuple[int, int, int, int]:
        """Bottom-up (x, y, w, h) canvas rectangle holding every given vertex.

        Outside it the canvas shows the static scene, so only this rectangle is restored, drawn
        and read: it is what keeps a stereo pair within budget on a CPU rasteriser.
        """
        width, height = self._canvas_size
        if not vertices:
            return 0, 0, 1, 1
        T = self.rig.T_world_cam(side)
        p = (np.vstack(vertices) - T[:3, 3]) @ T[:3, :3]
        if np.any(p[:, 2] <= _ZNEAR_M):
            return 0, 0, width, height  # something reaches behind the camera: draw everything
        K = self._eyes[side].K_canvas
        u = K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2]
        v = K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]
        pad = 4  # anti-aliasing and rounding
        x0 = int(np.clip(math.floor(u.min()) - pad, 0, width))
        x1 = int(np.clip(math.ceil(u.max()) + pad + 1, 0, width))
        top = int(np.clip(math.floor(v.min()) - pad, 0, height))
        bottom = int(np.clip(math.ceil(v.max()) + pad + 1, 0, height))
        if x1 <= x0 or bottom <= top:
            return 0, 0, 1, 1
        return x0, height - bottom, x1 - x0, bottom - top

    def _triangle_rects(self, side: str, meshes: list[tuple[np.ndarray, np.ndarray]]) -> list | None:
        """Bottom-up (x, y, w, h) canvas rectangles that together hold every triangle of the meshes
        ((world vertices, faces) pairs), in pieces of ``_PIECE_PX`` along the longer side of their box:
        a cable slanting across the whole view costs its own pixels, not its bounding box. None when
        something reaches behind the camera."""
        width, height = self._canvas_size
        T = self.rig.T_world_cam(side)
        K = self._eyes[side].K_canvas
        lows, highs = [], []
        for vertices, faces in meshes:
            p = (vertices - T[:3, 3]) @ T[:3, :3]
            if np.any(p[:, 2] <= _ZNEAR_M):
                return None
            uv = np.column_stack([K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2], K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]])
            a, b, c = uv[faces[:, 0]], uv[faces[:, 1]], uv[faces[:, 2]]
            lows.append(np.minimum(np.minimum(a, b), c))
            highs.append(np.maximum(np.maximum(a, b), c))
        if not lows:
            return []
        pad = 4  # anti-aliasing and rounding, as in _drawn_rect
        size = np.array([width, height])
        low = np.clip(np.floor(np.vstack(lows)) - pad, 0, size).astype(np.int64)
        high = np.clip(np.ceil(np.vstack(highs)) + pad + 1, 0, size).astype(np.int64)
        start, end = low.min(axis=0), high.max(axis=0)
        along = 0 if end[0] - start[0] >= end[1] - start[1] else 1
        across = 1 - along
        # Each triangle widens the across-range of every piece its box reaches along.
        first = (low[:, along] - start[along]) // _PIECE_PX
        last = (high[:, along] - 1 - start[along]) // _PIECE_PX
        count = int(last.max()) + 1
        b0 = np.full(count, np.iinfo(np.int64).max)
        b1 = np.full(count, np.iinfo(np.int64).min)
        for step in range(int((last - first).max()) + 1):
            reach = first + step <= last
            np.minimum.at(b0, first[reach] + step, low[reach, across])
            np.maximum.at(b1, first[reach] + step, high[reach, across])
        rects = []
        for k in np.flatnonzero(b1 > b0):
            a0 = int(start[along]) + int(k) * _PIECE_PX
            a1 = min(a0 + _PIECE_PX, int(end[along]))
            (x0, x1), (top, bottom) = ((a0, a1), (int(b0[k]), int(b1[k]))) if along == 0 else \
                ((int(b0[k]), int(b1[k])), (a0, a1))
            rects.append((x0, height - bottom, x1 - x0, bottom - top))
        return rects

    def _render_regions(self, side: str, rects: list, depth: bool) -> list[tuple[np.ndarray, np.ndarray | None]]:
        """Draw one eye's canvas rectangles (bottom-up GL coordinates) in one pass; returns each one's
        colour (and raw OpenGL depth if asked).

        Each rectangle gets the static scene's samples (colour and depth, every multisample) copied in
        instead of a clear, and only what moves is drawn over them, with the depth test: the same
        samples as drawing everything, at the cost of the moving things alone. Outside the rectangles
        the canvas is left stale and is not read.
        """
        GL = self._GL
        self._scene.main_camera_node = self._camera_nodes[side]
        self._want_depth = depth
        self._rects = rects
        self._renderer._platform.make_current()
        x0 = min(r[0] for r in rects)
        y0 = min(r[1] for r in rects)
        GL.glEnable(GL.GL_SCISSOR_TEST)
        GL.glScissor(x0, y0, max(r[0] + r[2] for r in rects) - x0, max(r[1] + r[3] for r in rects) - y0)
        hidden = [node for node in self._static_nodes if node.mesh.is_visible]
        for node in hidden:
            node.mesh.is_visible = False
        renderer_module = self._pyrender.renderer
        clear = renderer_module.glClear
        renderer_module.glClear = functools.partial(self._restore_static_samples, side)
        try:
            return self._renderer.render(self._scene)
        finally:
            renderer_module.glClear = clear
            for node in hidden:
                node.mesh.is_visible = True

    def _keep_static_samples(self, side: str) -> None:
        """Copy the multisampled static scene just drawn for ``side`` into a framebuffer of its own
        (4 samples of colour and depth: about 50 MB per eye for a 1664x941 canvas)."""
        GL = self._GL
        width, height = self._canvas_size
        colour_rb, depth_rb = GL.glGenRenderbuffers(2)
        for buffer, kind in ((colour_rb, GL.GL_RGBA), (depth_rb, GL.GL_DEPTH_COMPONENT24)):
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, buffer)
            GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, _SAMPLES, kind, width, height)
        framebuffer = GL.glGenFramebuffers(1)
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, framebuffer)
        GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, colour_rb)
        GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER, depth_rb)
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._renderer._renderer._main_fb_ms)
        GL.glBlitFramebuffer(0, 0, width, height, 0, 0, width, height,
                             GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT, GL.GL_NEAREST)
        self._static_samples[side] = framebuffer

    def _restore_static_samples(self, side: str, _mask=None) -> None:
        """pyrender's clear, replaced: the drawn rectangles get the static scene's samples back."""
        GL = self._GL
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._static_samples[side])
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._renderer._renderer._main_fb_ms)
        for x, y, w, h in self._rects:
            GL.glBlitFramebuffer(x, y, x + w, y + h, x, y, x + w, y + h,
                                 GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT, GL.GL_NEAREST)

    def _restore(self, side: str) -> None:
        """Put the static scene back where the last frame drew."""
        canvas = self._canvas[side]
        static_colour, static_depth = self._static_canvas[side]
        for px, py, pw, ph in canvas[2] or ():
            canvas[0][py:py + ph, px:px + pw] = static_colour[py:py + ph, px:px + pw]
            canvas[1][py:py + ph, px:px + pw] = static_depth[py:py + ph, px:px + pw]
        canvas[2] = []

    def _paste(self, side: str, rect, colour: np.ndarray, zbuf: np.ndarray | None) -> None:
        """Put a drawn rectangle into the canvas (after ``_restore`` for the frame)."""
        canvas = self._canvas[side]
        x, y, w, h = rect
        canvas[0][y:y + h, x:x + w] = colour
        if zbuf is not None:
            canvas[1][y:y + h, x:x + w] = zbuf
        canvas[2].append(rect)

    def _raw_box(self, side: str, rect) -> tuple[int, int, int, int]:
        """(x0, y0, x1, y1) raw pixels whose rays land in one canvas rectangle.

        Elsewhere the raw image shows the static scene. The distortion maps the rectangle's border
        onto the border of its image (the map is one-to-one), so the border's bounding box holds
        the whole region.
        """
        x, y_up, w, h = rect
        height = self._canvas_size[1]
        top = height - (y_up + h)  # top-down canvas rows
        t = np.linspace(0.0, 1.0, 24)
        xs = np.concatenate([x + t * w, x + t * w, np.full(24, x), np.full(24, x + w)]) - 0.5
        ys = np.concatenate([np.full(24, top), np.full(24, top + h), top + t * h, top + t * h]) - 0.5
        K = self._eyes[side].K_canvas
        rays = np.column_stack([(xs - K[0, 2]) / K[0, 0], (ys - K[1, 2]) / K[1, 1], np.ones(len(xs))])
        calib = self.rig.calibration
        uv, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), calib.K(side), calib.dist(side).reshape(1, -1))
        uv = uv.reshape(-1, 2)
        W, H = calib.image_size
        x0 = int(np.clip(np.floor(uv[:, 0].min()) - 2, 0, W))
        x1 = int(np.clip(np.ceil(uv[:, 0].max()) + 3, 0, W))
        y0 = int(np.clip(np.floor(uv[:, 1].min()) - 2, 0, H))
        y1 = int(np.clip(np.ceil(uv[:, 1].max()) + 3, 0, H))
        return x0, y0, x1, y1

    def _to_raw(self, side: str, canvas: np.ndarray, bottom_up: bool) -> tuple[np.ndarray, list | None]:
        """The distorted raw optical image and the raw regions that differ from the static scene."""
        eye = self._eyes[side]
        if not bottom_up:
            canvas = np.ascontiguousarray(canvas[::-1])
        if not self._fast_readback:
            return cv2.remap(canvas, eye.map1, eye.map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), None
        # Only the regions that can show something new are resampled; the rest is the static scene.
        out = self._static_raw[side].copy()
        boxes = [self._raw_box(side, rect) for rect in self._canvas[side][2]]
        self._raw_boxes[side] = boxes
        for x0, y0, x1, y1 in boxes:
            if x1 > x0 and y1 > y0:
                out[y0:y1, x0:x1] = cv2.remap(canvas, eye.map1[y0:y1, x0:x1], eye.map2[y0:y1, x0:x1],
                                              cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return out, boxes

    def _depth_to_raw(self, zbuf: np.ndarray, bottom_up: bool) -> np.ndarray:
        eye = self._eyes["left"]
        if not bottom_up:  # pyrender's own read-back: already linear metres, 0 = background
            z = cv2.remap(np.ascontiguousarray(zbuf[::-1]), eye.nearest, None, cv2.INTER_NEAREST,
                          borderMode=cv2.BORDER_REPLICATE)
            z[z <= 0] = np.inf
            return z
        z = self._static_depth.copy()
        for x0, y0, x1, y1 in self._raw_boxes["left"]:  # the left image's boxes, from _to_raw
            if x1 > x0 and y1 > y0:
                d = cv2.remap(zbuf, eye.nearest[y0:y1, x0:x1], None, cv2.INTER_NEAREST,
                              borderMode=cv2.BORDER_REPLICATE)
                z[y0:y1, x0:x1] = _gl_depth_to_metres(d)
        return z

    def _subframes(self, shape: ArmShape | None, t_s: float,
                   previous: tuple[ArmShape, float] | None) -> list[tuple[ArmShape | None, float]]:
        """(arm shape, time) of each sub-frame of the exposure, the last at ``t_s`` (one at the
        exposure's middle when nothing moves enough to blur).

        The arm's shape between ``previous`` (the shape as the exposure opened, or the previous frame's)
        and this one is interpolated linearly; moving objects follow their paths exactly.
        """
        e = self.effects
        if e.exposure_s <= 0 or e.motion_subframes < 2:
            return [(shape, t_s)]

        def at(tau: float) -> ArmShape | None:
            return _shape_at(shape, t_s, previous, tau)

        # As many sub-frames as the motion needs: neighbouring ones at most MOTION_STEP_PX apart on
        # the canvas, up to ``motion_subframes``. Under half a step, one render at the middle of the
        # exposure stands for all: its centroid is the blur's, and the spread it leaves out (a box
        # under 0.5 px, 0.14 px standard deviation) is lost in the optics' blur.
        start = t_s - e.exposure_s
        sweep = self._motion_px(at(start), shape, start, t_s)
        if sweep < 0.5 * MOTION_STEP_PX:
            middle = t_s - 0.5 * e.exposure_s
            return [(at(middle), middle)]
        count = min(e.motion_subframes, 1 + math.ceil(sweep / MOTION_STEP_PX))
        return [(at(float(tau)), float(tau)) for tau in np.linspace(start, t_s, count)]

    def exposed_shape(self, shape: ArmShape | None, t_s: float,
                      previous: tuple[ArmShape, float] | None = None) -> ArmShape | None:
        """The arm at the middle of the exposure ending at ``t_s``: what the frame's motion blur is
        centred on, so its truth (the shape at ``t_s`` itself without an exposure time).

        A silhouette swept over the exposure has its edges where the arm was halfway through it; scored
        against the shape at the exposure's end, a fast arm looked ``speed * exposure / 2`` off (the
        bench's random pressure sequences, 30 ms: up to 13 mm at the tip) for a lag no image shows.
        """
        e = self.effects
        if e.exposure_s <= 0 or e.motion_subframes < 2:  # drawn at t_s (see _subframes)
            return shape
        return _shape_at(shape, t_s, previous, t_s - 0.5 * e.exposure_s)

    def _motion_px(self, first: ArmShape | None, last: ArmShape | None, t0: float, t1: float) -> float:
        """The largest distance (canvas pixels, either eye) that the arm's backbone and plates or a
        moving object's points travel between two times."""
        pairs = list(zip(self._moving_vertices(t0), self._moving_vertices(t1), strict=True))
        if (first is not None and last is not None and len(first.points_world) == len(last.points_world)
                and len(first.plates) == len(last.plates)):
            pairs.append((first.points_world, last.points_world))
            pairs += [(a.center_world[None], b.center_world[None])
                      for a, b in zip(first.plates, last.plates, strict=True)]
        if not pairs:
            return 0.0
        before = np.vstack([a for a, _ in pairs])
        after = np.vstack([b for _, b in pairs])
        sweep = 0.0
        for side in _SIDES:
            T = self.rig.T_world_cam(side)
            K = self._eyes[side].K_canvas
            p, q = (before - T[:3, 3]) @ T[:3, :3], (after - T[:3, 3]) @ T[:3, :3]
            if np.any(p[:, 2] <= _ZNEAR_M) or np.any(q[:, 2] <= _ZNEAR_M):
                return math.inf  # reaching behind the camera: sample the exposure fully
            moved = (p[:, :2] / p[:, 2:3] - q[:, :2] / q[:, 2:3]) * np.array([K[0, 0], K[1, 1]])
            sweep = max(sweep, float(np.max(np.linalg.norm(moved, axis=1))))
        return sweep

    def background(self, side: str) -> np.ndarray | None:
        """The noise-free image of the static scene (nothing that moves, no arm) for one eye: outside
        the region a frame redraws, its ``clean_left``/``clean_right`` equal this exactly (a run stores
        a frame as its difference from it). None without the fast read-back (no static scene kept)."""
        if not self._fast_readback:
            return None
        if side not in self._background:
            done = self._static_done[side]
            self._background[side] = self._sensors[side].clean(self._static_raw[side]) if done is None else done
        return self._background[side]

    def background_depth(self) -> np.ndarray | None:
        """(H, W) float32 metres: the left depth of the static scene (inf: nothing), which a frame's
        ``depth_left_m`` equals outside the region it redraws; None without the fast read-back."""
        return self._static_depth if self._fast_readback else None

    def render(self, shape: ArmShape | None, *, depth: bool = True, props: Sequence[Prop] = (), t_s: float = 0.0,
               previous: tuple[ArmShape, float] | None = None, frame_index: int | None = None) -> StereoImages:
        """Render one raw stereo pair.

        Args:
            shape: the arm (``None`` renders no arm, e.g. for calibration-board views).
            depth: also return the left depth map (in raw left pixels).
            props: extra objects for this frame only.
            t_s: the time of the frame (moving scene objects follow their paths; the exposure ends here).
            previous: the arm's (shape, time) at the previous frame, for motion blur over the exposure.
            frame_index: the frame's number in the noise sequence (its noise is drawn from the seed
                and this number only); None: the one after the last frame rendered (0 at first).

        Returns:
            StereoImages with BGR uint8 raw images of ``rig.image_size``, their noise-free versions
            and the left depth.
        """
        index = self._next_frame if frame_index is None else int(frame_index)
        if index < 0:
            raise ValueError(f"frame_index: expected an integer >= 0, got {frame_index}")
        self._next_frame = index + 1
        t0 = time.perf_counter()
        subframes = [(None if s is None else self._arm_geometry(s), tau)
                     for s, tau in self._subframes(shape, t_s, previous)]
        self._set_props(props)
        gl = {"left": 0.0, "right": 0.0}
        accumulate = len(subframes) > 1
        canvases: dict[str, np.ndarray] = {}
        bottom_up = True
        zbuf = None
        t1 = time.perf_counter()
        if self._fast_readback:
            # One rectangle for the arm (and props), pieces around each moving object's triangles;
            # rectangles that overlap, or cost little more merged, are merged.
            arm: list[np.ndarray] = list(self._prop_vertices)
            moving: list[tuple[np.ndarray, np.ndarray]] = []  # (world vertices, faces) of every moving mesh
            for geometry, tau in subframes:
                if geometry is not None:
                    arm.append(geometry[1][0].astype(np.float64))
                    arm += [_disc_points(plate, pose) for plate, pose in zip(geometry[0].plates, geometry[2],
                                                                              strict=True)]
                for vertices, faces in zip(self._moving_vertices_by_object(tau), self._moving_faces, strict=True):
                    moving += list(zip(vertices, faces, strict=True))
            rects = {}
            for side in _SIDES:
                pieces = self._triangle_rects(side, moving)
                drawn = [self._drawn_rect(side, arm)] if arm else []
                drawn += [self._drawn_rect(side, [v for v, _ in moving])] if pieces is None else pieces
                rects[side] = _merged_rects(drawn)
            sums: dict[tuple[str, int], np.ndarray] = {}
            for side in _SIDES:
                self._restore(side)
            for k, (geometry, tau) in enumerate(subframes):
                self._set_arm(None if geometry is None else geometry[0], geometry)
                self._set_moving(tau)
                last = k == len(subframes) - 1
                for side in _SIDES:
                    start = time.perf_counter()
                    drawn = self._render_regions(side, rects[side], depth and last and side == "left")
                    gl[side] += time.perf_counter() - start
                    for j, (rect, (colour, z)) in enumerate(zip(rects[side], drawn, strict=True)):
                        if accumulate:
                            linear = _TO_LINEAR[colour]
                            sums[side, j] = linear if k == 0 else sums[side, j] + linear
                            if last:
                                colour = _from_linear(sums[side, j] / len(subframes))
                        if last:
                            self._paste(side, rect, colour, z)
                    if last and side == "left":
                        zbuf = self._canvas["left"][1]
            for side in _SIDES:
                canvases[side] = self._canvas[side][0]
        else:
            bottom_up = False
            sums = {}
            for k, (geometry, tau) in enumerate(subframes):
                self._set_arm(None if geometry is None else geometry[0], geometry)
                self._set_moving(tau)
                last = k == len(subframes) - 1
                for side in _SIDES:
                    start = time.perf_counter()
                    self._scene.main_camera_node = self._camera_nodes[side]
                    colour, z = self._renderer.render(self._scene)  # top-down, linear depth, 0 = background
                    gl[side] += time.perf_counter() - start
                    if accumulate:
                        linear = _TO_LINEAR[colour]
                        sums[side] = linear if k == 0 else sums[side] + linear
                        colour = _from_linear(sums[side] / len(subframes)) if last else colour
                    if last:
                        canvases[side] = np.ascontiguousarray(colour)
                        zbuf = np.ascontiguousarray(z) if side == "left" else zbuf
        t3 = time.perf_counter()
        images, clean = {}, {}
        for side in _SIDES:
            raw, roi = self._to_raw(side, canvases[side], bottom_up)
            static_done = None if not self._fast_readback else self._static_done[side]
            sensor = self._sensors[side]
            clean[side] = sensor.clean(raw, static_done, roi)
            images[side] = sensor.noisy(clean[side], frame_generator(self.seed, index, side))
        depth_m = self._depth_to_raw(zbuf, bottom_up) if depth else None
        t4 = time.perf_counter()
        if props:
            self._set_props(())
        self.timings_s = {"scene": t1 - t0, "gl_left": gl["left"], "gl_right": gl["right"], "post": t4 - t3,
                          "total": t4 - t0}
        return StereoImages(images["left"], images["right"], depth_m, clean["left"], clean["right"], index)

    def close(self) -> None:
        """Release the OpenGL context; closing twice is harmless."""
        renderer, self._renderer = getattr(self, "_renderer", None), None
        if renderer is not None:
            renderer.delete()

    def __enter__(self) -> StereoRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


_TO_LINEAR = ((np.arange(256) / 255.0) ** _GAMMA).astype(np.float32)


def _from_linear(linear: np.ndarray) -> np.ndarray:
    """Linear light in 0..1 -> display uint8, exactly (a table in linear steps loses the dark values:
    display 1..4 are closer together in linear light than a 12-bit step)."""
    display = cv2.pow(np.ascontiguousarray(linear, np.float32), 1.0 / _GAMMA)
    return np.clip(display * 255.0 + 0.5, 0, 255).astype(np.uint8)


def _merged_rects(rects: list[tuple[int, int, int, int]]) -> list[tuple[int, int, int, int]]:
    """Bottom-up (x, y, w, h) rectangles, merged while two of them overlap or a merge costs little more
    area than drawing them apart (30 %, or less than a rectangle's own cost); empty (1 x 1) rectangles
    dropped."""
    rects = [r for r in rects if r[2] > 1 and r[3] > 1]
    merged = True
    while merged and len(rects) > 1:
        merged = False
        for a in range(len(rects)):
            for b in range(a + 1, len(rects)):
                ax, ay, aw, ah = rects[a]
                bx, by, bw, bh = rects[b]
                x0, y0 = min(ax, bx), min(ay, by)
                x1, y1 = max(ax + aw, bx + bw), max(ay + ah, by + bh)
                union, apart = (x1 - x0) * (y1 - y0), aw * ah + bw * bh
                if union <= 1.3 * apart or union - apart <= _RECT_COST_PX:
                    rects[a] = (x0, y0, x1 - x0, y1 - y0)
                    del rects[b]
                    merged = True
                    break
            if merged:
                break
    return rects or [(0, 0, 1, 1)]


def _disc_points(plate: Plate, pose: np.ndarray) -> np.ndarray:
    """(16, 3) points on the rims of a plate's two faces: enough to bound its image."""
    angles = np.linspace(0.0, 2.0 * math.pi, 8, endpoint=False)
    h = plate.thickness_m / 2.0
    local = np.array([[plate.radius_m * math.cos(a), plate.radius_m * math.sin(a), z]
                      for z in (-h, h) for a in angles])
    return local @ pose[:3, :3].T + pose[:3, 3]


def _gl_depth_to_metres(d: np.ndarray) -> np.ndarray:
    """OpenGL depth-buffer values -> camera z in metres (``inf`` where nothing was drawn)."""
    n, f = _ZNEAR_M, _ZFAR_M
    with np.errstate(divide="ignore"):
        linear = (2.0 * n * f) / ((f + n) - (2.0 * d.astype(np.float32) - 1.0) * (f - n))
    linear = linear.astype(np.float32)
    linear[d >= 1.0] = np.inf
    return linear


def _shape_at(shape: ArmShape | None, t_s: float, previous: tuple[ArmShape, float] | None,
              tau: float) -> ArmShape | None:
    """The arm at time ``tau`` within the exposure ending at ``t_s``: interpolated linearly back
    towards ``previous`` (shape, time): the arm as the exposure opened, or at the previous frame."""
    if shape is not None and previous is not None and previous[1] < t_s:
        weight = float(np.clip((t_s - tau) / (t_s - previous[1]), 0.0, 1.0))
        return interpolate_shape(shape, previous[0], weight)
    return shape


def interpolate_shape(current: ArmShape, previous: ArmShape, weight: float) -> ArmShape:
    """The arm a fraction ``weight`` of the way back from ``current`` to ``previous`` (0: current).

    Points and plates move on straight lines; shapes with different sampling are not mixed.
    """
    if weight <= 0 or len(current.points_world) != len(previous.points_world) or \
            len(current.plates) != len(previous.plates):
        return current
    points = current.points_world + weight * (previous.points_world - current.points_world)
    plates = []
    for a, b in zip(current.plates, previous.plates, strict=True):
        normal = a.normal_world + weight * (b.normal_world - a.normal_world)
        plates.append(Plate(a.center_world + weight * (b.center_world - a.center_world),
                            normal / np.linalg.norm(normal), a.radius_m, a.thickness_m))
    return ArmShape(points, current.s_m, current.radius_m, tuple(plates))
