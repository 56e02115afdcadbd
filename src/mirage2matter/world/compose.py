"""One Gaussian world in the robot-base frame (paper eq. ``merge``): the scene's Gaussians plus every object's
Gaussians moved by the same Sim3 that places its mesh (eq. ``mesh_place``).

:class:`WorldGaussians` keeps each part's Gaussians in its own object frame, so a renderer can place them at
the simulator's current poses every frame (``at(poses)``); :func:`compose` is the world at its placements.
``world.ply`` is written with ``world.json`` beside it: the index range of each part, so a PLY edited in
SuperSplat can be matched back to its parts (see ``world.edit.import_placement``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..atomic import atomic_write
from ..gaussians.model import Gaussians
from ..gaussians.ply import read_ply, write_ply
from ..gaussians.transform import apply_sim3
from ..geometry.sim3 import Sim3
from .config import WorldConfig, WorldConfigError
from .validate import load_mesh, validate_world

__all__ = ["Part", "WorldGaussians", "compose", "consistency", "part_names", "write_world_ply"]


@dataclass
class Part:
    """Gaussians of one rigid body in its object frame and where the world places them.

    placement  Sim3 object -> base at the world's start (scale included)
    mesh       the body's watertight mesh file (object frame)
    """

    name: str
    gaussians: Gaussians
    placement: Sim3
    mesh: Path

    def at(self, T_base_obj: np.ndarray | None = None) -> Gaussians:
        """The part's Gaussians at rigid pose ``T_base_obj`` [4,4] (default: its placement); the placement's
        scale is kept."""
        if T_base_obj is None:
            return apply_sim3(self.gaussians, self.placement)
        T = np.asarray(T_base_obj, dtype=np.float64)
        return apply_sim3(self.gaussians, Sim3(self.placement.scale, T[:3, :3], T[:3, 3]))


def part_names(cfg: WorldConfig) -> list[str]:
    """Names of the rigid parts: each object, and ``<name>`` + ``<name>/cap`` per press button (the same keys
    as ``Twin.object_poses``)."""
    out = [o.name for o in cfg.objects]
    for a in cfg.articulated:
        out += [a.name, f"{a.name}/cap"]
    return out


def _part_gaussians(name: str, path) -> Gaussians:
    g = read_ply(path)
    if len(g) == 0:
        raise WorldConfigError(f"{name}: {path} holds no Gaussians; an object is drawn from its Gaussians (rebuild it "
                               "with `m2m objects`, or give another PLY)")  # fmt: skip
    return g


class WorldGaussians:
    """The scene's Gaussians (base frame) and each part's Gaussians (object frame)."""

    def __init__(self, scene: Gaussians | None, parts: list[Part]) -> None:
        self.scene = scene
        self.parts = {p.name: p for p in parts}

    @classmethod
    def load(cls, cfg: WorldConfig) -> WorldGaussians:
        """Read every PLY the world names (scene optional; every part needs its Gaussians)."""
        validate_world(cfg, need_gaussians=True, overlaps=False)
        scene = read_ply(cfg.scene_gaussians) if cfg.scene_gaussians is not None else None
        parts = [Part(o.name, _part_gaussians(o.name, o.part.gaussians), o.placement, o.part.mesh)
                 for o in cfg.objects]  # fmt: skip
        for a in cfg.articulated:
            parts.append(Part(a.name, _part_gaussians(a.name, a.base.gaussians), a.placement, a.base.mesh))
            cap_placement = a.placement @ Sim3.from_matrix(np.asarray(a.T_base_cap, dtype=np.float64))
            cap = _part_gaussians(f"{a.name}/cap", a.cap.gaussians)
            parts.append(Part(f"{a.name}/cap", cap, cap_placement, a.cap.mesh))
        return cls(scene, parts)

    def at(self, poses: dict[str, np.ndarray] | None = None) -> Gaussians:
        """The whole world with each part at ``poses[name]`` (rigid [4,4], e.g. ``Twin.object_poses()``) or
        at its placement when absent. Order: scene, then parts in :func:`part_names` order."""
        poses = poses or {}
        pieces = [] if self.scene is None else [self.scene]
        pieces += [p.at(poses.get(name)) for name, p in self.parts.items()]
        return Gaussians.concat(pieces)

    def ranges(self) -> dict[str, tuple[int, int]]:
        """[start, end) index of the scene and of each part in :meth:`at`'s output."""
        out, i = {}, 0
        if self.scene is not None:
            out["scene"] = (0, len(self.scene))
            i = len(self.scene)
        for name, p in self.parts.items():
            out[name] = (i, i + len(p.gaussians))
            i += len(p.gaussians)
        return out


def compose(cfg: WorldConfig) -> Gaussians:
    """``world.ply``'s content: the scene and every part at its placement."""
    return WorldGaussians.load(cfg).at()


def consistency(cfg: WorldConfig, opacity: float = 0.5, max_points: int = 5000, seed: int = 0) -> dict[str, float]:
    """{part: median distance (m) from its opaque (> ``opacity``) placed Gaussian means to its placed mesh
    surface}: the visual and the physical object agree when this is a few millimetres."""
    import trimesh

    world = WorldGaussians.load(cfg)
    rng = np.random.default_rng(seed)
    out = {}
    for name, p in world.parts.items():
        g = p.at()
        keep = (g.opacities > opacity).cpu().numpy()
        X = g.means.detach().cpu().numpy()[keep].astype(np.float64)
        if len(X) == 0:
            raise WorldConfigError(f"{name}: no Gaussian is more opaque than {opacity}")
        if len(X) > max_points:
            X = X[rng.choice(len(X), max_points, replace=False)]
        mesh = load_mesh(p.mesh).copy()
        mesh.apply_transform(p.placement.matrix)
        _, dist, _ = trimesh.proximity.closest_point(mesh, X)
        out[name] = float(np.median(dist))
    return out


def write_world_ply(cfg: WorldConfig, out_dir: str | os.PathLike | None = None) -> Path:
    """Write ``world.ply`` and ``world.json`` (part index ranges, part placements) into ``out_dir``
    (default: the world folder), each atomically. Returns the PLY path."""
    out_dir = Path(out_dir) if out_dir is not None else cfg.root
    world = WorldGaussians.load(cfg)
    g = world.at()
    ply = out_dir / "world.ply"
    write_ply(ply, g.map(lambda t: t.detach().to(torch.float32)))
    manifest = {
        "gaussians": len(g),
        "ranges": {k: list(v) for k, v in world.ranges().items()},
        "placements": {k: p.placement.to_json() for k, p in world.parts.items()},
    }
    with atomic_write(out_dir / "world.json", "w", encoding="utf-8") as f:
        json.dump(manifest, f, indent=1)
    return ply
