"""3D reconstruction (section 3.3): linear least squares on the two projection equations."""

from __future__ import annotations

import numpy as np


def triangulate(P_left: np.ndarray, P_right: np.ndarray, uv_left: np.ndarray, uv_right: np.ndarray) -> np.ndarray:
    """Solve eq. (7) A_j Q_j = B_j for every point in the least-squares sense (eq. 8).

    Args:
        P_left, P_right: 3x4 projection matrices M_L, M_R of undistorted (rectified) images.
        uv_left, uv_right: (N, 2) corresponding pixels.

    Returns:
        (N, 3) points in the frame of the projection matrices, metres.
    """
    uv_left = np.asarray(uv_left, dtype=np.float64).reshape(-1, 2)
    uv_right = np.asarray(uv_right, dtype=np.float64).reshape(-1, 2)
    if uv_left.shape != uv_right.shape:
        raise ValueError(f"uv_left and uv_right: expected equal shapes, got {uv_left.shape} and {uv_right.shape}")
    rows = []
    rhs = []
    for P, uv in ((P_left, uv_left), (P_right, uv_right)):
        P = np.asarray(P, dtype=np.float64)
        if P.shape != (3, 4):
            raise ValueError(f"projection matrix: expected shape (3, 4), got {P.shape}")
        for axis in (0, 1):  # eq. (5)/(6): (u m_3 - m_1) Q = m_14 - u m_34, and the same for v
            c = uv[:, axis:axis + 1]
            rows.append(c * P[2, :3] - P[axis, :3])
            rhs.append(P[axis, 3] - c[:, 0] * P[2, 3])
    A = np.stack(rows, axis=1)  # (N, 4, 3)
    B = np.stack(rhs, axis=1)  # (N, 4)
    # Normal equations per point: the generalised-inverse solution of the paper.
    AtA = np.einsum("nki,nkj->nij", A, A)
    AtB = np.einsum("nki,nk->ni", A, B)
    return np.linalg.solve(AtA, AtB[..., None])[..., 0]
