"""The twin's camera effects (twin.sensor) on synthetic images, without rendering: YUYV 4:2:2 chroma
subsampling, shot and read noise, vignetting, the shake kernel, the region-only update of a static
scene, the original (legacy) sensor path, and the validation of CameraEffects."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.special import ndtri

from twin.rig import SensorModel, StereoRig
from twin.scene import load_scene
from twin.sensor import CameraEffects, SensorSimulator, shake_kernel, vignetting_map, yuyv_round_trip

REPO = Path(__file__).resolve().parents[2]
SIZE = (1280, 720)


@pytest.fixture(scope="module")
def K() -> np.ndarray:
    return StereoRig.load(REPO / "models" / "camera.toml").calibration.K("left")


def _luma(bgr: np.ndarray) -> np.ndarray:
    """BT.601 limited-range luma of BGR pixels (what YUYV keeps per pixel)."""
    b, g, r = (bgr[..., k].astype(np.float64) for k in range(3))
    return 16.0 + 0.256788 * r + 0.504129 * g + 0.097906 * b


def _chroma(bgr: np.ndarray) -> np.ndarray:
    """(..., 2) BT.601 U, V of BGR pixels."""
    b, g, r = (bgr[..., k].astype(np.float64) for k in range(3))
    return np.stack([-0.148223 * r - 0.290993 * g + 0.439216 * b, 0.439216 * r - 0.367788 * g - 0.071427 * b], -1)


# --- YUYV 4:2:2 ------------------------------------------------------------------------------------


def test_yuyv_keeps_grey_levels_and_colours_shared_by_a_pixel_pair():
    grey = np.repeat(np.tile(np.arange(256, dtype=np.uint8), 2)[None, :, None], 3, axis=2).repeat(4, axis=0)
    out = yuyv_round_trip(grey)
    assert out.shape == grey.shape and out.dtype == np.uint8
    assert np.abs(out.astype(int) - grey.astype(int)).max() <= 1, "grey survives up to the luma quantisation"
    rng = np.random.default_rng(0)
    pairs = rng.integers(30, 226, (40, 50, 3), dtype=np.uint8).repeat(2, axis=1)  # pixel 2k == pixel 2k + 1
    out = yuyv_round_trip(pairs)
    assert np.abs(out.astype(int) - pairs.astype(int)).max() <= 2


@pytest.mark.parametrize("edge", [101, 100])
def test_yuyv_averages_chroma_per_pair_and_keeps_luma_sharp(edge):
    """A red | blue edge: at an odd column the pair (edge - 1, edge) straddles it and shares one chroma
    sample, so its colours bleed into each other while each pixel keeps its own brightness; at an
    even column no pair straddles it and nothing changes."""
    red, blue = (40, 40, 200), (200, 60, 40)  # BGR
    image = np.zeros((6, 200, 3), np.uint8)
    image[:, :edge] = red
    image[:, edge:] = blue
    out = yuyv_round_trip(image)
    diff = np.abs(out.astype(int) - image.astype(int)).max(axis=(0, 2))
    luma_error = np.abs(_luma(out) - _luma(image)).max(axis=0)
    assert luma_error.max() <= 1.5, "every pixel keeps its luma, even across the edge"
    untouched = np.ones(200, bool)
    if edge % 2:
        pair = [edge - 1, edge]
        untouched[pair] = False
        assert diff[pair].min() > 40, "the pair straddling the edge mixes red and blue"
        chroma = _chroma(out[:, pair])
        assert np.abs(chroma[:, 0] - chroma[:, 1]).max() <= 2.0, "one chroma sample per pair"
        expected = 0.5 * (_chroma(np.array(red)) + _chroma(np.array(blue)))
        np.testing.assert_allclose(chroma[:, 0], np.broadcast_to(expected, chroma[:, 0].shape), atol=2.0)
    assert diff[untouched].max() <= 2


def test_yuyv_needs_an_even_width():
    with pytest.raises(ValueError, match="even image width"):
        yuyv_round_trip(np.zeros((4, 7, 3), np.uint8))


# --- noise -------------------------------------------------------------------------------------------


def _flat(level: int, shape=(240, 320)) -> np.ndarray:
    return np.full((*shape, 3), level, np.uint8)


def _noise_std(effects: CameraEffects, level: int, K, seed: int = 0) -> tuple[float, float]:
    sim = SensorSimulator(effects, K, (320, 240), np.random.default_rng(seed))
    out = sim.apply(_flat(level)).astype(np.float64)
    return float(np.std(out)), float(np.mean(out) - level)


def test_shot_noise_grows_with_the_signal_and_read_noise_does_not(K):
    read, shot = 2.0, 8.0
    both = CameraEffects(read_noise_dn=read, shot_noise_dn=shot)
    assert not both.legacy
    stds = {}
    for level in (20, 200):
        std, bias = _noise_std(both, level, K)
        expected = math.sqrt(read**2 + shot**2 * level / 255.0)
        assert std == pytest.approx(expected, rel=0.05), f"level {level}"
        assert abs(bias) < 0.1
        stds[level] = std
    assert stds[200] > 2.0 * stds[20]
    # Read noise alone, through the legacy path and (a vanishing vignetting) through the level table.
    for effects in (CameraEffects(read_noise_dn=3.0), CameraEffects(read_noise_dn=3.0, vignetting=1e-9)):
        low, high = (_noise_std(effects, level, K)[0] for level in (20, 200))
        assert low == pytest.approx(3.0, rel=0.05) and high == pytest.approx(3.0, rel=0.05)


def test_noise_is_drawn_from_the_shared_generator(K):
    effects = CameraEffects(read_noise_dn=2.0, shot_noise_dn=4.0, yuyv=True)
    a = SensorSimulator(effects, K, (320, 240), np.random.default_rng(3))
    b = SensorSimulator(effects, K, (320, 240), np.random.default_rng(3))
    first, second = a.apply(_flat(120)), a.apply(_flat(120))
    assert np.array_equal(first, b.apply(_flat(120))) and not np.array_equal(first, second)


# --- vignetting ----------------------------------------------------------------------------------------


def test_vignetting_is_one_at_the_principal_point_and_one_minus_the_fall_off_at_the_farthest_corner(K):
    fall_off = 0.3
    v = vignetting_map(K, SIZE, fall_off)
    w, h = SIZE
    assert v.shape == (h, w) and v.dtype == np.float32
    cx, cy = K[0, 2], K[1, 2]
    peak = np.unravel_index(np.argmax(v), v.shape)
    assert abs(peak[1] - cx) <= 1 and abs(peak[0] - cy) <= 1
    assert v[round(cy), round(cx)] == pytest.approx(1.0, abs=1e-5)
    corners = {(0, 0): v[0, 0], (w - 1, 0): v[0, -1], (0, h - 1): v[-1, 0], (w - 1, h - 1): v[-1, -1]}
    farthest = max(corners, key=lambda c: ((c[0] - cx) / K[0, 0]) ** 2 + ((c[1] - cy) / K[1, 1]) ** 2)
    assert corners[farthest] == pytest.approx(1.0 - fall_off, abs=1e-6)
    assert all(value >= 1.0 - fall_off - 1e-6 for value in corners.values())
    # Darker the farther from the principal point: along the diagonal to that corner.
    t = np.linspace(0.0, 1.0, 50)
    us, vs = cx + t * (farthest[0] - cx), cy + t * (farthest[1] - cy)
    profile = v[np.round(vs).astype(int), np.round(us).astype(int)]
    assert np.all(np.diff(profile) <= 1e-6)
    assert np.array_equal(vignetting_map(K, SIZE, 0.0), np.ones((h, w), np.float32))


def test_vignetting_and_gain_darken_and_brighten_the_image(K):
    sim = SensorSimulator(CameraEffects(vignetting=0.3, exposure_gain=1.5), K, SIZE, np.random.default_rng(0))
    out = sim.apply(_flat(100, (720, 1280))).astype(float)[..., 1]
    cx, cy = round(K[0, 2]), round(K[1, 2])
    assert out[cy, cx] == pytest.approx(150.0, abs=1.0)
    v = vignetting_map(K, SIZE, 0.3)
    np.testing.assert_allclose(out, np.rint(150.0 * v), atol=1.0)
    bright = SensorSimulator(CameraEffects(exposure_gain=3.0, yuyv=True), K, SIZE, np.random.default_rng(0))
    assert np.all(bright.apply(_flat(100, (720, 1280))) == 255), "over-exposure clips"


# --- the shake kernel ---------------------------------------------------------------------------------


def _reference_spread(length_px: float, angle_deg: float) -> tuple[float, float]:
    """Variance along and across the direction of a uniform segment splatted bilinearly onto pixels
    (dense sampling, no kernel border): what the shake kernel must reproduce."""
    t = np.linspace(-length_px / 2.0, length_px / 2.0, 20001)
    a = math.radians(angle_deg)
    x, y = 50.0 + t * math.cos(a), 50.0 + t * math.sin(a)
    x0, y0 = np.floor(x), np.floor(y)
    total = along = across = 0.0
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        weight = (x - x0 if dx else 1.0 - (x - x0)) * (y - y0 if dy else 1.0 - (y - y0))
        px, py = x0 + dx - 50.0, y0 + dy - 50.0
        total += weight.sum()
        along += (weight * (px * math.cos(a) + py * math.sin(a)) ** 2).sum()
        across += (weight * (-px * math.sin(a) + py * math.cos(a)) ** 2).sum()
    return along / total, across / total


def _moments(kernel: np.ndarray, angle_deg: float) -> tuple[np.ndarray, float, float, float]:
    n = kernel.shape[0]
    c = (n - 1) / 2.0
    y, x = np.mgrid[:n, :n] - c
    k = kernel.astype(np.float64)
    mean = np.array([(k * x).sum(), (k * y).sum()])
    a = math.radians(angle_deg)
    along = x * math.cos(a) + y * math.sin(a)
    across = -x * math.sin(a) + y * math.cos(a)
    cov = np.array([[(k * x * x).sum(), (k * x * y).sum()], [(k * x * y).sum(), (k * y * y).sum()]])
    vals, vecs = np.linalg.eigh(cov)
    axis_deg = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1])) % 180.0
    return mean, float((k * along**2).sum()), float((k * across**2).sum()), axis_deg


@pytest.mark.parametrize("length", [3.0, 5.5, 9.0, 12.5])
@pytest.mark.parametrize("angle", [0.0, 30.0, 90.0, 135.0])
def test_the_shake_kernel_sums_to_one_and_spans_its_length_along_its_angle(length, angle):
    kernel = shake_kernel(length, angle)
    assert kernel.dtype == np.float32 and kernel.shape[0] == kernel.shape[1] and kernel.shape[0] % 2 == 1
    assert float(kernel.sum(dtype=np.float64)) == pytest.approx(1.0, abs=1e-6)
    assert kernel.min() >= 0
    mean, along, across, axis_deg = _moments(kernel, angle)
    np.testing.assert_allclose(mean, 0.0, atol=1e-6)
    ref_along, ref_across = _reference_spread(length, angle)
    # A kernel cut at its border (a 9 px shake in a 9 px kernel) loses ~7 % of this spread.
    assert along == pytest.approx(ref_along, rel=0.05)
    assert across == pytest.approx(ref_across, abs=0.05)
    assert min(abs(axis_deg - angle % 180.0), 180.0 - abs(axis_deg - angle % 180.0)) < 1.0


def test_shake_blurs_across_its_direction_only(K):
    """Image angles are measured from the rows towards +v: 0 deg smears a vertical edge, 90 deg does not."""
    edge = np.zeros((60, 80, 3), np.uint8)
    edge[:, 40:] = 200
    for angle, smeared in ((0.0, True), (90.0, False)):
        sim = SensorSimulator(CameraEffects(shake_px=8.0, shake_angle_deg=angle), K, (80, 60), np.random.default_rng(0))
        row = sim.apply(edge)[30, :, 0].astype(int)
        intermediate = int(np.count_nonzero((row > 10) & (row < 190)))
        assert (intermediate >= 6) if smeared else (intermediate == 0), (angle, row[30:50])


# --- the static scene done once, the changed region per frame -------------------------------------------


@pytest.mark.parametrize("box", [(500, 200, 620, 420), (0, 0, 90, 60), (1200, 650, 1280, 720)])
def test_updating_only_the_changed_region_gives_the_whole_image_result(K, box):
    effects = CameraEffects(vignetting=0.3, exposure_gain=1.3, optics_blur_px=1.2, shake_px=9.0, shake_angle_deg=20.0,
                            yuyv=True)
    rng = np.random.default_rng(1)
    static_raw = cv2.resize(rng.integers(0, 256, (72, 128, 3), dtype=np.uint8), SIZE, interpolation=cv2.INTER_CUBIC)
    raw = static_raw.copy()
    x0, y0, x1, y1 = box
    raw[y0:y1, x0:x1] = rng.integers(0, 256, (y1 - y0, x1 - x0, 3), dtype=np.uint8)
    sim = SensorSimulator(effects, K, SIZE, np.random.default_rng(0))
    whole = sim.apply(raw)
    region = sim.apply(raw, sim.static(static_raw), box)
    assert np.array_equal(region, whole)


# --- the original sensor model ------------------------------------------------------------------------------


def _old_sensor(image: np.ndarray, sensor: SensorModel, rng: np.random.Generator) -> np.ndarray:
    """The renderer's sensor before lab scenes (twin/render.py at f67e884^): blur, then gain and read noise."""
    if sensor.blur_sigma_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), sensor.blur_sigma_px)
    if sensor.noise_std_dn > 0:
        q = ndtri((np.arange(256) + 0.5) / 256.0)
        lut = (q / np.sqrt(np.mean(q**2)) * sensor.noise_std_dn).astype(np.float32).reshape(1, 256)
        u8 = np.frombuffer(rng.bytes(image.size), dtype=np.uint8).reshape(image.shape)
        return cv2.addWeighted(image, sensor.exposure_gain, cv2.LUT(u8, lut), 1.0, 0.0, dtype=cv2.CV_8U)
    if sensor.exposure_gain != 1.0:
        return cv2.convertScaleAbs(image, alpha=sensor.exposure_gain)
    return image


