"""The 2D centerline stage: ordered nodes from one image's arm pixels, by the chosen method.

The SOM of the paper (online from a linear initialisation, or the default mode's batch SOM from
an ordered skeleton walk), or a baseline of section 4.3. Every method returns its nodes base
first: a warm chain keeps its order; otherwise the end nearest the base hint, or the top edge.
"""

from __future__ import annotations

import cv2
import numpy as np

from estimator.clustering import competitive_learning, kmeans_plus_plus, order_greedy
from estimator.config import EstimatorConfig
from estimator.segmentation import mask_points
from estimator.skeleton import ordered_skeleton_path, resample_polyline, thinning_centerline
from estimator.som import linear_init, som_batch, som_online


def centerline_nodes(mask: np.ndarray, samples: np.ndarray, config: EstimatorConfig, *,
                     warm: np.ndarray | None = None, base_hint: np.ndarray | None = None) -> np.ndarray:
    """Ordered 2D centerline nodes of one image.

    Args:
        mask: (H, W) uint8 arm mask of a rectified image (or a region of it).
        samples: (K, 2) the SOM's input pixels in the same coordinates (contour or mask points).
        config: method (``centerline``), SOM parameters, mode.
        warm: (n, 2) the previous frame's nodes in the same coordinates, or None for a cold start.
        base_hint: (2,) a pixel near the arm's base, or None (the end nearest the top edge).

    Returns:
        (n, 2) nodes, base first (fewer for thinning on a tiny skeleton, empty if none).
    """
    cfg = config
    n = cfg.n_points
    if cfg.centerline == "thinning":
        nodes = thinning_centerline(mask, n)
    elif cfg.centerline == "skeleton":
        nodes = resample_polyline(ordered_skeleton_path(mask, base_hint), n)
    elif cfg.centerline == "kmeans++":
        nodes = _walk_from_base(kmeans_plus_plus(samples, n, seed=cfg.som_seed), samples, base_hint)
    else:
        if warm is not None:
            init = warm
        elif cfg.mode == "default":
            init = _skeleton_start(mask, base_hint, n)
        else:
            init = linear_init(samples, n)
        if cfg.centerline == "competitive":
            nodes = competitive_learning(samples, init, epochs=cfg.som_epochs, alpha=cfg.som_alpha0,
                                         seed=cfg.som_seed, order=cfg.som_order)
            # Winner-take-all keeps no neighbourhood, so nodes overtake each other (a straight arm
            # comes back with rows 271, 247, 298, ...): order them like the K-Means++ centres.
            nodes = _walk_from_base(nodes, samples, base_hint if warm is None else nodes[0])
        else:
            nodes = init
            if cfg.som_schedule == "online":
                nodes = som_online(samples, nodes, epochs=cfg.som_epochs, alpha0=cfg.som_alpha0,
                                   lam=float(cfg.som_epochs), radius=cfg.som_radius, sigma0=cfg.som_sigma,
                                   seed=cfg.som_seed, time=cfg.som_time, compiled=cfg.som_compiled,
                                   order=cfg.som_order, shrink=cfg.som_shrink)
            nodes = som_batch(samples, nodes, iterations=cfg.som_refine_iterations)
    if len(nodes) < 2 or warm is not None:
        return nodes
    return _base_first(nodes, base_hint)


def _walk_from_base(centres: np.ndarray, samples: np.ndarray, base_hint: np.ndarray | None) -> np.ndarray:
    """Unordered centres as a chain: a greedy nearest-neighbour walk from the one nearest the base.

    This is the sorting step a user of the clustering baselines has to add (section 4.3); it
    fails where two parts of the arm come closer than the node spacing, which is the point of
    the comparison.
    """
    start = base_hint if base_hint is not None else samples[np.argmin(samples[:, 1])]
    return order_greedy(centres, start)


def _skeleton_start(mask: np.ndarray, base_hint: np.ndarray | None, n: int) -> np.ndarray:
    """Ordered initial nodes from the skeleton (half resolution), robust to U and S shapes."""
    half = cv2.resize(mask, (mask.shape[1] // 2, mask.shape[0] // 2), interpolation=cv2.INTER_AREA)
    half = np.where(half >= 128, 255, 0).astype(np.uint8)
    path = ordered_skeleton_path(half, None if base_hint is None else base_hint / 2)
    if len(path) < 2:
        return linear_init(mask_points(mask, 2), n)
    return resample_polyline(path * 2.0 + 0.5, n)


def _base_first(nodes: np.ndarray, base_hint: np.ndarray | None) -> np.ndarray:
    """Flip a chain so that it starts at the end nearest the base hint, or the top edge."""
    if base_hint is not None:
        flip = np.linalg.norm(nodes[-1] - base_hint) < np.linalg.norm(nodes[0] - base_hint)
    else:
        flip = nodes[-1, 1] < nodes[0, 1]
    return nodes[::-1].copy() if flip else nodes
