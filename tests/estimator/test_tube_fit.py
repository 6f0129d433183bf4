"""The 3D tube fit (estimator.tube_fit) on edges computed exactly from a known tube.

For an axis point C with unit tangent t and a camera centre O, the tube's silhouette touches the
circle of radius r across the axis at the two points where the line of sight is tangent to it:
with w the part of C - O across t (length d, unit w^), m^ = t x w^,

    P = C - (r^2 / d) w^ +- r sqrt(1 - r^2 / d^2) m^.

Projected into both cameras of an ideal rectified rig (normalised coordinates, x = X / Z, the right
camera B to the right), these are the exact sub-pixel edges the fit is meant to explain.
"""

import dataclasses
import math
import warnings

import numpy as np
import pytest

from estimator import CenterlineEstimator
from estimator.bspline import basis
from estimator.metrics import closest_points_on_polyline
from estimator.tube_fit import (
    CAP_SAMPLES,
    EDGE_SIGMA_PX,
    RADIUS_BINS,
    RADIUS_FLOOR_M,
    SIDE_PIECE,
    EdgeSet,
    _cap_piece,
    _cap_residual_piece,
    _edge_residual,
    _edge_residual_gradient,
    _edge_sides,
    fit_tube,
    fuse_radius,
    misfit_edges,
)
from tests.scenes import Section, backbone, rectified_calibration, render_scene

F, B = 700.0, 0.12  # focal length (px) and baseline (m) of the ideal rectified rig
CENTRES = (np.zeros(3), np.array([B, 0.0, 0.0]))  # left and right camera centres in the left frame
NO_ENDS = {"base": np.full((2, 2), np.nan), "tip": np.full((2, 2), np.nan)}


def silhouette_points(C: np.ndarray, t: np.ndarray, r: float, O: np.ndarray) -> np.ndarray:
    """(2, 3) the two silhouette points of the tube at axis point C (tangent t) seen from O."""
    w = C - O
    across = w - (w @ t) * t
    d = np.linalg.norm(across)
    w_hat = across / d
    m_hat = np.cross(t, w_hat)
    foot = C - (r * r / d) * w_hat
    spread = r * np.sqrt(1.0 - r * r / (d * d)) * m_hat
    return np.array([foot + spread, foot - spread])


