"""Lab scenes for the twin: what surrounds the arm, how it is lit and what the camera does to it.

The paper films its arm in front of a single-colour backdrop; labs have textured walls, wooden
shelves, skin, cables and changing light. A scene file (``models/scene.toml``) describes named
presets; each gives:

- a backdrop: a uniform colour, an image file or a procedural texture, placed as a wall (and
  optionally a floor) at a distance, so both eyes see it with its true disparity;
- objects: boxes, cables and blobs of named materials (wood, skin, orange, ...) beside the arm,
  static or moving back and forth along a path; occluders are objects that cross in front of it;
- lighting: ambient and directional lights with intensities, colour temperatures and directions;
- camera effects (:class:`twin.sensor.CameraEffects`): exposure, shot and read noise,
  vignetting, YUYV chroma subsampling, optical blur, shake and the arm's motion blur.

A preset may start from another (``base = "lab"``) and change only what differs: tables merge
key by key, objects add to the base's. The preset ``random`` is a seeded draw over every knob.
What a preset leaves out comes from ``camera.toml`` (its background colour, lights and sensor),
so ``clean`` renders exactly the images of a twin without a scene file.

World frame: metres, z up, origin at the arm's base; the camera looks along +y from y ~ -1 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.interpolate import make_interp_spline

from estimator.config_file import ConfigFileError, TableReader, number, read_toml, vector
from twin.rig import SensorModel
from twin.sensor import CameraEffects
from twin.textures import PATTERNS

KINDS = ("box", "cable", "blob")
ROLES = ("distractor", "occluder")
BACKDROPS = ("uniform", "image", "procedural")
BLOB_BUMP = 0.15  # a blob's radius varies by up to this share of its semi-axes (twin.lab_objects.blob_part)
REQUIRED_PRESETS = ("clean", "lab", "dim", "bright_warm", "blur", "occluded", "random")

# Named materials: display RGB and the texture they carry. Wood, skin and orange sit inside the
# arm's own hue range (OpenCV H 5..25): colour alone cannot tell them from the arm.
MATERIALS: dict[str, tuple[tuple[float, float, float], str | None]] = {
    "wood": ((0.70, 0.47, 0.27), "wood"),
    "light_wood": ((0.86, 0.68, 0.46), "wood"),
    "skin": ((0.88, 0.63, 0.50), None),
    "orange": ((1.0, 0.52, 0.14), None),
    "yellow": ((0.95, 0.82, 0.12), None),
    "red": ((0.80, 0.12, 0.10), None),
    "dark": ((0.07, 0.07, 0.08), None),
    "grey": ((0.45, 0.46, 0.48), None),
    "aluminium": ((0.66, 0.67, 0.70), None),
    "white": ((0.88, 0.88, 0.86), None),
    "blue": ((0.16, 0.30, 0.72), None),
    "green": ((0.22, 0.58, 0.30), None),
}


@dataclass(frozen=True)
class Surface:
    """How a surface looks: a display RGB colour, optionally modulated by a procedural texture.

    Attributes:
        rgb: display colour in 0..1.
        texture: one of :data:`twin.textures.PATTERNS`, or None (plain colour).
        contrast: relative brightness variation of the texture.
        feature_m: size of the texture's features (brick height, grain spacing), metres.
    """

    rgb: tuple[float, float, float]
    texture: str | None = None
    contrast: float = 0.2
    feature_m: float = 0.02


@dataclass(frozen=True)
class Backdrop:
    """A wall behind the arm (and optionally a floor), seen by both eyes as real geometry.

    Attributes:
        kind: "uniform" (a plain wall of ``surface.rgb``), "image" (``image`` stretched over the
            wall) or "procedural" (``surface.texture``).
        surface: colour and texture of the wall.
        image: the image file for ``kind = "image"``.
        wall_y_m: the wall's plane, y = wall_y_m (behind the arm: the camera is at y ~ -1).
        size_m: (width, height) of the wall.
        centre_xz_m: (x, z) of the wall's centre.
        floor_z_m: height of a floor plane under the arm, or None for no floor.
        floor: the floor's surface.
    """

    kind: str
    surface: Surface
    image: Path | None = None
    wall_y_m: float = 0.9
    size_m: tuple[float, float] = (6.0, 4.0)
    centre_xz_m: tuple[float, float] = (0.0, -0.3)
    floor_z_m: float | None = None
    floor: Surface | None = None


@dataclass(frozen=True)
class SceneObject:
    """A box, cable or blob beside (distractor) or in front of (occluder) the arm.

    Attributes:
        name: for messages and reports.
        kind: "box" (``size_m`` full extents), "blob" (an irregular ellipsoid of semi-axes
            ``size_m``) or "cable" (a tube of ``radius_m`` through ``points_m``).
        role: "distractor" or "occluder".
        surface: how it looks.
        centre_m: (3,) world position of its frame's origin.
        rotation_deg: (3,) rotation about x, then y, then z (world axes), degrees.
        size_m: box extents or blob semi-axes.
        points_m: cable control points in the object's frame.
        radius_m: cable radius.
        path_m: offsets from ``centre_m`` visited in turn, back and forth (empty: static).
        period_s: time of one full back-and-forth along the path.
        phase: where on the path it is at t = 0, as a fraction of the period.
    """

    name: str
    kind: str
    role: str
    surface: Surface
    centre_m: tuple[float, float, float]
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    size_m: tuple[float, float, float] = (0.1, 0.1, 0.1)
    points_m: tuple[tuple[float, float, float], ...] = ()
    radius_m: float = 0.005
    path_m: tuple[tuple[float, float, float], ...] = ()
    period_s: float = 10.0
    phase: float = 0.0

    @property
    def moving(self) -> bool:
        return len(self.path_m) >= 2

    def offset_at(self, t_s: float) -> np.ndarray:
        """(3,) offset along the path at time ``t_s``: piecewise linear, back and forth, smooth turns."""
        if not self.moving:
            return np.zeros(3)
        path = np.asarray(self.path_m, dtype=np.float64)
        u = ((t_s / self.period_s + self.phase) % 1.0) * 2.0
        u = u if u <= 1.0 else 2.0 - u  # there and back
        u = 0.5 - 0.5 * math.cos(math.pi * u)  # slow down at the turns
        lengths = np.linalg.norm(np.diff(path, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(lengths)])
        s = u * arc[-1]
        return np.array([np.interp(s, arc, path[:, k]) for k in range(3)])

    def bounding_points_m(self) -> np.ndarray:
        """(N, 3) points in the object's frame whose convex hull holds its surface (a cable: its axis)."""
        if self.kind == "cable":
            return cable_curve(self.points_m)
        semi = np.asarray(self.size_m, dtype=np.float64) * (0.5 if self.kind == "box" else 1.0 + BLOB_BUMP)
        return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * semi

    def T_world(self, t_s: float = 0.0) -> np.ndarray:
        """(4, 4) pose of the object's frame in the world at time ``t_s``."""
        rx, ry, rz = np.radians(self.rotation_deg)
        R = _rot("z", rz) @ _rot("y", ry) @ _rot("x", rx)
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = np.asarray(self.centre_m, dtype=np.float64) + self.offset_at(t_s)
        return T


