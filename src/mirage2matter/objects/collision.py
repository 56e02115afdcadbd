"""Collision geometry: approximate convex decomposition of a watertight mesh with CoACD."""

from __future__ import annotations

import numpy as np

__all__ = ["convex_decomposition"]


def convex_decomposition(mesh, threshold: float = 0.05, max_parts: int = 16, seed: int = 0) -> list:
    """Convex parts (trimesh.Trimesh, same frame as ``mesh``) whose union approximates it within
    CoACD's concavity ``threshold`` (relative to the mesh size)."""
    import coacd
    import trimesh

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32)),
        threshold=threshold,
        max_convex_hull=max_parts,
        preprocess_mode="off",  # the mesh is already watertight (checked before)
        seed=seed,
    )
    out = []
    for verts, faces in parts:
        part = trimesh.Trimesh(np.asarray(verts), np.asarray(faces), process=True)
        out.append(part.convex_hull)  # exactly convex, consistently wound
    return out
