"""Lab scene files (twin.scene): the presets of models/scene.toml, inheritance between presets, the
seeded random preset, and the errors a bad scene file gets (naming the file and the key).

No rendering here: what the scenes look like is tested in test_lab_render.py.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from twin.lab_objects import backdrop_parts, object_parts, scene_parts
from twin.rig import ConfigFileError, SensorModel
from twin.scene import (
    MATERIALS,
    RANDOM_RANGES,
    REQUIRED_PRESETS,
    Backdrop,
    LabScene,
    SceneObject,
    Surface,
    load_scene,
    preset_names,
    random_scene,
    temperature_rgb,
)
from twin.textures import PATTERNS, procedural_texture
from twin.twin import TwinConfig

REPO = Path(__file__).resolve().parents[2]
MODELS = REPO / "models"
SCENES = MODELS / "scene.toml"


# --- writing small scene files -------------------------------------------------------------------


def _toml_lines(prefix: str, table: dict) -> list[str]:
    """TOML text of one table: its plain keys, then its sub-tables, then its arrays of tables."""
    lines = [f"[{prefix}]"] if prefix else []
    nested = []
    for key, value in table.items():
        if isinstance(value, dict) or (isinstance(value, list) and value and all(isinstance(v, dict) for v in value)):
            nested.append((key, value))
        else:
            lines.append(f"{key} = {json.dumps(value)}")
    for key, value in nested:
        name = f"{prefix}.{key}" if prefix else key
        if isinstance(value, dict):
            lines += _toml_lines(name, value)
        else:
            for item in value:
                sub = _toml_lines(name, item)
                sub[0] = f"[[{name}]]"
                lines += sub
    return lines


def write_scene(folder: Path, presets: dict, extra_top: dict | None = None, name: str = "scene.toml") -> Path:
    path = folder / name
    path.write_text("\n".join(_toml_lines("", {**(extra_top or {}), "preset": presets})) + "\n")
    return path


def full_preset() -> dict:
    """A preset that uses every table a preset may have."""
    return {
        "description": "every table",
        "backdrop": {"kind": "procedural", "texture": "bricks", "rgb": [0.8, 0.7, 0.6], "contrast": 0.1,
                     "feature_m": 0.07, "wall_y_m": 1.0, "floor_z_m": -1.0,
                     "floor": {"rgb": [0.4, 0.4, 0.4], "texture": "plaster"}},
        "lighting": {"ambient": 0.3, "temperature_k": 4000,
                     "lights": [{"intensity": 0.5, "direction_world": [0.0, 1.0, -0.5], "temperature_k": 5000}]},
        "camera": {"read_noise_dn": 1.0, "vignetting": 0.1},
        "objects": [{"name": "crate", "kind": "box", "material": "wood", "centre_m": [0.5, 0.3, -0.5],
                     "size_m": [0.2, 0.2, 0.2]}],
    }


# --- the presets of models/scene.toml ---------------------------------------------------------------


@pytest.mark.parametrize("preset", REQUIRED_PRESETS)
def test_every_required_preset_loads_from_the_models_scene_file(preset):
    assert set(REQUIRED_PRESETS) <= set(preset_names(SCENES))
    scene = load_scene(SCENES, preset, seed=3)
    assert isinstance(scene, LabScene)
    assert scene.preset == preset and scene.seed == 3 and scene.source == SCENES
    assert scene.description
    effects = scene.effects(SensorModel(noise_std_dn=1.5))
    if preset == "clean":  # today's images: no backdrop geometry, camera.toml's lights and sensor
        assert scene.backdrop is None and scene.objects == () and scene.lighting is None and scene.camera == {}
        assert effects.legacy and effects.read_noise_dn == 1.5
    else:
        assert scene.backdrop is not None and scene.lighting is not None and len(scene.objects) >= 2
        assert not effects.legacy, "a lab preset adds camera effects"
    json.dumps(scene.as_dict())  # a run folder can record it


def test_presets_built_on_lab_keep_its_objects_and_change_what_they_say():
    lab = load_scene(SCENES, "lab")
    dim = load_scene(SCENES, "dim")
    warm = load_scene(SCENES, "bright_warm")
    occluded = load_scene(SCENES, "occluded")
    blur = load_scene(SCENES, "blur")
    for scene in (dim, warm, occluded, blur):
        assert scene.backdrop == lab.backdrop
        assert scene.objects[:len(lab.objects)] == lab.objects
    assert dim.lighting.ambient == pytest.approx(0.30 * 0.33)
    assert [light.intensity for light in dim.lighting.lights] == pytest.approx([0.50 * 0.33, 0.15 * 0.33])
    assert dim.camera["read_noise_dn"] == 3.0 and dim.camera["vignetting"] == lab.camera["vignetting"]
    # bright_warm replaces the lights (an array is a value, not a table to merge)
    assert [light.temperature_k for light in warm.lighting.lights] == [3000, 3200]
    assert warm.lighting.ambient_temperature_k == 3000
    # occluded adds one moving occluder to lab's static objects
    extra = occluded.objects[len(lab.objects):]
    assert len(extra) == 1 and extra[0].role == "occluder" and extra[0].moving
    assert all(not o.moving for o in lab.objects)
    assert blur.camera["exposure_s"] > 0 and blur.camera["shake_px"] > 0


# --- inheritance -----------------------------------------------------------------------------------


def test_base_merges_tables_key_by_key_and_appends_objects(tmp_path):
    child = {
        "base": "parent",
        "backdrop": {"contrast": 0.3, "floor": {"texture": "none"}},
        "lighting": {"scale": 0.5},
        "camera": {"yuyv": True},
        "objects": [{"name": "ball", "kind": "blob", "material": "skin", "centre_m": [-0.5, 0.2, -0.4]}],
    }
    grandchild = {"base": "child", "camera": {"read_noise_dn": 2.5}, "description": "third generation"}
    path = write_scene(tmp_path, {"parent": full_preset(), "child": child, "grandchild": grandchild})
    parent = load_scene(path, "parent")
    scene = load_scene(path, "child")
    assert scene.description == "every table"  # inherited
    assert scene.backdrop.surface.texture == "bricks" and scene.backdrop.surface.rgb == (0.8, 0.7, 0.6)
    assert scene.backdrop.surface.contrast == 0.3  # overridden
    assert scene.backdrop.floor.rgb == (0.4, 0.4, 0.4) and scene.backdrop.floor.texture is None
    assert scene.backdrop.floor_z_m == -1.0
    assert scene.lighting.ambient == pytest.approx(0.15) and scene.lighting.ambient_temperature_k == 4000
    assert scene.lighting.lights[0].intensity == pytest.approx(0.25)
    assert scene.camera == {"read_noise_dn": 1.0, "vignetting": 0.1, "yuyv": True}
    assert [o.name for o in scene.objects] == ["crate", "ball"]
    third = load_scene(path, "grandchild")
    assert third.description == "third generation"
    assert third.camera == {"read_noise_dn": 2.5, "vignetting": 0.1, "yuyv": True}
    assert [o.name for o in third.objects] == ["crate", "ball"]
    # The base's own scene is untouched by what its children change.
    assert parent.backdrop.surface.contrast == 0.1 and parent.camera == {"read_noise_dn": 1.0, "vignetting": 0.1}
    assert [o.name for o in parent.objects] == ["crate"]


@pytest.mark.parametrize("cycle", [{"a": "b", "b": "a"}, {"a": "a"}, {"a": "b", "b": "c", "c": "a"}])
def test_a_cycle_of_bases_is_an_error_naming_the_file_and_the_cycle(tmp_path, cycle):
    presets = {"fine": {"description": "no base"}}
    presets.update({name: {"base": base} for name, base in cycle.items()})
    path = write_scene(tmp_path, presets)
    for preset in ("fine", "a"):  # reading any preset reads them all
        with pytest.raises(ConfigFileError, match="cycle") as info:
            load_scene(path, preset)
        assert str(path) in str(info.value) and "base" in str(info.value)


def test_an_unknown_base_names_the_known_presets(tmp_path):
    path = write_scene(tmp_path, {"a": {"base": "lab"}, "b": {}})
    with pytest.raises(ConfigFileError, match="base") as info:
        load_scene(path, "b")
    assert str(path) in str(info.value) and "'lab'" in str(info.value) and "a, b" in str(info.value)


# --- the random preset -----------------------------------------------------------------------------


def _knobs(scene: LabScene) -> dict[str, list[float]]:
    """Every value of the random draw that RANDOM_RANGES bounds, by its key there."""
    lights = scene.lighting.lights
    distractors = [o for o in scene.objects if o.role == "distractor"]
    knobs = {"wall_y_m": [scene.backdrop.wall_y_m], "wall_contrast": [scene.backdrop.surface.contrast],
             "objects": [len(distractors)], "ambient": [scene.lighting.ambient],
             "key_intensity": [lights[0].intensity],
             "temperature_k": [scene.lighting.ambient_temperature_k] + [light.temperature_k for light in lights]}
    for key in ("exposure_gain", "read_noise_dn", "shot_noise_dn", "vignetting", "optics_blur_px", "exposure_s",
                "shake_px"):
        knobs[key] = [scene.camera[key]]
    return knobs


def test_the_random_preset_is_a_seeded_draw_within_its_ranges():
    a = load_scene(SCENES, "random", seed=11)
    b = load_scene(SCENES, "random", seed=11)
    c = load_scene(SCENES, "random", seed=12)
    assert a.as_dict() == b.as_dict()
    assert a.as_dict() != c.as_dict()
    assert a.preset == "random" and a.seed == 11 and a.source == SCENES
    seen: dict[str, list[float]] = {key: [] for key in RANDOM_RANGES}
    yuyv, occluders, floors, shakes = set(), 0, 0, 0
    for seed in range(60):
        scene = random_scene(seed)
        assert scene.as_dict() == random_scene(seed).as_dict()
        for key, values in _knobs(scene).items():
            lo, hi = RANDOM_RANGES[key]
            assert all(lo <= v <= hi for v in values), f"seed {seed}: {key} = {values} outside [{lo}, {hi}]"
            seen[key] += values
        yuyv.add(scene.camera["yuyv"])
        occluders += any(o.role == "occluder" for o in scene.objects)
        floors += scene.backdrop.floor_z_m is not None
        shakes += scene.camera["shake_px"] > 0
        assert scene.backdrop.kind == "procedural" and scene.backdrop.surface.texture in PATTERNS
        assert {o.surface.rgb for o in scene.objects} <= {rgb for rgb, _ in MATERIALS.values()}
        scene.effects(SensorModel())  # a valid camera
    # Every knob is drawn, not pinned: its values spread over most of its range.
    for key, values in seen.items():
        lo, hi = RANDOM_RANGES[key]
        assert max(values) - min(values) > 0.5 * (hi - lo), f"{key} barely varies: {min(values)}..{max(values)}"
    assert yuyv == {True, False} and 0 < occluders < 60 and 0 < floors < 60 and 0 < shakes < 60


def _world_points(obj: SceneObject, seed: int) -> np.ndarray:
    """The vertices of the object's meshes in the world (built untextured: only the shape counts)."""
    T = obj.T_world(0.0)
    plain = dataclasses.replace(obj, surface=Surface(obj.surface.rgb))
    return np.vstack([part.positions @ T[:3, :3].T + T[:3, 3] for part in object_parts(plain, seed)])