@dataclass(frozen=True)
class Light:
    """A directional light: intensity (share of full light), travel direction, colour temperature."""

    intensity: float
    direction_world: tuple[float, float, float]
    temperature_k: float = 6500.0


@dataclass(frozen=True)
class Lighting:
    """Ambient light (share of full light, colour temperature) plus directional lights."""

    ambient: float
    lights: tuple[Light, ...]
    ambient_temperature_k: float = 6500.0


@dataclass(frozen=True)
class LabScene:
    """Everything around the arm in one preset.

    Attributes:
        preset: the preset's name.
        seed: the seed of the textures and of the ``random`` draw.
        description: what the preset shows.
        backdrop: the wall (None: the uniform background colour of camera.toml, no geometry).
        objects: distractors and occluders.
        lighting: lights (None: camera.toml's ambient and directional light).
        camera: camera-effect keys the preset sets (the rest come from camera.toml's sensor).
        source: the scene file, if any.
    """

    preset: str = "clean"
    seed: int = 0
    description: str = ""
    backdrop: Backdrop | None = None
    objects: tuple[SceneObject, ...] = ()
    lighting: Lighting | None = None
    camera: dict[str, Any] = field(default_factory=dict)
    source: Path | None = None

    def effects(self, sensor: SensorModel) -> CameraEffects:
        """The camera effects: camera.toml's sensor, with what this scene sets."""
        base = {"exposure_gain": sensor.exposure_gain, "read_noise_dn": sensor.noise_std_dn,
                "optics_blur_px": sensor.blur_sigma_px}
        return CameraEffects(**{**base, **self.camera})

    @property
    def moving_objects(self) -> tuple[SceneObject, ...]:
        return tuple(o for o in self.objects if o.moving)

    @property
    def static_objects(self) -> tuple[SceneObject, ...]:
        return tuple(o for o in self.objects if not o.moving)

    def as_dict(self) -> dict:
        """A JSON-friendly description (for run folders and study records)."""
        import dataclasses

        def clean(value):
            if dataclasses.is_dataclass(value):
                return {f.name: clean(getattr(value, f.name)) for f in dataclasses.fields(value)}
            if isinstance(value, dict):
                return {k: clean(v) for k, v in value.items()}
            if isinstance(value, tuple | list):
                return [clean(v) for v in value]
            if isinstance(value, Path):
                return str(value)
            return value

        return clean(self)


