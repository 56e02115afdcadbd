"""Which points lie inside a closed triangle mesh: the parity of a +z ray's crossings, with the triangles
binned on an xy grid, in numba.

trimesh's ``mesh.contains`` (ray tests through an rtree) took 9.6 s for 8,192 points against a 22k-face
object mesh on 2 cores; the objects stage asks it for ~60k Gaussians twice per object (pruning the
Gaussians deep inside the reconstruction), which was about a quarter of the stage. This answers the same
question in well under a second. Crossings are counted once per shared edge or vertex (a top-left rule
on the xy edge functions), so a ray through an edge is not counted twice.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

__all__ = ["points_inside"]


@njit(cache=True)
def _bin_triangles(tri_xy_lo, tri_xy_hi, lo, cell, nx, ny):
    """CSR (start [nx*ny+1], ids) of the triangles whose xy box overlaps each cell."""
    n = tri_xy_lo.shape[0]
    counts = np.zeros(nx * ny + 1, np.int64)
    for t in range(n):
        i0 = max(0, min(nx - 1, int((tri_xy_lo[t, 0] - lo[0]) / cell[0])))
        i1 = max(0, min(nx - 1, int((tri_xy_hi[t, 0] - lo[0]) / cell[0])))
        j0 = max(0, min(ny - 1, int((tri_xy_lo[t, 1] - lo[1]) / cell[1])))
        j1 = max(0, min(ny - 1, int((tri_xy_hi[t, 1] - lo[1]) / cell[1])))
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                counts[i * ny + j + 1] += 1
    start = np.cumsum(counts)
    fill = start[:-1].copy()
    ids = np.empty(start[-1], np.int64)
    for t in range(n):
        i0 = max(0, min(nx - 1, int((tri_xy_lo[t, 0] - lo[0]) / cell[0])))
        i1 = max(0, min(nx - 1, int((tri_xy_hi[t, 0] - lo[0]) / cell[0])))
        j0 = max(0, min(ny - 1, int((tri_xy_lo[t, 1] - lo[1]) / cell[1])))
        j1 = max(0, min(ny - 1, int((tri_xy_hi[t, 1] - lo[1]) / cell[1])))
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                c = i * ny + j
                ids[fill[c]] = t
                fill[c] += 1
    return start, ids


@njit(cache=True, inline="always")
def _owns(w, ex, ey):
    """Whether a point with edge function ``w`` belongs to the edge (ex, ey): strictly inside, or exactly on
    it and the edge is a "top" or "left" one, so that of two triangles sharing it exactly one counts."""
    if w != 0.0:
        return w > 0.0
    return ey < 0.0 or (ey == 0.0 and ex > 0.0)


@njit(parallel=True, cache=True)
def _parity(points, v, faces, start, ids, lo, cell, nx, ny, out):
    for k in prange(points.shape[0]):
        px, py, pz = points[k, 0], points[k, 1], points[k, 2]
        i, j = int((px - lo[0]) / cell[0]), int((py - lo[1]) / cell[1])
        out[k] = False
        if px < lo[0] or py < lo[1] or i >= nx or j >= ny:
            continue
        c = i * ny + j
        crossings = 0
        for s in range(start[c], start[c + 1]):
            f = ids[s]
            a, b, d = faces[f, 0], faces[f, 1], faces[f, 2]
            ax, ay, bx, by, dx, dy = v[a, 0], v[a, 1], v[b, 0], v[b, 1], v[d, 0], v[d, 1]
            area = (bx - ax) * (dy - ay) - (by - ay) * (dx - ax)
            if area == 0.0:
                continue  # seen edge-on from the ray: no transversal crossing
            sgn = 1.0 if area > 0.0 else -1.0
            # edge functions of the xy projection, oriented so that the inside is positive
            w0 = sgn * ((dx - bx) * (py - by) - (dy - by) * (px - bx))
            w1 = sgn * ((ax - dx) * (py - dy) - (ay - dy) * (px - dx))
            w2 = sgn * ((bx - ax) * (py - ay) - (by - ay) * (px - ax))
            if not (_owns(w0, sgn * (dx - bx), sgn * (dy - by)) and _owns(w1, sgn * (ax - dx), sgn * (ay - dy))
                    and _owns(w2, sgn * (bx - ax), sgn * (by - ay))):  # fmt: skip
                continue
            z = (w0 * v[a, 2] + w1 * v[b, 2] + w2 * v[d, 2]) / (sgn * area)
            if z > pz:
                crossings += 1
        out[k] = crossings % 2 == 1


def points_inside(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, cells: int = 64) -> np.ndarray:
    """bool [N]: whether each of ``points`` [N,3] lies inside the closed mesh (``vertices`` [V,3], ``faces``
    [F,3]); the mesh must be watertight (parity is meaningless otherwise)."""
    v = np.ascontiguousarray(vertices, np.float64)
    f = np.ascontiguousarray(faces, np.int64)
    pts = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    out = np.zeros(len(pts), bool)
    if not len(f) or not len(pts):
        return out
    tri = v[f][:, :, :2]  # [F,3,2]
    lo = v[:, :2].min(0)
    span = np.maximum(v[:, :2].max(0) - lo, 1e-12)
    cell = span / cells * (1 + 1e-9)
    start, ids = _bin_triangles(tri.min(1), tri.max(1), lo, cell, cells, cells)
    _parity(pts, v, f, start, ids, lo, cell, cells, cells, out)
    return out