def test_random_distractors_stand_in_front_of_the_wall_and_on_the_floor():
    """A box half inside the wall or sunk into the floor is no lab (seen in ~1 object in 10 before)."""
    for seed in range(60):
        scene = random_scene(seed)
        wall_y, floor_z = scene.backdrop.wall_y_m, scene.backdrop.floor_z_m
        for obj in scene.objects:
            if obj.role != "distractor":
                continue
            points = _world_points(obj, seed)
            assert points[:, 1].max() < wall_y, f"seed {seed}: {obj.name} pierces the wall"
            if floor_z is not None:
                assert points[:, 2].min() > floor_z, f"seed {seed}: {obj.name} sinks into the floor"


def test_a_random_preset_under_another_name_keeps_its_name_and_takes_no_other_keys(tmp_path):
    path = write_scene(tmp_path, {"chaos": {"random": True, "description": "anything"}, "plain": {}})
    scene = load_scene(path, "chaos", seed=4)
    assert scene.preset == "chaos" and scene.description == "anything"
    assert scene.as_dict() == dataclasses.replace(random_scene(4, source=path, description="anything"),
                                                  preset="chaos").as_dict()
    # A knob beside random = true would be ignored by the draw: it is an error instead.
    for extra in ({"camera": {"yuyv": False}}, {"colour": 1}):
        bad = write_scene(tmp_path, {"chaos": {"random": True, **extra}, "plain": {}}, name="bad.toml")
        with pytest.raises(ConfigFileError) as info:
            load_scene(bad, "plain")
        message = str(info.value)
        assert str(bad) in message and "preset.chaos" in message and next(iter(extra)) in message


