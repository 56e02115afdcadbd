"""Where an object is in each keyframe: a 3D proxy from its points, and image regions around it.

The proxy is the object's points plus their footprint on the support plane, grown by a margin: a
convex region sure to contain the object. Its projection bounds the object in every keyframe, and
the work on that object (matting, training, metrics) runs on crops around it (``roi``), with the
intrinsics shifted accordingly.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ..geometry.camera import Camera
from .support import ObjectCluster, Plane

__all__ = ["crop_camera", "object_rois", "proxy_mask", "proxy_points"]


def proxy_points(points: np.ndarray, plane: Plane, margin: float) -> np.ndarray:
    """Points [K,3] whose convex hull holds the object: the vertices of the convex hull of ``points`` [N,3]
    and their footprint on the plane, each grown by ``margin`` sideways and upwards (never below the
    plane). Only the hull's vertices: every use (image bounds, projected hulls, sampling inside) depends on
    the hull alone, since a pinhole camera maps the hull of the points in front of it to the hull of their
    images; the full set (36 x the object's points) cost ~20 s of projections per object."""
    pts = np.asarray(points, np.float64)
    foot = pts - plane.height(pts)[:, None] * plane.normal
    both = np.concatenate([pts, foot])
    n = plane.normal
    e1 = np.cross(n, [1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.cross(n, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    steps = (-margin, 0.0, margin)
    offsets = np.array([a * e1 + b * e2 + c * n for a in steps for b in steps for c in (0.0, margin)])
    grown = (both[:, None] + offsets[None]).reshape(-1, 3)
    grown = grown[plane.height(grown) >= -1e-6]
    try:
        from scipy.spatial import ConvexHull

        return grown[np.sort(ConvexHull(grown).vertices)]
    except Exception:  # a degenerate (flat) set has no 3D hull: keep every point
        return grown


def proxy_mask(camera: Camera, proxy: np.ndarray, roi: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """The proxy's projection [h,w] bool inside ``roi`` (default: the whole image; its convex hull,
    filled). A proxy reaching behind the camera covers the whole roi."""
    import cv2

    x0, y0, x1, y1 = roi or (0, 0, camera.width, camera.height)
    uv, z = camera.project(proxy)
    if (z <= 0).any():
        return np.ones((y1 - y0, x1 - x0), bool)
    hull = cv2.convexHull(np.round((uv - 0.5 - [x0, y0]) * 16).astype(np.int32))
    m = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillConvexPoly(m, hull, 1, lineType=cv2.LINE_8, shift=4)
    return m.astype(bool)


def object_rois(
    cameras: Sequence[Camera], cluster: ObjectCluster, plane: Plane, margin: float = 0.03, min_px: int = 16
) -> dict[int, tuple[int, int, int, int]]:
    """Keyframe index -> roi (x0, y0, x1, y1) around the object, for the keyframes that see it: its
    centroid projects into the image, in front of the camera, and the clipped roi is at least
    ``min_px`` pixels on each side."""
    proxy = proxy_points(cluster.points, plane, margin)
    out = {}
    for i, cam in enumerate(cameras):
        (c_uv,), (c_z,) = cam.project(cluster.centroid[None])
        if c_z <= 0 or not (0 <= c_uv[0] < cam.width and 0 <= c_uv[1] < cam.height):
            continue
        uv, z = cam.project(proxy)
        if (z <= 0).any():
            continue
        x0, y0 = np.floor(uv.min(0) - 0.5).astype(int)
        x1, y1 = np.ceil(uv.max(0) + 0.5).astype(int)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, cam.width), min(y1, cam.height)
        if x1 - x0 >= min_px and y1 - y0 >= min_px:
            out[i] = (int(x0), int(y0), int(x1), int(y1))
    return out


def crop_camera(camera: Camera, roi: tuple[int, int, int, int]) -> Camera:
    """The camera of the crop ``roi``: the same pose, principal point shifted, size of the crop."""
    x0, y0, x1, y1 = roi
    K = camera.K.copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    return dataclasses.replace(camera, K=K, T_world_cam=camera.T_world_cam.copy(), width=x1 - x0, height=y1 - y0,
                               distortion=dict(camera.distortion))  # fmt: skip
