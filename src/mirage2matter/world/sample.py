"""A world from the bundled sample's ground truth: the stand-in for a reconstruction.

``sample_world(sample_dir, world_dir)`` writes, per object, what the objects stage writes
(``<assets>/<name>/{gaussians.ply, mesh.obj (+ .mtl, .png), collision/*.obj}``, assets in ``world_dir/assets``
unless given) from the sample's ground-truth meshes: Gaussians are flat discs sampled on the textured surface
(colour from the texture, disc normal along the surface normal), collision parts come from CoACD. Without a
trained scene splat (``scene_ply``) a stand-in scene is sampled the same way on the sample's table and board.
Then ``world.yaml`` places every object at its ground-truth pose, the head camera at the sample's mount (or
``T_base_headcam``, a calibrated one) and a wrist camera on the robot's hand.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import torch
import trimesh

from ..atomic import atomic_dir
from ..gaussians.model import Gaussians
from ..gaussians.ply import write_ply
from ..geometry.rotation import matrix_to_quat
from ..geometry.sim3 import Sim3
from ..robots import DEFAULT_ROBOT, RobotError, RobotSpec, get_robot
from .config import (
    ArticulatedConfig,
    CameraConfig,
    LightConfig,
    ObjectConfig,
    PartConfig,
    RobotConfig,
    WorldConfig,
    WorldConfigError,
    save_world,
)
from .sample_assets import assets_of_sample

__all__ = ["default_wrist_camera", "sample_world", "surface_gaussians", "convex_parts"]


def surface_gaussians(
    mesh: trimesh.Trimesh, n: int, seed: int = 0, opacity: float = 0.95, thickness: float = 0.15
) -> Gaussians:
    """``n`` flat Gaussians on the surface of a (textured or vertex-coloured) mesh, in the mesh's frame.

    Area-weighted samples; each disc lies in the local tangent plane (its smallest axis along the face
    normal, ``thickness`` of its radius) with a radius from the sampling density, so the discs tile the
    surface; colour from the texture at the sample's UV (else vertex / face colour, else grey). SH degree 0.
    """
    rng = np.random.default_rng(seed)
    mesh = mesh if isinstance(mesh, trimesh.Trimesh) else trimesh.util.concatenate(list(mesh.geometry.values()))
    area = mesh.area_faces
    face = rng.choice(len(area), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)  # uniform on each triangle
    tri = mesh.triangles[face]
    points = np.einsum("nk,nkd->nd", bary, tri)
    normals = mesh.face_normals[face]
    rgb = np.full((n, 3), 0.6)
    vis = mesh.visual
    if isinstance(vis, trimesh.visual.TextureVisuals) and vis.uv is not None and getattr(vis.material, "image", None):
        uv = np.einsum("nk,nkd->nd", bary, np.asarray(vis.uv)[mesh.faces[face]])
        img = np.asarray(vis.material.image.convert("RGB"), dtype=np.float64) / 255.0
        h, w = img.shape[:2]
        u = np.clip((uv[:, 0] % 1.0) * w, 0, w - 1).astype(int)
        v = np.clip((1.0 - uv[:, 1] % 1.0) * h, 0, h - 1).astype(int)
        rgb = img[v, u]
    elif hasattr(vis, "vertex_colors") and len(getattr(vis, "vertex_colors", [])) == len(mesh.vertices):
        vc = np.asarray(vis.vertex_colors, dtype=np.float64)[:, :3] / 255.0
        rgb = np.einsum("nk,nkd->nd", bary, vc[mesh.faces[face]])
    # Tangent frame per sample: columns (t1, t2, normal).
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    R = np.stack([t1, t2, normals], axis=2)
    quats = np.asarray(matrix_to_quat(R), dtype=np.float64)
    radius = 0.6 * math.sqrt(area.sum() / n)
    scales = np.tile([radius, radius, radius * thickness], (n, 1))
    f32 = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)
    return Gaussians.from_activated(
        f32(points), f32(quats), f32(scales), torch.full((n,), float(opacity)), rgb=f32(rgb).clamp(0, 1)
    )


def convex_parts(mesh: trimesh.Trimesh, max_parts: int = 8, threshold: float = 0.05) -> list[trimesh.Trimesh]:
    """Convex decomposition (CoACD) of a watertight mesh; the hull itself when that is within 2% of the volume."""
    hull = mesh.convex_hull
    if mesh.is_volume and hull.volume <= 1.02 * mesh.volume:
        return [hull]
    import coacd

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
        threshold=threshold,
        max_convex_hull=max_parts,
        preprocess_resolution=30,
        seed=0,
    )
    return [trimesh.Trimesh(v, f).convex_hull for v, f in parts]


def default_wrist_camera(
    width: int | None = None, height: int | None = None, fov_deg: float | None = None, robot: RobotSpec | None = None
) -> CameraConfig:
    """The robot's wrist camera at its mount (``RobotSpec.wrist_camera``; default robot: ``robots.DEFAULT_ROBOT``,
    whose camera sits on the hand, behind the fingers, looking between the fingertips); size and vertical field
    of view default to the mount's."""
    spec = robot or get_robot(DEFAULT_ROBOT)
    try:
        mount = spec.wrist_camera
    except KeyError as e:
        raise WorldConfigError(str(e.args[0])) from None
    width = mount.width if width is None else width
    height = mount.height if height is None else height
    fov_deg = mount.fov_deg if fov_deg is None else fov_deg
    f = 0.5 * height / math.tan(math.radians(0.5 * fov_deg))
    K = np.array([[f, 0, 0.5 * width], [0, f, 0.5 * height], [0, 0, 1.0]])
    return CameraConfig(mount=mount.link, T_mount_cam=mount.T_link_cam, K=K, width=width, height=height)


