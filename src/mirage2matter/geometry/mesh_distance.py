"""Exact unsigned distance from points to a triangle mesh's surface, fast on the CPU.

Candidates come from a k-d tree of the triangles' centroids: a triangle whose centroid lies at distance c from
the point is at least c - r from it (r: the largest centroid-to-corner distance of any triangle), so once the
best of the k nearest centroids' triangles is closer than the k-th centroid's distance minus r, no other
triangle can beat it. The few points without that proof (k too small there) fall back to every triangle
within the bound. Point-triangle distances by Voronoi regions (Ericson, Real-Time Collision Detection, 5.1.5).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["point_mesh_distance", "point_mesh_nearest"]


@njit(cache=True, inline="always")
def _point_triangle_sq(p, a, b, c):
    """Squared distance from p [3] to the triangle (a, b, c)."""
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ac0, ac1, ac2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    ap0, ap1, ap2 = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    if d1 <= 0.0 and d2 <= 0.0:  # vertex a
        q0, q1, q2 = a[0], a[1], a[2]
    else:
        bp0, bp1, bp2 = p[0] - b[0], p[1] - b[1], p[2] - b[2]
        d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
        d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
        cp0, cp1, cp2 = p[0] - c[0], p[1] - c[1], p[2] - c[2]
        d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
        d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:  # vertex b
            q0, q1, q2 = b[0], b[1], b[2]
        elif d6 >= 0.0 and d5 <= d6:  # vertex c
            q0, q1, q2 = c[0], c[1], c[2]
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:  # edge ab
            t = d1 / (d1 - d3)
            q0, q1, q2 = a[0] + t * ab0, a[1] + t * ab1, a[2] + t * ab2
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:  # edge ac
            t = d2 / (d2 - d6)
            q0, q1, q2 = a[0] + t * ac0, a[1] + t * ac1, a[2] + t * ac2
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:  # edge bc
            t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            q0, q1, q2 = b[0] + t * (c[0] - b[0]), b[1] + t * (c[1] - b[1]), b[2] + t * (c[2] - b[2])
        else:  # inside the face
            den = va + vb + vc
            v, w = vb / den, vc / den
            q0 = a[0] + v * ab0 + w * ac0
            q1 = a[1] + v * ab1 + w * ac1
            q2 = a[2] + v * ab2 + w * ac2
    e0, e1, e2 = p[0] - q0, p[1] - q1, p[2] - q2
    return e0 * e0 + e1 * e1 + e2 * e2


@njit(parallel=True, cache=True)
def _nearest_of_candidates(points, tris, cand, out, out_tri):
    """out[n] = distance from points[n] to the nearest of the triangles tris[cand[n, j]] (j with cand >= 0), out_tri[n]
    that triangle's index."""
    for n in prange(points.shape[0]):
        best = np.inf
        best_t = -1
        for j in range(cand.shape[1]):
            t = cand[n, j]
            if t < 0:
                continue
            d = _point_triangle_sq(points[n], tris[t, 0], tris[t, 1], tris[t, 2])
            if d < best:
                best = d
                best_t = t
        out[n] = math.sqrt(best)
        out_tri[n] = best_t


def point_mesh_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, k: int = 16) -> np.ndarray:
    """Distance [N] from ``points`` [N,3] to the nearest point of the triangles ``vertices[faces]`` (exact)."""
    return point_mesh_nearest(points, vertices, faces, k)[0]


def point_mesh_nearest(
    points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, k: int = 16
) -> tuple[np.ndarray, np.ndarray]:
    """Distance [N] from ``points`` [N,3] to the nearest point of the triangles ``vertices[faces]`` (exact), and the
    index [N] of that triangle in ``faces``."""
    from scipy.spatial import cKDTree

    pts = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    tris = np.ascontiguousarray(np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)])  # [T,3,3]
    if len(tris) == 0:
        raise ValueError("point_mesh_distance: the mesh has no triangles")
    out, out_tri = np.empty(len(pts)), np.empty(len(pts), np.int64)
    if len(pts) == 0:
        return out, out_tri
    centroids = tris.mean(1)
    reach = float(np.linalg.norm(tris - centroids[:, None], axis=2).max())
    tree = cKDTree(centroids)
    k = min(k, len(tris))
    c_dist, cand = tree.query(pts, k=k, workers=-1)
    c_dist, cand = c_dist.reshape(len(pts), k), cand.reshape(len(pts), k)
    _nearest_of_candidates(pts, tris, np.ascontiguousarray(cand, np.int64), out, out_tri)
    # unproven: a triangle beyond the k-th centroid could still be nearer; take every one within the bound
    unproven = np.flatnonzero((k < len(tris)) & (c_dist[:, -1] - reach < out))
    if len(unproven):
        near = tree.query_ball_point(pts[unproven], out[unproven] + reach, workers=-1)
        width = max(len(ix) for ix in near)
        more = np.full((len(unproven), width), -1, np.int64)
        for row, ix in enumerate(near):
            more[row, : len(ix)] = ix
        best, best_tri = np.empty(len(unproven)), np.empty(len(unproven), np.int64)
        _nearest_of_candidates(pts[unproven], tris, more, best, best_tri)
        nearer = best < out[unproven]
        out[unproven[nearer]], out_tri[unproven[nearer]] = best[nearer], best_tri[nearer]
    return out, out_tri