def tube_edges(axis: np.ndarray, radius, step_m: float = 0.008, noise_px: float = 0.0, seed: int = 0) -> EdgeSet:
    """Exact silhouette edges of a tube along ``axis`` (dense (N, 3), left frame) in both images, one
    chord every ``step_m`` of arc length, with Gaussian noise of ``noise_px``."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(axis, axis=0), axis=1))])
    tangents = np.gradient(axis, s, axis=0)
    picks = np.arange(step_m, s[-1], step_m)
    radii = np.broadcast_to(np.interp(picks, s, np.broadcast_to(radius, s.shape)), picks.shape)
    side, xy, centre = [], [], []
    for k, O in enumerate(CENTRES):
        for sp, r in zip(picks, radii, strict=True):
            C = np.array([np.interp(sp, s, axis[:, c]) for c in range(3)])
            t = np.array([np.interp(sp, s, tangents[:, c]) for c in range(3)])
            for P in silhouette_points(C, t / np.linalg.norm(t), r, O):
                xy.append((P - O)[:2] / (P - O)[2])
                centre.append((C - O)[:2] / (C - O)[2])
                side.append(k)
    xy = np.array(xy) + np.random.default_rng(seed).normal(0.0, noise_px / F, (len(xy), 2))
    return EdgeSet(np.array(side), xy, np.array(centre), np.ones(len(side)))


def axis_ends(axis: np.ndarray) -> dict[str, np.ndarray]:
    """Both ends of the axis in both images (ends seen as points: fit with ``cap=0``)."""
    return {name: np.array([(p - O)[:2] / (p - O)[2] for O in CENTRES])
            for name, p in (("base", axis[0]), ("tip", axis[-1]))}


def distances_mm(fit, axis: np.ndarray, samples: int = 300) -> np.ndarray:
    """Distance of each fitted axis point to the true axis, millimetres."""
    points = fit.points(np.linspace(0.0, 1.0, samples))
    closest, _ = closest_points_on_polyline(points, axis)
    return np.linalg.norm(points - closest, axis=1) * 1e3


def fit(edges, axis, initial, radius=0.025, sigma=0.004, ends=None, **kwargs):
    return fit_tube(edges, axis_ends(axis) if ends is None else ends, initial, np.full(RADIUS_BINS, radius),
                    np.full(RADIUS_BINS, sigma), focal_px=F, baseline_m=B, cap=0.0, **kwargs)


@pytest.fixture(scope="module")
def bent_tube():
    """A 600 mm three-section bend (in the image, towards the camera, twisted) a metre away, radius 22 mm,
    and a start 15 mm too far with lateral wiggles (a rough triangulated estimate)."""
    axis, _ = backbone([Section(0.2, 1.5, 0.0), Section(0.2, 2.0, 1.2), Section(0.2, 1.5, 0.6)], (0.0, -0.3, 1.0),
                       n=600)
    t = np.linspace(0.0, 1.0, len(axis))
    initial = axis + np.column_stack([0.006 * np.sin(3 * t), 0.004 * np.cos(2 * t), 0.015 + 0.01 * np.sin(4 * t)])
    return axis, initial


def test_edge_residual_is_the_distance_to_the_silhouette_line():
    C, t, r = np.array([0.05, 0.02, 0.9]), np.array([0.3, 0.9, -0.3]), 0.025
    t /= np.linalg.norm(t)
    for O in CENTRES:
        Cc = C - O
        near = [(P - O)[:2] / (P - O)[2] for P in silhouette_points(C, t, r, O)]
        further = [(P - O)[:2] / (P - O)[2] for P in silhouette_points(C + 0.1 * t, t, r, O)]
        for k in range(2):
            on_line = [min(abs(_edge_residual(Cc, t, r, *near[k], sign)) for sign in (1.0, -1.0)),
                       min(abs(_edge_residual(Cc, t, r, *further[k], sign)) for sign in (1.0, -1.0))]
            assert max(on_line) * F < 1e-6  # both points of each silhouette line lie on one of the two lines
            direction = (further[k] - near[k]) / np.linalg.norm(further[k] - near[k])
            normal = np.array([-direction[1], direction[0]])
            moved = near[k] + 0.7 / F * normal  # 0.7 px off the line, across it
            assert min(abs(_edge_residual(Cc, t, r, *moved, sign)) for sign in (1.0, -1.0)) * F == pytest.approx(
                0.7, abs=1e-3)
        # the two edges belong to different lines: each vanishes for one sign only
        signs = [[abs(_edge_residual(Cc, t, r, *near[k], sign)) * F < 1e-6 for sign in (1.0, -1.0)]
                 for k in range(2)]
        assert signs[0] != signs[1] and all(sum(s) == 1 for s in signs)


def test_edge_residual_gradient_matches_central_differences():
    """The fit's exact partials of an edge residual in C, D and r, against central differences over
    random tubes, sides and image points (a sign or a chain-rule term wrong shows at once)."""
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(300):
        C = np.array([*rng.normal(0.0, 0.3, 2), rng.uniform(0.5, 1.5)])
        D, r = rng.normal(0.0, 1.0, 3), rng.uniform(0.005, 0.03)
        x, y = rng.normal(0.0, 0.3, 2)
        sign = float(rng.choice([-1.0, 1.0]))
        gC, gD = np.empty(3), np.empty(3)
        res, gr = _edge_residual_gradient(C, D, r, x, y, sign, gC, gD)
        assert res == _edge_residual(C, D, r, x, y, sign)
        h = 1e-7
        numeric = []
        for which in range(7):
            step = np.zeros(7)
            step[which] = h
            up = _edge_residual(C + step[:3], D + step[3:6], r + step[6], x, y, sign)
            down = _edge_residual(C - step[:3], D - step[3:6], r - step[6], x, y, sign)
            numeric.append((up - down) / (2.0 * h))
        exact = np.concatenate([gC, gD, [gr]])
        assert np.allclose(exact, numeric, rtol=1e-5, atol=1e-6 * np.max(np.abs(numeric)))
        checked += 1
    assert checked == 300


def _beyond_the_end(C, D, x, y, outward):
    """Whether the image point lies beyond the image of the axis's end, out of the tube."""
    tangent = np.array([D[0] * C[2] - C[0] * D[2], D[1] * C[2] - C[1] * D[2]]) * outward
    return float((np.array([x, y]) - C[:2] / C[2]) @ tangent) > 0.0


