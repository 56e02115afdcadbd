"""Silhouette fit of a mesh to the object's masks: a robust 2D chamfer between the mesh's projected
outline and each mask's outline, minimised over a similarity.

Used to place a user-supplied mesh. A 3D fit against the reconstruction cannot tell a near-symmetric
object (a banana) from its half-turned copy, and it inherits the reconstruction's bias (the carved
surface sits a few millimetres inside the true one, thin tips are missing), which tilts the fit by
several degrees. The masks see the outline directly in every keyframe, so they pick the right
hypothesis and pin the rotation; their own bias (an outline about a pixel inside, thin parts lost
to the background) still limits the scale to a percent or a few.

The mesh's outline in a view is the projection of its smooth contour generator: over each face,
where the interpolated vertex normal is perpendicular to the view ray (Hertzmann & Zorin's smooth
silhouettes), sampled a few times per pixel; the points that project inside the silhouette (folds)
are dropped. Unlike the polygonal contour (edges between front and back faces), which jumps from
edge to edge, it moves continuously with the pose, and so does the cost: a derivative-free search
stops in fewer and shallower local minima.

Masks grow at the object's foot (its contact shadow, on the table right beside it, where the
matting's background is least known), which pulls the outline fit into the table and rolls it
towards the shadow (a banana: 1 deg or so). Given the support plane, a second term keeps the mesh's
lowest point on it: the object rests on the table.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geometry.camera import Camera
from ..geometry.rotation import rotvec_to_matrix
from ..geometry.sim3 import Sim3
from .carve import signed_distance_image
from .support import Plane

__all__ = ["SilhouetteCost", "refine_by_silhouettes"]


class SilhouetteCost:
    """``cost(sim3_mesh_to_base)``: mean over views of the robust mean distance (pixels) from the
    mesh's projected outline to the mask's outline plus the mask outline's to the mesh outline.
    Cauchy loss with scale ``tau`` pixels, so a part the mask lost (a tip) or gained (a shadow)
    counts little. With a support ``plane``, plus ``contact_weight`` times the Cauchy loss (scale
    ``contact_scale`` metres) of the mesh's lowest point's height above the plane."""

    def __init__(
        self,
        mesh,
        cameras: Sequence[Camera],
        masks: Sequence[np.ndarray | None],
        tau: float = 1.0,
        max_faces: int = 6000,
        samples_per_px: float = 2.0,
        plane: Plane | None = None,
        contact_weight: float = 1.0,
        contact_scale: float = 0.001,
    ):
        # the lowest point of the mesh on any plane is a vertex of its convex hull (the full mesh's)
        self.hull_vertices = np.asarray(mesh.convex_hull.vertices, np.float64) if plane is not None else None
        mesh = _decimated(mesh, max_faces)
        self.vertices = np.asarray(mesh.vertices, np.float64)  # [V,3] in the mesh's frame
        self.faces = np.asarray(mesh.faces, np.int64)  # [F,3]
        # area-weighted face and vertex normals in the mesh's frame: a similarity only rotates them
        # (its scale multiplies all by s^2, which neither the signs nor the crossings below see)
        V, F = self.vertices, self.faces
        self.face_normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # [F,3]
        self.vertex_normals = np.zeros_like(V)  # [V,3]
        np.add.at(self.vertex_normals, F.ravel(), np.repeat(self.face_normals, 3, axis=0))
        self.tau = float(tau)
        self.samples_per_px = float(samples_per_px)
        self.plane, self.contact_weight, self.contact_scale = plane, float(contact_weight), float(contact_scale)
        self.views: list[tuple[Camera, np.ndarray, np.ndarray]] = []  # (camera, mask SDF [H,W], outline [K,2])
        for cam, m in zip(cameras, masks, strict=True):
            if m is None or not m.any():
                continue
            m8 = (np.asarray(m) > 0).astype(np.uint8)  # bool or 0/255
            # signed distance to the mask's outline in pixels, > 0 outside (the carving's, negated)
            self.views.append((cam, -signed_distance_image(m8), _mask_outline(m8)))
        if not self.views:
            raise ValueError("no keyframe has a non-empty mask")

    def outline(
        self,
        vertices_base: np.ndarray,
        vertex_normals: np.ndarray,
        face_normals: np.ndarray,
        camera: Camera,
        shape: tuple[int, int],
    ) -> np.ndarray:
        """Pixel positions [K,2] of the mesh's projected smooth outline in ``camera`` (vertices [V,3],
        their normals [V,3] and the faces' [F,3] in its frame), ``samples_per_px`` per pixel along it."""
        import cv2

        V, F = vertices_base, self.faces
        eye = camera.T_world_cam[:3, 3]
        facing = np.einsum("ij,ij->i", vertex_normals, eye - V)[F]  # [F,3] > 0: towards the camera
        front = facing > 0
        crossed = front.any(1) & ~front.all(1)
        Fc, fc, frc = F[crossed], facing[crossed], front[crossed]
        # each crossed face holds one segment of the zero set, between its two edges that change sign
        corner_a, corner_b = np.array([0, 1, 2]), np.array([1, 2, 0])
        changes = frc[:, corner_a] != frc[:, corner_b]  # [M,3]
        ga, gb = fc[:, corner_a], fc[:, corner_b]
        t = np.where(changes, ga / np.where(changes, ga - gb, 1.0), 0.0)
        Va, Vb = V[Fc[:, corner_a]], V[Fc[:, corner_b]]  # [M,3,3]
        crossing = Va + t[..., None] * (Vb - Va)
        first = np.argmax(changes, axis=1)
        second = 2 - np.argmax(changes[:, ::-1], axis=1)
        rows = np.arange(len(Fc))
        a, _ = camera.project(crossing[rows, first])
        b, _ = camera.project(crossing[rows, second])
        n = np.maximum(np.ceil(self.samples_per_px * np.linalg.norm(b - a, axis=1)), 1).astype(np.int64)
        seg = np.repeat(np.arange(len(a)), n)
        s = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 0.5) / np.repeat(n, n)
        uv = a[seg] + s[:, None] * (b[seg] - a[seg])
        # drop folds: points more than 2 px inside the silhouette, rasterised from the faces facing the
        # camera (fillPoly's even-odd rule leaves holes where they overlap: filled from the outside)
        vuv, _ = camera.project(V)
        lo = np.maximum(np.floor(vuv.min(0)).astype(np.int64) - 3, -3)
        hi = np.minimum(np.ceil(vuv.max(0)).astype(np.int64) + 3, [shape[1] + 3, shape[0] + 3])
        if np.any(hi - lo < 3):
            return uv[:0]
        roi = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), np.uint8)
        towards = np.einsum("ij,ij->i", face_normals, eye - V[F].mean(1)) > 0
        tris = np.round((vuv[F[towards]] - lo - 0.5) * 16).astype(np.int32)
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
        R = sim3_mesh_to_base.rotation
        vertex_normals, face_normals = self.vertex_normals @ R.T, self.face_normals @ R.T
        total = 0.0
        for cam, sdf, mask_outline in self.views:
            uv = self.outline(V, vertex_normals, face_normals, cam, sdf.shape)
            if len(uv) == 0:
                return float("inf")
            to_mask = map_coordinates(sdf, [uv[:, 1] - 0.5, uv[:, 0] - 0.5], order=1, mode="nearest")
            to_mesh = cKDTree(uv).query(mask_outline)[0]
            total += self._rho(to_mask).mean() + self._rho(to_mesh).mean()
        total /= len(self.views)
        if self.plane is not None:
            lowest = float(self.plane.height(sim3_mesh_to_base.apply(self.hull_vertices)).min())
            total += self.contact_weight * float(np.log1p((lowest / self.contact_scale) ** 2))
        return total

    def _rho(self, r: np.ndarray) -> np.ndarray:
        return np.log1p((r / self.tau) ** 2)