# --- bad input ------------------------------------------------------------------------------------


def _with(path_in_preset: tuple, value) -> dict:
    """full_preset() with ``value`` set at ``path_in_preset`` (keys and list indices)."""
    preset = full_preset()
    where = preset
    for step in path_in_preset[:-1]:
        where = where[step]
    where[path_in_preset[-1]] = value
    return preset


UNKNOWN_KEYS = {  # where the stray key goes -> what the message must name
    "preset": (("colour",), "[preset.p] colour"),
    "backdrop": (("backdrop", "colour"), "[preset.p.backdrop] colour"),
    "floor": (("backdrop", "floor", "colour"), "[preset.p.backdrop.floor] colour"),
    "object": (("objects", 0, "colour"), "objects #1] colour"),
    "lighting": (("lighting", "colour"), "[preset.p.lighting] colour"),
    "light": (("lighting", "lights", 0, "colour"), "lights #1] colour"),
    "camera": (("camera", "colour"), "[preset.p.camera] colour"),
}


@pytest.mark.parametrize("where", sorted(UNKNOWN_KEYS))
def test_an_unknown_key_anywhere_names_the_file_and_the_key(tmp_path, where):
    steps, named = UNKNOWN_KEYS[where]
    path = write_scene(tmp_path, {"p": _with(steps, 1), "other": {}})
    for preset in ("p", "other"):  # a typo in any preset shows whichever preset is used
        with pytest.raises(ConfigFileError, match="unknown key") as info:
            load_scene(path, preset)
        assert str(path) in str(info.value) and named in str(info.value), str(info.value)


