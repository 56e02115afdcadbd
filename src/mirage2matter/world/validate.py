"""Checks on a :class:`WorldConfig` that must pass before anything is composed or simulated.

Every failure is a :class:`WorldConfigError` naming the field and what to do: an unknown robot file, a model
without the joints of the named robot (``robot.name``), a home of the wrong length, an object without a mesh,
a missing file, duplicate names, a camera mounted on a link the robot lacks, objects that overlap (or sink into
the table) at their start placements.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ..inputs import InputError, check_joints, check_mesh
from ..robots.model import ModelError, ModelInfo, model_info, resolve_model
from .config import _NAME_RE, ArticulatedConfig, ObjectConfig, PartConfig, WorldConfig, WorldConfigError

__all__ = ["check_overlaps", "load_collision_parts", "placed_parts", "validate_world"]

# Penetration (m) beyond which two start placements count as overlapping; contact is fine.
OVERLAP_TOL = 0.002


def _robot_model(file: str) -> ModelInfo:
    """What the robot model file says (MuJoCo reads MJCF and URDF in well under a second, without Genesis)."""
    try:
        path = resolve_model(file)
    except ModelError as e:
        raise WorldConfigError(f"robot.file: {e}") from None
    if path.suffix.lower() not in (".xml", ".urdf", ".mjcf"):
        raise WorldConfigError(f"robot.file: {path} is neither MJCF (.xml) nor URDF (.urdf)")
    try:
        return model_info(path)
    except ModelError as e:
        raise WorldConfigError(f"robot.file: {path} cannot be loaded as a robot model ({e})") from None


def _check_part(p: PartConfig, where: str, need_gaussians: bool) -> None:
    if p.mesh is None:
        raise WorldConfigError(
            f"{where}: no mesh; every simulated object needs a watertight mesh (`mesh: path/to/mesh.obj`, e.g. "
            "from `m2m objects`)"
        )
    if not p.mesh.is_file():
        raise WorldConfigError(f"{where}.mesh: {p.mesh} not found")
    load_mesh(p.mesh)  # a usable mesh (the world's check of every mesh it simulates)
    if p.collision is not None and (not p.collision.is_dir() or not any(p.collision.glob("*.obj"))):
        raise WorldConfigError(f"{where}.collision: {p.collision} is not a folder of convex *.obj parts")
    if need_gaussians and (p.gaussians is None or not p.gaussians.is_file()):
        raise WorldConfigError(f"{where}.gaussians: {p.gaussians} not found")


# Where a world's objects may be: a robot's workspace is a few metres; scales far from 1 are a unit mistake.
MAX_DISTANCE = 10.0  # m from the base
SCALE_RANGE = (1e-2, 1e2)


def _check_placement(sim, where: str) -> None:
    t = np.asarray(sim.translation, dtype=np.float64)
    if not np.isfinite(t).all() or np.linalg.norm(t) > MAX_DISTANCE:
        raise WorldConfigError(f"{where}: translation {t.tolist()} is more than {MAX_DISTANCE} m from the robot base "
                               "(metres, base frame)")  # fmt: skip
    if not SCALE_RANGE[0] <= sim.scale <= SCALE_RANGE[1]:
        raise WorldConfigError(f"{where}: scale {sim.scale:.3g} is outside {SCALE_RANGE[0]:g}..{SCALE_RANGE[1]:g}; "
                               "an asset in other units than metres? scale its mesh and Gaussians instead")  # fmt: skip


def load_mesh(path: Path) -> trimesh.Trimesh:
    """A mesh file as one Trimesh (scenes are merged); WorldConfigError for a file that is no usable mesh."""
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as e:  # noqa: BLE001 - trimesh raises anything on a broken file
        raise WorldConfigError(f"{path}: not a mesh file trimesh can read ({type(e).__name__}: {e})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise WorldConfigError(f"{path}: no triangles in this mesh file")
    try:
        check_mesh(mesh.vertices, mesh.faces, str(path))
    except InputError as e:
        raise WorldConfigError(str(e)) from None
    return mesh


def load_collision_parts(p: PartConfig) -> list[trimesh.Trimesh]:
    """Convex parts (object frame): the collision folder's *.obj, else the convex hull of the mesh."""
    if p.collision is not None:
        return [load_mesh(f).convex_hull for f in sorted(p.collision.glob("*.obj"))]
    return [load_mesh(p.mesh).convex_hull]


def placed_parts(item: ObjectConfig | ArticulatedConfig) -> list[trimesh.Trimesh]:
    """Convex collision parts of an object (or a button's base and cap) in the base frame at its placement."""
    if isinstance(item, ObjectConfig):
        pieces = [(item.part, np.eye(4))]
    else:
        pieces = [(item.base, np.eye(4)), (item.cap, item.T_base_cap)]
    out = []
    M = item.placement.matrix
    for part, T in pieces:
        for m in load_collision_parts(part):
            m = m.copy()
            m.apply_transform(M @ T)
            out.append(m)
    return out


