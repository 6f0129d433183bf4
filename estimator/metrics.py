"""Error measures: the paper's SOM errors (eqs. 9-11), scores against a ground-truth backbone,
and the paper's own comparison with depth-camera points Q' (section 5.3)."""

from __future__ import annotations

import cv2
import numpy as np

from estimator.calibration import StereoCalibration


def topology_error(points: np.ndarray, nodes: np.ndarray) -> float:
    """Eq. (9): fraction of samples whose best and second-best nodes are not neighbours."""
    points, nodes = _as2d(points, "points"), _as2d(nodes, "nodes")
    if len(nodes) < 2 or len(points) == 0:
        return 0.0
    d = ((points[:, None, :] - nodes[None, :, :]) ** 2).sum(2)
    two = np.argsort(d, axis=1)[:, :2]
    return float(np.mean(np.abs(two[:, 0] - two[:, 1]) != 1))


def quantization_error(points: np.ndarray, nodes: np.ndarray) -> float:
    """Eq. (10): mean distance from each sample to its winning node, pixels."""
    points, nodes = _as2d(points, "points"), _as2d(nodes, "nodes")
    d = np.sqrt(((points[:, None, :] - nodes[None, :, :]) ** 2).sum(2))
    return float(d.min(1).mean()) if len(points) else 0.0


def misalignment_error(left_nodes: np.ndarray, right_nodes: np.ndarray) -> float:
    """Eq. (11): mean |v_L - v_R| of corresponding rectified nodes, pixels."""
    left_nodes, right_nodes = _as2d(left_nodes, "left_nodes"), _as2d(right_nodes, "right_nodes")
    if left_nodes.shape != right_nodes.shape:
        raise ValueError(f"expected equal node counts, got {left_nodes.shape} and {right_nodes.shape}")
    return float(np.mean(np.abs(left_nodes[:, 1] - right_nodes[:, 1])))