@pytest.mark.parametrize("outward", [1.0, -1.0])
def test_cap_residual_is_its_nearest_piece(outward):
    """An end's outline residual is the distance to the nearest of its pieces (two silhouette lines,
    the rim's segments; beyond the end, the rim's alone), and the piece it names gives that distance
    again (its derivatives are that piece's)."""
    rng = np.random.default_rng(4)
    C, D, r = np.array([0.05, 0.02, 0.9]), np.array([0.8, 0.3, -0.2]), 0.02
    for _ in range(100):
        x, y = C[0] / C[2] + rng.normal(0.0, 0.03), C[1] / C[2] + rng.normal(0.0, 0.03)
        best, piece = _cap_residual_piece(C, D, r, x, y, outward)
        sides = () if _beyond_the_end(C, D, x, y, outward) else (SIDE_PIECE, SIDE_PIECE - 1)
        pieces = [_cap_piece(C, D, r, x, y, k) for k in (*sides, *range(CAP_SAMPLES))]
        assert best == pytest.approx(min(pieces), abs=1e-15)
        assert _cap_piece(C, D, r, x, y, piece) == pytest.approx(best, abs=1e-15)


@pytest.mark.parametrize("outward", [1.0, -1.0])
def test_a_silhouette_line_does_not_run_on_past_the_end(outward):
    """A point on a silhouette line's continuation beyond the end is as far off as the rim is from it:
    taken as on the line, the far arc of a cap seen face-on ended a tube 13 mm short."""
    C, D, r = np.array([0.05, 0.02, 0.9]), np.array([0.0, 1.0, 0.0]), 0.02  # the axis runs down the image
    side_x = (C[0] + r) / C[2]  # a silhouette line, seen square on
    inside, beyond = C[1] / C[2] - 0.03 * outward, C[1] / C[2] + 0.03 * outward
    assert _cap_residual_piece(C, D, r, side_x, inside, outward)[0] == pytest.approx(0.0, abs=1e-4)
    far, piece = _cap_residual_piece(C, D, r, side_x, beyond, outward)
    assert piece >= 0 and far > 0.02  # the rim's, over a third of the tube's width away


def test_fit_recovers_axis_and_radius_from_a_rough_start(bent_tube):
    """0.05 px edge noise (measured: 0.20-0.25 mm RMS over seeds; noiseless 0.06 mm)."""
    axis, initial = bent_tube
    assert np.sqrt(np.mean(distances_mm(_initial_fit(initial), axis) ** 2)) > 10.0  # the start is well off
    result = fit(tube_edges(axis, 0.022, noise_px=0.05), axis, initial)
    d = distances_mm(result, axis)
    assert np.sqrt(np.mean(d**2)) <= 0.3, d.max()
    assert np.abs(result.radius_bins - 0.022).max() <= 0.2e-3
    assert result.inliers > 0.99 and result.rms_px < 0.1


def _initial_fit(initial):
    """The start as a curve (a fit with no iterations)."""
    class Start:
        def points(self, us):
            arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(initial, axis=0), axis=1))])
            return np.column_stack([np.interp(us * arc[-1], arc, initial[:, k]) for k in range(3)])
    return Start()


def test_noiseless_edges_give_the_axis_to_a_tenth_of_a_millimetre(bent_tube):
    axis, initial = bent_tube
    result = fit(tube_edges(axis, 0.022), axis, initial)
    assert distances_mm(result, axis).max() <= 0.25
    assert np.abs(result.radius_bins - 0.022).max() <= 0.05e-3


def test_radius_profile_per_bin():
    """Sections of different radii (26, 23, 20 mm): each bin takes its own."""
    axis, _ = backbone([Section(0.2, 1.0, 0.0), Section(0.2, 1.5, 0.8), Section(0.2, 1.0, 0.3)], (0.0, -0.3, 1.0),
                       n=600)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(axis, axis=0), axis=1))])
    radius = np.where(s < 0.2, 0.026, np.where(s < 0.4, 0.023, 0.020))
    result = fit(tube_edges(axis, radius, noise_px=0.05), axis, axis + [0.0, 0.0, 0.01])
    centre = (np.arange(RADIUS_BINS) + 0.5) / RADIUS_BINS * s[-1]
    clear = np.min(np.abs(centre[:, None] - np.array([0.2, 0.4])[None]), axis=1) > 0.04  # bins away from the steps
    expected = np.where(centre < 0.2, 0.026, np.where(centre < 0.4, 0.023, 0.020))
    assert np.abs(result.radius_bins - expected)[clear].max() <= 0.3e-3


