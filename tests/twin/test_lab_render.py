"""Lab scenes rendered (offscreen EGL on the CPU): the clean scene is today's images, presets render
reproducibly, the wall is geometry both eyes see at its true disparity and depth, occluders cross in
front of the arm, the arm's motion blurs over the exposure, light has a colour temperature, image
backdrops stand upright, and the Twin facade renders a preset.

Most renders use a half-size ZED (640 x 360) to keep the suite fast: the scene code does not care
about the image size. Renderers are module-scoped and each test renders a few frames at most.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest

from estimator import StereoCalibration
from tests.twin.test_render import _bare, arc, hanging
from twin import Twin
from twin.render import StereoRenderer, interpolate_shape
from twin.rig import StereoRig
from twin.scene import Backdrop, LabScene, Light, Lighting, Surface, load_scene
from twin.sensor import CameraEffects
from twin.shape import ArmShape
from twin.twin import TwinConfig

REPO = Path(__file__).resolve().parents[2]
MODELS = REPO / "models"
SCENES = MODELS / "scene.toml"
IDEAL = CameraEffects()  # no noise, blur or subsampling: geometry and colour measured exactly


@pytest.fixture(scope="module")
def small_rig() -> StereoRig:
    """camera.toml's ZED at half resolution: the same pose, distortion and baseline."""
    rig = StereoRig.load(MODELS / "camera.toml")
    c = rig.calibration
    half = np.diag([0.5, 0.5, 1.0])
    calib = StereoCalibration(half @ c.K_left, c.dist_left, half @ c.K_right, c.dist_right, c.R, c.T, (640, 360))
    return StereoRig(calib, rig.T_world_cam_left, rig.appearance, rig.sensor)


def _shifted(shape: ArmShape, dx_m: float) -> ArmShape:
    return ArmShape(shape.points_world + [dx_m, 0.0, 0.0], shape.s_m, shape.radius_m, shape.plates)


def _plane_depth(rig: StereoRig, uv_raw: np.ndarray, wall_y_m: float) -> np.ndarray:
    """(N,) left-camera z of the wall plane y = wall_y_m seen through raw left pixels ``uv_raw``."""
    calib = rig.calibration
    xy = cv2.undistortPoints(np.asarray(uv_raw, np.float64).reshape(-1, 1, 2), calib.K("left"),
                             calib.dist("left").reshape(1, -1),
                             criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12)).reshape(-1, 2)
    rays_world = np.column_stack([xy, np.ones(len(xy))]) @ rig.T_world_cam_left[:3, :3].T
    return (wall_y_m - rig.T_world_cam_left[1, 3]) / rays_world[:, 1]


def _few_differences(a: np.ndarray, b: np.ndarray, near_uv: np.ndarray) -> None:
    """``a`` equals ``b`` except at a handful of pixels by a few DN, all near the arm.

    Separate renderer instances can disagree by 1 DN on an arm-silhouette pixel over a textured
    wall (llvmpipe; seen in about one pair of instances in three, whatever the draw order); the
    sensor noise and YUYV carry that on to a few DN. Everywhere else the images are bit-identical.
    """
    diff = np.abs(a.astype(int) - b.astype(int)).max(axis=2)
    rows, cols = np.nonzero(diff)
    assert len(rows) <= 8 and (len(rows) == 0 or diff.max() <= 4), f"{len(rows)} pixels differ, up to {diff.max()}"
    for r, c in zip(rows, cols, strict=True):
        assert np.min(np.hypot(near_uv[:, 0] - c, near_uv[:, 1] - r)) < 40, f"pixel ({c}, {r}) is far from the arm"


# --- the clean scene is today's images ----------------------------------------------------------------


def test_the_clean_scene_renders_exactly_the_images_of_a_renderer_without_a_scene(small_rig):
    """Arms without plates: pyrender draws the tube and the base plate (both at the world origin) in set
    order, which moves a few pixels where they meet between renderer instances (render.py, reported)."""
    clean = load_scene(SCENES, "clean")
    with StereoRenderer(small_rig, seed=4) as plain, StereoRenderer(small_rig, seed=4, scene=clean) as scened:
        assert scened.effects == plain.effects and scened.effects.legacy
        for shape in (_bare(hanging()), _bare(arc()), None):
            a, b = plain.render(shape), scened.render(shape)
            assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
            assert np.array_equal(a.depth_left_m, b.depth_left_m)