def cable_curve(points_m, spacing_m: float = 0.01) -> np.ndarray:
    """(M, 3) a smooth curve through a cable's control points (cubic where there are four or more),
    sampled every ``spacing_m`` or closer (at least 8 samples)."""
    control = np.asarray(points_m, np.float64)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(control, axis=0), axis=1))])
    keep = np.concatenate([[True], np.diff(arc) > 1e-9])
    control, arc = control[keep], arc[keep]
    at = np.linspace(0.0, arc[-1], max(int(arc[-1] / spacing_m), 8))
    return make_interp_spline(arc, control, k=min(3, len(control) - 1))(at)


# --- colour temperature ------------------------------------------------------------------------


def temperature_rgb(kelvin: float) -> np.ndarray:
    """(3,) linear RGB of a black body at ``kelvin``, relative to 6500 K (white), green = 1.

    Planck's law at wavelengths near the peaks of the sRGB primaries' sensitivity (610, 550 and
    465 nm): coarse, but it gives 3000 K its warm cast and 9000 K its blue one.
    """
    if not 1000.0 <= kelvin <= 20000.0:
        raise ValueError(f"colour temperature: expected 1000..20000 K, got {kelvin!r}")

    def planck(lam_nm, t):
        lam = lam_nm * 1e-9
        return 1.0 / (lam**5 * (math.exp(1.4388e-2 / (lam * t)) - 1.0))

    rgb = np.array([planck(w, kelvin) / planck(w, 6500.0) for w in (610.0, 550.0, 465.0)])
    return rgb / rgb[1]


# --- loading -------------------------------------------------------------------------------------


def clean_scene() -> LabScene:
    """The scene without a scene file: camera.toml's backdrop colour, lights and sensor."""
    return LabScene(preset="clean", description="a uniform backdrop, the camera.toml lighting and sensor")


def preset_names(path: str | Path) -> list[str]:
    """The presets a scene file defines."""
    data = read_toml(path, "scene")
    presets = data.get("preset", {})
    return sorted(presets) if isinstance(presets, dict) else []


def load_scene(path: str | Path, preset: str, seed: int = 0) -> LabScene:
    """Read one preset of a scene file.

    Args:
        path: the scene TOML file.
        preset: the preset's name; "random" (if the file marks it ``random = true``) draws every
            knob from ``seed``.
        seed: the seed of procedural textures and of the random draw.

    Raises:
        ConfigFileError: missing file, unknown preset (names the known ones), unknown key or bad
            value (names the file, the preset and the key), unreadable backdrop image (names it).
    """
    path = Path(path)
    data = read_toml(path, "scene")
    unknown = sorted(set(data) - {"preset"})
    if unknown:
        raise ConfigFileError(f"{path}: unknown key {unknown[0]}; a scene file holds only [preset.<name>] tables")
    raw = data.get("preset")
    if not isinstance(raw, dict) or not raw:
        raise ConfigFileError(f"{path}: no presets: expected [preset.<name>] tables")
    if preset not in raw:
        raise ConfigFileError(f"{path}: unknown preset {preset!r}; the file defines {', '.join(sorted(raw))}")
    scenes = {}
    for name in sorted(raw):  # every preset is read when any is used, so a typo anywhere shows at once
        merged = _merged(path, raw, name)
        if merged.get("random") is True:
            scenes[name] = _parse_random(path, name, merged, seed)
        else:
            scenes[name] = _parse_preset(path, name, merged, seed)
    return scenes[preset]