@pytest.mark.parametrize("x_m", [0.0, 0.05934, -0.05])
def test_straight_tube_on_the_rectified_rig_has_no_depth_bias(x_m):
    """Issue 11's case from exact edges: a straight tube 0.92 m away (no quantisation to hide in)."""
    axis, _ = backbone([Section(0.685, 0.0, 0.0)], (x_m, -0.34, 0.92), n=300)
    result = fit(tube_edges(axis, 0.025, noise_px=0.05), axis, axis + [0.002, 0.0, -0.012])
    points = result.points(np.linspace(0.05, 0.95, 40))
    assert abs(np.mean(points[:, 2] - 0.92)) <= 0.2e-3


def _rows_curve(bulge_m: float = 0.0) -> np.ndarray:
    """Down, a quarter turn, 300 mm along the image rows in the plane through both camera centres
    (every point of it on the same row in both images), a quarter turn, down again. ``bulge_m``
    moves the middle stretch towards the camera (0 at its ends, all of it half way)."""
    t = np.linspace(0.0, 1.0, 200, endpoint=False)
    a1 = np.linspace(np.pi, np.pi / 2, 100, endpoint=False)
    a2 = np.linspace(np.pi / 2, 0.0, 100, endpoint=False)
    m = np.linspace(0.0, 1.0, 300, endpoint=False)
    d = np.linspace(0.0, 1.0, 150)
    return np.vstack([
        np.column_stack([np.full_like(t, -0.2), -0.35 + 0.25 * t, np.ones_like(t)]),
        np.column_stack([-0.1 + 0.1 * np.cos(a1), -0.1 + 0.1 * np.sin(a1), np.ones_like(a1)]),
        np.column_stack([-0.1 + 0.3 * m, np.zeros_like(m), 1.0 - bulge_m * np.sin(np.pi * m) ** 2]),
        np.column_stack([0.2 + 0.1 * np.cos(a2), 0.1 - 0.1 * np.sin(a2), np.ones_like(a2)]),
        np.column_stack([np.full_like(d, 0.3), 0.1 + 0.2 * d, np.ones_like(d)]),
    ])


def _middle_depth_error_mm(result) -> float:
    points = result.points(np.linspace(0.0, 1.0, 600))
    middle = np.argmin(np.abs(points[:, 0] - 0.05) + 10.0 * np.abs(points[:, 1]))
    return float((points[middle, 2] - 1.0) * 1e3)


def test_depth_along_the_rows_comes_from_the_apparent_width():
    """Where the tube runs along the rows, disparity says nothing: the start's 20 mm bulge there
    (measured with issue 11's disparity profile: 16-22 mm) is removed by the width 2 r f / Z, if r is known."""
    axis = _rows_curve()
    edges = tube_edges(axis, 0.025, noise_px=0.05)
    known = fit(edges, axis, _rows_curve(0.02), radius=0.025, sigma=1e-4)
    assert abs(_middle_depth_error_mm(known)) <= 1.5  # measured 0.9 mm
    assert known.inliers > 0.99


def test_a_wrong_radius_moves_that_depth_and_shows_in_the_residuals():
    """The coupling: a radius held 10 % too large puts the stretch along the rows 10 % too far (100 mm),
    and the edges elsewhere no longer fit (what the pipeline checks before it trusts a frame)."""
    axis = _rows_curve()
    edges = tube_edges(axis, 0.025, noise_px=0.05)
    for wrong, sign in ((0.0275, 1.0), (0.0225, -1.0)):
        result = fit(edges, axis, _rows_curve(0.02), radius=wrong, sigma=1e-4)
        assert sign * _middle_depth_error_mm(result) > 30.0
        assert result.inliers < 0.8 or result.rms_px > 0.6