# --- the lab preset ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def lab_frames(small_rig):
    """The lab preset from two renderers with the same seeds and one with another render seed:
    (arm-less frame, frame with the arm) from each."""
    lab = load_scene(SCENES, "lab", seed=0)
    shape = _bare(hanging())
    frames = {}
    for name, seed in (("a", 0), ("b", 0), ("other_noise", 1)):
        with StereoRenderer(small_rig, seed=seed, scene=lab) as renderer:
            frames[name] = (renderer.render(None, t_s=0.5), renderer.render(shape, t_s=1.0))
    return lab, shape, frames


def test_the_same_preset_and_seeds_render_the_same_images(small_rig, lab_frames):
    _, shape, frames = lab_frames
    (empty_a, arm_a), (empty_b, arm_b) = frames["a"], frames["b"]
    assert np.array_equal(empty_a.left, empty_b.left) and np.array_equal(empty_a.right, empty_b.right)
    assert np.array_equal(empty_a.depth_left_m, empty_b.depth_left_m)
    for side in ("left", "right"):
        near = small_rig.project_world(shape.points_world, side)
        _few_differences(getattr(arm_a, side), getattr(arm_b, side), near)
    finite = np.isfinite(arm_a.depth_left_m)
    assert np.array_equal(finite, np.isfinite(arm_b.depth_left_m))
    assert np.count_nonzero(arm_a.depth_left_m[finite] != arm_b.depth_left_m[finite]) <= 4


def _local_mean(image: np.ndarray) -> np.ndarray:
    return cv2.blur(image.astype(np.float32), (15, 15))


def test_another_render_seed_changes_only_the_noise(lab_frames):
    _, _, frames = lab_frames
    a, other = frames["a"][0], frames["other_noise"][0]
    for x, y in ((a.left, other.left), (a.right, other.right)):
        diff = x.astype(np.float32) - y.astype(np.float32)
        assert np.count_nonzero(diff) > 0.5 * diff.size, "the noise is drawn afresh"
        assert abs(float(diff.mean())) < 0.1
        assert 1.5 < float(diff.std()) < 8.0
        # No structure in the difference: its local means vanish (the scene itself is the same) ...
        assert np.abs(_local_mean(diff)[8:-8, 8:-8]).max() < 1.5
        # ... which a change of the scene would not pass: the image against itself shifted by 2 px.
        moved = x.astype(np.float32) - np.roll(x, 2, axis=1).astype(np.float32)
        assert np.abs(_local_mean(moved)[8:-8, 8:-8]).max() > 5.0
    assert np.array_equal(a.depth_left_m, other.depth_left_m)


def _ncc_disparity(left: np.ndarray, right: np.ndarray, u: int, v: int, half: int, max_d: int) -> tuple[float, float]:
    """Sub-pixel shift d maximising the normalised correlation of left[v, u] with right[v, u - d]."""
    patch = left[v - half:v + half + 1, u - half:u + half + 1].astype(np.float64)
    patch = (patch - patch.mean()) / (patch.std() + 1e-9)
    scores = []
    for d in range(max_d + 1):
        other = right[v - half:v + half + 1, u - d - half:u - d + half + 1].astype(np.float64)
        other = (other - other.mean()) / (other.std() + 1e-9)
        scores.append(float(np.mean(patch * other)))
    scores = np.array(scores)
    k = int(np.argmax(scores))
    if 0 < k < max_d:
        a, b, c = scores[k - 1], scores[k], scores[k + 1]
        return k + 0.5 * (a - c) / (a - 2 * b + c), float(b)
    return float(k), float(scores[k])


