"""Visual hull of an object from its masks (space carving on a voxel grid) and its surface.

Each keyframe's mask becomes a signed distance image (pixels, positive inside). A voxel's value is
a low order statistic over the views that see it (the ``skip``-th smallest: a mask that misses
part of the object in one view does not cut it away), so the zero level set is the visual hull with
sub-pixel boundaries. Depth maps (e.g. rendered from the object's Gaussians) carve the free space
in front of the surfaces they see. Below the support plane the field is negative: the unseen
underside is closed against the table. Marching cubes (scikit-image) turns the zero level into a mesh.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..geometry.camera import Camera
from .errors import ObjectsError

__all__ = ["Grid", "carve", "signed_distance_image", "surface_mesh"]


@dataclass
class Grid:
    """An axis-aligned voxel grid in the base frame: ``origin`` [3] (centre of voxel 0,0,0), ``voxel``
    edge (metres), ``shape`` (nx, ny, nz)."""

    origin: np.ndarray
    voxel: float
    shape: tuple[int, int, int]

    @classmethod
    def around(cls, lo: np.ndarray, hi: np.ndarray, voxel: float) -> Grid:
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        shape = tuple(int(v) for v in np.ceil((hi - lo) / voxel).astype(int) + 1)
        return cls(lo, float(voxel), shape)  # type: ignore[arg-type]

    def centres(self) -> np.ndarray:
        """Voxel centres [nx*ny*nz, 3] in C order (x slowest)."""
        axes = [self.origin[k] + self.voxel * np.arange(self.shape[k]) for k in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def signed_distance_image(mask: np.ndarray) -> np.ndarray:
    """Signed distance [H,W] float32 in pixels to the mask boundary: > 0 inside, < 0 outside,
    +-0.5 on the pixels next to the boundary (so the zero level lies on pixel edges)."""
    import cv2

    m = np.asarray(mask, bool).astype(np.uint8)
    inside = cv2.distanceTransform(m, cv2.DIST_L2, 5)
    outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, 5)
    return np.where(m > 0, inside - 0.5, -(outside - 0.5)).astype(np.float32)


def _bilinear(img: np.ndarray, uv: np.ndarray, outside: float) -> np.ndarray:
    """Sample img [H,W] at pixel coordinates uv [N,2] (pixel centres at +0.5), ``outside`` off-image."""
    h, w = img.shape
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5
    ok = (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)
    x0 = np.clip(np.floor(x).astype(np.int64), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(np.int64), 0, h - 2)
    fx, fy = np.clip(x - x0, 0, 1), np.clip(y - y0, 0, 1)
    v = (
        img[y0, x0] * (1 - fx) * (1 - fy)
        + img[y0, x0 + 1] * fx * (1 - fy)
        + img[y0 + 1, x0] * (1 - fx) * fy
        + img[y0 + 1, x0 + 1] * fx * fy
    )
    return np.where(ok, v, outside)


def _nearest(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """img [H,W] at the pixels containing uv [N,2] (NaN off-image)."""
    h, w = img.shape
    ij = np.floor(uv).astype(np.int64)
    ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < w) & (ij[:, 1] < h)
    out = np.full(len(uv), np.nan, np.float64)
    out[ok] = img[ij[ok, 1], ij[ok, 0]]
    return out


def carve(
    grid: Grid,
    cameras: Sequence[Camera],
    masks: Sequence[np.ndarray | None],
    plane_height=None,
    skip: int = 1,
    name: str = "object",
    depths: Sequence[np.ndarray | None] | None = None,
    depth_edge_px: float = 2.0,
    depth_margin: float = 0.0,
) -> np.ndarray:
    """Carving field [nx,ny,nz] float32 (pixels; > 0 inside the hull) from the ``masks`` [H,W] bool of
    the ``cameras`` (None: the object is not seen there). ``plane_height(points) -> [N]`` gives the
    height above the support plane; the field is negative below it. ``skip`` views may disagree.

    ``depths`` [H,W] (metres along the camera's z, NaN where unknown) carve free space too: a voxel
    in front of the surface a keyframe sees is empty. Silhouettes alone cannot carve what lies
    above a flat top seen only from above at an angle; depth can. Only what lies more than
    ``depth_margin`` (metres) in front of the seen surface is carved (rendered depth is noisy)."""
    pts = grid.centres()
    dists = []
    for k, (cam, mask) in enumerate(zip(cameras, masks, strict=True)):
        if mask is None or not mask.any():  # an empty mask of a seen object is a failed mask, not evidence
            continue
        if mask.shape != (cam.height, cam.width):
            raise ObjectsError(f"{name}: mask of {cam.name} is {mask.shape[::-1]}, camera is {cam.width}x{cam.height}")
        uv, z = cam.project(pts)
        sdi = signed_distance_image(mask)
        sd = _bilinear(sdi, uv, np.nan)  # off-image: no evidence
        depth = None if depths is None else depths[k]
        if depth is not None:
            # depth jumps at the silhouette: a voxel beside the object may fall in a pixel that sees
            # its front; only depth well inside the mask is used
            d = _nearest(np.where(sdi >= depth_edge_px, depth, np.nan), uv)
            behind = (z - d + depth_margin) * cam.fx / np.maximum(z, 1e-9)  # pixels, > 0 behind the surface
            sd = np.where(np.isfinite(behind), np.minimum(sd, behind), sd)
        sd[z <= 0] = np.nan
        dists.append(sd.astype(np.float32))
    if len(dists) <= skip + 1:
        raise ObjectsError(f"{name}: masks in only {len(dists)} keyframe(s); carving needs at least {skip + 2}")
    d = np.stack(dists)  # [V, N]
    n_seen = np.isfinite(d).sum(0)
    d = np.where(np.isfinite(d), d, np.inf)
    d.sort(axis=0)
    k = np.minimum(skip, np.maximum(n_seen - 1, 0))
    field = np.take_along_axis(d, k[None], axis=0)[0]
    field[n_seen < max(3, skip + 2)] = -1.0  # seen by too few views to say
    if plane_height is not None:
        h = plane_height(pts)
        field = np.where(h < 0, np.minimum(field, h / grid.voxel), field)
    return field.reshape(grid.shape).astype(np.float32)


def surface_mesh(field: np.ndarray, grid: Grid, name: str = "object"):
    """Zero level set of ``field`` as a closed trimesh.Trimesh in the base frame (the field is padded
    with a negative border, so the surface closes at the grid's edges too)."""
    import trimesh
    from skimage.measure import marching_cubes

    f = np.pad(field, 1, constant_values=-1.0)
    f = np.nan_to_num(f, nan=-1.0, posinf=1e3, neginf=-1e3)
    if f.max() <= 0:
        raise ObjectsError(f"{name}: the masks carve the whole volume away (no voxel inside every view's mask)")
    verts, faces, _, _ = marching_cubes(f, level=0.0, spacing=(grid.voxel,) * 3)
    verts = verts - grid.voxel + grid.origin  # undo the pad
    # marching_cubes orients faces towards the higher values (inside); flip them to point outward
    mesh = trimesh.Trimesh(verts, faces[:, ::-1], process=True)
    parts = mesh.split(only_watertight=False)
    if len(parts) > 1:  # keep the object, not carving debris
        mesh = max(parts, key=lambda m: abs(m.volume) if m.is_watertight else len(m.faces))
    return mesh