def _parse_random(path: Path, name: str, table: dict, seed: int) -> LabScene:
    """A preset marked ``random = true``: the draw sets every knob, so only a description may go with it."""
    top = TableReader(path, table, f"preset.{name}")
    top.take("random", _boolean)
    description = top.take("description", _text, "")
    unused = sorted(set(table) - {"random", "description"})
    if unused:
        raise top.error(unused[0], "a random preset draws every knob from the seed; it takes only "
                                   "random and description")
    return random_scene(seed, source=path, description=description, preset=name)


def _merged(path: Path, presets: dict, name: str, chain: tuple[str, ...] = ()) -> dict:
    """The preset's table with its base's merged under it (tables key by key, objects appended)."""
    if name in chain:
        raise ConfigFileError(f"{path}: [preset.{name}] base: a cycle of bases ({' -> '.join(chain + (name,))})")
    table = presets.get(name)
    if not isinstance(table, dict):
        raise ConfigFileError(f"{path}: [preset.{name}]: expected a table")
    base_name = table.get("base")
    if base_name is None:
        return table
    if not isinstance(base_name, str) or base_name not in presets:
        raise ConfigFileError(f"{path}: [preset.{name}] base: unknown preset {base_name!r}; "
                              f"the file defines {', '.join(sorted(presets))}")
    base = _merged(path, presets, base_name, chain + (name,))
    return _deep_merge(base, {k: v for k, v in table.items() if k != "base"})


def _deep_merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for key, value in over.items():
        if key == "objects" and isinstance(value, list) and isinstance(base.get(key), list):
            out[key] = base[key] + value
        elif isinstance(value, dict) and isinstance(base.get(key), dict):
            out[key] = _deep_merge(base[key], value)
        else:
            out[key] = value
    return out


def _choice(options: tuple[str, ...]):
    def convert(value):
        if not isinstance(value, str) or value not in options:
            raise ValueError(f"expected one of {', '.join(options)}, got {value!r}")
        return value

    return convert


def _text(value):
    if not isinstance(value, str):
        raise TypeError(f"expected a string, got {value!r}")
    return value


def _boolean(value):
    if not isinstance(value, bool):
        raise TypeError(f"expected true or false, got {value!r}")
    return value


def _points(value):
    if not isinstance(value, list) or len(value) < 2:
        raise ValueError(f"expected a list of at least two [x, y, z] points, got {value!r}")
    return tuple(tuple(vector(3, -20, 20)(p).tolist()) for p in value)


def _surface(reader: TableReader, default_rgb=(0.5, 0.5, 0.5), default_texture=None) -> Surface:
    """A surface from ``material`` (a named one) and/or ``rgb``, ``texture``, ``contrast``, ``feature_m``."""
    material = reader.take("material", _choice(tuple(MATERIALS)), None)
    rgb, texture = (default_rgb, default_texture) if material is None else MATERIALS[material]
    rgb = tuple(reader.take("rgb", vector(3, 0.0, 1.0), np.asarray(rgb)).tolist())
    texture = reader.take("texture", _choice(PATTERNS + ("none",)), texture or "none")
    return Surface(rgb=rgb, texture=None if texture == "none" else texture,
                   contrast=reader.take("contrast", number(0.0, 1.0), 0.2),
                   feature_m=reader.take("feature_m", number(0.001, 2.0), 0.02))