def test_robust_loss_reads_each_residual_in_units_of_its_own_sigma(bent_tube):
    """A blurred edge's place is less certain (a larger sigma): 2 px off with a sigma of 1.4 px is as
    ordinary as 0.5 px off with 0.35 px, and must count alike. A threshold in pixels, the same for
    every edge, treated the blurred one as half an outlier and let the smoothness prior outweigh the
    blurred edges round tight late-ramp bends (the twin's dim and blur scenes: tips 10-20 mm off)."""
    axis, _ = bent_tube
    edges = tube_edges(axis, 0.022)
    outward = edges.xy - edges.centre
    outward /= np.linalg.norm(outward, axis=1, keepdims=True)

    def cost_off(offset_px: float, sigma_px: float) -> float:
        moved = EdgeSet(edges.side, edges.xy + outward * offset_px / F, edges.centre,
                        np.full(len(edges.side), EDGE_SIGMA_PX / sigma_px))
        return fit(moved, axis, axis, radius=0.022, iterations=0).cost  # the cost where the fit starts

    # Each against the same edges unmoved: the smoothness prior holds firmer where the edges count less
    # (SMOOTH_BLUR_POWER), so the exact tube's own cost differs between the two weightings.
    sharp = cost_off(0.5, EDGE_SIGMA_PX) - cost_off(0.0, EDGE_SIGMA_PX)
    blurred = cost_off(2.0, 4.0 * EDGE_SIGMA_PX) - cost_off(0.0, 4.0 * EDGE_SIGMA_PX)
    assert sharp > 1.0 * len(edges.side)  # about (0.5 / 0.35)^2 per edge
    assert blurred == pytest.approx(sharp, rel=0.01)


def test_a_stretch_of_one_silhouette_line_the_tube_does_not_follow_is_found(bent_tube):
    """An occluder along the tube's side moves one image's edges on one line inwards, evenly: 4 px over
    120 mm of arc is found (and only there); the same edges with noise alone are not. (The fit takes
    up part of such a shift: 2 px leave a mean residual of 0.8 px, below the 1.4 px flagged.)"""
    axis, initial = bent_tube
    edges = tube_edges(axis, 0.022, noise_px=0.1, seed=3)
    clean = fit(edges, axis, initial, radius=0.022)
    assert not misfit_edges(clean, edges, B).any()
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(axis, axis=0), axis=1))])
    edge_s = np.interp(clean.edge_u, np.linspace(0.0, 1.0, len(s)), s)
    lines = _edge_sides(clean.knots, clean.control, B, edges.side.astype(np.int64), clean.edge_u, edges.xy,
                        edges.centre)
    hidden = (edges.side == 0) & (lines > 0) & (edge_s > 0.28) & (edge_s < 0.40)
    inward = edges.centre - edges.xy
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    moved = EdgeSet(edges.side, edges.xy + hidden[:, None] * inward * 4.0 / F, edges.centre, edges.weight)
    spoilt = fit(moved, axis, clean.points(np.linspace(0.0, 1.0, 200)), radius=0.022)
    found = misfit_edges(spoilt, moved, B)
    assert found[hidden].mean() >= 0.5
    width = 0.044  # nothing a tube width away (a flagged window grows out to its neighbours, MISFIT_GROW_SIGMAS)
    assert not found[~hidden & ((edge_s < 0.28 - width) | (edge_s > 0.40 + width))].any()


