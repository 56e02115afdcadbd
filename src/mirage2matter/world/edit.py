"""Edits of a world (paper section 3.3: insert new assets, edit existing ones, reproduce the lighting).

Every edit takes a :class:`WorldConfig` and returns a new one (the input is left alone); the caller saves it.
Placements move the Gaussians and the mesh together because both are read through the one Sim3.

- :func:`insert`: a new object from a Gaussian PLY + a mesh (+ convex parts; computed when absent), copied into
  ``<world>/assets/<name>/``.
- :func:`move`, :func:`duplicate`, :func:`delete`.
- :func:`import_placement`: a person moved an object in SuperSplat and exported the PLY (the object alone or
  the whole ``world.ply``): the Gaussians are the same, only moved, so Umeyama on corresponding means
  recovers the new Sim3 exactly (to float32 precision).
- :func:`match_lighting`: scales an inserted asset's colours (SH, all bands) per channel so that, under the
  grey-world assumption, its illuminant matches the scene's around it.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import torch

from ..atomic import atomic_dir
from ..gaussians.ply import read_ply, write_ply
from ..gaussians.sh import SH_C0
from ..geometry.sim3 import Sim3
from ..geometry.umeyama import umeyama
from ..inputs import InputError, read_json
from ..objects.errors import ObjectsError
from .config import ObjectConfig, PartConfig, WorldConfig, WorldConfigError
from .validate import load_mesh, validate_world

__all__ = [
    "delete",
    "duplicate",
    "import_placement",
    "insert",
    "match_lighting",
    "move",
    "placement_from_pose",
    "placement_of",
]


SCALE_CHANGE = 1.5  # an imported placement that grows or shrinks an object more than this is asked about


def placement_from_pose(
    xyz: tuple[float, float, float], yaw_deg: float = 0.0, scale: float = 1.0, base: Sim3 | None = None
) -> Sim3:
    """A placement with its origin at ``xyz`` (base frame), turned ``yaw_deg`` about z relative to ``base``'s
    rotation (default: upright), at ``scale``."""
    a = np.radians(yaw_deg)
    Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    R = Rz @ (base.rotation if base is not None else np.eye(3))
    return Sim3(scale, R, np.asarray(xyz, dtype=np.float64))


def placement_of(cfg: WorldConfig, name: str) -> Sim3:
    """The placement of object or articulated asset ``name``."""
    return _item(cfg, name).placement


def _item(cfg: WorldConfig, name: str):
    for it in [*cfg.objects, *cfg.articulated]:
        if it.name == name:
            return it
    raise WorldConfigError(f"no object named {name!r} in the world; names: {cfg.names}")


def insert(
    cfg: WorldConfig,
    name: str,
    gaussians: str | os.PathLike,
    mesh: str | os.PathLike,
    placement: Sim3,
    *,
    collision: str | os.PathLike | None = None,
    objects_dir: str | os.PathLike | None = None,
    mass: float | None = None,
    density: float | None = 500.0,
    friction: float = 1.0,
) -> WorldConfig:
    """Copy an asset (Gaussian PLY + mesh [+ its .mtl/texture] [+ collision folder]) into
    ``<objects_dir>/<name>/`` (default ``<world>/assets``: the world's own assets, apart from the objects stage's
    reconstructions) and add it at ``placement``; convex parts are
    computed (CoACD) when no collision folder is given. Raises WorldConfigError on a taken name or an
    overlap with what is there."""
    from ..objects.mesh import ensure_watertight
    from .sample import convex_parts

    if name in cfg.names:
        raise WorldConfigError(f"name {name!r} is taken; choose another or delete it first")
    gaussians, mesh = Path(gaussians), Path(mesh)
    for p, what in ((gaussians, "Gaussians PLY"), (mesh, "mesh")):
        if not p.is_file():
            raise WorldConfigError(f"{what} {p} not found")
    if len(read_ply(gaussians)) == 0:  # read_ply fails early with the PLY's own message on a broken file
        raise WorldConfigError(f"Gaussians PLY {gaussians} holds no Gaussians; an object is drawn from them")
    original = load_mesh(mesh)
    try:  # the objects stage's rule: a simulated object is a closed solid (repaired when nearly closed)
        m = ensure_watertight(original, name, source=str(mesh))
    except ObjectsError as e:
        raise WorldConfigError(str(e)) from None
    dest = Path(objects_dir) if objects_dir is not None else cfg.root / "assets"
    final = dest / name
    mesh_name = f"mesh{mesh.suffix}" if m is original else "mesh.obj"
    with atomic_dir(final) as tmp:
        shutil.copy2(gaussians, tmp / "gaussians.ply")
        if m is original:
            shutil.copy2(mesh, tmp / mesh_name)
        else:
            m.export(tmp / mesh_name)
        for extra in mesh.parent.glob("*"):  # materials and textures the mesh refers to
            if extra.suffix.lower() in (".mtl", ".png", ".jpg", ".jpeg") and extra.is_file():
                shutil.copy2(extra, tmp / extra.name)
        (tmp / "collision").mkdir()
        if collision is not None:
            parts = sorted(Path(collision).glob("*.obj"))
            if not parts:
                raise WorldConfigError(f"collision folder {collision} holds no *.obj parts")
            for f in parts:
                shutil.copy2(f, tmp / "collision" / f.name)
        else:
            for i, part in enumerate(convex_parts(m)):
                part.export(tmp / "collision" / f"part_{i:02d}.obj")
    new = cfg.copy()
    part = PartConfig(final / "gaussians.ply", final / mesh_name, final / "collision")
    new.objects.append(ObjectConfig(name, part, placement, mass=mass, density=density, friction=friction))
    try:
        validate_world(new)
    except WorldConfigError:
        shutil.rmtree(final, ignore_errors=True)
        raise
    return new


def move(cfg: WorldConfig, name: str, placement: Sim3, check: bool = True) -> WorldConfig:
    """``name`` (object or articulated asset) at a new placement."""
    new = cfg.copy()
    _item(new, name).placement = placement
    if check:
        validate_world(new)
    return new


def duplicate(cfg: WorldConfig, name: str, new_name: str, placement: Sim3) -> WorldConfig:
    """A second copy of object ``name`` (same files) called ``new_name`` at ``placement``."""
    if new_name in cfg.names:
        raise WorldConfigError(f"name {new_name!r} is taken")
    new = cfg.copy()
    src = _item(new, name)
    if not isinstance(src, ObjectConfig):
        raise WorldConfigError(f"{name!r} is an articulated asset; only objects can be duplicated")
    copy = ObjectConfig(new_name, src.part, placement, src.mass, src.density, src.friction)
    new.objects.append(copy)
    validate_world(new)
    return new


def delete(cfg: WorldConfig, name: str) -> WorldConfig:
    """The world without ``name`` (its files stay on disk)."""
    new = cfg.copy()
    _item(new, name)
    new.objects = [o for o in new.objects if o.name != name]
    new.articulated = [a for a in new.articulated if a.name != name]
    return new


def import_placement(
    cfg: WorldConfig, name: str, edited_ply: str | os.PathLike, *, tol: float = 1e-4, allow_scale: bool = False
) -> tuple[WorldConfig, Sim3]:
    """New placement of object ``name`` from a PLY a person moved it in (SuperSplat): either the object's own
    Gaussians (same count as its ``gaussians.ply``) or the whole world (same count as ``world.ply``; the
    object's index range comes from ``world.json``). Umeyama (with scale) on corresponding means: the
    rotation/scale/translation that maps the object's Gaussians (object frame) to the edited ones. Raises
    when the Gaussians were changed other than by one similarity (RMS residual > ``tol`` x their size), and,
    unless ``allow_scale``, when the object's size changes by more than ``SCALE_CHANGE`` (SuperSplat edits move
    and turn things; a changed size is usually a slip)."""
    item = _item(cfg, name)
    if not isinstance(item, ObjectConfig):
        raise WorldConfigError(f"{name!r} is an articulated asset; import its placement by moving it instead")
    local = read_ply(item.part.gaussians).means.detach().double().numpy()
    edited = read_ply(edited_ply).means.detach().double().numpy()
    if len(edited) != len(local):
        manifest = cfg.root / "world.json"
        if not manifest.is_file():
            raise WorldConfigError(
                f"{edited_ply} has {len(edited)} Gaussians, {name}'s PLY {len(local)}, and there is no world.json "
                "to find it in a whole-world PLY; run `m2m compose` and edit world/world.ply"
            )
        try:
            info = read_json(manifest, "world.json")
        except InputError as e:
            raise WorldConfigError(str(e)) from None
        if info.get("gaussians") != len(edited) or name not in info.get("ranges", {}):
            raise WorldConfigError(
                f"{edited_ply} has {len(edited)} Gaussians: neither {name}'s {len(local)} nor world.ply's "
                f"{info.get('gaussians')}; export the same Gaussians you loaded (no deletions or additions)"
            )
        a, b = info["ranges"][name]
        edited = edited[a:b]
    try:
        sim = umeyama(local, edited, with_scale=True)
    except ValueError as e:  # the edited Gaussians collapsed to a point or a line
        raise WorldConfigError(f"{edited_ply}: {name}'s Gaussians there do not span a solid ({e}); export the "
                               "object as it looks, moved and turned") from None  # fmt: skip
    resid = np.sqrt(np.mean(np.sum((sim.apply(local) - edited) ** 2, axis=1)))
    size = float(np.linalg.norm(np.ptp(edited, axis=0))) or 1.0
    if resid > tol * size:
        raise WorldConfigError(
            f"the Gaussians of {name} in {edited_ply} were changed other than moved/rotated/scaled "
            f"(RMS residual {resid:.2e} m); import needs the same Gaussians, only transformed"
        )
    change = sim.scale / item.placement.scale
    if not allow_scale and not 1 / SCALE_CHANGE <= change <= SCALE_CHANGE:
        raise WorldConfigError(
            f"{edited_ply} changes {name}'s size by x{change:.3g} (scale {item.placement.scale:.3g} -> "
            f"{sim.scale:.3g}); if that is intended, import it again with --allow-scale"
        )
    return move(cfg, name, sim, check=False), sim


def _rgb_dc(sh: torch.Tensor) -> torch.Tensor:
    return sh[:, 0] * SH_C0 + 0.5


def match_lighting(
    cfg: WorldConfig,
    name: str,
    out_ply: str | os.PathLike | None = None,
    *,
    radius: float = 0.3,
    strength: float = 1.0,
    opacity: float = 0.5,
) -> tuple[WorldConfig, np.ndarray]:
    """Adjust object ``name``'s colours toward the scene's illumination around it (grey-world von Kries).

    The illuminant of a set of Gaussians is estimated as its mean DC colour (opacity-weighted, opaque ones);
    the scene's from the scene Gaussians within ``radius`` metres (xy) of the object's placement, the
    asset's from its own. Every SH coefficient is scaled per channel by ``(scene / asset) ** strength`` about
    the DC offset (colour = SH.basis + 0.5), so colours move to the scene's white balance and brightness while
    view-dependent effects scale with them. Writes ``out_ply`` (default ``<world>/assets/<name>/gaussians_lit.ply``:
    inside the world, wherever the object's own PLY is) and returns the world pointing at it plus the
    per-channel gain [3].
    """
    item = _item(cfg, name)
    if not isinstance(item, ObjectConfig):
        raise WorldConfigError(f"{name!r} is an articulated asset; match_lighting takes objects")
    if cfg.scene_gaussians is None or not cfg.scene_gaussians.is_file():
        raise WorldConfigError("match_lighting needs the scene's Gaussians (scene.gaussians in world.yaml)")
    scene = read_ply(cfg.scene_gaussians)
    asset = read_ply(item.part.gaussians)
    centre = torch.tensor(np.array(item.placement.translation), dtype=scene.means.dtype)
    near = torch.linalg.norm(scene.means[:, :2] - centre[:2], dim=1) <= radius
    near &= scene.opacities > opacity
    if int(near.sum()) < 50:
        raise WorldConfigError(
            f"only {int(near.sum())} opaque scene Gaussians within {radius} m of {name}; raise the radius"
        )

    def illuminant(g, mask) -> torch.Tensor:
        w = g.opacities[mask][:, None]
        return (_rgb_dc(g.sh[mask]).clamp(0, 1) * w).sum(0) / w.sum()

    mask_asset = asset.opacities > opacity
    if int(mask_asset.sum()) == 0:
        raise WorldConfigError(f"{name}: no opaque Gaussians to take colours from")
    gain = (illuminant(scene, near) / illuminant(asset, mask_asset).clamp_min(1e-4)) ** strength
    sh = asset.sh.clone()
    # colour c = C0*dc + rest + 0.5  ->  gain * (c - 0.5) + 0.5 + (gain - 1) * 0.5 = gain * c on every channel
    sh = sh * gain[None, None, :]
    sh[:, 0] += (gain - 1.0) * 0.5 / SH_C0
    lit = type(asset)(asset.means, asset.quats, asset.log_scales, asset.logit_opacities, sh)
    out = Path(out_ply) if out_ply is not None else cfg.root / "assets" / name / "gaussians_lit.ply"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_ply(out, lit)
    new = cfg.copy()
    obj = _item(new, name)
    obj.part = PartConfig(out, obj.part.mesh, obj.part.collision)
    return new, gain.detach().cpu().numpy()
