"""Silhouette fit of a mesh to the object's masks: a robust 2D chamfer between the mesh's projected
outline and each mask's outline, minimised over a similarity.

Used to place a user-supplied mesh. A 3D fit against the reconstruction cannot tell a near-symmetric
object (a banana) from its half-turned copy, and it inherits the reconstruction's bias (the carved
surface sits a few millimetres inside the true one, thin tips are missing), which tilts the fit by
several degrees. The masks see the outline directly in every keyframe, so they pick the right
hypothesis and pin the rotation; their own bias (an outline about a pixel inside, thin parts lost
to the background) still limits the scale to a percent or a few.

The mesh's outline in a view is the projection of its contour generator: the edges between a
face turned towards the camera and one turned away, sampled about once per pixel; the points that
project inside the silhouette (folds) are dropped. Its distance terms move continuously with the
pose, unlike a rasterised silhouette's pixel steps, so a derivative-free search converges.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geometry.camera import Camera
from ..geometry.rotation import rotvec_to_matrix
from ..geometry.sim3 import Sim3
from .carve import signed_distance_image

__all__ = ["SilhouetteCost", "refine_by_silhouettes"]


class SilhouetteCost:
    """``cost(sim3_mesh_to_base)``: mean over views of the robust mean distance (pixels) from the
    mesh's projected outline to the mask's outline plus the mask outline's to the mesh outline.
    Cauchy loss with scale ``tau`` pixels, so a part the mask lost (a tip) or gained (a shadow)
    counts little."""

    def __init__(
        self,
        mesh,
        cameras: Sequence[Camera],
        masks: Sequence[np.ndarray | None],
        tau: float = 1.0,
        max_faces: int = 6000,
    ):
        mesh = _decimated(mesh, max_faces)
        self.vertices = np.asarray(mesh.vertices, np.float64)  # [V,3] in the mesh's frame
        self.faces = np.asarray(mesh.faces, np.int64)  # [F,3]
        self.face_pairs = np.asarray(mesh.face_adjacency, np.int64)  # [E,2] faces sharing an edge
        self.pair_edges = np.asarray(mesh.face_adjacency_edges, np.int64)  # [E,2] that edge's vertices
        self.tau = float(tau)
        self.views: list[tuple[Camera, np.ndarray, np.ndarray]] = []  # (camera, mask SDF [H,W], outline [K,2])
        for cam, m in zip(cameras, masks, strict=True):
            if m is None or not m.any():
                continue
            m8 = (np.asarray(m) > 0).astype(np.uint8)  # bool or 0/255
            # signed distance to the mask's outline in pixels, > 0 outside (the carving's, negated)
            self.views.append((cam, -signed_distance_image(m8), _mask_outline(m8)))
        if not self.views:
            raise ValueError("no keyframe has a non-empty mask")

    def outline(self, vertices_base: np.ndarray, camera: Camera, shape: tuple[int, int]) -> np.ndarray:
        """Pixel positions [K,2] of the mesh's projected outline in ``camera`` (vertices in its frame),
        about one per pixel along it."""
        import cv2

        V, F = vertices_base, self.faces
        normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        eye = camera.T_world_cam[:3, 3]
        front = np.einsum("ij,ij->i", normals, eye - V[F].mean(1)) > 0
        edges = self.pair_edges[front[self.face_pairs[:, 0]] != front[self.face_pairs[:, 1]]]
        vuv, _ = camera.project(V)
        a, b = vuv[edges[:, 0]], vuv[edges[:, 1]]
        # samples along each contour edge, at least one per pixel of its projected length
        n = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1)), 1).astype(np.int64)
        edge = np.repeat(np.arange(len(edges)), n)
        t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 0.5) / np.repeat(n, n)
        uv = a[edge] + t[:, None] * (b[edge] - a[edge])
        # drop folds: points more than 2 px inside the silhouette, rasterised from the faces facing the
        # camera (fillPoly's even-odd rule leaves holes where they overlap: filled from the outside)
        lo = np.maximum(np.floor(vuv.min(0)).astype(np.int64) - 3, -3)
        hi = np.minimum(np.ceil(vuv.max(0)).astype(np.int64) + 3, [shape[1] + 3, shape[0] + 3])
        if np.any(hi - lo < 3):
            return uv[:0]
        roi = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), np.uint8)
        tris = np.round((vuv[F[front]] - lo - 0.5) * 16).astype(np.int32)
        cv2.fillPoly(roi, list(tris), 1, lineType=cv2.LINE_8, shift=4)
        reach = np.zeros((roi.shape[0] + 2, roi.shape[1] + 2), np.uint8)
        cv2.floodFill(roi, reach, (0, 0), 2)
        inner = cv2.erode((roi != 2).astype(np.uint8), np.ones((5, 5), np.uint8))
        ij = np.clip(np.floor(uv).astype(np.int64) - lo, 0, [roi.shape[1] - 1, roi.shape[0] - 1])
        return uv[inner[ij[:, 1], ij[:, 0]] == 0]

    def __call__(self, sim3_mesh_to_base: Sim3) -> float:
        from scipy.ndimage import map_coordinates
        from scipy.spatial import cKDTree

        V = sim3_mesh_to_base.apply(self.vertices)
        total = 0.0
        for cam, sdf, mask_outline in self.views:
            uv = self.outline(V, cam, sdf.shape)
            if len(uv) == 0:
                return float("inf")
            to_mask = map_coordinates(sdf, [uv[:, 1] - 0.5, uv[:, 0] - 0.5], order=1, mode="nearest")
            to_mesh = cKDTree(uv).query(mask_outline)[0]
            total += self._rho(to_mask).mean() + self._rho(to_mesh).mean()
        return total / len(self.views)

    def _rho(self, r: np.ndarray) -> np.ndarray:
        return np.log1p((r / self.tau) ** 2)


def refine_by_silhouettes(cost: SilhouetteCost, start: Sim3, max_evaluations: int = 600) -> tuple[Sim3, float]:
    """Powell search of a similarity about the mesh's centre (log-scale, rotation vector, translation)
    from ``start`` (mesh -> base); returns (sim3_mesh_to_base, final cost)."""
    from scipy.optimize import minimize

    centre = start.apply(cost.vertices).mean(0)
    step = np.array([0.01, 0.01, 0.01, 0.01, 0.002, 0.002, 0.002])  # 1% scale, ~0.6 deg, 2 mm

    def sim3(y: np.ndarray) -> Sim3:
        x = y * step
        s, R = float(np.exp(x[0])), rotvec_to_matrix(x[1:4])
        return Sim3(s, R, centre + x[4:7] - s * R @ centre) @ start

    res = minimize(
        lambda y: cost(sim3(y)),
        np.zeros(7),
        method="Powell",
        options={"maxfev": max_evaluations, "xtol": 1e-2, "ftol": 1e-5},
    )
    best = sim3(res.x)
    return best, float(cost(best))


def _mask_outline(m8: np.ndarray) -> np.ndarray:
    """Points [K,2] on the mask's outline: the midpoints of the pixel edges between a mask pixel and a
    4-neighbour outside it (pixel (x, y) spans [x, x+1] x [y, y+1])."""
    m = np.pad(m8 > 0, 1)
    core = m[1:-1, 1:-1]
    pts = []
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        y, x = np.nonzero(core & ~m[1 + dy : m.shape[0] - 1 + dy, 1 + dx : m.shape[1] - 1 + dx])
        pts.append(np.c_[x + 0.5 + 0.5 * dx, y + 0.5 + 0.5 * dy])
    return np.concatenate(pts).astype(np.float64)


def _decimated(mesh, max_faces: int):
    """The mesh with at most ``max_faces`` faces (outline accuracy needs no more; scans have 100k+)."""
    import trimesh

    if len(mesh.faces) <= max_faces:
        return mesh
    import fast_simplification

    v, f = fast_simplification.simplify(
        np.asarray(mesh.vertices, np.float32),
        np.asarray(mesh.faces),
        target_reduction=1.0 - max_faces / len(mesh.faces),
    )
    return trimesh.Trimesh(v.astype(np.float64), f, process=True)