def refine_by_silhouettes(
    cost: SilhouetteCost, start: Sim3, max_evaluations: int = 600, restart_deg: float = 1.0
) -> tuple[Sim3, float]:
    """Powell search of a similarity about the mesh's centre (log-scale, rotation vector, translation)
    from ``start`` (mesh -> base); returns (sim3_mesh_to_base, final cost). Then two more searches
    from the result turned by +-``restart_deg`` about the mesh's long axis (0: none), the best kept:
    turning an elongated object about its long axis changes its outline least, and the cost has
    shallow local minima along it (a banana's stopped 0.4-1.2 deg from the truth, by start)."""
    best, best_cost = _powell(cost, start, max_evaluations)
    if restart_deg > 0:
        V = best.apply(cost.vertices)
        centre = V.mean(0)
        long_axis = np.linalg.eigh(np.cov((V - centre).T))[1][:, -1]
        for sign in (-1.0, 1.0):
            R = rotvec_to_matrix(np.radians(sign * restart_deg) * long_axis)
            fit, c = _powell(cost, Sim3(1.0, R, centre - R @ centre) @ best, max_evaluations)
            if c < best_cost:
                best, best_cost = fit, c
    return best, best_cost


def _powell(cost: SilhouetteCost, start: Sim3, max_evaluations: int) -> tuple[Sim3, float]:
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