def _parse_preset(path: Path, name: str, table: dict, seed: int) -> LabScene:
    top = TableReader(path, table, f"preset.{name}")
    description = top.take("description", _text, "")
    backdrop = None
    wall = top.sub("backdrop", required=False)
    if wall is not None:
        wall_table = table["backdrop"]
        kind = wall.take("kind", _choice(BACKDROPS))
        surface = _surface(wall, (0.64, 0.69, 0.76), "plaster" if kind == "procedural" else None)
        if kind != "procedural":
            if "texture" in wall_table:  # it would be dropped without a word
                raise wall.error("texture", f"a {kind} backdrop has no texture; use kind = \"procedural\"")
            surface = replace(surface, texture=None)
        elif surface.texture is None:
            raise wall.error("texture", f"a procedural backdrop needs a texture: one of {', '.join(PATTERNS)}")
        image = None
        if kind == "image":
            image = wall.take("image", _text)
            image = Path(image) if Path(image).is_absolute() else path.parent / image
            if not image.is_file():  # said here, not by OpenCV's own warning first
                raise ConfigFileError(f"{path}: [preset.{name}.backdrop] image: {image} "
                                      + ("is a folder, not an image" if image.is_dir() else "does not exist"))
            if cv2.imread(str(image), cv2.IMREAD_COLOR) is None:
                raise ConfigFileError(f"{path}: [preset.{name}.backdrop] image: cannot read {image} as an image "
                                      "(unreadable, or not an image format OpenCV knows)")
        floor = None
        floor_z = wall.take("floor_z_m", number(-5.0, 0.0), None)
        floor_table = wall.sub("floor", required=False)
        if floor_table is not None and floor_z is None:  # a floor without a height would be dropped
            raise wall.error("floor", "a [floor] table needs floor_z_m, the floor's height")
        if floor_table is not None:
            floor = _surface(floor_table, (0.5, 0.48, 0.45), None)
            floor_table.done()
        elif floor_z is not None:
            floor = Surface(rgb=(0.5, 0.48, 0.45), texture="plaster", contrast=0.1, feature_m=0.05)
        backdrop = Backdrop(kind=kind, surface=surface, image=image,
                            wall_y_m=wall.take("wall_y_m", number(0.2, 20.0), 0.9),
                            size_m=tuple(wall.take("size_m", vector(2, 0.1, 100.0), np.array([6.0, 4.0])).tolist()),
                            centre_xz_m=tuple(wall.take("centre_xz_m", vector(2, -50, 50),
                                                        np.array([0.0, -0.3])).tolist()),
                            floor_z_m=floor_z, floor=floor if floor_z is not None else None)
        wall.done()
    objects = []
    raw_objects = top.take("objects", lambda v: v if isinstance(v, list) else _raise_type(v), [])
    for i, item in enumerate(raw_objects):
        if not isinstance(item, dict):
            raise ConfigFileError(f"{path}: [[preset.{name}.objects]] #{i + 1}: expected a table")
        objects.append(_parse_object(TableReader(path, item, f"preset.{name}.objects #{i + 1}"), i))
    lighting = None
    lights_table = top.sub("lighting", required=False)
    if lights_table is not None:
        lighting = _parse_lighting(lights_table)
    camera = {}
    cam = top.sub("camera", required=False)
    if cam is not None:
        camera = _parse_camera(cam)
    top.take("random", _boolean, False)
    top.done()
    scene = LabScene(preset=name, seed=int(seed), description=description, backdrop=backdrop,
                     objects=tuple(objects), lighting=lighting, camera=camera, source=path)
    try:
        scene.effects(SensorModel())
    except ValueError as e:
        raise ConfigFileError(f"{path}: [preset.{name}.camera] {e}") from e
    return scene


def _raise_type(value):
    raise TypeError(f"expected an array of tables [[...objects]], got {value!r}")


def _parse_object(reader: TableReader, index: int) -> SceneObject:
    kind = reader.take("kind", _choice(KINDS))
    surface = _surface(reader)
    obj = SceneObject(
        name=reader.take("name", _text, f"{kind}{index + 1}"),
        kind=kind,
        role=reader.take("role", _choice(ROLES), "distractor"),
        surface=surface,
        centre_m=tuple(reader.take("centre_m", vector(3, -20, 20)).tolist()),
        rotation_deg=tuple(reader.take("rotation_deg", vector(3, -360, 360), np.zeros(3)).tolist()),
        size_m=tuple(reader.take("size_m", vector(3, 1e-4, 10.0), np.full(3, 0.1)).tolist()),
        points_m=reader.take("points_m", _points, ()),
        radius_m=reader.take("radius_m", number(1e-4, 0.5), 0.005),
        path_m=reader.take("path_m", _points, ()),
        period_s=reader.take("period_s", number(0.05, 1e6), 10.0),
        phase=reader.take("phase", number(0.0, 1.0), 0.0),
    )
    if kind == "cable" and len(obj.points_m) < 2:
        raise reader.error("points_m", "a cable needs at least two [x, y, z] points")
    reader.done()
    return obj