@pytest.mark.parametrize("sensor", [SensorModel(1.5), SensorModel(2.0, 0.8, 1.2), SensorModel(0.0, 1.5, 0.7),
                                    SensorModel(0.0, 0.0, 1.0)])
def test_legacy_effects_give_the_images_of_the_original_sensor(K, sensor):
    effects = load_scene(REPO / "models" / "scene.toml", "clean").effects(sensor)
    assert effects.legacy
    assert (effects.read_noise_dn, effects.optics_blur_px, effects.exposure_gain) == (
        sensor.noise_std_dn, sensor.blur_sigma_px, sensor.exposure_gain)
    rng = np.random.default_rng(4)
    raw = cv2.resize(rng.integers(0, 256, (36, 64, 3), dtype=np.uint8), (320, 180), interpolation=cv2.INTER_CUBIC)
    sim = SensorSimulator(effects, K, (320, 180), np.random.default_rng(9))
    old_rng = np.random.default_rng(9)
    for _ in range(2):  # the generator's sequence carries on identically
        assert np.array_equal(sim.apply(raw), _old_sensor(raw, sensor, old_rng))


def test_only_read_noise_gain_and_optical_blur_keep_the_legacy_path():
    assert CameraEffects(read_noise_dn=2, exposure_gain=1.4, optics_blur_px=1, exposure_s=0.02).legacy
    for change in ({"shot_noise_dn": 1.0}, {"vignetting": 0.1}, {"yuyv": True}, {"shake_px": 2.0}):
        assert not CameraEffects(**change).legacy, change