def test_an_unknown_top_level_key_names_the_file_and_the_key(tmp_path):
    path = write_scene(tmp_path, {"p": full_preset()}, extra_top={"presets_dir": "x"})
    with pytest.raises(ConfigFileError, match="unknown key presets_dir") as info:
        load_scene(path, "p")
    assert str(path) in str(info.value)


BAD_VALUES = {  # (where, value) -> the key the message must name
    "backdrop kind": ((("backdrop", "kind"), "wallpaper"), "kind"),
    "backdrop texture": ((("backdrop", "texture"), "stripes"), "texture"),
    "backdrop rgb range": ((("backdrop", "rgb"), [1.2, 0.5, 0.5]), "rgb"),
    "backdrop rgb type": ((("backdrop", "rgb"), "red"), "rgb"),
    "backdrop rgb length": ((("backdrop", "rgb"), [0.5, 0.5]), "rgb"),
    "wall behind the camera": ((("backdrop", "wall_y_m"), -3.0), "wall_y_m"),
    "floor above the arm": ((("backdrop", "floor_z_m"), 0.5), "floor_z_m"),
    "floor material": ((("backdrop", "floor", "material"), "lava"), "material"),
    "object material": ((("objects", 0, "material"), "plastic"), "material"),
    "object kind": ((("objects", 0, "kind"), "sphere"), "kind"),
    "object role": ((("objects", 0, "role"), "hero"), "role"),
    "object size": ((("objects", 0, "size_m"), [0.1, -0.1, 0.1]), "size_m"),
    "object path": ((("objects", 0, "path_m"), [[0.0, 0.0, 0.0]]), "path_m"),
    "object period": ((("objects", 0, "period_s"), 0.0), "period_s"),
    "object phase": ((("objects", 0, "phase"), 1.5), "phase"),
    "object name": ((("objects", 0, "name"), 7), "name"),
    "cable without points": ((("objects", 0, "kind"), "cable"), "points_m"),
    "ambient": ((("lighting", "ambient"), -0.1), "ambient"),
    "lighting scale": ((("lighting", "scale"), "double"), "scale"),
    "light temperature": ((("lighting", "lights", 0, "temperature_k"), 500), "temperature_k"),
    "light direction": ((("lighting", "lights", 0, "direction_world"), [0, 0, 0]), "direction_world"),
    "light intensity": ((("lighting", "lights", 0, "intensity"), True), "intensity"),
    "vignetting": ((("camera", "vignetting"), 0.99), "vignetting"),
    "yuyv": ((("camera", "yuyv"), 1), "yuyv"),
    "motion_subframes": ((("camera", "motion_subframes"), 0), "motion_subframes"),
    "motion_subframes type": ((("camera", "motion_subframes"), 2.5), "motion_subframes"),
    "exposure_s": ((("camera", "exposure_s"), 2.0), "exposure_s"),
    "exposure_gain": ((("camera", "exposure_gain"), 0.0), "exposure_gain"),
    "description": ((("description",), 3), "description"),
    "random flag": ((("random",), "yes"), "random"),
    "objects not tables": ((("objects",), [1, 2]), "objects"),
}