def _parse_lighting(reader: TableReader) -> Lighting:
    scale = reader.take("scale", number(0.0, 10.0), 1.0)
    ambient = reader.take("ambient", number(0.0, 4.0)) * scale
    ambient_k = reader.take("temperature_k", number(1000.0, 20000.0), 6500.0)
    lights = []
    raw = reader.take("lights", lambda v: v if isinstance(v, list) else _raise_type(v), [])
    for i, item in enumerate(raw):
        if not isinstance(item, dict):
            raise reader.error("lights", f"light #{i + 1}: expected a table")
        light = TableReader(reader.path, item, f"{reader.section}.lights #{i + 1}")
        direction = light.take("direction_world", vector(3, -1e3, 1e3))
        if np.linalg.norm(direction) < 1e-9:
            raise light.error("direction_world", "must not be the zero vector")
        lights.append(Light(intensity=light.take("intensity", number(0.0, 8.0)) * scale,
                            direction_world=tuple(direction.tolist()),
                            temperature_k=light.take("temperature_k", number(1000.0, 20000.0), 6500.0)))
        light.done()
    reader.done()
    return Lighting(ambient=ambient, lights=tuple(lights), ambient_temperature_k=ambient_k)


_CAMERA_KEYS = {"exposure_gain": number(1e-3, 16.0), "read_noise_dn": number(0.0, 64.0),
                "shot_noise_dn": number(0.0, 64.0), "vignetting": number(0.0, 0.95), "yuyv": _boolean,
                "optics_blur_px": number(0.0, 20.0), "exposure_s": number(0.0, 0.5),
                "shake_px": number(0.0, 100.0), "shake_angle_deg": number(-360.0, 360.0)}


def _parse_camera(reader: TableReader) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, convert in _CAMERA_KEYS.items():
        value = reader.take(key, convert, None)
        if value is not None:
            out[key] = value
    subframes = reader.take("motion_subframes", lambda v: _int_in(v, 1, 32), None)
    if subframes is not None:
        out["motion_subframes"] = subframes
    reader.done()
    return out