def _penetration(a: list[trimesh.Trimesh], b: list[trimesh.Trimesh]) -> float:
    """Largest depth (m) of a vertex of one convex set inside a convex part of the other (0 if apart).

    Vertex-in-hull catches the overlaps that matter for start placements (one object resting in another);
    two hulls crossing edge-on without any vertex inside each other are not caught.
    """
    depth = 0.0
    for pa in a:
        for pb in b:
            if np.any(pa.bounds[0] > pb.bounds[1]) or np.any(pb.bounds[0] > pa.bounds[1]):
                continue
            for x, h in ((pa, pb), (pb, pa)):
                normals, origins = h.face_normals, h.triangles[:, 0]
                # signed distance of each vertex of x to each face plane of h; inside h = all negative
                s = np.einsum("vfk,fk->vf", x.vertices[:, None, :] - origins[None], normals)
                inside = -s.max(axis=1)
                depth = max(depth, float(inside.max()))
    return depth


def check_overlaps(cfg: WorldConfig, tol: float = OVERLAP_TOL) -> None:
    """Raise if two items' collision parts interpenetrate by more than ``tol`` or one sinks into the table."""
    items = [*cfg.objects, *cfg.articulated]
    parts = {it.name: placed_parts(it) for it in items}
    for name, ps in parts.items():
        low = min(float(p.bounds[0, 2]) for p in ps)
        if low < cfg.table_z - tol:
            raise WorldConfigError(
                f"{name}: its placement puts it {1000 * (cfg.table_z - low):.1f} mm below the table (z = "
                f"{cfg.table_z}); raise its placement's translation z"
            )
    names = list(parts)
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            d = _penetration(parts[names[i]], parts[names[j]])
            if d > tol:
                raise WorldConfigError(
                    f"objects {names[i]!r} and {names[j]!r} overlap by {1000 * d:.1f} mm at their start placements; "
                    "move one of them (`m2m world move`)"
                )


def validate_world(cfg: WorldConfig, need_gaussians: bool = False, overlaps: bool = True) -> None:
    """Raise :class:`WorldConfigError` on the first problem; see the module docstring."""
    info = _robot_model(cfg.robot.file)
    links, joints = list(info.bodies), info.joint_names
    spec = cfg.robot.spec
    missing = [j for j in (*spec.arm_joints, *spec.gripper_joints) if j not in joints]
    if missing:
        raise WorldConfigError(
            f"robot.file: {cfg.robot.file} lacks the joints {missing} of robot {spec.name!r}; give the model of that "
            "robot, or set robot.name to the robot this model is"
        )
    if joints != (*spec.arm_joints, *spec.gripper_joints):
        raise WorldConfigError(
            f"robot.file: the joints of {cfg.robot.file} are, in order, {list(joints)}; robot {spec.name!r} needs "
            f"exactly its arm's then its gripper's {[*spec.arm_joints, *spec.gripper_joints]}"
        )
    lim = np.array([info.joint(j).limits or (-np.inf, np.inf) for j in spec.arm_joints])
    try:
        check_joints(cfg.robot.home, spec.arm_joints, lim, "robot.home")
    except InputError as e:
        raise WorldConfigError(str(e)) from None
    if cfg.robot.ee_link not in links:
        raise WorldConfigError(f"robot.ee_link: {cfg.robot.ee_link!r} is not a link of {cfg.robot.file} ({links})")
    for name, cam in cfg.cameras.items():
        if cam.mount != "base" and cam.mount not in links:
            raise WorldConfigError(f"cameras.{name}.mount: {cam.mount!r} is neither 'base' nor a robot link {links}")
        if cam.width < 1 or cam.height < 1:
            raise WorldConfigError(f"cameras.{name}: width and height must be positive")
    seen = set()
    for name in cfg.names:
        if not _NAME_RE.match(name):
            raise WorldConfigError(f"name {name!r}: use letters, digits, '_' or '-', starting with a letter")
        if name in seen or name == "robot":
            raise WorldConfigError(f"name {name!r} is used twice (or is reserved); names must be unique")
        seen.add(name)
    if cfg.scene_gaussians is not None and need_gaussians and not cfg.scene_gaussians.is_file():
        raise WorldConfigError(f"scene.gaussians: {cfg.scene_gaussians} not found")
    for it in [*cfg.objects, *cfg.articulated]:
        _check_placement(it.placement, f"{it.name}.placement")
    for o in cfg.objects:
        _check_part(o.part, f"objects.{o.name}", need_gaussians)
        if o.mass is None and o.density is None:
            raise WorldConfigError(f"objects.{o.name}: give a mass (kg) or a density (kg/m^3)")
    for a in cfg.articulated:
        _check_part(a.base, f"articulated.{a.name}.base", need_gaussians)
        _check_part(a.cap, f"articulated.{a.name}.cap", need_gaussians)
        axis = np.asarray(a.axis, dtype=np.float64)
        if np.linalg.norm(axis) < 1e-9:
            raise WorldConfigError(f"articulated.{a.name}.axis: must be a non-zero direction")
    r = cfg.randomize
    if r.x[0] > r.x[1] or r.y[0] > r.y[1] or r.yaw_deg[0] > r.yaw_deg[1]:
        raise WorldConfigError("randomize: each range must be [low, high] with low <= high")
    if overlaps:
        check_overlaps(cfg)