@pytest.mark.parametrize("case", sorted(BAD_VALUES))
def test_a_bad_value_names_the_file_and_the_key(tmp_path, case):
    (steps, value), key = BAD_VALUES[case]
    path = write_scene(tmp_path, {"p": _with(steps, value)})
    with pytest.raises(ConfigFileError) as info:
        load_scene(path, "p")
    message = str(info.value)
    assert message.startswith(str(path)) and key in message and "preset.p" in message, message


def test_knobs_a_backdrop_would_drop_are_errors(tmp_path):
    """A texture on a uniform wall, or a floor table without a floor height, used to vanish silently."""
    uniform = _with(("backdrop", "kind"), "uniform")
    path = write_scene(tmp_path, {"p": uniform})
    with pytest.raises(ConfigFileError, match=r"\[preset.p.backdrop\] texture") as info:
        load_scene(path, "p")
    assert str(path) in str(info.value)
    no_height = full_preset()
    del no_height["backdrop"]["floor_z_m"]
    path = write_scene(tmp_path, {"p": no_height})
    with pytest.raises(ConfigFileError, match=r"\[preset.p.backdrop\] floor.*floor_z_m") as info:
        load_scene(path, "p")
    assert str(path) in str(info.value)
    # A uniform wall with a floor height and its colour alone is fine.
    del uniform["backdrop"]["texture"]
    scene = load_scene(write_scene(tmp_path, {"p": uniform}), "p")
    assert scene.backdrop.kind == "uniform" and scene.backdrop.surface.texture is None
    assert scene.backdrop.floor.texture == "plaster" and scene.backdrop.floor_z_m == -1.0


def test_an_unknown_preset_lists_the_known_ones(tmp_path):
    with pytest.raises(ConfigFileError, match="unknown preset 'labb'") as info:
        load_scene(SCENES, "labb")
    message = str(info.value)
    assert str(SCENES) in message and all(name in message for name in REQUIRED_PRESETS)
    with pytest.raises(ConfigFileError, match="not found"):
        load_scene(tmp_path / "missing.toml", "lab")


def _image_backdrop(image: str) -> dict:
    return {"backdrop": {"kind": "image", "image": image, "rgb": [0.5, 0.5, 0.5]}}


def test_an_image_backdrop_is_read_relative_to_the_scene_file(tmp_path):
    picture = np.zeros((20, 30, 3), np.uint8)
    (tmp_path / "walls").mkdir()
    assert cv2.imwrite(str(tmp_path / "walls" / "poster.png"), picture)
    scene = load_scene(write_scene(tmp_path, {"p": _image_backdrop("walls/poster.png")}), "p")
    assert scene.backdrop.kind == "image" and scene.backdrop.image == tmp_path / "walls" / "poster.png"
    assert scene.backdrop.surface.texture is None


@pytest.mark.parametrize("kind", ["missing", "text renamed .png", "directory"])
def test_an_unreadable_backdrop_image_names_the_path(tmp_path, kind):
    target = tmp_path / "wall.png"
    if kind == "text renamed .png":
        target.write_text("this is not a picture\n")
    elif kind == "directory":
        target.mkdir()
    path = write_scene(tmp_path, {"p": _image_backdrop("wall.png"), "other": {}})
    for preset in ("p", "other"):
        with pytest.raises(ConfigFileError, match="image") as info:
            load_scene(path, preset)
        message = str(info.value)
        assert message.startswith(str(path)) and str(target) in message and "[preset.p.backdrop]" in message
        said = {"missing": "does not exist", "directory": "is a folder, not an image"}.get(kind, "cannot read")
        assert said in message


def test_twin_config_with_an_unknown_scene_preset_fails_at_load(tmp_path):
    for name in ("twin.toml", "arm.toml", "camera.toml", "scene.toml"):
        (tmp_path / name).write_text((MODELS / name).read_text())
    twin_toml = tmp_path / "twin.toml"
    text = twin_toml.read_text()
    assert 'preset = "clean"' in text
    twin_toml.write_text(text.replace('preset = "clean"', 'preset = "labb"'))
    with pytest.raises(ConfigFileError) as info:
        TwinConfig.load(twin_toml)
    message = str(info.value)
    assert "'labb'" in message and "bright_warm" in message
    good = TwinConfig.load(MODELS / "twin.toml")
    assert good.scene_file == SCENES and good.scene() == load_scene(SCENES, good.scene_preset, good.scene_seed)
    lab = dataclasses.replace(good, scene_preset="lab", scene_seed=2)
    assert lab.scene() == load_scene(SCENES, "lab", 2)


