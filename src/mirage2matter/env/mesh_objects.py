"""Objects drawn from their meshes instead of their Gaussians: the paper's "mesh-only" ablation (its Table 3).

The objects stage gives each object a watertight mesh (for physics) and a 3DGS (for pictures). In the ablation
the hybrid renderer draws the objects with Genesis' rasterizer from that mesh, coloured per vertex from the
object's own Gaussians (the opacity- and distance-weighted mean colour of the nearest Gaussians: the best colour
a mesh-only pipeline could get from the same capture), and the Gaussians draw only the static scene.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..world.config import WorldConfig

__all__ = ["colored_mesh", "mesh_object_world"]

SH_C0 = 0.28209479177387814  # the degree-0 spherical-harmonic constant: rgb = 0.5 + C0 * dc


def _cache_dir() -> Path:
    return Path(os.environ.get("M2M_CACHE", Path.home() / ".cache" / "mirage2matter")) / "mesh_objects"


def vertex_colors(vertices: np.ndarray, means: np.ndarray, rgb: np.ndarray, opacity: np.ndarray,
                  k: int = 8) -> np.ndarray:  # fmt: skip
    """uint8 [V, 4] colours of ``vertices`` [V, 3] from Gaussians (``means`` [N, 3], ``rgb`` [N, 3] in [0, 1],
    ``opacity`` [N]): the mean colour of the ``k`` nearest, weighted by opacity / distance."""
    from scipy.spatial import cKDTree

    keep = opacity > 0.05
    means, rgb, opacity = means[keep], rgb[keep], opacity[keep]
    if len(means) == 0:
        return np.full((len(vertices), 4), 160, np.uint8)
    k = min(k, len(means))
    d, idx = cKDTree(means).query(vertices, k=k)
    d, idx = d.reshape(len(vertices), k), idx.reshape(len(vertices), k)
    w = opacity[idx] / np.maximum(d, 1e-4)
    col = (w[..., None] * rgb[idx]).sum(1) / w.sum(1, keepdims=True)
    out = np.empty((len(vertices), 4), np.uint8)
    out[:, :3] = np.clip(np.rint(col * 255), 0, 255).astype(np.uint8)
    out[:, 3] = 255
    return out


def colored_mesh(mesh_path: str | Path, gaussians_path: str | Path, cache_dir: Path | None = None) -> Path:
    """A PLY copy of ``mesh_path`` (same vertices and faces) with vertex colours from ``gaussians_path`` (same
    object frame), built once per content under ``cache_dir``."""
    import trimesh

    from ..gaussians.ply import read_ply

    mesh_path, gaussians_path = Path(mesh_path), Path(gaussians_path)
    h = hashlib.sha1(b"colored_mesh/1")
    for p in (mesh_path, gaussians_path):
        h.update(p.read_bytes())
    out = Path(cache_dir or _cache_dir()) / f"{mesh_path.stem}-{h.hexdigest()[:16]}.ply"
    if out.is_file():
        return out
    mesh = trimesh.load(str(mesh_path), force="mesh", process=False)
    g = read_ply(gaussians_path)
    rgb = np.clip(0.5 + SH_C0 * g.sh[:, 0, :].numpy(), 0.0, 1.0)
    opacity = 1.0 / (1.0 + np.exp(-g.logit_opacities.numpy()))
    colors = vertex_colors(np.asarray(mesh.vertices), g.means.numpy(), rgb, opacity)
    colored = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=colors, process=False)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        colored.export(str(tmp), file_type="ply")
    return out


def mesh_object_world(world: WorldConfig) -> WorldConfig:
    """A copy of ``world`` whose objects' (and buttons' parts') meshes are vertex-coloured copies."""
    world = world.copy()
    parts = [o.part for o in world.objects]
    for a in world.articulated:
        parts += [a.base, a.cap]
    for part in parts:
        part.mesh = colored_mesh(part.mesh, part.gaussians)
    return world
