"""A picture for a person: the object's Gaussians beside its mesh, from the same cameras.

The mesh is drawn with the same splat renderer: tiny flat-shaded Gaussians sampled densely on its
surface (grey, Lambert-lit from the camera), so both columns share exactly one projection.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from ..gaussians.model import Gaussians
from ..gaussians.sh import rgb_to_sh_dc
from ..geometry.camera import Camera
from .matting import render_alpha

__all__ = ["mesh_as_gaussians", "side_by_side"]


def mesh_as_gaussians(mesh, camera_centre: np.ndarray, n: int = 60000, seed: int = 0) -> Gaussians:
    """Surface samples of ``mesh`` as small opaque discs shaded by the angle to ``camera_centre``."""
    import trimesh

    pts, faces = trimesh.sample.sample_surface(mesh, n, seed=seed)
    normals = mesh.face_normals[faces]
    to_cam = camera_centre[None] - pts
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
    shade = 0.25 + 0.7 * np.abs(np.sum(normals * to_cam, axis=1))
    colors = np.repeat(shade[:, None], 3, axis=1) * np.array([0.85, 0.88, 0.95])
    radius = np.sqrt(mesh.area / n) * 0.7
    # flat discs in the tangent plane: rotation taking z to the normal
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, normals)
    c = normals @ z
    quats = np.concatenate([(1 + c)[:, None], v], axis=1)
    bad = c < -0.999999
    quats[bad] = [0.0, 1.0, 0.0, 0.0]
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    log_scales = np.log(np.array([radius, radius, radius * 0.1]))[None].repeat(n, 0)
    return Gaussians(
        torch.as_tensor(pts, dtype=torch.float32),
        torch.as_tensor(quats, dtype=torch.float32),
        torch.as_tensor(log_scales, dtype=torch.float32),
        torch.full((n,), 6.0),
        rgb_to_sh_dc(torch.as_tensor(colors, dtype=torch.float32))[:, None],
    )


def side_by_side(
    g: Gaussians, mesh, cameras: Sequence[Camera], images: Sequence[np.ndarray] | None = None, tile: int = 200
) -> np.ndarray:
    """uint8 [rows*tile, cols*tile, 3]: per camera (one row each) the photo crop when given, the
    Gaussians over white, and the mesh. Cameras must look at the object (same frame as g and mesh)."""
    import cv2

    rows = []
    for k, cam in enumerate(cameras):
        rgb, alpha, _ = render_alpha(g, cam)
        gs = rgb + (1 - alpha[..., None])  # over white
        mrgb, malpha, _ = render_alpha(mesh_as_gaussians(mesh, cam.center), cam)
        ms = mrgb + (1 - malpha[..., None])
        tiles = ([images[k]] if images is not None else []) + [gs, ms]
        rows.append(
            np.concatenate(
                [
                    cv2.resize(np.clip(t, 0, 1).astype(np.float32), (tile, tile), interpolation=cv2.INTER_AREA)
                    for t in tiles
                ],
                axis=1,
            )
        )
    return (np.concatenate(rows, axis=0) * 255).round().astype(np.uint8)