def test_twin_config_with_an_unknown_scene_preset_names_twin_toml(tmp_path):
    for name in ("twin.toml", "arm.toml", "camera.toml", "scene.toml"):
        (tmp_path / name).write_text((MODELS / name).read_text())
    twin_toml = tmp_path / "twin.toml"
    twin_toml.write_text(twin_toml.read_text().replace('preset = "clean"', 'preset = "labb"'))
    with pytest.raises(ConfigFileError) as info:
        TwinConfig.load(twin_toml)
    assert str(twin_toml) in str(info.value) and "[scene] preset" in str(info.value)


# --- colour temperature and textures -----------------------------------------------------------------


def test_colour_temperature_is_white_at_6500_k_warm_below_and_blue_above():
    np.testing.assert_allclose(temperature_rgb(6500.0), [1.0, 1.0, 1.0], atol=1e-12)
    ratios = [temperature_rgb(k)[0] / temperature_rgb(k)[2] for k in (2000, 3000, 4500, 6500, 9000, 15000)]
    assert all(a > b for a, b in zip(ratios, ratios[1:], strict=False)), ratios
    assert ratios[1] > 2.0 and ratios[4] < 0.9
    assert all(temperature_rgb(k)[1] == pytest.approx(1.0) for k in (2000, 9000))
    for bad in (500.0, 30000.0):
        with pytest.raises(ValueError, match="colour temperature"):
            temperature_rgb(bad)


@pytest.mark.parametrize("pattern", PATTERNS)
def test_procedural_textures_are_seeded_and_carry_their_base_colour(pattern):
    base = (0.7, 0.47, 0.27)
    a = procedural_texture(pattern, (96, 160), base, 0.2, 12.0, seed=5)
    b = procedural_texture(pattern, (96, 160), base, 0.2, 12.0, seed=5)
    c = procedural_texture(pattern, (96, 160), base, 0.2, 12.0, seed=6)
    assert a.shape == (96, 160, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert np.std(a.astype(float)) > 3, "a texture has structure"
    if pattern != "clutter":  # posters of any hue cover part of a cluttered wall (mortar: under a quarter)
        median = np.median(a.reshape(-1, 3), axis=0) / 255.0
        np.testing.assert_allclose(median, base, atol=0.06)
    with pytest.raises(ValueError, match="plaster"):
        procedural_texture("stripes", (8, 8), base, 0.2, 4.0, seed=0)


def test_a_scene_seed_changes_the_textures_not_the_geometry():
    a, b = scene_parts(load_scene(SCENES, "lab", seed=0)), scene_parts(load_scene(SCENES, "lab", seed=1))
    again = scene_parts(load_scene(SCENES, "lab", seed=0))
    wall_a, wall_b, wall_again = a[0][0], b[0][0], again[0][0]
    assert np.array_equal(wall_a.texture, wall_again.texture)
    assert not np.array_equal(wall_a.texture, wall_b.texture)
    np.testing.assert_array_equal(wall_a.positions, wall_b.positions)
    for (obj_a, parts_a), (obj_b, parts_b) in zip(a[1], b[1], strict=True):
        assert obj_a == obj_b
        for pa, pb in zip(parts_a, parts_b, strict=True):
            if obj_a.kind != "blob":  # a blob's bumps are seeded too
                np.testing.assert_array_equal(pa.positions, pb.positions)


def test_a_procedural_wall_keeps_its_texture_square_when_the_size_limit_bites():
    """A 30 m wide wall used to get 4096 px across but 800 px up: its texture stretched 2.9x sideways."""
    for size, px_per_m in (((7.0, 4.0), 100.0), ((30.0, 2.0), 400.0), ((1.0, 12.0), 400.0)):
        backdrop = Backdrop(kind="procedural", surface=Surface((0.8, 0.8, 0.8), "plaster", 0.1, 0.07), size_m=size)
        wall = backdrop_parts(backdrop, seed=0, px_per_m=px_per_m)[0]
        h, w = wall.texture.shape[:2]
        assert w <= 4096 and h <= 2048
        assert (w / size[0]) == pytest.approx(h / size[1], rel=0.01), f"{size}: {w}x{h} px"
