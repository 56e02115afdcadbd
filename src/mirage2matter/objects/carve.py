"""Visual hull of an object from its masks (space carving on a voxel grid) and its surface.

Each keyframe's mask becomes a signed distance image (pixels, positive inside). A voxel's value is
a low order statistic over the views that see it (the ``skip``-th smallest: a mask that misses
part of the object in one view does not cut it away), so the zero level set is the visual hull with
sub-pixel boundaries. The vote has a price: a voxel just outside the object is cut only by the few
views that see it at the object's rim, and skipping those keeps a shell around the whole object.
Where masks are unreliable (low, against the table) it is worth it; higher up (``skip_below``) a
disagreement keeps only a chunk, as a missing piece of one mask leaves, not a shell. Depth maps
(e.g. rendered from the object's Gaussians) carve the free space in front of the surfaces they see.
Below the support plane the field is negative: the unseen underside is closed against the table.
Marching cubes (scikit-image) turns the zero level into a mesh.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from ..geometry.camera import Camera
from .errors import ObjectsError

__all__ = ["Grid", "carve", "largest_part", "signed_distance_image", "surface_mesh", "vote_near_support"]


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


@njit(parallel=True, cache=True)
def _view_distances_kernel(pts, V, K, sdi, depth, use_depth, depth_margin, out):
    h, w = sdi.shape
    for n in prange(pts.shape[0]):
        px, py, pz = pts[n, 0], pts[n, 1], pts[n, 2]
        x = V[0, 0] * px + V[0, 1] * py + V[0, 2] * pz + V[0, 3]
        y = V[1, 0] * px + V[1, 1] * py + V[1, 2] * pz + V[1, 3]
        z = V[2, 0] * px + V[2, 1] * py + V[2, 2] * pz + V[2, 3]
        if z <= 0.0:
            out[n] = np.nan
            continue
        u = (K[0, 0] * x + K[0, 1] * y + K[0, 2] * z) / z
        v = (K[1, 0] * x + K[1, 1] * y + K[1, 2] * z) / z
        # bilinear in the signed distance image (pixel centres at +0.5), no evidence off the image
        bx, by = u - 0.5, v - 0.5
        if not (bx >= 0.0 and by >= 0.0 and bx <= w - 1 and by <= h - 1):
            out[n] = np.nan
            continue
        x0 = min(max(int(math.floor(bx)), 0), w - 2)
        y0 = min(max(int(math.floor(by)), 0), h - 2)
        fx, fy = min(max(bx - x0, 0.0), 1.0), min(max(by - y0, 0.0), 1.0)
        sd = (sdi[y0, x0] * (1 - fx) * (1 - fy) + sdi[y0, x0 + 1] * fx * (1 - fy)
              + sdi[y0 + 1, x0] * (1 - fx) * fy + sdi[y0 + 1, x0 + 1] * fx * fy)  # fmt: skip
        if use_depth:
            i, j = int(math.floor(u)), int(math.floor(v))
            if 0 <= i < w and 0 <= j < h:
                behind = (z - depth[j, i] + depth_margin) * K[0, 0] / max(z, 1e-9)  # pixels, > 0 behind
                if np.isfinite(behind):
                    sd = min(sd, behind)
        out[n] = sd


def _view_distances(pts: np.ndarray, cam: Camera, sdi: np.ndarray, depth: np.ndarray | None, margin: float):
    """One view's evidence [N] float32 for voxel centres pts [N,3]: the signed distance image sdi [H,W]
    sampled bilinearly where each centre projects (pixels, > 0 inside the mask), lowered to the distance
    behind the surface the depth [H,W] (NaN: unknown) sees there; NaN off the image and behind the
    camera. One fused numba pass (numpy's projection of a 1M-voxel grid took 0.27 s per view)."""
    out = np.empty(len(pts), np.float32)
    d = np.zeros((1, 1), np.float64) if depth is None else np.ascontiguousarray(depth, np.float64)
    _view_distances_kernel(np.ascontiguousarray(pts, np.float64), np.ascontiguousarray(cam.viewmat, np.float64),
                           np.ascontiguousarray(cam.K, np.float64), np.ascontiguousarray(sdi, np.float64), d,
                           depth is not None, float(margin), out)  # fmt: skip
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
    skip_below: float | None = None,
) -> np.ndarray:
    """Carving field [nx,ny,nz] float32 (pixels; > 0 inside the hull) from the ``masks`` [H,W] bool of
    the ``cameras`` (None: the object is not seen there). ``plane_height(points) -> [N]`` gives the
    height above the support plane; the field is negative below it. ``skip`` views may disagree.

    ``depths`` [H,W] (metres along the camera's z, NaN where unknown) carve free space too: a voxel
    in front of the surface a keyframe sees is empty. Silhouettes alone cannot carve what lies
    above a flat top seen only from above at an angle; depth can. Only what lies more than
    ``depth_margin`` (metres) in front of the seen surface is carved (rendered depth is noisy).

    ``skip_below`` (metres above the plane; None: everywhere): the vote holds in full below it; above
    twice it, the voxels the vote keeps are kept only where they form a chunk (:func:`vote_near_support`)."""
    pts = grid.centres()
    dists = []
    for k, (cam, mask) in enumerate(zip(cameras, masks, strict=True)):
        if mask is None or not mask.any():  # an empty mask of a seen object is a failed mask, not evidence
            continue
        if mask.shape != (cam.height, cam.width):
            raise ObjectsError(f"{name}: mask of {cam.name} is {mask.shape[::-1]}, camera is {cam.width}x{cam.height}")
        sdi = signed_distance_image(mask)
        depth = None if depths is None else depths[k]
        # depth jumps at the silhouette: a voxel beside the object may fall in a pixel that sees its
        # front; only depth well inside the mask is used
        near = None if depth is None else np.where(sdi >= depth_edge_px, depth, np.nan)
        dists.append(_view_distances(pts, cam, sdi, near, depth_margin))
    if len(dists) <= skip + 1:
        raise ObjectsError(f"{name}: masks in only {len(dists)} keyframe(s); carving needs at least {skip + 2}")
    d = np.stack(dists)  # [V, N]
    n_seen = np.isfinite(d).sum(0)
    d = np.where(np.isfinite(d), d, np.inf)
    d.sort(axis=0)
    k = np.minimum(skip, np.maximum(n_seen - 1, 0))
    field = np.take_along_axis(d, k[None], axis=0)[0]
    h = None if plane_height is None else plane_height(pts)
    if skip_below is not None and h is not None and skip > 0:
        strict = d[0]  # no view may disagree
        field = vote_near_support(field.reshape(grid.shape), strict.reshape(grid.shape), h.reshape(grid.shape),
                                  skip_below, grid.voxel).ravel()  # fmt: skip
    field[n_seen < max(3, skip + 2)] = -1.0  # seen by too few views to say
    if h is not None:
        field = np.where(h < 0, np.minimum(field, h / grid.voxel), field)
    return field.reshape(grid.shape).astype(np.float32)