def test_both_eyes_see_the_wall_at_the_disparity_of_its_depth(small_rig, lab_frames):
    """The backdrop is geometry, not a picture pasted into each image: its texture shifts between the
    rectified images by f B / Z for the wall's true depth Z."""
    lab, _, frames = lab_frames
    frame = frames["a"][0]
    rect = small_rig.calibration.rectification
    grey = {side: cv2.cvtColor(rect.rectify_image(getattr(frame, side), side), cv2.COLOR_BGR2GRAY)
            for side in ("left", "right")}
    seen = {side: rect.rectify_image(np.full((360, 640), 255, np.uint8), side) == 255 for side in ("left", "right")}
    f, baseline = rect.focal_px, rect.baseline_m
    T = small_rig.T_world_cam_left
    half, max_d = 10, 70
    errors, expected_all = [], []
    height, width = grey["left"].shape
    for v in range(20, height - 20, 30):
        for u in range(max_d + 20, width - 20, 30):
            rows, cols = slice(v - half, v + half + 1), slice(u - max_d - half, u + half + 1)
            if not (seen["left"][rows, cols].all() and seen["right"][rows, cols].all()):
                continue  # the patch or its search range leaves the raw images
            raw = rect.unrectify_points(np.array([[u, v]], float), "left")[0]
            c, r = np.round(raw).astype(int)
            # Only where the left eye sees the wall around the patch and 25 px to its right: what stands
            # in front of the wall (1 m or more from the camera here) shifts at most that much further
            # in the right image and could hide the patch there.
            window = frame.depth_left_m[max(r - half - 2, 0):r + half + 3, max(c - half - 2, 0):c + half + 28]
            wall = _plane_depth(small_rig, np.array([[c, r]], float), lab.backdrop.wall_y_m)[0]
            if not np.all(np.abs(window - wall) < 0.05):
                continue
            ray_cam = rect.to_left_camera(np.array([[(u - rect.P["left"][0, 2]) / f, (v - rect.P["left"][1, 2]) / f,
                                                     1.0]]))[0]
            z_rect = (lab.backdrop.wall_y_m - T[1, 3]) / (T[:3, :3] @ ray_cam)[1]
            expected = f * baseline / z_rect
            if grey["left"][rows, u - half:u + half + 1].std() < 6.0:
                continue  # inside one brick: too little texture against the noise to correlate
            measured, score = _ncc_disparity(grey["left"], grey["right"], u, v, half, max_d)
            assert score > 0.8, f"({u}, {v}): the wall patch is not found in the right image"
            errors.append(measured - expected)
            expected_all.append(expected)
    errors = np.array(errors)
    assert len(errors) >= 15, f"only {len(errors)} wall patches measured"
    assert 15.0 < np.median(expected_all) < 30.0  # 2 m away at half resolution
    print(f"{len(errors)} wall patches: disparity error median {np.median(np.abs(errors)):.3f} px, "
          f"worst {np.max(np.abs(errors)):.3f} px at {np.median(expected_all):.1f} px")
    assert np.median(np.abs(errors)) < 0.15 and np.max(np.abs(errors)) < 0.5, errors


def test_the_left_depth_map_shows_the_wall_at_its_depth_where_nothing_stands_in_front(small_rig, lab_frames):
    lab, shape, frames = lab_frames
    for frame in frames["a"]:  # without and with the arm (its rectangle is drawn again per frame)
        depth = frame.depth_left_m
        h, w = depth.shape
        u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        wall = _plane_depth(small_rig, np.column_stack([u.ravel(), v.ravel()]), lab.backdrop.wall_y_m).reshape(h, w)
        assert np.all(np.isfinite(depth)), "the wall and the floor fill the view"
        assert np.all(depth <= wall + 0.01), "nothing is seen behind the wall"
        on_wall = np.abs(depth - wall) < 0.01
        assert on_wall.mean() > 0.5
        assert on_wall[:30].all(), "above the rig bar only the wall is seen"
        assert np.all(np.abs(depth[:30] - wall[:30]) < 2e-3)
    # Beside the arm, inside the rectangle drawn around it, the wall is back at its depth.
    depth = frames["a"][1].depth_left_m
    uv = small_rig.project_world(shape.points_world[50:150], "left")
    for (c, r) in np.round(uv).astype(int)[::10]:
        assert depth[r, c] == pytest.approx(small_rig.world_to_left_camera(shape.points_world[:1])[0, 2], abs=0.1)
        for side_c in (c - 20, c + 20):  # 20 px beside the axis: the arm is 9 px in radius here
            wall = _plane_depth(small_rig, np.array([[side_c, r]], float), lab.backdrop.wall_y_m)[0]
            assert depth[r, side_c] == pytest.approx(wall, abs=2e-3)


# --- occluders -------------------------------------------------------------------------------------------