def test_a_blurred_occluder_along_one_side_is_found_over_its_whole_stretch(bent_tube):
    """A dark cable lying along the tube is blurred against it: its edges' steps are wide, so they weigh
    about a third and 4 px inwards read under 4 sigmas. Found by their mean in pixels, and over the whole
    stretch, its fading ends (1.5 px) and the few edges left between it and a gap of the line included:
    left in, they held an independent scene's tube 16-39 mm off in depth (seed 76, occluded)."""
    axis, initial = bent_tube
    edges = tube_edges(axis, 0.022, noise_px=0.1, seed=3)
    clean = fit(edges, axis, initial, radius=0.022)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(axis, axis=0), axis=1))])
    edge_s = np.interp(clean.edge_u, np.linspace(0.0, 1.0, len(s)), s)
    lines = _edge_sides(clean.knots, clean.control, B, edges.side.astype(np.int64), clean.edge_u, edges.xy,
                        edges.centre)
    line = (edges.side == 0) & (lines > 0)
    cable = line & (edge_s > 0.30) & (edge_s < 0.42)
    fading = line & (((edge_s > 0.28) & (edge_s <= 0.30)) | ((edge_s >= 0.42) & (edge_s < 0.45)))
    gap = line & (edge_s > 0.48) & (edge_s < 0.53)  # the line unseen here (a cable crossing it) ...
    stub = line & (edge_s >= 0.45) & (edge_s <= 0.48)  # ... and three edges between it and the cable
    inward = edges.centre - edges.xy
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    shift = np.where(cable, 4.0, np.where(fading, 1.5, 0.0)) / F
    weight = np.where(cable | fading, 0.3, 1.0)
    kept = ~gap
    moved = EdgeSet(edges.side[kept], (edges.xy + shift[:, None] * inward)[kept], edges.centre[kept], weight[kept])
    spoilt = fit(moved, axis, clean.points(np.linspace(0.0, 1.0, 200)), radius=0.022)
    found = misfit_edges(spoilt, moved, B)
    assert found[cable[kept]].all() and found[fading[kept]].all() and found[stub[kept]].all()
    assert not found[(~line[kept]) | (edge_s[kept] < 0.22) | (edge_s[kept] > 0.60)].any()


HUBER_DRIFT = pytest.mark.xfail(
    strict=True, reason="estimator/tube_fit.py: 10 % of edges pushed 3-15 px outwards still move the fitted axis "
                        "by up to 5.2 mm (7.2 under Huber alone) after the switch to a redescending loss: the "
                        "first two Huber iterations settle part of the pull in")