def _int_in(value, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ValueError(f"expected an integer in [{lo}, {hi}], got {value!r}")
    return value


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


# --- the random preset ---------------------------------------------------------------------------

# Ranges of the random draw (uniform unless noted). Distractors are drawn beside the arm (0.3 to
# 0.9 m to its side), then moved just clear of the wall and the floor (_inside_room).
RANDOM_RANGES = {
    "wall_y_m": (0.5, 1.6),
    "wall_contrast": (0.03, 0.35),
    "objects": (2, 6),
    "ambient": (0.12, 0.5),
    "key_intensity": (0.2, 0.9),
    "temperature_k": (2700.0, 7500.0),
    "exposure_gain": (0.7, 1.5),
    "read_noise_dn": (0.5, 3.5),
    "shot_noise_dn": (0.0, 6.0),
    "vignetting": (0.0, 0.4),
    "optics_blur_px": (0.0, 1.0),
    "exposure_s": (0.0, 0.02),
    "shake_px": (0.0, 8.0),
}


def random_scene(seed: int, *, source: Path | None = None, description: str = "", preset: str = "random") -> LabScene:
    """A seeded draw over every knob: backdrop, objects (an occluder sometimes), lights, camera.

    Distractors stand in front of the wall and on or above the floor (a box half inside the wall
    is no lab): each is moved towards the camera or up just enough, after the draw, so the
    sequence of random numbers and every other knob stay as drawn.
    """
    rng = np.random.default_rng(seed)
    R = RANDOM_RANGES

    def uniform(key):
        lo, hi = R[key]
        return float(rng.uniform(lo, hi))

    hue = rng.uniform(0, 180)
    wall_rgb = cv2.cvtColor(np.array([[[hue, rng.uniform(0, 80), rng.uniform(120, 230)]]], np.uint8),
                            cv2.COLOR_HSV2RGB)[0, 0] / 255.0
    pattern = str(rng.choice(["plaster", "bricks", "clutter", "wood"]))
    floor_z = float(rng.uniform(-1.3, -0.95)) if rng.random() < 0.5 else None
    backdrop = Backdrop(kind="procedural",
                        surface=Surface(tuple(wall_rgb.tolist()), pattern, uniform("wall_contrast"),
                                        float(rng.uniform(0.01, 0.12))),
                        wall_y_m=uniform("wall_y_m"), floor_z_m=floor_z,
                        floor=Surface((0.5, 0.47, 0.44), "plaster", 0.1, 0.05) if floor_z is not None else None)
    materials = list(MATERIALS)
    objects = []
    for i in range(int(rng.integers(R["objects"][0], R["objects"][1] + 1))):
        kind = str(rng.choice(KINDS))
        material = str(rng.choice(materials))
        rgb, texture = MATERIALS[material]
        side = rng.choice([-1.0, 1.0])
        centre = (float(side * rng.uniform(0.3, 0.9)), float(rng.uniform(-0.3, 0.8)), float(rng.uniform(-0.9, 0.1)))
        size = tuple(float(v) for v in rng.uniform(0.03, 0.3, 3))
        points = ()
        if kind == "cable":
            start = np.array([0.0, 0.0, rng.uniform(0.0, 0.3)])
            points = tuple(tuple((start + [rng.uniform(-0.15, 0.15), rng.uniform(-0.1, 0.1), -0.25 * k]).tolist())
                           for k in range(4))
        obj = SceneObject(name=f"{material}_{kind}{i + 1}", kind=kind, role="distractor",
                          surface=Surface(rgb, texture, 0.25, 0.01), centre_m=centre,
                          rotation_deg=tuple(float(v) for v in rng.uniform(-30, 30, 3)), size_m=size,
                          points_m=points, radius_m=float(rng.uniform(0.003, 0.012)))
        objects.append(_inside_room(obj, backdrop))
    if rng.random() < 0.4:
        y = float(rng.uniform(-0.55, -0.25))
        z = float(rng.uniform(-0.6, -0.15))
        objects.append(SceneObject(name="occluding_cable", kind="cable", role="occluder",
                                   surface=Surface(MATERIALS["dark"][0]), centre_m=(0.0, y, z),
                                   points_m=((-0.05, 0.0, 0.35), (0.0, 0.0, 0.0), (0.05, 0.0, -0.35)),
                                   radius_m=float(rng.uniform(0.003, 0.008)),
                                   path_m=((-0.6, 0.0, 0.0), (0.6, 0.0, 0.0)), period_s=float(rng.uniform(8, 30)),
                                   phase=float(rng.random())))
    lights = [Light(uniform("key_intensity"), tuple(_random_direction(rng).tolist()), uniform("temperature_k"))]
    if rng.random() < 0.5:
        lights.append(Light(float(rng.uniform(0.05, 0.4)), tuple(_random_direction(rng).tolist()),
                            uniform("temperature_k")))
    lighting = Lighting(ambient=uniform("ambient"), lights=tuple(lights),
                        ambient_temperature_k=uniform("temperature_k"))
    camera = {"exposure_gain": uniform("exposure_gain"), "read_noise_dn": uniform("read_noise_dn"),
              "shot_noise_dn": uniform("shot_noise_dn"), "vignetting": uniform("vignetting"),
              "yuyv": bool(rng.random() < 0.7), "optics_blur_px": uniform("optics_blur_px"),
              "exposure_s": uniform("exposure_s"),
              "shake_px": uniform("shake_px") if rng.random() < 0.3 else 0.0,
              "shake_angle_deg": float(rng.uniform(-90, 90))}
    return LabScene(preset=preset, seed=int(seed), description=description or "a seeded draw over every knob",
                    backdrop=backdrop, objects=tuple(objects), lighting=lighting, camera=camera, source=source)


def _inside_room(obj: SceneObject, backdrop: Backdrop, clearance_m: float = 0.005) -> SceneObject:
    """The object moved towards the camera (-y) and up (+z) just enough to clear the wall and the floor."""
    points = obj.bounding_points_m() @ obj.T_world(0.0)[:3, :3].T + np.asarray(obj.centre_m)
    margin = clearance_m + (obj.radius_m if obj.kind == "cable" else 0.0)
    dy = min(0.0, backdrop.wall_y_m - margin - float(points[:, 1].max()))
    dz = 0.0 if backdrop.floor_z_m is None else max(0.0, backdrop.floor_z_m + margin - float(points[:, 2].min()))
    if dy == 0.0 and dz == 0.0:
        return obj
    x, y, z = obj.centre_m
    return replace(obj, centre_m=(x, y + dy, z + dz))


def _random_direction(rng: np.random.Generator) -> np.ndarray:
    """A light travelling into the scene from the camera's side (+y), from above or the sides."""
    d = np.array([rng.uniform(-1, 1), rng.uniform(0.3, 1.0), rng.uniform(-1, 0.2)])
    return d / np.linalg.norm(d)
