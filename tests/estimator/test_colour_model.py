"""The arm's colour model (estimator.colour_model): learned from the arm's pixels against the gate's others.

HSV images are built directly (OpenCV ranges: H 0-180, S and V 0-255). Every colour below passes
the configured gate (5, 100, 50)-(25, 255, 255): the model must tell them apart by itself.
"""

import numpy as np

from estimator.colour_model import ArmColourModel

ARM = ((8, 19), (190, 256))  # (hue range, saturation range) of the dye, lit and shaded
WOOD = ((14, 21), (110, 171))
SKIN = ((6, 13), (100, 141))


def patch(colours, shape=(60, 60), seed=0) -> np.ndarray:
    """(H, W, 3) uint8 HSV pixels drawn uniformly from ((h0, h1), (s0, s1)), V 120-250."""
    (h0, h1), (s0, s1) = colours
    rng = np.random.default_rng(seed)
    return np.stack([rng.integers(h0, h1, shape), rng.integers(s0, s1, shape), rng.integers(120, 251, shape)],
                    axis=-1).astype(np.uint8)


def every_colour(colours) -> np.ndarray:
    """(1, N, 3) one pixel of every (hue, saturation) pair in the ranges."""
    (h0, h1), (s0, s1) = colours
    h, s = np.meshgrid(np.arange(h0, h1), np.arange(s0, s1))
    return np.stack([h.ravel(), s.ravel(), np.full(h.size, 200)], axis=-1)[None].astype(np.uint8)


def scene(background_parts, seed=0):
    """An arm patch beside background patches: (hsv, gate, arm mask, background mask)."""
    parts = [patch(ARM, seed=seed)] + [patch(p, seed=seed + 1 + k) for k, p in enumerate(background_parts)]
    hsv = np.concatenate(parts, axis=1)
    arm = np.zeros(hsv.shape[:2], np.uint8)
    arm[:, :60] = 255
    gate = np.full(hsv.shape[:2], 255, np.uint8)
    return hsv, gate, arm, 255 - arm


def kept(model: ArmColourModel, colours) -> np.ndarray:
    pixels = colours if isinstance(colours, np.ndarray) else every_colour(colours)
    return model.apply(pixels, np.full(pixels.shape[:2], 255, np.uint8)) > 0


def test_learns_to_drop_wood_and_skin_and_keeps_every_arm_colour():
    model = ArmColourModel()
    assert not model.active
    for frame in range(3):
        assert model.update(*scene([WOOD, SKIN, WOOD], seed=10 * frame))
    assert model.active
    assert kept(model, ARM).all()
    assert not kept(model, WOOD).any()
    assert not kept(model, SKIN).any()


def test_colours_never_seen_stay_in():
    model = ArmColourModel()
    assert model.update(*scene([WOOD, SKIN]))
    unseen = every_colour(((22, 26), (200, 256)))  # a yellower dye, seen in neither
    assert kept(model, unseen).all()


def test_a_colour_the_arm_shares_with_the_background_stays():
    """Only where the background dominates is a colour dropped: an orange object beside the arm with a
    little of the arm's colour does not take that colour away."""
    hsv, gate, arm, background = scene([WOOD, WOOD])
    hsv[:6, 60:120] = patch(ARM, shape=(6, 60), seed=5)  # a tenth of one background patch has the dye
    model = ArmColourModel()
    assert model.update(hsv, gate, arm, background)
    assert kept(model, ARM).all()
    assert not kept(model, WOOD).any()


def test_an_update_that_would_drop_the_arm_is_refused_and_changes_nothing():
    model = ArmColourModel()
    assert model.update(*scene([WOOD, SKIN]))
    probe = np.concatenate([every_colour(ARM), every_colour(WOOD), every_colour(SKIN)], axis=1)
    before = model.apply(probe, np.full(probe.shape[:2], 255, np.uint8)).copy()
    # A frame whose "background" is a big patch of a few of the arm's own colours (an orange case of the
    # same dye next to it, or a mislabelled frame): learning it would drop far more than 3 % of the arm.
    case = ((11, 14), (208, 232))
    hsv, gate, arm, background = scene([case, case, case])
    assert model.update(hsv, gate, arm, background) is False
    after = model.apply(probe, np.full(probe.shape[:2], 255, np.uint8))
    assert np.array_equal(before, after)
    # and the next ordinary frame is still learned from where it stood
    assert model.update(*scene([WOOD, SKIN], seed=7))
    assert kept(model, ARM).all()


def test_too_few_arm_pixels_teach_nothing():
    model = ArmColourModel()
    hsv, gate, arm, background = scene([WOOD])
    arm[:] = 0
    arm[:5, :5] = 255
    assert model.update(hsv, gate, arm, background) is False
    assert not model.active


def test_reset_forgets():
    model = ArmColourModel()
    model.update(*scene([WOOD, SKIN]))
    assert model.active and not kept(model, WOOD).any()
    model.reset()
    assert not model.active
    assert kept(model, WOOD).all() and kept(model, SKIN).all()


def test_apply_never_adds_to_the_gate():
    model = ArmColourModel()
    model.update(*scene([WOOD, SKIN]))
    hsv = patch(ARM, seed=3)
    gate = np.zeros(hsv.shape[:2], np.uint8)
    gate[::2] = 255
    out = model.apply(hsv, gate)
    assert not np.any(out[1::2]) and np.array_equal(out[::2] > 0, gate[::2] > 0)