# A piece one mask misses is a chunk; the vote's shell at the rim is about a voxel or two thick (bundled sample, 1.5 mm
# voxels: its median distance to the true surface 1 mm). Kept: what survives an opening of this radius.
CHUNK_RADIUS = 0.003


def vote_near_support(voted: np.ndarray, strict: np.ndarray, height: np.ndarray, below: float,
                      voxel: float) -> np.ndarray:  # fmt: skip
    """The carving field [nx,ny,nz] with the vote (``voted``) near the support and none (``strict``) higher up,
    linear in between (``height`` [nx,ny,nz] metres above the plane: ``below`` .. 2 ``below``). Higher up the voxels
    the vote alone keeps stay where they form a chunk (an opening of CHUNK_RADIUS): one mask's missing piece.

    Why the height: near the table an object's masks are least sure (the matting's floor, contact shadows, low edges
    the colour of the wood) and its views' misses are real; higher up the outline stands against the table behind
    and what the vote keeps is mostly a shell. Bundled sample, 40 keyframes, the vote (3 of 36 views) everywhere:
    the volume it added below 10 mm lay 92 % inside the true croissant, above 20 mm 17 % (banana 35 %, button 15 %)."""
    from scipy import ndimage

    cross = ndimage.generate_binary_structure(3, 1)
    only_voted = (voted > 0) & ~(strict > 0)
    r = max(1, int(round(CHUNK_RADIUS / voxel)))
    chunks = ndimage.binary_dilation(ndimage.binary_opening(only_voted, cross, iterations=r), cross)
    high = np.where(chunks, voted, strict)
    w = np.clip(height / below - 1.0, 0.0, 1.0)
    return (1.0 - w) * voted + w * high


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
        mesh = largest_part(parts)
    return mesh


def largest_part(parts: Sequence):
    """The part of a split mesh with the largest surface: the object, not debris. (Ranked by volume where closed
    and by face count where not, a one-face sliver (1) outranked a closed object of 3e-4 m^3: the bundled sample's
    button, its matting floor at 3 mm, came out as one face and failed the stage.)"""
    return max(parts, key=lambda m: m.area)