def _write_part(mesh: trimesh.Trimesh, folder: Path, n_gaussians: int, seed: int, max_parts: int) -> PartConfig:
    """objects/<name>/{mesh.obj, gaussians.ply, collision/part_XX.obj} in ``folder`` (already a temp dir)."""
    export = mesh.copy()
    if isinstance(export.visual, trimesh.visual.TextureVisuals) and export.visual.material is not None:
        export.visual.material.name = "material"
    export.export(folder / "mesh.obj")
    write_ply(folder / "gaussians.ply", surface_gaussians(mesh, n_gaussians, seed))
    (folder / "collision").mkdir()
    for i, part in enumerate(convex_parts(mesh, max_parts)):
        part.export(folder / "collision" / f"part_{i:02d}.obj")
    return PartConfig(folder / "gaussians.ply", folder / "mesh.obj", folder / "collision")


def _final(part: PartConfig, tmp: Path, final: Path) -> PartConfig:
    swap = lambda p: final / p.relative_to(tmp)
    return PartConfig(swap(part.gaussians), swap(part.mesh), swap(part.collision))


# The floor is far and out of focus in every view: coarse discs (5 cm apart) fill it in. The walls stay out: a
# viewer's orbit from outside the room would see their backs and nothing else (they fill the head view's top corner).
FAR_DENSITY_PER_M2 = 400.0


def _scene_stand_in(seed: int, density_per_m2: float, gt: dict) -> Gaussians:
    """Gaussians on the sample's table top and board (where the sample put it: ``gt``, its ground_truth.json), and
    coarser ones on its floor: a scene for worlds without a trained one, seen from the sample's cameras."""
    parts = []
    for a in assets_of_sample(gt):
        if a.name not in ("table", "board", "floor"):
            continue
        far = a.name == "floor"
        mesh = a.mesh.copy()
        mesh.apply_transform(np.asarray(a.T_base_obj))
        if a.name == "table":  # only the top face: its sides and legs are out of every view that matters here
            keep = mesh.face_normals[:, 2] > 0.9
            mesh = mesh.submesh([np.nonzero(keep)[0]], append=True)
        n = max(1000, int(mesh.area * (FAR_DENSITY_PER_M2 if far else density_per_m2)))
        g = surface_gaussians(mesh, n, seed + len(parts))
        if a.name == "board":  # 1 mm proud of the table, drawn over it
            g.means[:, 2] += 0.0005
        parts.append(g)
    return Gaussians.concat(parts)