# --- validation ----------------------------------------------------------------------------------------------

BAD_EFFECTS = [
    ("exposure_gain", 0.0), ("exposure_gain", 20.0), ("exposure_gain", float("nan")),
    ("read_noise_dn", -1.0), ("read_noise_dn", "2"), ("shot_noise_dn", 100.0), ("shot_noise_dn", True),
    ("vignetting", 0.96), ("vignetting", -0.1), ("optics_blur_px", float("inf")), ("exposure_s", 0.6),
    ("shake_px", -1.0), ("shake_angle_deg", 400.0), ("yuyv", 1), ("yuyv", "yes"),
    ("motion_subframes", 0), ("motion_subframes", 33), ("motion_subframes", 2.0), ("motion_subframes", True),
]


@pytest.mark.parametrize(("field", "value"), BAD_EFFECTS)
def test_camera_effects_validation_names_the_field(field, value):
    with pytest.raises(ValueError) as info:
        CameraEffects(**{field: value})
    assert str(info.value).startswith(f"{field}:"), str(info.value)
    assert repr(value) in str(info.value)


def test_camera_effects_round_trip_through_a_dict_and_scenes_override_the_sensor():
    effects = CameraEffects(exposure_gain=1.2, shot_noise_dn=3.0, yuyv=True, motion_subframes=6)
    assert CameraEffects(**effects.as_dict()) == effects
    assert {f.name for f in dataclasses.fields(CameraEffects)} == set(effects.as_dict())
    lab = load_scene(REPO / "models" / "scene.toml", "lab")
    e = lab.effects(SensorModel(noise_std_dn=9.0, blur_sigma_px=2.0, exposure_gain=1.1))
    assert e.read_noise_dn == 1.5 and e.optics_blur_px == 0.4  # the preset's
    assert e.exposure_gain == 1.1  # the preset leaves it to camera.toml
    assert e.yuyv and e.vignetting == 0.2 and e.shot_noise_dn == 3.0