def test_an_occluder_moves_along_its_path_in_front_of_the_arm(small_rig):
    scene = load_scene(SCENES, "occluded")
    cable = next(o for o in scene.objects if o.role == "occluder")
    shape = _bare(hanging())
    column = int(round(small_rig.project_world(np.array([[0.0, 0.0, -0.4]]), "left")[0, 0]))
    arm_z = small_rig.world_to_left_camera(np.array([[0.0, 0.0, -0.4]]))[0, 2]
    rows, images = {}, {}
    with StereoRenderer(small_rig, scene=scene, effects=IDEAL) as renderer:
        for t_s in (5.0, 2.0, 5.0):
            frame = renderer.render(shape, t_s=t_s)
            # Where the cable's middle should be: its centre on the path, at the curve's apex.
            middle = cable.T_world(t_s) @ np.array([0.0, 0.0, -0.03, 1.0])
            expected_row = small_rig.project_world(middle[None, :3], "left")[0, 1]
            expected_z = small_rig.world_to_left_camera(middle[None, :3])[0, 2]
            d = frame.depth_left_m[:, column]
            near = np.flatnonzero(d < 0.5 * (expected_z + arm_z))
            assert 2 <= len(near) <= 12 and np.ptp(near) == len(near) - 1, f"t = {t_s}: cable rows {near}"
            assert abs(near.mean() - expected_row) < 2.0
            assert d[near].min() == pytest.approx(expected_z - cable.radius_m, abs=0.01)
            # The arm is there above and below the cable, behind it.
            for r in (near[0] - 8, near[-1] + 8):
                assert d[r] == pytest.approx(arm_z - shape.radius_m[0], abs=0.01)
            assert frame.left[near[1:-1], column].max() < 60, "the dark cable, not the orange arm (edges blend)"
            rows.setdefault(t_s, []).append(near.mean())
            images.setdefault(t_s, []).append(frame.left)
    assert abs(rows[2.0][0] - rows[5.0][0]) > 50, "the cable moved along its path between the two times"
    # Back at t = 5 s the same image: the rectangle of the frame before was put back to the static scene.
    assert np.array_equal(images[5.0][0], images[5.0][1])


def _everything_in_each_rectangle(self, side, rects, depth):
    """The reference: per rectangle, clear it and draw every object of the scene into it."""
    GL = self._GL
    self._scene.main_camera_node = self._camera_nodes[side]
    self._want_depth = depth
    self._renderer._platform.make_current()
    GL.glEnable(GL.GL_SCISSOR_TEST)
    out = []
    for rect in rects:
        self._rects = [rect]
        GL.glScissor(*rect)
        out += self._renderer.render(self._scene)
    return out


@pytest.mark.parametrize("preset", ["lab", "occluded"])
def test_drawn_rectangles_start_from_the_static_samples_with_the_same_pixels(small_rig, monkeypatch, preset):
    """A frame copies the static scene's multisamples (colour and depth) into each drawn rectangle and
    draws only what moves over them: the frames equal those drawn from a cleared rectangle with every
    object of the scene, bit for bit (a shelf or a cable in front of the arm hides it either way)."""
    scene = load_scene(SCENES, preset)
    shapes = [_bare(hanging()), _bare(arc())]
    times = np.arange(0.0, 12.0, 1.5)
    with StereoRenderer(small_rig, scene=scene, effects=IDEAL) as renderer:
        lean = [renderer.render(shapes[k % 2], t_s=t, frame_index=0) for k, t in enumerate(times)]
        monkeypatch.setattr(StereoRenderer, "_render_regions", _everything_in_each_rectangle)
        full = [renderer.render(shapes[k % 2], t_s=t, frame_index=0) for k, t in enumerate(times)]
    for a, b in zip(lean, full, strict=True):
        assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
        assert np.array_equal(a.depth_left_m, b.depth_left_m)


def test_a_moving_objects_pieces_hold_every_pixel_it_changes(small_rig, monkeypatch):
    """The occluding cable is drawn in 96 px pieces around its triangles, not in its bounding box: the
    frames equal those drawn in the whole box, bit for bit, while the cable sweeps across the arm."""
    scene = load_scene(SCENES, "occluded")
    shape = _bare(hanging())
    times = np.arange(0.0, 23.0, 1.0)
    pieces = []
    cut = StereoRenderer._triangle_rects

    def counting(self, side, meshes):
        rects = cut(self, side, meshes)
        pieces.append(len(rects))
        return rects

    monkeypatch.setattr(StereoRenderer, "_triangle_rects", counting)
    with StereoRenderer(small_rig, scene=scene, effects=IDEAL) as renderer:
        cut_up = [renderer.render(shape, t_s=t, frame_index=0) for t in times]
        monkeypatch.setattr(StereoRenderer, "_triangle_rects", lambda self, side, meshes: None)
        whole = [renderer.render(shape, t_s=t, frame_index=0) for t in times]
    assert max(pieces) >= 4, "the cable was never cut into pieces"
    for a, b in zip(cut_up, whole, strict=True):
        assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
        assert np.array_equal(a.depth_left_m, b.depth_left_m)