@HUBER_DRIFT
def test_gross_outlier_edges_do_not_move_the_fit(bent_tube):
    axis, initial = bent_tube
    edges = tube_edges(axis, 0.022, noise_px=0.05, seed=1)
    clean = fit(edges, axis, initial)
    rng = np.random.default_rng(2)
    bad = rng.choice(len(edges.side), len(edges.side) // 10, replace=False)
    outward = edges.xy - edges.centre
    outward /= np.linalg.norm(outward, axis=1, keepdims=True)
    xy = edges.xy.copy()
    xy[bad] += outward[bad] * rng.uniform(3.0, 15.0, len(bad))[:, None] / F  # a distractor's or shadow's edge
    spoilt = fit(EdgeSet(edges.side, xy, edges.centre, edges.weight), axis, initial)
    points = spoilt.points(np.linspace(0.0, 1.0, 300))
    closest, _ = closest_points_on_polyline(points, clean.points(np.linspace(0.0, 1.0, 600)))
    assert np.linalg.norm(points - closest, axis=1).max() * 1e3 <= 0.5


def test_point_std_leaves_out_sliding_along_the_axis(bent_tube):
    """Without end observations nothing holds the axis along itself (the fit's own covariance there is
    tens of millimetres), but every point is well placed across it."""
    axis, initial = bent_tube
    result = fit(tube_edges(axis, 0.022, noise_px=0.05), axis, initial, ends=NO_ENDS)
    us = np.linspace(0.1, 0.9, 9)
    across = result.point_std_m(us)
    assert np.all(np.isfinite(across)) and across.max() <= 3e-3
    count = len(result.control)
    full = []
    for u in us:
        first, values, _ = basis(result.knots, count, float(u))
        block = result.covariance[3 * first:3 * (first + 4), 3 * first:3 * (first + 4)]
        W = np.kron(values[None, :], np.eye(3))
        full.append(np.sqrt(np.linalg.eigvalsh(W @ block @ W.T)[-1]))
    assert np.min(np.array(full) / across) > 10.0
    # and the points themselves are where the std says, across the axis
    assert np.percentile(distances_mm(result, axis, 200)[20:180], 95) <= 3.0 * across.max() * 1e3


def test_a_fit_with_no_edge_within_a_pixel_knows_nothing(bent_tube):
    """Started three times too thick and not allowed to move, no edge lies within a pixel of the tube: its RMS is
    infinite and so is every standard deviation (not NaN, and without numpy's warnings, which a
    study printed among its results)."""
    axis, _ = bent_tube
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = fit(tube_edges(axis, 0.022), axis, axis, radius=0.066, ends=NO_ENDS, iterations=0)
    assert result.inliers == 0.0 and result.rms_px == math.inf
    assert np.all(np.isinf(result.point_std_m(np.linspace(0.0, 1.0, 5))))
    assert np.all(np.isinf(result.radius_std))


def _fused(template, frames, std_m: float, noise_m: float = 0.0, seed: int = 3):
    """Run ``fuse_radius`` over ``frames`` (profiles (RADIUS_BINS,)) measured with ``std_m`` (the last two
    bins badly, 2 mm: never fused), from the configured 25 mm +- 4 mm; checks the floor on the way."""
    std = np.full(RADIUS_BINS, std_m)
    std[-2:] = 2e-3
    rng = np.random.default_rng(seed)
    mean, info = np.full(RADIUS_BINS, 0.025), np.full(RADIUS_BINS, 1.0 / 0.004**2)
    for profile in frames:
        measured = dataclasses.replace(template, radius_bins=profile + rng.normal(0.0, noise_m, RADIUS_BINS),
                                       radius_std=std)
        mean, info = fuse_radius(mean, info, measured)
        assert np.all(info <= 1.0 / RADIUS_FLOOR_M**2 * (1 + 1e-9))
    return mean


PROFILE = np.where(np.arange(RADIUS_BINS) < RADIUS_BINS // 2, 0.024, 0.021)


@pytest.fixture(scope="module")
def template(bent_tube):
    axis, initial = bent_tube
    return fit(tube_edges(axis, 0.022), axis, initial)


def test_fuse_radius_takes_the_measured_profile_and_keeps_its_floor(template):
    mean = _fused(template, [PROFILE] * 10, 0.15e-3)
    assert np.abs(mean - PROFILE)[:-2].max() <= 0.01e-3
    assert np.all(mean[-2:] == 0.025)  # badly measured bins keep the configured radius
    # The floor keeps it following: the radius changes (pressure), and a few frames later so has the profile.
    mean = _fused(template, [PROFILE] * 60 + [PROFILE + 0.002] * 5, 0.15e-3)
    assert np.abs(mean - PROFILE - 0.002)[:-2].max() <= 0.05e-3


def test_fuse_radius_averages_noisy_frames(template):
    """60 frames, each bin measured with its stated 0.15 mm noise: the fused profile is better than one frame."""
    mean = _fused(template, [PROFILE] * 60, 0.15e-3, noise_m=0.15e-3)
    assert np.abs(mean - PROFILE)[:-2].max() <= 0.1e-3


@pytest.fixture(scope="module")
def straight_scenes():
    """Issue 11's straight tube 0.92 m from an ideal rectified rig, rendered by tests/scenes.py at
    several lateral places (the chord midpoints' sub-pixel phases differ), as a 20-sided prism (the
    scenes' usual tube) and as a round one (96 sides)."""
    calib = rectified_calibration()
    scenes = {}
    for sides in (20, 96):
        for k, x in enumerate((0.05934, 0.0, 0.0123, -0.05)):
            points, _ = backbone([Section(0.685, 0.0, 0.0)], (x, -0.34, 0.92))
            scenes[sides, x] = render_scene(calib, points, (), seed=k, sides=sides)
    return scenes


def _depth_bias_mm(scene) -> float:
    result = CenterlineEstimator(scene.calibration).estimate(scene.left, scene.right)
    assert result.valid, result.reason
    closest, _ = closest_points_on_polyline(result.points, scene.gt_points)
    return float(np.mean(result.points[:, 2] - closest[:, 2]) * 1e3)


def test_straight_tube_through_the_estimator_lost_the_half_pixel_bias(straight_scenes):
    """Issue 11 measured 7.0 mm too close (chord midpoints on half pixels): that is gone, also on the
    20-sided prism, whose faces make it look up to 1.2 % narrower (measured +0.2 to +1.5 mm)."""
    biases = {key: _depth_bias_mm(scene) for key, scene in straight_scenes.items()}
    assert max(abs(b) for b in biases.values()) <= 2.0, biases


def test_straight_round_tube_through_the_estimator_depth_bias_within_half_a_millimetre(straight_scenes):
    """Issue 11's target on a round tube (measured -0.06 to +0.08 mm)."""
    biases = {x: _depth_bias_mm(scene) for (sides, x), scene in straight_scenes.items() if sides == 96}
    assert max(abs(b) for b in biases.values()) <= 0.5, biases