def closest_points_on_polyline(points: np.ndarray, polyline: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each point, the closest point on a polyline and its arc length along it.

    Args:
        points: (N, D); polyline: (M, D) ordered, M >= 2.

    Returns:
        closest (N, D) and arc (N,) in the polyline's units.
    """
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    seg_len2 = np.maximum((ab**2).sum(1), 1e-300)
    t = np.clip(np.einsum("nmd,md->nm", points[:, None, :] - a[None], ab) / seg_len2, 0.0, 1.0)
    proj = a[None] + t[..., None] * ab[None]
    d2 = ((points[:, None, :] - proj) ** 2).sum(2)
    best = np.argmin(d2, axis=1)
    rows = np.arange(len(points))
    cum = np.concatenate([[0.0], np.cumsum(np.sqrt(seg_len2))])
    return proj[rows, best], cum[best] + t[rows, best] * np.sqrt(seg_len2[best])


def score_against_backbone(points: np.ndarray, backbone: np.ndarray) -> dict[str, float]:
    """Errors of an estimated centerline against the exact backbone (same frame, metres).

    Returns (millimetres):
        rmse_mm: point-to-curve RMSE; rmse_x/y/z_mm: per-axis RMSE of that residual;
        max_mm: largest point-to-curve distance; tip_mm, base_mm: end-point errors;
        arc_rmse_mm: RMSE against the backbone point at the same arc-length fraction
        (penalises points sliding along the curve); length_error_mm: estimated minus true length.
    """
    points, backbone = _as2d(points, "points", 3), _as2d(backbone, "backbone", 3)
    if len(backbone) < 2 or len(points) == 0:
        raise ValueError("score_against_backbone: need at least one point and a backbone of two points")
    closest, _ = closest_points_on_polyline(points, backbone)
    residual = points - closest
    dist = np.linalg.norm(residual, axis=1)
    frac_est = _fractions(points)
    frac_gt = _fractions(backbone)
    matched = np.column_stack([np.interp(frac_est, frac_gt, backbone[:, k]) for k in range(3)])
    rmse_axes = np.sqrt(np.mean(residual**2, axis=0)) * 1e3
    return {
        "rmse_mm": float(np.sqrt(np.mean(dist**2)) * 1e3),
        "rmse_x_mm": float(rmse_axes[0]),
        "rmse_y_mm": float(rmse_axes[1]),
        "rmse_z_mm": float(rmse_axes[2]),
        "max_mm": float(dist.max() * 1e3),
        "tip_mm": float(np.linalg.norm(points[-1] - backbone[-1]) * 1e3),
        "base_mm": float(np.linalg.norm(points[0] - backbone[0]) * 1e3),
        "arc_rmse_mm": float(np.sqrt(np.mean(((points - matched) ** 2).sum(1))) * 1e3),
        "length_error_mm": float((_length(points) - _length(backbone)) * 1e3),
    }


def depth_camera_points(uv_left_raw: np.ndarray, depth_left_m: np.ndarray,
                        calibration: StereoCalibration) -> np.ndarray:
    """Q' of section 5.3: back-project left-image pixels with a depth map (Q'_j = g(u_Lj, v_Lj)).

    Args:
        uv_left_raw: (n, 2) raw left pixels (e.g. the SOM centerline).
        depth_left_m: (H, W) depth along the optical axis in raw left pixels; <= 0 or non-finite
            means no depth.
        calibration: gives the left intrinsics and distortion.

    Returns:
        (n, 3) points in the left camera frame, metres; NaN rows where there is no depth.
    """
    uv = _as2d(uv_left_raw, "uv_left_raw")
    h, w = depth_left_m.shape
    if (w, h) != calibration.image_size:
        raise ValueError(f"depth_left_m: expected {calibration.image_size[1]}x{calibration.image_size[0]}, "
                         f"got {h}x{w}")
    cols = np.clip(np.round(uv[:, 0]).astype(int), 0, w - 1)
    rows = np.clip(np.round(uv[:, 1]).astype(int), 0, h - 1)
    z = depth_left_m[rows, cols].astype(np.float64)
    z = np.where(np.isfinite(z) & (z > 0), z, np.nan)
    rays = cv2.undistortPoints(uv.reshape(-1, 1, 2), calibration.K_left, calibration.dist_left.reshape(1, -1))
    rays = rays.reshape(-1, 2)
    return np.column_stack([rays[:, 0] * z, rays[:, 1] * z, z])


def axis_depth_points(uv_left_raw: np.ndarray, backbone_m: np.ndarray, calibration: StereoCalibration,
                      samples: int = 2000) -> np.ndarray:
    """Q' with the axis's depth instead of the surface's: back-project left pixels at the depth of
    the exact backbone point seen nearest to each pixel.

    The paper's Q' reads the depth camera at the centerline pixels, which sees the tube's surface,
    about one radius in front of the axis; this variant (twin only: it needs the exact backbone)
    takes that offset out of Table 2's z column.

    Args:
        uv_left_raw: (n, 2) raw left pixels.
        backbone_m: (N, 3) exact backbone, left camera frame, metres, N >= 2.
        calibration: the left intrinsics and distortion.
        samples: backbone points (evenly along it) the nearest one is chosen from.

    Returns:
        (n, 3) points in the left camera frame, metres.
    """
    uv = _as2d(uv_left_raw, "uv_left_raw")
    backbone = _as2d(backbone_m, "backbone_m", 3)
    if len(backbone) < 2:
        raise ValueError("backbone_m: expected at least two points")
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(backbone, axis=0), axis=1))])
    at = np.linspace(0.0, arc[-1], samples)
    dense = np.column_stack([np.interp(at, arc, backbone[:, k]) for k in range(3)])
    seen = calibration.project(dense, "left")
    nearest = np.argmin(((uv[:, None, :] - seen[None, :, :]) ** 2).sum(axis=2), axis=1)
    z = dense[nearest, 2]
    rays = cv2.undistortPoints(uv.reshape(-1, 1, 2), calibration.K_left, calibration.dist_left.reshape(1, -1))
    rays = rays.reshape(-1, 2)
    return np.column_stack([rays[:, 0] * z, rays[:, 1] * z, z])


def axis_rmse(points: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """Per-axis RMSE between corresponding points (the paper's Table 2 measure), millimetres.

    Rows with NaN in either set are skipped; ``count`` says how many were used.
    """
    points, reference = _as2d(points, "points", 3), _as2d(reference, "reference", 3)
    if points.shape != reference.shape:
        raise ValueError(f"expected equal shapes, got {points.shape} and {reference.shape}")
    ok = np.all(np.isfinite(points), 1) & np.all(np.isfinite(reference), 1)
    if not ok.any():
        return {"x_mm": float("nan"), "y_mm": float("nan"), "z_mm": float("nan"), "count": 0}
    rmse = np.sqrt(np.mean((points[ok] - reference[ok]) ** 2, axis=0)) * 1e3
    return {"x_mm": float(rmse[0]), "y_mm": float(rmse[1]), "z_mm": float(rmse[2]), "count": int(ok.sum())}


def _fractions(points: np.ndarray) -> np.ndarray:
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return arc / max(arc[-1], 1e-12)


def _length(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def _as2d(array, name: str, dim: int = 2) -> np.ndarray:
    array = np.asarray(array, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != dim:
        raise ValueError(f"{name}: expected shape (N, {dim}), got {array.shape}")
    return array