# --- motion blur -------------------------------------------------------------------------------------------


def _edge_widths(image: np.ndarray, row: int, background: float, arm: float) -> list[int]:
    """Pixels of each edge of the arm along one row that sit between 15 % and 85 % of the way."""
    blue = image[row, :, 0].astype(float)
    level = (blue - background) / (arm - background)
    inside = np.flatnonzero(level > 0.5)
    centre = int(inside.mean())
    between = (level > 0.15) & (level < 0.85)
    return [int(between[:centre].sum()), int(between[centre:].sum())]


def test_a_moving_arm_blurs_over_the_exposure_and_a_static_one_does_not(small_rig):
    shape = _bare(hanging())
    previous = (_shifted(shape, -0.03), 0.96)  # 0.75 m/s along +x: 1.5 cm over a 20 ms exposure
    blurred = CameraEffects(exposure_s=0.02, motion_subframes=8)
    with StereoRenderer(small_rig, effects=IDEAL) as sharp, StereoRenderer(small_rig, effects=blurred) as slow:
        still = sharp.render(shape, t_s=1.0)
        moving = slow.render(shape, t_s=1.0, previous=previous)
        static = slow.render(shape, t_s=1.0)  # no previous shape: nothing to blur
        standing = slow.render(shape, t_s=1.0, previous=(shape, 0.96))  # the same shape before
        moving_sharp = sharp.render(shape, t_s=1.0, previous=previous)  # no exposure: no blur
    assert np.array_equal(static.left, still.left) and np.array_equal(static.right, still.right)
    assert np.array_equal(standing.left, still.left) and np.array_equal(standing.right, still.right)
    assert np.array_equal(moving_sharp.left, still.left)
    row = int(round(small_rig.project_world(np.array([[0.0, 0.0, -0.3]]), "left")[0, 1]))
    background = float(np.median(still.left[row, :40, 0]))
    arm = float(np.median(still.left[row, :, 0][still.left[row, :, 0] < 0.5 * background]))
    sharp_widths = _edge_widths(still.left, row, background, arm)
    blurred_widths = _edge_widths(moving.left, row, background, arm)
    assert max(sharp_widths) <= 2
    depth_m = small_rig.world_to_left_camera(shape.points_world[:1])[0, 2]
    sweep_px = 0.015 * small_rig.calibration.K("left")[0, 0] / depth_m
    for before, after in zip(sharp_widths, blurred_widths, strict=True):
        assert after >= before + 0.5 * sweep_px, (sharp_widths, blurred_widths, sweep_px)
    # The smear trails towards where the arm came from (-x, image left): the silhouette's centre moves left.
    def centre(image):
        weight = np.clip(background - image[row, :, 0].astype(float), 0, None)
        return float((weight * np.arange(len(weight))).sum() / weight.sum())

    assert centre(moving.left) - centre(still.left) == pytest.approx(-0.5 * sweep_px, abs=0.8)


def test_an_exposure_draws_as_many_sub_frames_as_the_motion_needs(small_rig):
    """An arm that moves under a quarter pixel over the exposure is drawn once, as it stands at the
    exposure's middle (the blur's centroid); a fast one gets every sub-frame, at most half a pixel apart."""
    shape = _bare(hanging())
    effects = CameraEffects(exposure_s=0.02, motion_subframes=8)
    depth_m = small_rig.world_to_left_camera(shape.points_world[:1])[0, 2]
    metres_per_px = depth_m / small_rig.calibration.K("left")[0, 0]
    slow = (_shifted(shape, -0.2 * metres_per_px), 0.96)  # 0.2 px in 40 ms: 0.1 px over the exposure
    fast = (_shifted(shape, -0.03), 0.96)
    with StereoRenderer(small_rig, effects=IDEAL) as sharp, StereoRenderer(small_rig, effects=effects) as blurred:
        once = blurred._subframes(shape, 1.0, slow)
        assert [tau for _, tau in once] == [pytest.approx(0.99)]
        assert len(blurred._subframes(shape, 1.0, fast)) == 8
        middle = interpolate_shape(shape, slow[0], 0.25)  # 10 ms back of a 40 ms step
        assert np.array_equal(blurred.render(shape, t_s=1.0, previous=slow).left, sharp.render(middle, t_s=1.0).left)