def sample_world(
    sample_dir: str | os.PathLike,
    world_dir: str | os.PathLike,
    *,
    assets_dir: str | os.PathLike | None = None,
    scene_ply: str | os.PathLike | None = None,
    T_base_headcam: np.ndarray | None = None,
    gaussians_per_object: int = 20000,
    scene_density_per_m2: float = 60000.0,
    max_collision_parts: int = 8,
    seed: int = 0,
    overwrite: bool = False,
    robot: str = DEFAULT_ROBOT,
) -> WorldConfig:
    """Write ``<assets_dir>/<name>/...`` (default ``world_dir/assets``) and ``world_dir/world.yaml`` from a sample's
    ground truth (see the module docstring), with ``robot`` (a registered name or a robot spec file) at the base
    and its wrist camera. Existing asset folders are kept (delete them, or pass ``overwrite``, to rebuild).
    Returns the config."""
    sample_dir, world_dir = Path(sample_dir), Path(world_dir)
    assets = Path(assets_dir) if assets_dir is not None else world_dir / "assets"
    gt_path = sample_dir / "ground_truth.json"
    if not gt_path.is_file():
        raise WorldConfigError(f"{gt_path} not found; give the sample folder (e.g. samples/tabletop)")
    gt = json.loads(gt_path.read_text())
    by_name = {o["name"]: o for o in gt["objects"]}
    world_dir.mkdir(parents=True, exist_ok=True)

    def load(name: str) -> trimesh.Trimesh:
        return trimesh.load(str(sample_dir / by_name[name]["mesh"]), process=False, force="mesh")

    def build(name: str, mesh: trimesh.Trimesh, k: int) -> PartConfig:
        final = assets / name
        if final.is_dir() and not overwrite and (final / "gaussians.ply").is_file():
            return PartConfig(final / "gaussians.ply", final / "mesh.obj", final / "collision")
        with atomic_dir(final) as tmp:
            part = _write_part(mesh, tmp, gaussians_per_object, seed + k, max_collision_parts)
        return _final(part, tmp, final)

    objects, articulated = [], []
    for k, o in enumerate(gt["objects"]):
        if o["category"] != "object":
            continue
        part = build(o["name"], load(o["name"]), k)
        meta = o.get("meta", {})
        placement = Sim3.from_matrix(np.asarray(o["T_base_obj"]))
        objects.append(
            ObjectConfig(name=o["name"], part=part, placement=placement, mass=meta.get("mass"), friction=1.0)
        )
    for o in gt["objects"]:
        if o["category"] != "button" or o["meta"].get("part") != "base":
            continue
        cap = by_name[o["meta"]["cap"]]
        name = o["name"].removesuffix("_base") or "button"
        base_part = build(o["name"], load(o["name"]), 10)
        cap_part = build(cap["name"], load(cap["name"]), 11)
        travel = float(o["meta"].get("travel", 0.008))
        articulated.append(
            ArticulatedConfig(
                name=name,
                kind="press_button",
                base=base_part,
                cap=cap_part,
                placement=Sim3.from_matrix(np.asarray(o["T_base_obj"])),
                T_base_cap=np.asarray(cap["meta"]["T_base_cap_rest"], dtype=np.float64),
                axis=tuple(o["meta"].get("press_axis", (0.0, 0.0, -1.0))),
                travel=travel,
                threshold=0.75 * travel,
                cap_mass=float(cap["meta"].get("mass", 0.02)),
            )
        )

    if scene_ply is None:
        scene_ply = world_dir / "scene_stand_in.ply"
        if overwrite or not scene_ply.is_file():
            write_ply(scene_ply, _scene_stand_in(seed, scene_density_per_m2, gt))
    try:
        robot_cfg = RobotConfig(name=str(robot))
    except RobotError as e:
        raise WorldConfigError(f"robot: {e}") from None
    head = gt["head_camera"]
    if T_base_headcam is None:
        T_base_headcam = np.asarray(head["T_base_headcam"], dtype=np.float64)
    cameras = {
        "head": CameraConfig("base", T_base_headcam, np.asarray(head["K"]), int(head["width"]), int(head["height"])),
        "wrist": default_wrist_camera(robot=robot_cfg.spec),
    }
    lights = [
        LightConfig(dir=(-0.6, -0.8, -1.0), intensity=3.0),
        LightConfig(dir=(0.8, 0.5, -0.7), color=(0.95, 0.97, 1.0), intensity=1.2),
    ]
    cfg = WorldConfig(
        root=world_dir.resolve(),
        robot=robot_cfg,
        cameras=cameras,
        scene_gaussians=Path(scene_ply).resolve(),
        objects=objects,
        articulated=articulated,
        lights=lights,
    )
    save_world(cfg)
    return cfg
