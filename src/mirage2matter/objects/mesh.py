"""Object meshes: reconstruction from masks, user-supplied meshes, watertightness, mass properties.

Reconstruction carves the masks and the depth rendered from the object's Gaussians (``carve``) on
a voxel grid around the object's points, closes the underside against the support plane, extracts
the surface with marching cubes and smooths it lightly (Taubin, volume-preserving). Every mesh,
reconstructed or supplied, must be watertight (a simulator needs a closed volume for mass and
contacts): small defects are repaired; a mesh that is open beyond repair is an error naming the
object and the file.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..geometry.camera import Camera
from ..inputs import InputError, check_mesh
from .carve import Grid, carve, surface_mesh
from .errors import ObjectsError
from .support import ObjectCluster, Plane

__all__ = ["ensure_watertight", "load_mesh", "mass_properties", "reconstruct_mesh"]


def reconstruct_mesh(
    cluster: ObjectCluster,
    plane: Plane,
    cameras: Sequence[Camera],
    masks: Sequence[np.ndarray | None],
    voxel: float = 0.0015,
    margin: float = 0.03,
    skip_fraction: float = 0.08,
    smooth_iterations: int = 5,
    name: str | None = None,
    depths: Sequence[np.ndarray | None] | None = None,
    depth_margin: float = 0.0005,
    skip_below: float | None = None,
):
    """Watertight trimesh.Trimesh (base frame) of the object from its masks (and, when given, depth
    maps [H,W] per keyframe, NaN where unknown, that carve the free space in front of what they
    see, beyond ``depth_margin``; 2 mm left the sample's meshes fat where depth carves: the button's
    walls 1.8 mm outside its ground truth). ``skip_fraction`` of the views that see a voxel may
    disagree without cutting it away, fully below ``skip_below`` metres above the plane (None: everywhere) and,
    above twice that, only where that keeps a chunk (``carve.vote_near_support``)."""
    import trimesh

    name = name or cluster.name
    lo = cluster.points.min(0) - margin
    hi = cluster.points.max(0) + margin
    lo[2] = min(lo[2], -plane.offset / max(plane.normal[2], 1e-6)) - 2 * voxel
    hi[2] = cluster.points[:, 2].max() + margin / 2
    grid = Grid.around(lo, hi, voxel)
    n_seen = sum(1 for m in masks if m is not None)
    skip = int(round(skip_fraction * n_seen))
    field = carve(grid, cameras, masks, plane_height=plane.height, skip=skip, name=name, depths=depths,
                  depth_margin=depth_margin, skip_below=skip_below)  # fmt: skip
    mesh = surface_mesh(field, grid, name=name)
    if smooth_iterations > 0:
        trimesh.smoothing.filter_taubin(mesh, iterations=smooth_iterations)
    return ensure_watertight(mesh, name, source="reconstruction")


def _voxel_remesh(mesh, pitch: float):
    """Closed surface of the filled voxelisation of ``mesh`` (None when nothing encloses a volume)."""
    vox = mesh.voxelized(pitch).fill()
    if vox.filled_count == 0:
        return None
    out = vox.marching_cubes
    out.apply_transform(vox.transform)
    return out


def ensure_watertight(mesh, name: str, source: str = "mesh"):
    """``mesh`` if watertight; else a repaired copy (merge vertices, fill small holes, fix normals;
    then a voxel remesh if it still encloses most of its convex hull). Raises ObjectsError naming
    ``name`` and ``source`` when it cannot be made watertight."""
    import trimesh

    if mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0:
        return mesh
    m = mesh.copy()
    m.merge_vertices()
    m.update_faces(m.nondegenerate_faces())
    m.remove_unreferenced_vertices()
    trimesh.repair.fill_holes(m)
    trimesh.repair.fix_normals(m)
    if m.is_watertight and m.volume > 0:
        return m
    extent = float(np.max(mesh.extents)) if len(mesh.vertices) else 0.0
    hull_volume = float(mesh.convex_hull.volume) if len(mesh.vertices) >= 4 and extent > 0 else 0.0
    if hull_volume > 0:
        remeshed = _voxel_remesh(mesh, extent / 100)
        # a mesh that is only a little open fills to most of its hull; a sheet or a shell with a big
        # opening does not, and filling it would invent the shape
        if remeshed is not None and remeshed.is_watertight and remeshed.volume >= 0.2 * hull_volume:
            trimesh.repair.fix_normals(remeshed)
            return remeshed
    raise ObjectsError(
        f"object {name!r}: the mesh from {source} is not watertight and cannot be repaired (open boundary of "
        f"{len(mesh.outline().entities) if len(mesh.faces) else 0} loop(s)); close it in a mesh editor "
        "(e.g. Blender's 3D-Print toolbox) or let the stage reconstruct one"
    )


def load_mesh(path: str | os.PathLike[str], name: str):
    """A user-supplied mesh (obj / stl / ply / glb / gltf / off) as one trimesh.Trimesh; errors name
    the object and the file."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise ObjectsError(f"object {name!r}: mesh file {path} not found")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=True)
    except Exception as e:  # trimesh raises many types for malformed files
        raise ObjectsError(f"object {name!r}: mesh file {path} does not parse ({type(e).__name__}: {e})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ObjectsError(f"object {name!r}: mesh file {path} holds no triangles (is it a mesh? obj/stl/glb)")
    try:  # a user mesh comes in any scale (it is aligned by a similarity): only absurd sizes are refused
        check_mesh(loaded.vertices, loaded.faces, f"object {name!r}: mesh file {path}", max_extent=1e4)
    except InputError as e:
        raise ObjectsError(str(e)) from None
    return loaded


def mass_properties(mesh, density: float) -> dict[str, Any]:
    """Mass, volume, centre of mass and inertia (about the centre of mass, mesh axes) of a watertight
    mesh of uniform ``density`` (kg/m^3)."""
    if not density > 0:
        raise ObjectsError(f"density must be positive, got {density}")
    m = mesh.copy()
    m.density = float(density)
    props = m.mass_properties
    return {
        "density": float(density),
        "volume": float(props["volume"]),
        "mass": float(props["mass"]),
        "center_of_mass": np.asarray(props["center_mass"]).tolist(),
        "inertia": np.asarray(props["inertia"]).tolist(),
    }