def test_sub_frame_averaging_keeps_dark_static_pixels(small_rig):
    dark = LabScene(preset="dark", backdrop=Backdrop(kind="uniform", surface=Surface((0.02, 0.02, 0.02))),
                    lighting=Lighting(ambient=1.0, lights=()))
    shape = _bare(hanging())
    with StereoRenderer(small_rig, scene=dark, effects=CameraEffects(exposure_s=0.02, motion_subframes=4)) as r:
        frame = r.render(shape, t_s=1.0)
    wall = ~np.isfinite(frame.depth_left_m) | (frame.depth_left_m > 1.5)
    # away from the arm's anti-aliased edge, whose pixels mix the arm's colour but keep the wall's depth
    wall = cv2.erode(wall.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    values = np.unique(frame.left[wall])
    assert len(values) == 1, f"a uniformly lit wall shows the values {values}"


# --- light ----------------------------------------------------------------------------------------------------


def _grey_wall(temperature_k: float) -> LabScene:
    return LabScene(preset=f"grey_{temperature_k:.0f}",
                    backdrop=Backdrop(kind="uniform", surface=Surface((0.6, 0.6, 0.6))),
                    lighting=Lighting(ambient=0.2, lights=(Light(0.6, (0.0, 1.0, -0.3), temperature_k),)))


def test_a_warm_light_makes_a_grey_wall_redder_than_daylight(small_rig):
    ratios = {}
    for kelvin in (3000.0, 6500.0):
        with StereoRenderer(small_rig, scene=_grey_wall(kelvin), effects=IDEAL) as renderer:
            image = renderer.render(None).left.astype(float)
        b, g, r = (image[..., k].mean() for k in range(3))
        ratios[kelvin] = r / b
        assert np.ptp(image[..., 1]) <= 1, "a uniform wall under a directional light is uniform"
    assert ratios[6500.0] == pytest.approx(1.0, abs=0.01), "6500 K is white"
    assert ratios[3000.0] > 1.3 * ratios[6500.0]


# --- image backdrops ---------------------------------------------------------------------------------------------


def test_an_image_backdrop_stands_upright_and_unmirrored(small_rig, tmp_path):
    """pyrender uploads textures bottom row first; the wall's texture coordinates used to ignore that
    and showed the picture upside down."""
    picture = np.zeros((200, 300, 3), np.uint8)
    picture[:100] = (0, 0, 255)  # top: red (BGR)
    picture[100:] = (255, 0, 0)  # bottom: blue
    picture[:, :150] //= 2  # left half darker
    assert cv2.imwrite(str(tmp_path / "poster.png"), picture)
    scene_file = tmp_path / "scene.toml"
    scene_file.write_text('[preset.poster.backdrop]\nkind = "image"\nimage = "poster.png"\n'
                          '[preset.poster.lighting]\nambient = 1.0\n')
    scene = load_scene(scene_file, "poster")
    with StereoRenderer(small_rig, scene=scene, effects=IDEAL) as renderer:
        image = renderer.render(None).left.astype(int)
    top, bottom = image[:40].reshape(-1, 3).mean(axis=0), image[-40:].reshape(-1, 3).mean(axis=0)
    assert top[2] > 150 and top[0] < 10, f"top of the view: {top} (BGR)"
    assert bottom[0] > 150 and bottom[2] < 10, f"bottom of the view: {bottom} (BGR)"
    assert image[:40, :40, 2].mean() < image[:40, -40:, 2].mean(), "the darker half is on the left"


# --- the Twin facade -------------------------------------------------------------------------------------------------


def test_the_twin_renders_a_lab_preset_from_its_config():
    config = dataclasses.replace(TwinConfig.load(MODELS / "twin.toml"), scene_preset="lab", scene_seed=1)
    with Twin(config) as tw:
        expected = load_scene(SCENES, "lab", seed=1)
        assert tw.scene == expected and tw.camera.scene == expected
        first = tw.camera.grab()
        tw.advance(0.05)
        second = tw.camera.grab()
        depth = tw.camera.depth_left()
    w, h = tw.camera.calibration.image_size
    for frame in (first, second):
        assert frame.left.shape == (h, w, 3) and frame.right.shape == (h, w, 3)
    assert (first.index, second.index) == (0, 1) and second.timestamp_s == pytest.approx(0.05)
    # The wall: finite depth about 2 m away where the clean scene has none.
    assert np.all(np.isfinite(depth)) and depth[10, 10] == pytest.approx(2.0, abs=0.1)
    assert not np.array_equal(first.left, second.left), "noise is drawn per frame"
