"""Scaled ICP (paper eq. `icp`): the similarity that best maps a source cloud onto a target cloud.

Point-to-point ICP with a similarity (Umeyama) step, nearest neighbours from a k-d tree, a robust
trim of the worst correspondences and a coarse-to-fine schedule of the trim distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .sim3 import Sim3
from .umeyama import umeyama


@dataclass
class ICPResult:
    sim3: Sim3  # source -> target
    rmse: float  # of the inlier correspondences at the end, target units
    inlier_fraction: float
    iterations: int


def scaled_icp(
    source: np.ndarray,
    target: np.ndarray,
    init: Sim3 | None = None,
    with_scale: bool = True,
    max_iterations: int = 60,
    trim_fraction: float = 0.9,
    max_distance: float | None = None,
    tolerance: float = 1e-9,
    anchors: tuple[np.ndarray, np.ndarray] | None = None,
    anchor_weight: float = 1.0,
) -> ICPResult:
    """Align ``source`` [N,3] to ``target`` [M,3] starting from ``init`` (default identity).

    Each iteration pairs every transformed source point with its nearest target point, keeps the
    ``trim_fraction`` closest pairs (and those within ``max_distance``, which shrinks towards the
    current error: coarse to fine), and solves for the similarity with Umeyama.
    ``anchors`` = (src [K,3], dst [K,3]) are fixed correspondences (landmarks) added to every solve
    with a total weight of ``anchor_weight`` times that of the nearest-neighbour pairs: they pin the
    directions in which the surfaces alone are ambiguous (e.g. sliding along a plane).
    """
    from scipy.spatial import cKDTree

    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if source.ndim != 2 or source.shape[1] != 3 or len(source) < 3:
        raise ValueError(f"scaled_icp: source must be [N>=3, 3], got {source.shape}")
    if target.ndim != 2 or target.shape[1] != 3 or len(target) < 3:
        raise ValueError(f"scaled_icp: target must be [M>=3, 3], got {target.shape}")
    tree = cKDTree(target)
    sim = init or Sim3.identity()
    prev = np.inf
    rmse, inlier_fraction, iterations = np.inf, 0.0, 0
    gate = max_distance
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (reported after the loop)
        moved = sim.apply(source)
        dist, idx = tree.query(moved, workers=-1)  # every core: the queries are most of the time
        keep = dist <= np.quantile(dist, trim_fraction)
        if gate is not None:
            keep &= dist <= gate
        if keep.sum() < 3:
            raise ValueError("scaled_icp: fewer than 3 correspondences left; give a closer initial alignment")
        # Solve for the full transform from the original source points (not an increment).
        src, dst = source[keep], target[idx[keep]]
        if anchors is None:
            sim = umeyama(src, dst, with_scale=with_scale)
        else:
            a_src, a_dst = (np.asarray(a, dtype=np.float64) for a in anchors)
            w = np.concatenate([np.ones(len(src)), np.full(len(a_src), anchor_weight * len(src) / len(a_src))])
            sim = umeyama(np.concatenate([src, a_src]), np.concatenate([dst, a_dst]), with_scale=with_scale, weights=w)
        rmse = float(np.sqrt(np.mean(dist[keep] ** 2)))
        inlier_fraction = float(keep.mean())
        if gate is not None:
            gate = max(3.0 * rmse, 0.5 * gate)  # coarse to fine, never below the current spread
        if abs(prev - rmse) <= tolerance * max(rmse, 1e-12):
            break
        prev = rmse
    return ICPResult(sim, rmse, inlier_fraction, iterations)
