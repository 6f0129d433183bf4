"""A 3D tube fitted to the silhouette edges of both images: depth where disparity alone is weak.

Triangulating two 2D centerlines row by row fails where the arm runs along the image rows: the
rows no longer say which left point goes with which right one, and at 1.3 m one pixel of
disparity is 2 cm of depth. A tube constrains more than its centerline: each of its two
silhouette edges, in each image, is a line in which the tube is tangent to a plane through that
camera's centre. Fitted together, the four edges fix the axis where the rows do (the two eyes'
mid-planes cross there), and where they do not, the apparent width (2 r over the distance) does.

Model (rectified left camera frame, metres): a clamped cubic B-spline axis C(u), u in [0, 1] from
the first visible point at the base to the tip, carrying a tube whose radius is constant within
each of a few bins of arc length (an arm's sections have different radii, with steps between
them). Residuals, in pixels:

- every sub-pixel edge point: its distance to the tangent plane's image line on its side, in
  the image it was found in (a point-to-line distance, so it does not care where along the
  tube it lies);
- the two ends along the curve: the base at the first visible point, the tip at the silhouette's
  end less the flat end cap's projected overshoot, r |t . s| / Z;
- a weak third-difference prior on the control points (bridges occluded stretches smoothly, and
  costs nothing for a bend of constant curvature), and each radius bin's prior (the radius
  measured in earlier frames, or the configured one).

Gauss-Newton (Levenberg-Marquardt when a step fails) with analytic basis functions, exact
compiled partials of the edge residuals (nearly all of them) and compiled forward differences of
the few end and tip-outline residuals; Huber weights make occluded or
mis-segmented edges count less. The normal matrix's inverse gives each output point's standard
deviation, which, with the residuals, decides whether the frame is trusted.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numba
import numpy as np

from estimator.bspline import DEGREE, basis_into, basis_workspace, clamped_knots, evaluate_many, fit_control_points

CONTROL_POINTS = 16
RADIUS_BINS = 24
EDGE_SIGMA_PX = 0.35  # noise of one sub-pixel edge
HUBER_PX = 1.0  # a focused edge's residual beyond this (pixels; others scaled by their sigma) counts linearly
SMOOTH_BLUR_POWER = 0.5  # see fit_tube: the prior's weight grows by (median edge weight) ** -this
SMOOTH_SIGMA_M = 0.015  # third difference of the control points that costs as much as one pixel of edge
END_SIGMA_PX = 2.0  # the ends are found like the edges, but on a cap or against the mount's rim
END_STIFFNESS = 4.0
CAP_SAMPLES = 32  # points on the rim of the tube's flat end, for its outline
CAP_SIGMA_PX = 0.7  # an outline point around the tip: an edge, but on a curved and differently lit cap
MIN_CAP_POINTS = 4  # per image; with fewer the tip keeps its single end point
OUTLINE_ITERATIONS = 3
BASE_RESTART_PX = 0.3  # a free base's outline missed by more (RMS, either image) restarts its outline stage
BASE_RESTART_POINTS = 5  # control points (tapering) taken back from the initial curve by that restart
END_SIDES = (0, 1)
RADIUS_FLOOR_M = 3e-5  # the learned radius is never held more certain than this
BASE_SIGMA_M = 0.001  # the mount does not move: a learned base point holds to a millimetre
BASE_DIRECTION_SIGMA = 0.02  # and the arm leaves it in the same direction (radians)
ITERATIONS = 5
REDESCEND_AFTER = 2  # iterations under Huber (robust while far off) before gross outliers stop counting
CONVERGED = 5e-3  # stop once an iteration lowers the cost by less than this fraction
REASSIGN_AT = (2, 4)  # iterations after which every edge is re-attached to the nearest point of the axis
CURVE_SAMPLES = 160
CONNECTOR_SIGMA_PX = 0.2  # a connector's centre along the tube, from the dip of the arm's colour across it
MISFIT_WINDOW = 8  # consecutive edges of one silhouette line (about a tube width of arc)
MISFIT_SIGMAS = 4.0  # their mean residual beyond this many sigmas: that stretch of line is not the tube's
# An occluder's edge that lies along the tube is often blurred against it (a dark cable's shading):
# its steps are wide, so its edges weigh little and a stretch of them 3.5 px off measured under 4 sigmas
# while it held a tube 39 mm off in depth (benchmarks/unseen_scenes.py, seed 76, occluded). A window
# whose mean lies beyond MISFIT_PX pixels (and MISFIT_GROW_SIGMAS) is flagged too, and a flagged window
# grows along its line while its neighbours' means stay beyond MISFIT_GROW_SIGMAS on its side: the
# occluder's stretch fades into the tube's edges, and what was left of it still held the tube 16 mm off.
MISFIT_PX = 1.5
MISFIT_GROW_SIGMAS = 2.0


@dataclass(frozen=True, eq=False)
class EdgeSet:
    """Sub-pixel edge points of both images, in normalised rectified coordinates.

    Attributes:
        side: (K,) 0 left image, 1 right image.
        xy: (K, 2) the edge point, (u - cx) / f, (v - cy) / f.
        centre: (K, 2) the chord's centre it belongs to (to attach it to the axis).
        weight: (K,) prior weight of each edge (1 for a clean edge).
    """

    side: np.ndarray
    xy: np.ndarray
    centre: np.ndarray
    weight: np.ndarray

    def subset(self, keep: np.ndarray) -> EdgeSet:
        """The edges where ``keep`` (a (K,) boolean mask) is True."""
        return EdgeSet(self.side[keep], self.xy[keep], self.centre[keep], self.weight[keep])


@dataclass(frozen=True, eq=False)
class TubeFit:
    """The fitted tube.

    Attributes:
        knots, control: the axis B-spline (rectified left frame, metres).
        radius_bins: (RADIUS_BINS,) radius in each bin of arc length (equal bins from base to tip), metres.
        radius_std: (RADIUS_BINS,) their posterior standard deviations, metres.
        covariance: the parameters' covariance (control points then radius bins).
        rms_px: RMS of the edge residuals within ``HUBER_PX`` pixels (pixels).
        inliers: share of edges within ``HUBER_PX`` pixels of the fitted silhouette (not scaled by their sigma).
        edge_u: (K,) where each edge is attached on the axis.
        edge_residual_px: (K,) each edge's final residual.
        tip_residual_px: image (0 left, 1 right) -> the final residuals of what located the tip in
            that image: its outline's points, or its single end point (absent where unseen).
        base_residual_px: the same for the base.
        cost: the final robust cost (residuals and priors): of two fits to the same observations
            from different starts, the lower one is the better.
        connector_u: (C,) where each connector pair the fit was given lies on the final axis, in
            the pairs' order (empty without connectors).
    """

    knots: np.ndarray
    control: np.ndarray
    radius_bins: np.ndarray
    radius_std: np.ndarray
    covariance: np.ndarray
    rms_px: float
    inliers: float
    edge_u: np.ndarray
    edge_residual_px: np.ndarray
    tip_residual_px: dict = field(default_factory=dict)
    cost: float = math.inf
    connector_u: np.ndarray = field(default_factory=lambda: np.zeros(0))
    base_residual_px: dict = field(default_factory=dict)

    def points(self, us: np.ndarray) -> np.ndarray:
        return evaluate_many(self.knots, self.control, np.asarray(us, np.float64))[0]

    def point_std_m(self, us: np.ndarray) -> np.ndarray:
        """(M,) standard deviation of each axis point across the axis, along its least certain
        direction, metres. Sliding along the axis is left out: it moves no point off the curve."""
        known = self._point_covariances(us)
        if known is None:
            return np.full(len(us), math.inf)
        S, tangents = known
        across = np.eye(3)[None] - tangents[:, :, None] * tangents[:, None, :]
        S = across @ S @ across
        return np.sqrt(np.maximum(np.linalg.eigvalsh(S)[:, -1], 0.0))

    def along_std_m(self, us: np.ndarray) -> np.ndarray:
        """(M,) standard deviation of each axis point along the axis, metres: where the tip ends.
        Large where the tip points along a line of sight (its end's image barely moves as it slides)."""
        known = self._point_covariances(us)
        if known is None:
            return np.full(len(us), math.inf)
        S, tangents = known
        return np.sqrt(np.maximum(np.einsum("mi,mij,mj->m", tangents, S, tangents), 0.0))

    def _point_covariances(self, us: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(M, 3, 3) covariance of each axis point and (M, 3) its unit tangent; None for a fit that
        knows nothing (no edge within a pixel: its covariance is infinite)."""
        if not np.all(np.isfinite(self.covariance)):
            return None
        S, tangents = _point_covariances(self.knots, self.control, self.covariance, np.asarray(us, np.float64))
        tangents /= np.maximum(np.linalg.norm(tangents, axis=1, keepdims=True), 1e-12)
        return S, tangents


@numba.njit(cache=True, nogil=True)
def _point_covariances(knots, control, covariance, us):
    """(M, 3, 3) covariance of the axis point at each u (a weighted sum of four control points, so
    a weighted sum of their covariance blocks) and (M, 3) the axis's derivative there."""
    count = control.shape[0]
    m = us.shape[0]
    S = np.zeros((m, 3, 3))
    tangents = np.zeros((m, 3))
    work, values, deriv = basis_workspace()
    for i in range(m):
        first = basis_into(knots, count, min(max(us[i], 0.0), 1.0), work, values, deriv)
        for a in range(DEGREE + 1):
            for c in range(3):
                tangents[i, c] += deriv[a] * control[first + a, c]
            for b in range(DEGREE + 1):
                w = values[a] * values[b]
                for c in range(3):
                    for d in range(3):
                        S[i, c, d] += w * covariance[3 * (first + a) + c, 3 * (first + b) + d]
    return S, tangents


# --- residuals --------------------------------------------------------------------------------


_NO_VECTOR = (0.0, 0.0, 0.0)

# The per-edge steps (``_tangent_plane``, ``_edge_residual``, ``_axis_at``) are inlined where they are
# called: left as calls, the fit's loop over a frame's ~500 edges spent about half its time in them
# (cost alone 105 -> 52 us, with the normal equations 205 -> 146 us; the same numbers bit for bit).


@numba.njit(cache=True, nogil=True, inline="always")
def _tangent_plane(C, D, r, sign):
    """The plane through the camera centre that touches the tube on side ``sign``, and the steps to it.

    Its normal is n = sqrt(1 - rho^2) m - sign rho e, with m the normal of the plane holding the
    axis and the centre, e the unit perpendicular from the centre's foot on the axis line to C, and
    rho = r / d, d the distance from the centre to the axis line.

    Returns:
        (ok, |D|, unit tangent T, |C x T|, m, C . T, d, e, rho, sqrt(1 - rho^2), n); ok False where
        the axis is degenerate or the centre lies within the tube.
    """
    tn = math.sqrt(D[0] * D[0] + D[1] * D[1] + D[2] * D[2])
    if tn < 1e-12:
        return False, tn, _NO_VECTOR, 0.0, _NO_VECTOR, 0.0, 0.0, _NO_VECTOR, 0.0, 0.0, _NO_VECTOR
    T0, T1, T2 = D[0] / tn, D[1] / tn, D[2] / tn
    M0 = C[1] * T2 - C[2] * T1
    M1 = C[2] * T0 - C[0] * T2
    M2 = C[0] * T1 - C[1] * T0
    mn = math.sqrt(M0 * M0 + M1 * M1 + M2 * M2)
    ct = C[0] * T0 + C[1] * T1 + C[2] * T2
    E0, E1, E2 = C[0] - ct * T0, C[1] - ct * T1, C[2] - ct * T2
    d = math.sqrt(E0 * E0 + E1 * E1 + E2 * E2)
    if mn < 1e-12 or d <= r or d < 1e-9:
        return False, tn, (T0, T1, T2), mn, _NO_VECTOR, ct, d, _NO_VECTOR, 0.0, 0.0, _NO_VECTOR
    m0, m1, m2 = M0 / mn, M1 / mn, M2 / mn
    e0, e1, e2 = E0 / d, E1 / d, E2 / d
    rho = r / d
    a = math.sqrt(1.0 - rho * rho)
    n = (a * m0 - sign * rho * e0, a * m1 - sign * rho * e1, a * m2 - sign * rho * e2)
    return True, tn, (T0, T1, T2), mn, (m0, m1, m2), ct, d, (e0, e1, e2), rho, a, n


@numba.njit(cache=True, nogil=True, inline="always")
def _edge_residual(C, D, r, x, y, sign):
    """Distance (normalised image units) from (x, y) to the silhouette line on side ``sign``: the line
    in which the tangent plane (``_tangent_plane``) meets the image."""
    ok, _, _, _, _, _, _, _, _, _, (n0, n1, n2) = _tangent_plane(C, D, r, sign)
    if not ok:
        return np.nan
    return (n0 * x + n1 * y + n2) / math.sqrt(n0 * n0 + n1 * n1)


@numba.njit(cache=True, nogil=True)
def _edge_residual_gradient(C, D, r, x, y, sign, gC, gD):
    """``_edge_residual`` and its exact partials: in C and D (into ``gC``, ``gD``) and in r (returned
    second), by reverse-mode differentiation of the same steps (within 1e-8 relative of central
    differences). Forward differences cost seven more evaluations per edge, most of the fit's time."""
    ok, tn, (T0, T1, T2), mn, (m0, m1, m2), ct, d, (e0, e1, e2), rho, a, (n0, n1, n2) = _tangent_plane(C, D, r, sign)
    if not ok:
        return np.nan, np.nan
    den = math.sqrt(n0 * n0 + n1 * n1)
    num = n0 * x + n1 * y + n2
    res = num / den
    # adjoints, from the residual back to C, D and r
    k = num / (den * den * den)
    q0, q1, q2 = x / den - k * n0, y / den - k * n1, 1.0 / den
    gm0, gm1, gm2 = a * q0, a * q1, a * q2
    ge0, ge1, ge2 = -sign * rho * q0, -sign * rho * q1, -sign * rho * q2
    ga = q0 * m0 + q1 * m1 + q2 * m2
    grho = -sign * (q0 * e0 + q1 * e1 + q2 * e2) - ga * rho / a
    gr = grho / d
    gd = -grho * r / (d * d)
    # e = E / d and d = |E|
    eg = e0 * ge0 + e1 * ge1 + e2 * ge2
    gE0 = (ge0 - eg * e0) / d + gd * e0
    gE1 = (ge1 - eg * e1) / d + gd * e1
    gE2 = (ge2 - eg * e2) / d + gd * e2
    # m = M / |M|
    mg = m0 * gm0 + m1 * gm1 + m2 * gm2
    gM0, gM1, gM2 = (gm0 - mg * m0) / mn, (gm1 - mg * m1) / mn, (gm2 - mg * m2) / mn
    # M = C x T: dC . (T x gM) and dT . (gM x C)
    gC[0] = T1 * gM2 - T2 * gM1
    gC[1] = T2 * gM0 - T0 * gM2
    gC[2] = T0 * gM1 - T1 * gM0
    gT0 = gM1 * C[2] - gM2 * C[1]
    gT1 = gM2 * C[0] - gM0 * C[2]
    gT2 = gM0 * C[1] - gM1 * C[0]
    # E = C - (C . T) T
    ET = gE0 * T0 + gE1 * T1 + gE2 * T2
    gC[0] += gE0 - ET * T0
    gC[1] += gE1 - ET * T1
    gC[2] += gE2 - ET * T2
    gT0 += -ET * C[0] - ct * gE0
    gT1 += -ET * C[1] - ct * gE1
    gT2 += -ET * C[2] - ct * gE2
    # T = D / |D|
    tg = T0 * gT0 + T1 * gT1 + T2 * gT2
    gD[0] = (gT0 - tg * T0) / tn
    gD[1] = (gT1 - tg * T1) / tn
    gD[2] = (gT2 - tg * T2) / tn
    return res, gr


@numba.njit(cache=True, nogil=True)
def _side_of(C, D, dx, dy):
    """+1 or -1: the side of the plane through the centre and the axis that an edge lies on, from
    the direction (dx, dy) from its chord's centre to it (robust to an axis that is a little off)."""
    m0 = C[1] * D[2] - C[2] * D[1]
    m1 = C[2] * D[0] - C[0] * D[2]
    return 1.0 if m0 * dx + m1 * dy >= 0.0 else -1.0


@numba.njit(cache=True, nogil=True)
def _end_residual(C, D, r, x, y, cap):
    """Along-curve distance (normalised units) from the projected end (plus ``cap`` times the
    flat cap's overshoot r |t . s| / Z) to the observed end (x, y)."""
    if C[2] <= 1e-6:
        return np.nan
    px, py = C[0] / C[2], C[1] / C[2]
    tx = (D[0] * C[2] - C[0] * D[2]) / (C[2] * C[2])
    ty = (D[1] * C[2] - C[1] * D[2]) / (C[2] * C[2])
    tl = math.sqrt(tx * tx + ty * ty)
    if tl < 1e-12:
        return np.nan
    tx, ty = tx / tl, ty / tl
    over = 0.0
    if cap != 0.0:
        dn = math.sqrt(D[0] * D[0] + D[1] * D[1] + D[2] * D[2])
        cn = math.sqrt(C[0] * C[0] + C[1] * C[1] + C[2] * C[2])
        ts = abs(D[0] * C[0] + D[1] * C[1] + D[2] * C[2]) / (dn * cn)
        over = cap * r * ts / C[2]
    return (px + over * tx - x) * tx + (py + over * ty - y) * ty


@numba.njit(cache=True, nogil=True)
def _band_centre(C, D, r, connector_radius):
    """The 3D point whose image is the centre of a connector's band (``_connector_residual``): the axis
    point C (tangent D, camera frame) moved (r + R) / 2 across the axis towards the camera; NaNs where
    C is not in front of it or D vanishes."""
    cn = math.sqrt(C[0] * C[0] + C[1] * C[1] + C[2] * C[2])
    dn = math.sqrt(D[0] * D[0] + D[1] * D[1] + D[2] * D[2])
    if C[2] <= 1e-6 or dn < 1e-12:
        return np.nan, np.nan, np.nan
    vt = (C[0] * D[0] + C[1] * D[1] + C[2] * D[2]) / (cn * dn)
    nx = C[0] / cn - vt * D[0] / dn
    ny = C[1] / cn - vt * D[1] / dn
    nz = C[2] / cn - vt * D[2] / dn
    nl = math.sqrt(nx * nx + ny * ny + nz * nz)
    shift = 0.5 * (r + connector_radius) / nl if nl > 1e-9 else 0.0
    return C[0] - shift * nx, C[1] - shift * ny, C[2] - shift * nz


@numba.njit(cache=True, nogil=True)
def _connector_residual(C, D, r, x, y, connector_radius):
    """Along-curve distance (normalised units) from where a connector's dark band is centred along
    the tube's image to the observed centre (x, y).

    In the plane of the axis and the line of sight, the band runs from where the near tube (the one
    in front of the disc) leaves the disc's face, r from the axis on the camera's side, to the
    disc's rim on the far face, R from it: its centre is the image of the axis point moved by
    (r + R) / 2 towards the camera, across the axis. Seen square on (the line of sight across the
    axis) that moves nothing along the tube; tilted, up to a disc radius: on the twin's ramp the band
    lay 2-16 px along the tube from the image of the disc's centre, and 1.5 px of disparity off at
    most; moved so, within 0.2 px in either image (``tests/estimator/test_connectors.py``)."""
    P0, P1, P2 = _band_centre(C, D, r, connector_radius)
    if not P2 > 1e-6:
        return np.nan
    px, py = P0 / P2, P1 / P2
    tx = (D[0] * P2 - P0 * D[2]) / (P2 * P2)
    ty = (D[1] * P2 - P1 * D[2]) / (P2 * P2)
    tl = math.sqrt(tx * tx + ty * ty)
    if tl < 1e-12:
        return np.nan
    tx, ty = tx / tl, ty / tl
    return (px - x) * tx + (py - y) * ty


@numba.njit(cache=True, nogil=True)
def _connector_pair_residual(C, D, r, xl, yl, xr, yr, connector_radius, baseline):
    """The difference between a connector's along-curve residuals in the left and the right image
    (``_connector_residual``; C, D in the left camera's frame), over the square root of two.

    Moving the shared place along the axis moves both images' residuals alike: their difference is
    what the connector says of depth alone, and it leaves the axis's parametrisation to the edges
    (the residuals themselves, at a place held between re-attachments, slid the spline along itself
    and bent the first section by 3 mm on the twin's blurred ramp)."""
    left = _connector_residual(C, D, r, xl, yl, connector_radius)
    Cr = np.empty(3)
    Cr[0] = C[0] - baseline
    Cr[1] = C[1]
    Cr[2] = C[2]
    right = _connector_residual(Cr, D, r, xr, yr, connector_radius)
    return (left - right) * 0.7071067811865476


_RIM_COS = np.cos(2.0 * np.pi * (np.arange(CAP_SAMPLES + 1) % CAP_SAMPLES) / CAP_SAMPLES)
_RIM_SIN = np.sin(2.0 * np.pi * (np.arange(CAP_SAMPLES + 1) % CAP_SAMPLES) / CAP_SAMPLES)
SIDE_PIECE = -1  # a cap piece: the silhouette line on side +1 (-2: on side -1); 0.. the rim's segments


@numba.njit(cache=True, nogil=True)
def _rim_point(C, T, r, k):
    """The image (x, y) of the k-th point of the tube end's rim (a circle of radius r across the unit
    axis direction T, centred at C); (NaN, NaN) behind the camera."""
    if abs(T[0]) < 0.9:
        a0, a1, a2 = 0.0, -T[2], T[1]  # T x (1, 0, 0)
    else:
        a0, a1, a2 = T[2], 0.0, -T[0]  # T x (0, 1, 0)
    an = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    a0, a1, a2 = a0 / an, a1 / an, a2 / an
    b0 = T[1] * a2 - T[2] * a1
    b1 = T[2] * a0 - T[0] * a2
    b2 = T[0] * a1 - T[1] * a0
    c, s = _RIM_COS[k], _RIM_SIN[k]
    Z = C[2] + r * (c * a2 + s * b2)
    if Z <= 1e-6:
        return np.nan, np.nan
    return (C[0] + r * (c * a0 + s * b0)) / Z, (C[1] + r * (c * a1 + s * b1)) / Z


@numba.njit(cache=True, nogil=True)
def _cap_piece(C, D, r, x, y, piece):
    """Distance (normalised units) from (x, y) to one piece of the tube end's outline: a silhouette
    line (``SIDE_PIECE``, ``SIDE_PIECE - 1``) or the rim's segment ``piece``."""
    if piece < 0:
        return abs(_edge_residual(C, D, r, x, y, 1.0 if piece == SIDE_PIECE else -1.0))
    tn = math.sqrt(D[0] * D[0] + D[1] * D[1] + D[2] * D[2])
    if tn < 1e-12:
        return np.nan
    T = (D[0] / tn, D[1] / tn, D[2] / tn)  # a tuple: no allocation in the fit's inner loop
    px, py = _rim_point(C, T, r, piece)
    qx, qy = _rim_point(C, T, r, piece + 1)
    ex, ey = qx - px, qy - py
    den = ex * ex + ey * ey
    t = ((x - px) * ex + (y - py) * ey) / den if den > 0.0 else 0.0
    t = min(max(t, 0.0), 1.0)
    dx, dy = px + t * ex - x, py + t * ey - y
    return math.sqrt(dx * dx + dy * dy)


@numba.njit(cache=True, nogil=True)
def _cap_residual_piece(C, D, r, x, y, outward=1.0):
    """Distance (normalised units) from (x, y) to the outline of the tube's flat end: the nearer of
    its two silhouette lines and the image of the end's rim (a circle of radius r across the axis);
    and which piece of the outline that is (``_cap_piece``: its derivatives are that piece's).

    The silhouette lines end at the cap: a point beyond the image of the axis's end (``outward``: +1
    where the axis runs out through this end as u grows, the tip; -1 at the base) can only be on the
    rim. Taken as infinite lines, they explained the far arc of a tip whose face was seen, and the
    fit ended the tube 13 mm short with its outline fitted to 0.5 px (tests/scenes.py, dim light)."""
    best = abs(_edge_residual(C, D, r, x, y, 1.0))
    piece = SIDE_PIECE
    other = abs(_edge_residual(C, D, r, x, y, -1.0))
    if best != best or other != other:
        return np.nan, piece
    if other < best:
        best, piece = other, SIDE_PIECE - 1
    tn = math.sqrt(D[0] * D[0] + D[1] * D[1] + D[2] * D[2])
    if tn < 1e-12 or C[2] <= 1e-6:
        return np.nan, piece
    # the image of the axis's direction at the end, pointing out of the tube
    tx = (D[0] * C[2] - C[0] * D[2]) * outward
    ty = (D[1] * C[2] - C[1] * D[2]) * outward
    if (x - C[0] / C[2]) * tx + (y - C[1] / C[2]) * ty > 0.0:
        best, piece = np.inf, 0  # beyond the end: the rim's (found below)
    T = (D[0] / tn, D[1] / tn, D[2] / tn)  # a tuple: no allocation in the fit's inner loop
    px, py = _rim_point(C, T, r, 0)
    if px != px:
        return np.nan, piece
    for k in range(1, CAP_SAMPLES + 1):
        qx, qy = _rim_point(C, T, r, k)
        if qx != qx:
            return np.nan, piece
        # distance from (x, y) to the segment (px, py)-(qx, qy)
        ex, ey = qx - px, qy - py
        den = ex * ex + ey * ey
        t = ((x - px) * ex + (y - py) * ey) / den if den > 0.0 else 0.0
        t = min(max(t, 0.0), 1.0)
        dx, dy = px + t * ex - x, py + t * ey - y
        dist = math.sqrt(dx * dx + dy * dy)
        if dist < best:
            best, piece = dist, k - 1
        px, py = qx, qy
    return best, piece


@numba.njit(cache=True, nogil=True)
def _residual_of(kind, C, D, r, x, y, extra):
    if kind == 0:
        return _edge_residual(C, D, r, x, y, extra)
    if kind == 2:
        return _cap_residual_piece(C, D, r, x, y, extra)[0]
    return _end_residual(C, D, r, x, y, extra)


@numba.njit(cache=True, nogil=True, inline="always")
def _axis_at(control, first, values, deriv, shift_x, C, D):
    """The axis point C and its derivative D from one observation's basis (into C, D), in the frame of
    the camera ``shift_x`` metres along x from the left one (the right camera: the baseline)."""
    for c in range(3):
        C[c] = 0.0
        D[c] = 0.0
    for j in range(DEGREE + 1):
        for c in range(3):
            C[c] += values[j] * control[first + j, c]
            D[c] += deriv[j] * control[first + j, c]
    C[0] -= shift_x


@numba.njit(cache=True, nogil=True)
def _bases(knots, count, us):
    """The B-spline basis at every observation's u: (first control point (n,), values (n, 4),
    derivatives (n, 4)). They change only when observations are re-attached, not with the control
    points, so the fit computes them once per attachment."""
    n = us.shape[0]
    firsts = np.empty(n, np.int64)
    values = np.empty((n, DEGREE + 1))
    derivs = np.empty((n, DEGREE + 1))
    work, v, d = basis_workspace()
    for i in range(n):
        first = basis_into(knots, count, min(max(us[i], 0.0), 1.0), work, v, d)
        firsts[i] = first
        values[i] = v
        derivs[i] = d
    return firsts, values, derivs


@numba.njit(cache=True, nogil=True)
def _normal_equations(bases, control, radii, bins, baseline, focal, kinds, sides, xs, ys, extras, sigmas, huber,
                      want_system):
    """Robust cost, residuals (px) and, if asked, J^T W J and J^T W r over every observation
    (``bases``: ``_bases`` of the observations' places on the axis)."""
    firsts, all_values, all_derivs = bases
    count = control.shape[0]
    nr = radii.shape[0]
    npar = 3 * count + nr
    A = np.zeros((npar, npar))
    g = np.zeros(npar)
    residuals = np.full(kinds.shape[0], np.nan)
    cost = 0.0
    idx = np.empty(3 * (DEGREE + 1) + 1, np.int64)
    jac = np.empty(3 * (DEGREE + 1) + 1)
    C = np.empty(3)
    D = np.empty(3)
    Cp = np.empty(3)
    Dp = np.empty(3)
    gC = np.empty(3)
    gD = np.empty(3)
    for i in range(kinds.shape[0]):
        first = firsts[i]
        values = all_values[i]
        deriv = all_derivs[i]
        _axis_at(control, first, values, deriv, baseline if sides[i] == 1 else 0.0, C, D)
        rj = bins[i]
        r = radii[rj]
        piece = 0
        gr = 0.0
        if kinds[i] == 4:
            continue  # a connector's right view: taken with its left one (kind 3)
        if kinds[i] == 3:
            res = _connector_pair_residual(C, D, r, xs[i], ys[i], xs[i + 1], ys[i + 1], extras[i], baseline)
        elif kinds[i] == 2:
            res, piece = _cap_residual_piece(C, D, r, xs[i], ys[i], extras[i])
        elif kinds[i] == 0 and want_system:  # an edge's residual comes with its partials
            res, gr = _edge_residual_gradient(C, D, r, xs[i], ys[i], extras[i], gC, gD)
        elif kinds[i] == 0:  # directly, not through ``_residual_of``: that call is not inlined, and cost as much
            res = _edge_residual(C, D, r, xs[i], ys[i], extras[i])
        else:
            res = _residual_of(kinds[i], C, D, r, xs[i], ys[i], extras[i])
        if res != res:
            continue
        res_px = res * focal
        residuals[i] = res_px
        scaled = res_px / sigmas[i]
        # The threshold is for a focused edge; any other observation's residual is read in units of its
        # own sigma (a blurred edge 2 px off is as ordinary as a focused one 0.5 px off).
        a = abs(res_px) * EDGE_SIGMA_PX / sigmas[i]
        # Huber (huber > 0): beyond the threshold a residual counts linearly; redescending (huber < 0,
        # Geman-McClure-like): a gross outlier stops counting at all.
        w = (1.0 if a <= huber else huber / a) if huber > 0.0 else 1.0 / (1.0 + (a / huber) ** 2)
        cost += w * scaled * scaled
        if not want_system:
            continue
        if kinds[i] == 0:  # an edge (nearly every observation): exact partials
            gr *= focal
            for c in range(3):
                gC[c] *= focal
                gD[c] *= focal
        else:
            # the ends and the tip's outline (there, only the piece of it nearest the point): forward
            # differences (steps far below any length that matters, far above rounding: the
            # residual is smooth on that scale)
            dn = math.sqrt(D[0] * D[0] + D[1] * D[1] + D[2] * D[2])
            h = 1e-6
            hd = 1e-6 * dn
            for c in range(3):
                for k in range(3):
                    Cp[k] = C[k]
                    Dp[k] = D[k]
                Cp[c] = C[c] + h
                Dp[c] = D[c] + hd
                if kinds[i] == 2:
                    gC[c] = (_cap_piece(Cp, D, r, xs[i], ys[i], piece) - res) / h * focal
                    gD[c] = (_cap_piece(C, Dp, r, xs[i], ys[i], piece) - res) / hd * focal
                elif kinds[i] == 3:
                    gC[c] = (_connector_pair_residual(Cp, D, r, xs[i], ys[i], xs[i + 1], ys[i + 1], extras[i],
                                                      baseline) - res) / h * focal
                    gD[c] = (_connector_pair_residual(C, Dp, r, xs[i], ys[i], xs[i + 1], ys[i + 1], extras[i],
                                                      baseline) - res) / hd * focal
                else:
                    gC[c] = (_end_residual(Cp, D, r, xs[i], ys[i], extras[i]) - res) / h * focal
                    gD[c] = (_end_residual(C, Dp, r, xs[i], ys[i], extras[i]) - res) / hd * focal
            hr = 1e-7
            if kinds[i] == 2:
                gr = (_cap_piece(C, D, r + hr, xs[i], ys[i], piece) - res) / hr * focal
            elif kinds[i] == 3:
                gr = (_connector_pair_residual(C, D, r + hr, xs[i], ys[i], xs[i + 1], ys[i + 1], extras[i],
                                               baseline) - res) / hr * focal
            else:
                gr = (_end_residual(C, D, r + hr, xs[i], ys[i], extras[i]) - res) / hr * focal
        n = 0
        for j in range(DEGREE + 1):
            for c in range(3):
                idx[n] = (first + j) * 3 + c
                jac[n] = gC[c] * values[j] + gD[c] * deriv[j]
                n += 1
        idx[n] = 3 * count + rj
        jac[n] = gr
        n += 1
        ws = w / (sigmas[i] * sigmas[i])
        finite = True
        for p in range(n):
            finite = finite and jac[p] == jac[p]
        if finite:  # nearly always: the same sums as below, on the contiguous block of four control points
            # The block's whole square, not its upper triangle: a fixed trip count the compiler unrolls
            # (8 % off the system's time); the lower triangle is overwritten from the upper one below.
            b = 3 * first
            rr = idx[n - 1]
            for p in range(3 * (DEGREE + 1)):
                wp = ws * jac[p]
                g[b + p] += wp * res_px
                for q in range(3 * (DEGREE + 1)):
                    A[b + p, b + q] += wp * jac[q]
                A[b + p, rr] += wp * jac[n - 1]
            wp = ws * jac[n - 1]
            g[rr] += wp * res_px
            A[rr, rr] += wp * jac[n - 1]
            continue
        for p in range(n):
            if jac[p] != jac[p]:
                continue
            g[idx[p]] += ws * jac[p] * res_px
            for q in range(p, n):
                if jac[q] == jac[q]:
                    A[idx[p], idx[q]] += ws * jac[p] * jac[q]
    if want_system:
        # the upper triangle holds every observation's sums (its indices ascend): mirror it
        for p in range(npar):
            for q in range(p + 1, npar):
                A[q, p] = A[p, q]
    return cost, residuals, A, g


@numba.njit(cache=True, nogil=True)
def _attach(knots, control, baseline, sides, centres, samples):
    """u of the axis point whose projection is nearest each chord centre, in its own image."""
    us = np.linspace(0.0, 1.0, samples)
    points, _ = evaluate_many(knots, control, us)
    # each sample's image in both cameras, once (NaN behind the camera)
    image_x = np.full((2, samples), np.nan)
    image_y = np.full((2, samples), np.nan)
    for k in range(samples):
        Z = points[k, 2]
        if Z > 1e-6:
            for side in range(2):
                image_x[side, k] = (points[k, 0] - (baseline if side == 1 else 0.0)) / Z
                image_y[side, k] = points[k, 1] / Z
    out = np.empty(sides.shape[0])
    dist = np.empty(samples)
    for i in range(sides.shape[0]):
        best = 1e18
        best_k = 0
        side = 1 if sides[i] == 1 else 0
        for k in range(samples):
            if image_x[side, k] != image_x[side, k]:
                dist[k] = 1e18
                continue
            dx = image_x[side, k] - centres[i, 0]
            dy = image_y[side, k] - centres[i, 1]
            dist[k] = dx * dx + dy * dy
            if dist[k] < best:
                best = dist[k]
                best_k = k
        out[i] = _vertex_u(us, dist, best_k)
    return out


@numba.njit(cache=True, nogil=True)
def _vertex_u(us, dist, best):
    """``us[best]`` moved between the neighbouring samples to the vertex of the parabola through the
    squared distances there (where they make one that opens upwards), clipped to [0, 1]."""
    u = us[best]
    if 0 < best < us.shape[0] - 1:
        a, b, c = dist[best - 1], dist[best], dist[best + 1]
        den = a - 2.0 * b + c
        if den > 0.0 and math.isfinite(den):
            u += 0.5 * (a - c) / den * (us[1] - us[0])
    return min(max(u, 0.0), 1.0)


@numba.njit(cache=True, nogil=True)
def _base_prior(control, point, direction):
    """Whitened residuals (6,) of the base priors (P0 at the point, P1 - P0 along the direction) and
    the two non-zero coefficients of each one's Jacobian row: on P0's and on P1's coordinate."""
    res = np.empty(6)
    on_p0 = np.empty(6)
    on_p1 = np.zeros(6)
    length = 0.0
    for c in range(3):
        length += (control[1, c] - control[0, c]) ** 2
    length = max(math.sqrt(length), 1e-9)
    for c in range(3):
        on_p0[c] = 1.0 / BASE_SIGMA_M
        res[c] = (control[0, c] - point[c]) / BASE_SIGMA_M
        on_p0[3 + c] = -1.0 / (length * BASE_DIRECTION_SIGMA)
        on_p1[3 + c] = 1.0 / (length * BASE_DIRECTION_SIGMA)
        res[3 + c] = ((control[1, c] - control[0, c]) / length - direction[c]) / BASE_DIRECTION_SIGMA
    return res, on_p0, on_p1


@numba.njit(cache=True, nogil=True)
def _system(bases, control, radii, bins, baseline, focal, kinds, sides, xs, ys, extras, sigmas, huber, want_system,
            smooth, smooth_normal, radius_prior, prior_w, base_point, base_direction):
    """``_normal_equations`` with the priors added: the control points' third differences
    (``smooth``, pre-scaled by its weight, and its normal matrix), each radius bin's, and the base's
    (where ``base_point`` is finite). Compiled whole: called about twenty times a frame, the priors'
    small numpy steps cost as much as the edges."""
    cost, residuals, A, g = _normal_equations(bases, control, radii, bins, baseline, focal, kinds, sides, xs, ys,
                                              extras, sigmas, huber, want_system)
    count = control.shape[0]
    n3 = 3 * count
    sx = np.zeros(smooth.shape[0])
    for i in range(smooth.shape[0]):
        for j in range(n3):
            sx[i] += smooth[i, j] * control[j // 3, j % 3]
        cost += sx[i] * sx[i]
    for k in range(radii.shape[0]):
        dr = radii[k] - radius_prior[k]
        cost += prior_w[k] * dr * dr
        if want_system:
            A[n3 + k, n3 + k] += prior_w[k]
            g[n3 + k] += prior_w[k] * dr
    if want_system:
        for i in range(n3):
            for j in range(n3):
                A[i, j] += smooth_normal[i, j]
            for k in range(smooth.shape[0]):
                g[i] += smooth[k, i] * sx[k]
    if base_point[0] == base_point[0]:
        # C(0) = P0 and C'(0) is along P1 - P0 on a clamped spline: both priors are (nearly) linear.
        res, on_p0, on_p1 = _base_prior(control, base_point, base_direction)
        for k in range(6):
            cost += res[k] * res[k]
        if want_system:
            for c in range(3):
                p0, p1 = c, 3 + c
                a, b = on_p0[c], on_p0[3 + c]
                e = on_p1[3 + c]
                # rows c (on P0 only) and 3 + c (on P0 and P1) of the prior's Jacobian
                A[p0, p0] += a * a + b * b
                A[p0, p1] += b * e
                A[p1, p0] += b * e
                A[p1, p1] += e * e
                g[p0] += a * res[c] + b * res[3 + c]
                g[p1] += e * res[3 + c]
    return cost, residuals, A, g


@numba.njit(cache=True, nogil=True)
def _damped_step(A, g, cost, damping, bases, control, radii, bins, baseline, focal, kinds, sides, xs, ys, extras,
                 sigmas, huber, smooth, smooth_normal, radius_prior, prior_w, base_point, base_direction):
    """One Levenberg-Marquardt step: the damping raised until a step lowers the cost.

    Returns (status, control, radii, new cost, damping): status 1 when a step was taken, 0 when
    none lowered the cost before the damping ran out, -1 when the system is singular or not finite."""
    n = g.shape[0]
    count = control.shape[0]
    H = np.empty((n, n))
    while True:
        for i in range(n):
            for j in range(n):
                H[i, j] = A[i, j]
            H[i, i] = A[i, i] + damping * (A[i, i] + 1e-12)
        try:
            step = np.linalg.solve(H, g)
        except Exception:  # noqa: BLE001 - numba raises LinAlgError as a plain exception here
            return -1, control, radii, cost, damping
        new_control = control.copy()
        for k in range(count):
            for c in range(3):
                new_control[k, c] -= step[3 * k + c]
        new_radii = np.empty(radii.shape[0])
        for k in range(radii.shape[0]):
            new_radii[k] = min(max(radii[k] - step[3 * count + k], 1e-4), 1.0)
        new_cost = _system(bases, new_control, new_radii, bins, baseline, focal, kinds, sides, xs, ys, extras, sigmas,
                           huber, False, smooth, smooth_normal, radius_prior, prior_w, base_point, base_direction)[0]
        if np.isfinite(new_cost) and new_cost <= cost:
            return 1, new_control, new_radii, new_cost, max(damping / 10.0, 1e-7)
        damping *= 10.0
        if damping > 1e6:
            return 0, control, radii, cost, damping


_ARC_GRID = np.linspace(0.0, 1.0, CURVE_SAMPLES)


def _attach_pairs(knots, control, baseline, connectors, radius, connector_radius):
    """u of the axis point whose connector model (``_connector_residual``: the band's centre, shifted
    from the axis towards each camera) lies nearest both images' views of each connector (the sum of
    the squared image distances): one place seen twice."""
    us = _ARC_GRID
    points, derivs = evaluate_many(knots, control, us)
    out = np.empty(len(connectors))
    for k, views in enumerate(connectors):
        dist = np.zeros(len(us))
        for side in range(2):
            C = points - np.array([baseline if side == 1 else 0.0, 0.0, 0.0])
            image = _connector_images(C, derivs, radius, connector_radius)
            dist += (image[:, 0] - views[side, 0]) ** 2 + (image[:, 1] - views[side, 1]) ** 2
        dist = np.where(np.isfinite(dist), dist, np.inf)
        out[k] = _vertex_u(us, dist, int(np.argmin(dist)))
    return out


@numba.njit(cache=True, nogil=True)
def _connector_images(C, D, radius, connector_radius):
    """(n, 2) where ``_band_centre`` puts the band's centre for axis points C with derivatives D
    (one camera's frame, normalised image coordinates; NaN where not in front of it)."""
    out = np.full((C.shape[0], 2), np.nan)
    for k in range(C.shape[0]):
        P0, P1, P2 = _band_centre(C[k], D[k], radius, connector_radius)
        if P2 > 1e-6:
            out[k, 0] = P0 / P2
            out[k, 1] = P1 / P2
    return out


@numba.njit(cache=True, nogil=True)
def arc_fraction(knots, control, us):
    """Arc length from the base as a fraction of the whole axis, at each u."""
    points = evaluate_many(knots, control, _ARC_GRID)[0]
    arc = np.zeros(CURVE_SAMPLES)
    for k in range(1, CURVE_SAMPLES):
        dx = points[k, 0] - points[k - 1, 0]
        dy = points[k, 1] - points[k - 1, 1]
        dz = points[k, 2] - points[k - 1, 2]
        arc[k] = arc[k - 1] + math.sqrt(dx * dx + dy * dy + dz * dz)
    return np.interp(us, _ARC_GRID, arc / max(arc[-1], 1e-12))


def radius_bins(knots: np.ndarray, control: np.ndarray, us: np.ndarray, count: int) -> np.ndarray:
    """The radius bin (equal bins of arc length, base to tip) each u falls in."""
    return np.minimum((arc_fraction(knots, control, us) * count).astype(np.int64), count - 1)


def _base_restart(fit: TubeFit | None, control: np.ndarray, initial_points: np.ndarray | None,
                  base_outline: dict[int, np.ndarray]) -> np.ndarray | None:
    """A second start for the outline stage where a free base's outline was left unexplained: the
    first stage's control points with the base's first ones taken back from the initial curve.

    With one end point per image, the first stage can trade the flat base's tilt towards the camera
    for its place along the axis (a tilted face's rim reaches further out in the image): it leaves
    the face seen edge-on at the outline's apex, and the outline stage cannot tilt it back (the
    rim's corners are then attributed to the side lines). Unseen scenes, bases 8-10 mm off with the
    outline missed by 0.4-1.2 px RMS; started from the initial curve's base, the same frames ended
    0.6-2 mm off at a lower cost. None where there is nothing to restart (no outline, no initial
    curve, or the outline explained)."""
    if fit is None or initial_points is None or len(initial_points) < 4:
        return None
    if not any(len(v) >= MIN_CAP_POINTS for v in base_outline.values()):
        return None
    misses = [float(np.sqrt(np.mean(np.square(r)))) for r in fit.base_residual_px.values() if len(r)]
    if not misses or max(misses) <= BASE_RESTART_PX:
        return None
    _, initial = fit_control_points(np.asarray(initial_points, np.float64), len(control))
    weight = np.clip(1.0 - np.arange(len(control)) / BASE_RESTART_POINTS, 0.0, 1.0)[:, None]
    return np.ascontiguousarray(weight * initial + (1.0 - weight) * control)


@functools.cache
def _smoothness(count: int) -> tuple[np.ndarray, np.ndarray]:
    """The third-difference prior on ``count`` control points: its (3 (count - 3), 3 count) operator,
    scaled by its weight (1 / SMOOTH_SIGMA_M), and that operator's normal matrix. Read-only (cached).

    Third, not second, differences: a bend of constant curvature (how a PMA section bends) costs
    nothing, a wiggle does; where the images do not fix the depth, the axis continues its bend.
    """
    S = np.zeros((3 * (count - 3), 3 * count))
    for k in range(count - 3):
        # At the free ends, beyond the last edges, only this prior shapes the axis: hold it firmer
        # there, so the tip continues its bend instead of hooking.
        end = END_STIFFNESS if k in (0, count - 4) else 1.0
        for c in range(3):
            row = 3 * k + c
            for j, w in enumerate((-1.0, 3.0, -3.0, 1.0)):
                S[row, 3 * (k + j) + c] = w * end
    w_smooth = 1.0 / SMOOTH_SIGMA_M
    scaled, normal = S * w_smooth, (w_smooth ** 2) * (S.T @ S)
    scaled.flags.writeable = normal.flags.writeable = False
    return scaled, normal


def fit_tube(edges: EdgeSet, ends: dict[str, np.ndarray], initial_points: np.ndarray, radius_prior: np.ndarray,
             radius_sigma: np.ndarray, *, focal_px: float, baseline_m: float, cap: float = 1.0,
             control_points: int = CONTROL_POINTS, base_prior: tuple[np.ndarray, np.ndarray] | None = None,
             initial_control: np.ndarray | None = None,
             tip_outline: dict[int, np.ndarray] | None = None, initial_radii: np.ndarray | None = None,
             connectors: np.ndarray | None = None, connector_radius_m: float = 0.0, iterations: int = ITERATIONS,
             base_outline: dict[int, np.ndarray] | None = None, outline_stage: bool = False) -> TubeFit | None:
    """Fit the tube to the edges of both images.

    Args:
        edges: sub-pixel edge points of both images (normalised rectified coordinates).
        ends: "base" and "tip": (2, 2) the observed ends in the left and right image (normalised),
            rows may be NaN where unseen.
        initial_points: (M, 3) a first 3D centerline, base first (rectified left frame, metres);
            ignored when ``initial_control`` is given.
        radius_prior, radius_sigma: (RADIUS_BINS,) prior radius of each bin of arc length (base to tip)
            and its uncertainty, metres.
        focal_px: rectified focal length; baseline_m: stereo baseline.
        cap: 1 for flat ends (a tube ending in a plane across its axis, at the mount and at the tip:
            its image overshoots the axis end by r |t . s| / Z), 0 for ends seen as points.
        control_points: B-spline control points of the axis.
        base_prior: (point (3,), unit direction (3,)) where the axis leaves its mount, learned from
            earlier frames (rectified left frame), or None. The mount is rigid: the base's first
            visible point and the arm's direction there stay put while the arm bends.
        initial_control: (control_points, 3) control points to start from (the previous frame's fit).
        tip_outline: image (0 left, 1 right) -> (K, 2) sub-pixel points of the silhouette's outline
            around the tip (normalised); where given, they replace that image's single tip end point
            in a second stage, started from the fit with the end point (an outline is attributed to
            the nearest of the rim and the sides: from a tip far off, to the wrong one).
        initial_radii: radii to start from (default: the prior).
        base_outline: the same for the base, where it is a free end (not a mount's face).
        outline_stage: fit to the outlines from the start given (``initial_control``, ``initial_radii``),
            without the first stage that places the ends by their single end points.
        connectors: (K, 2, 2) the centres of the bands the connectors between sections make along
            the tube's image, in the left (``[:, 0]``) and the right (``[:, 1]``) image (normalised),
            base first: one place on the axis each, seen from both cameras, so they give its
            disparity where the silhouette's lines cannot (a section along the image rows).
        connector_radius_m: the connectors' radius (where their band is centred: ``_connector_residual``).
        iterations: Gauss-Newton iterations at most.

    Returns:
        The fit, or None when it cannot be set up (too few edges, degenerate initial curve).
    """
    outlines = {"tip": tip_outline or {}, "base": base_outline or {}}
    if not outline_stage and any(len(v) >= MIN_CAP_POINTS for end in outlines.values() for v in end.values()):
        first = fit_tube(edges, ends, initial_points, radius_prior, radius_sigma, focal_px=focal_px,
                         baseline_m=baseline_m, cap=cap, control_points=control_points, base_prior=base_prior,
                         initial_control=initial_control, initial_radii=initial_radii, connectors=connectors,
                         connector_radius_m=connector_radius_m, iterations=iterations)
        if first is None:
            return None

        def outline_stage(start: np.ndarray) -> TubeFit | None:
            return fit_tube(edges, ends, initial_points, radius_prior, radius_sigma, focal_px=focal_px,
                            baseline_m=baseline_m, cap=cap, control_points=control_points, base_prior=base_prior,
                            initial_control=start, tip_outline=dict(outlines["tip"]),
                            initial_radii=first.radius_bins, connectors=connectors,
                            connector_radius_m=connector_radius_m, iterations=OUTLINE_ITERATIONS,
                            base_outline=dict(outlines["base"]), outline_stage=True)

        fit = outline_stage(first.control)
        restart = _base_restart(fit, first.control, initial_points, outlines["base"])
        if restart is not None:
            other = outline_stage(restart)
            if other is not None and other.cost < fit.cost:
                fit = other
        return fit
    if initial_control is not None:
        control = np.array(initial_control, np.float64)
        knots = clamped_knots(len(control))
    elif len(initial_points) < 4:
        return None
    else:
        knots, control = fit_control_points(initial_points, control_points)
    if len(edges.side) < 12:
        return None
    control = np.ascontiguousarray(control)
    radii = np.asarray(radius_prior if initial_radii is None else initial_radii, np.float64).copy()
    count = len(control)
    # Observations: edges, then the ends (base: no overshoot; tip: the cap's).
    kinds = [np.zeros(len(edges.side), np.int64)]
    sides = [edges.side.astype(np.int64)]
    xs, ys = [edges.xy[:, 0]], [edges.xy[:, 1]]
    sigmas = [EDGE_SIGMA_PX / np.maximum(edges.weight, 1e-3)]
    end_us, end_extra = [], []
    for name, u_end, extra in (("base", 0.0, -cap), ("tip", 1.0, cap)):  # overshoot beyond each end
        for side in END_SIDES:
            outline = outlines[name].get(side)
            if cap and outline is not None and len(outline) >= MIN_CAP_POINTS:
                # The whole outline of the flat end, not one point: its rim's ellipse seen from two
                # places fixes where the tip is in depth too.
                m = len(outline)
                kinds.append(np.full(m, 2))
                sides.append(np.full(m, side))
                xs.append(outline[:, 0])
                ys.append(outline[:, 1])
                sigmas.append(np.full(m, CAP_SIGMA_PX))
                end_us += [u_end] * m
                end_extra += [1.0 if name == "tip" else -1.0] * m  # which way is out of the tube
                continue
            point = ends[name][side]
            if np.all(np.isfinite(point)):
                kinds.append(np.array([1]))
                sides.append(np.array([side]))
                xs.append(np.array([point[0]]))
                ys.append(np.array([point[1]]))
                sigmas.append(np.array([END_SIGMA_PX]))
                end_us.append(u_end)
                end_extra.append(extra)
    n_connectors = 0 if connectors is None else len(connectors)
    for k in range(n_connectors):
        # Both images' views of one place on the axis, at one shared u (attached below): a single
        # residual (kind 3, ``_connector_pair_residual``) reads both (kind 4 carries the right view).
        kinds.append(np.array([3, 4]))
        sides.append(np.array([0, 0]))  # both in the left camera's frame: the pair's residual shifts the right
        xs.append(np.asarray(connectors[k, :, 0], np.float64))
        ys.append(np.asarray(connectors[k, :, 1], np.float64))
        sigmas.append(np.full(2, CONNECTOR_SIGMA_PX))
        end_extra += [connector_radius_m, connector_radius_m]
    kinds, sides = np.concatenate(kinds), np.concatenate(sides)
    xs, ys, sigmas = np.concatenate(xs), np.concatenate(ys), np.concatenate(sigmas)
    n_edges = len(edges.side)
    # Both edges of a chord share its centre: attach each centre once.
    spread = 2.0 * float(np.max(np.abs(edges.centre[:, 0]))) + 1.0
    key = (edges.centre[:, 0] + spread * sides[:n_edges]) + 1j * edges.centre[:, 1]
    _, first_of, chord_of = np.unique(key, return_index=True, return_inverse=True)
    chord_of = chord_of.reshape(-1)
    chord_sides, chord_centres = sides[first_of], np.ascontiguousarray(edges.centre[first_of])

    def attach(control_):
        return _attach(knots, control_, baseline_m, chord_sides, chord_centres, CURVE_SAMPLES)[chord_of]

    def attach_connectors(control_):
        if not n_connectors:
            return np.zeros(0)
        return np.repeat(_attach_pairs(knots, control_, baseline_m, connectors, float(np.mean(radii)),
                                       connector_radius_m), 2)

    us = np.concatenate([attach(control),
                         np.array(end_us), attach_connectors(control)])
    # Which silhouette line each edge belongs to, from the initial tube (edges lie well to one side).
    extras = np.concatenate([_edge_sides(knots, control, baseline_m, sides[:n_edges], us[:n_edges], edges.xy,
                                         edges.centre), np.array(end_extra)])
    smooth, smooth_normal = _smoothness(count)
    if len(edges.weight):
        # A blurred image's edges count less each (their sigma grows with their step's width), and
        # their errors run together along the arm (the wall's texture under a long step): the prior
        # holds relatively firmer there, by the square root of how much less a typical edge counts.
        # Measured on blur (the twin's 9 px pan): the independent lab scenes 1.68 -> 1.36 mm, worst
        # frame 9.5 -> 3.3 mm; the 12-frame CI set 1 -> 0 false valid. Firmer by the whole ratio
        # (power 1), or looser instead, blur got worse (3-7 false valid). Focused images: no change.
        boost = float(np.median(edges.weight)) ** -SMOOTH_BLUR_POWER
        smooth, smooth_normal = smooth * boost, smooth_normal * boost * boost
    npar = 3 * count + len(radii)
    prior_w = 1.0 / np.asarray(radius_sigma, np.float64) ** 2
    radius_prior = np.asarray(radius_prior, np.float64)
    bins = radius_bins(knots, control, us, len(radii))
    bases = _bases(knots, count, us)
    base_point, base_direction = ((np.full(3, np.nan), np.zeros(3)) if base_prior is None else
                                  (np.asarray(base_prior[0], np.float64), np.asarray(base_prior[1], np.float64)))
    loss = HUBER_PX  # Huber while the fit settles, then redescending (a negative threshold)

    def system(want):
        return _system(bases, control, radii, bins, baseline_m, focal_px, kinds, sides, xs, ys, extras, sigmas, loss,
                       want, smooth, smooth_normal, radius_prior, prior_w, base_point, base_direction)

    damping = 1e-4
    cost, residuals, A, g = system(True)
    for iteration in range(iterations):
        status, control, radii, new_cost, damping = _damped_step(
            A, g, cost, damping, bases, control, radii, bins, baseline_m, focal_px, kinds, sides, xs, ys, extras,
            sigmas, loss, smooth, smooth_normal, radius_prior, prior_w, base_point, base_direction)
        if status < 0:
            return None
        converged = status > 0 and cost - new_cost < CONVERGED * cost and iteration + 1 >= REASSIGN_AT[0]
        if iteration + 1 in REASSIGN_AT:
            us[:n_edges] = attach(control)
            if n_connectors:
                us[len(us) - 2 * n_connectors:] = attach_connectors(control)
            bins = radius_bins(knots, control, us, len(radii))
            bases = _bases(knots, count, us)
        if iteration + 1 == REDESCEND_AFTER or (outline_stage and iteration == 0):
            loss = -HUBER_PX
        cost, residuals, A, g = system(True)
        if damping > 1e6 or converged:
            break
    edge_res = residuals[:n_edges]
    finite = np.isfinite(edge_res)
    if finite.sum() < 12:
        return None
    inliers = float(np.mean(np.abs(edge_res[finite]) <= HUBER_PX))
    core = np.abs(edge_res[finite]) <= HUBER_PX
    rms = float(np.sqrt(np.mean(edge_res[finite][core] ** 2))) if core.any() else math.inf
    try:
        covariance = np.linalg.inv(A + 1e-12 * np.eye(npar))
    except np.linalg.LinAlgError:
        return None
    # Scale by the observed noise when it exceeds the assumed one (never below it). With no edge
    # within a pixel there is no noise to scale by: nothing about the tube is known.
    if math.isfinite(rms):
        covariance *= max(1.0, (rms / EDGE_SIGMA_PX) ** 2)
    else:
        covariance = np.full_like(covariance, math.inf)
    radius_std = np.sqrt(np.maximum(np.diag(covariance)[3 * count:], 0.0))
    at_tip = np.zeros(len(kinds), bool)
    at_tip[n_edges:n_edges + len(end_us)] = np.array(end_us) == 1.0
    at_base = np.zeros(len(kinds), bool)
    at_base[n_edges:n_edges + len(end_us)] = np.array(end_us) == 0.0
    tip_res = {int(side): residuals[at_tip & (sides == side)] for side in END_SIDES
               if np.any(at_tip & (sides == side))}
    base_res = {int(side): residuals[at_base & (sides == side)] for side in END_SIDES
                if np.any(at_base & (sides == side))}
    connector_u = attach_connectors(control)[::2]  # on the final axis (the fit may end between re-attachments)
    return TubeFit(knots, control, radii, radius_std, covariance, rms, inliers, us[:n_edges].copy(), edge_res,
                   tip_res, cost, connector_u, base_res)


def silhouette_lines(fit: TubeFit, edges: EdgeSet, baseline_m: float) -> np.ndarray:
    """(K,) which of its image's two silhouette lines of the fitted tube each edge belongs to (+1, -1)."""
    return _edge_sides(fit.knots, fit.control, baseline_m, edges.side.astype(np.int64), fit.edge_u, edges.xy,
                       edges.centre)


def misfit_edges(fit: TubeFit, edges: EdgeSet, baseline_m: float, window: int = MISFIT_WINDOW,
                 sigmas: float = MISFIT_SIGMAS) -> np.ndarray:
    """The edges of stretches of silhouette line that the fitted tube does not follow.

    Noise averages out over a stretch; an occluder along the tube's side does not. Its edge narrows
    one image's silhouette evenly, and the fit splits the difference between the two images (a
    cable along the tip's edge: 1.3-6 px means, the tip 16-32 mm off). Over 1,000 well-fitted twin
    frames the largest such mean was 3.5 sigma (blur; beside a baseplate about 2).

    Args:
        fit: the tube fitted to ``edges``.
        edges: the edges it was fitted to.
        baseline_m: the stereo baseline (the right camera's centre along x).
        window: consecutive edges of one line in one image (ordered along the axis) averaged.
        sigmas: a window whose mean residual exceeds this many of its edges' sigmas is flagged (or
            ``MISFIT_PX`` pixels, see there).

    Returns:
        (K,) True for every edge of a flagged window, of the windows it grew over and of the stubs
        beside them.
    """
    lines = silhouette_lines(fit, edges, baseline_m)
    scaled = fit.edge_residual_px * edges.weight / EDGE_SIGMA_PX
    out = np.zeros(len(edges.side), bool)
    for image in END_SIDES:
        for line in (-1.0, 1.0):
            members = np.flatnonzero((edges.side == image) & (lines == line) & np.isfinite(scaled))
            if len(members) < window:
                continue
            members = members[np.argsort(fit.edge_u[members], kind="stable")]
            means = np.convolve(scaled[members], np.ones(window) / window, mode="valid")
            pixels = np.convolve(fit.edge_residual_px[members], np.ones(window) / window, mode="valid")
            seeds = (np.abs(means) > sigmas) | ((np.abs(pixels) > MISFIT_PX) & (np.abs(means) > MISFIT_GROW_SIGMAS)
                                                & (np.sign(pixels) == np.sign(means)))
            flagged = np.zeros(len(members), bool)
            for start in _grown_windows(means, seeds, MISFIT_GROW_SIGMAS):
                flagged[start:start + window] = True
            out[members[_with_stubs(flagged, fit.edge_u[members], window)]] = True
    return out


def _grown_windows(means: np.ndarray, seeds: np.ndarray, grow: float) -> np.ndarray:
    """The seed windows and their neighbours on both sides out to where the mean falls under
    ``grow`` or changes sign (indices into ``means``)."""
    keep = np.zeros(len(means), bool)
    for i in np.flatnonzero(seeds):
        if keep[i]:
            continue
        sign = np.sign(means[i])
        a = b = i
        while a > 0 and means[a - 1] * sign > grow:
            a -= 1
        while b < len(means) - 1 and means[b + 1] * sign > grow:
            b += 1
        keep[a:b + 1] = True
    return np.flatnonzero(keep)


def _with_stubs(flagged: np.ndarray, u: np.ndarray, window: int) -> np.ndarray:
    """``flagged`` (edges of one line, in order of ``u``) and every unflagged run of fewer than ``window``
    edges that touches a flagged one: what an occluder left between its stretch and a gap of the line
    (where the edges skip more than three of their usual steps along ``u``) is too short to be checked
    and was seen beside it (seed 76: three edges between a crossing cable and one lying along the arm)."""
    if not flagged.any():
        return flagged
    out = flagged.copy()
    step = np.diff(u)
    gap = step > 3.0 * max(float(np.median(step)), 1e-12)
    start = 0
    for i in range(1, len(flagged) + 1):
        if i < len(flagged) and flagged[i] == flagged[i - 1] and not gap[i - 1]:
            continue
        if not flagged[start] and i - start < window:
            before = start > 0 and flagged[start - 1] and not gap[start - 1]
            after = i < len(flagged) and flagged[i] and not gap[i - 1]
            out[start:i] = before or after
        start = i
    return out


def fuse_radius(mean: np.ndarray, info: np.ndarray, fit: TubeFit, *, floor_m: float = RADIUS_FLOOR_M,
                forget: float = 0.995, change_sigmas: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """The radius profile learned over frames, updated with one fit's measurement.

    Each bin fuses the fit's posterior (inverse-variance weights) where the fit measured it well
    (standard deviation under a millimetre), so the noise of many frames averages out. A
    measurement further from the learned radius than ``change_sigmas`` standard deviations of
    their difference means the radius changed (a PMA swells with pressure): most of the past is
    dropped and the bin follows within a frame or two. The information decays slowly and never
    exceeds that of ``floor_m``.

    Returns:
        (mean, information = 1 / variance) per bin.
    """
    info = info * forget
    measured = np.isfinite(fit.radius_std) & (fit.radius_std < 1e-3)
    std = np.maximum(fit.radius_std, 1e-5)
    w = np.where(measured, 1.0 / std**2, 0.0)
    spread = np.sqrt(1.0 / np.maximum(info, 1e-12) + std**2)
    changed = measured & (np.abs(fit.radius_bins - mean) > change_sigmas * spread)
    info = np.where(changed, 0.05 * info, info)
    mean = np.where(measured, (mean * info + fit.radius_bins * w) / np.maximum(info + w, 1e-12), mean)
    info = np.minimum(info + w, 1.0 / floor_m**2)
    return mean, info


@numba.njit(cache=True, nogil=True)
def _edge_sides(knots, control, baseline, sides, us, xy, centres):
    out = np.empty(sides.shape[0])
    count = control.shape[0]
    C = np.empty(3)
    D = np.empty(3)
    work, values, deriv = basis_workspace()
    for i in range(sides.shape[0]):
        first = basis_into(knots, count, min(max(us[i], 0.0), 1.0), work, values, deriv)
        _axis_at(control, first, values, deriv, baseline if sides[i] == 1 else 0.0, C, D)
        out[i] = _side_of(C, D, xy[i, 0] - centres[i, 0], xy[i, 1] - centres[i, 1])
    return out
