"""A world from a reconstruction (no ground truth): :func:`world_from_reconstruction`.

Inputs (typed, read by the ``world`` stage from what the earlier stages wrote):

- the head camera (``CameraConfig``, from the hand-eye calibration: ``T_base_headcam``, ``K`` and image size, or
  the keyframe a fixed camera took); the wrist camera as calibrated (``wrist``), else the robot's default mount on
  its end-effector link (``default_wrist_camera``).
- object folders as the objects stage writes them (``{mesh.obj, collision/*.obj, gaussians.ply, align.json}``):
  one free object each, placed by ``align.json``'s ``sim3_obj_to_base`` (the same Sim3 for mesh and
  Gaussians), density from the objects stage. Placements are snapped vertically so the lowest collision
  vertex rests on the table (the reconstruction's bottom is a guess: the table hid it).
- An object named like a button (``"button" in name``, or listed in ``buttons``) becomes a press button: its one
  rigid reconstruction is cut at the height where the footprint narrows (the cap sits on a wider base; without
  such a step the top third is the cap). Below the cut is the fixed base, above it the cap on a sprung
  prismatic joint (travel 8 mm along -z by default). Meshes are cut and the cut closed with a fan, convex
  collision parts are clipped by the same plane (a clipped convex part stays convex), Gaussians go to the cap
  when above the cut and over the cap's footprint. The parts go to ``<world>/assets/<name>/{base,cap}/``.
- the scene splat, which also holds the objects, so every scene Gaussian within ``crop_margin`` of an
  object's placed mesh is removed (else a grasped object leaves a copy behind), and the table hole under
  each object is filled with flat Gaussians coloured like the table around it (the capture never saw the
  table under an object). Also removed: scene Gaussians within ``means_margin`` of the object's own opaque
  Gaussians, which cover thin tips (a stem, a horn) that the reconstructed mesh may miss. Written to
  ``<world>/scene.ply``.

Also written: ``<world>/reconstruction.json`` (what was done: snaps, removed and filled Gaussians, button cut
heights) and ``<world>/world.yaml``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import trimesh

from ..atomic import atomic_dir, atomic_write
from ..gaussians.model import Gaussians
from ..gaussians.ply import read_ply, write_ply
from ..geometry.sim3 import Sim3
from .config import (
    ArticulatedConfig,
    CameraConfig,
    LightConfig,
    ObjectConfig,
    PartConfig,
    RandomizeConfig,
    RobotConfig,
    WorldConfig,
    WorldConfigError,
    save_world,
)
from .sample import default_wrist_camera
from .validate import load_collision_parts, load_mesh

__all__ = ["ReconstructionOptions", "crop_scene", "is_button", "split_button", "world_from_reconstruction"]


@dataclass
class ReconstructionOptions:
    """How :func:`world_from_reconstruction` turns a reconstruction into a world.

    robot             the robot at the base origin
    buttons           object names that are press buttons besides those with "button" in their name
    crop_margin       m around each placed object mesh whose scene Gaussians are removed
    means_margin      m around each object's own opaque Gaussians whose scene Gaussians are removed too
    fill_spacing      m between the flat Gaussians filling the table under each object (0: no fill)
    snap_to_table     rest each object's lowest collision vertex on the table (z = table_z)
    table_z           height of the table plane in the base frame (m)
    friction          Coulomb friction of the objects and buttons
    button_travel     press button travel (m)
    button_axis       press direction in the button's frame
    button_stiffness  the button's spring (N/m)
    button_threshold  pressed beyond this fraction of the travel counts as pressed
    cap_fraction      height fraction of the cap when the button's footprint shows no step
    randomize         where the twin may put objects at reset
    """

    robot: RobotConfig = field(default_factory=RobotConfig)
    buttons: tuple[str, ...] = ()
    crop_margin: float = 0.01
    means_margin: float = 0.005
    fill_spacing: float = 0.003
    snap_to_table: bool = True
    table_z: float = 0.0
    friction: float = 1.0
    button_travel: float = 0.008
    button_axis: tuple[float, float, float] = (0.0, 0.0, -1.0)
    button_stiffness: float = 300.0
    button_threshold: float = 0.75
    cap_fraction: float = 1.0 / 3.0
    randomize: RandomizeConfig = field(default_factory=RandomizeConfig)


def is_button(name: str, options: ReconstructionOptions | None = None) -> bool:
    """Whether reconstructed object ``name`` is treated as a press button."""
    options = options or ReconstructionOptions()
    return "button" in name.lower() or name in options.buttons


# ---- geometry helpers --------------------------------------------------------------------------------
def _placed_bottom(part: PartConfig, placement: Sim3) -> float:
    return min(float(placement.apply(m.vertices)[:, 2].min()) for m in load_collision_parts(part))


def _lift(placement: Sim3, dz: float) -> Sim3:
    return Sim3(placement.scale, placement.rotation, placement.translation + np.array([0.0, 0.0, dz]))


def _cut_mesh(mesh: trimesh.Trimesh, z: float, keep_below: bool) -> trimesh.Trimesh:
    """The part of a watertight mesh below (or above) the plane at height ``z``, the cut closed by a fan from
    each boundary loop's centroid (exact for star-shaped sections: a button's is). Not closed: its hull."""
    from trimesh.intersections import slice_faces_plane

    normal = np.array([0.0, 0.0, -1.0 if keep_below else 1.0])
    v, f = slice_faces_plane(np.asarray(mesh.vertices), np.asarray(mesh.faces), normal, np.array([0.0, 0.0, z]))[:2]
    piece = trimesh.Trimesh(v, f, process=False)
    piece.merge_vertices()
    groups = trimesh.grouping.group_rows(piece.edges_sorted, require_count=1)
    boundary = piece.edges[groups]  # directed as in their faces
    verts, faces = [np.asarray(piece.vertices)], [np.asarray(piece.faces)]
    n = len(piece.vertices)
    if len(boundary):
        for loop in trimesh.graph.connected_components(boundary, min_len=3):
            loop_edges = boundary[np.isin(boundary[:, 0], loop)]
            centre = piece.vertices[np.unique(loop_edges)].mean(axis=0)
            verts.append(centre[None])
            # the cap face walks each boundary edge backwards, so the winding stays consistent
            faces.append(np.stack([loop_edges[:, 1], loop_edges[:, 0], np.full(len(loop_edges), n)], axis=1))
            n += 1
    out = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=True)
    if not out.is_volume:
        out = out.convex_hull
    return out


def _clip_convex(part: trimesh.Trimesh, z: float, keep_below: bool) -> trimesh.Trimesh | None:
    """A convex part clipped by the plane at height ``z`` (still convex), None when nothing is left."""
    V = np.asarray(part.vertices)
    side = V[:, 2] <= z if keep_below else V[:, 2] >= z
    e = part.edges_unique
    a, b = V[e[:, 0]], V[e[:, 1]]
    cross = (a[:, 2] - z) * (b[:, 2] - z) < 0
    t = (z - a[cross, 2]) / (b[cross, 2] - a[cross, 2])
    pts = np.concatenate([V[side], a[cross] + t[:, None] * (b[cross] - a[cross])])
    if len(pts) < 4 or np.ptp(pts, axis=0).min() < 1e-4:
        return None
    try:
        hull = trimesh.convex.convex_hull(pts)
    except Exception:  # noqa: BLE001 - degenerate (flat) remainder
        return None
    return hull if hull.volume > 1e-9 else None


def _cap_height(mesh: trimesh.Trimesh, fallback_fraction: float, bin_m: float = 0.001) -> tuple[float, str]:
    """Height (object frame) where a button's footprint narrows into its cap, found from the horizontal extent
    of its walls in 1 mm slabs (convex-hull area of the points in each); (top - fallback_fraction * height)
    when there is no clear step (the cap would be under 10% or over 60% of the height)."""
    from scipy.spatial import ConvexHull

    pts, face = trimesh.sample.sample_surface(mesh, 40000, seed=0)
    pts = pts[np.abs(mesh.face_normals[face, 2]) < 0.7]  # walls only: a flat top spans the slab it lies in
    z0, z1 = float(mesh.bounds[0, 2]), float(mesh.bounds[1, 2])
    height = z1 - z0
    edges = np.arange(z0, z1 + bin_m, bin_m)
    areas = np.zeros(len(edges) - 1)
    for i in range(len(edges) - 1):
        xy = pts[(pts[:, 2] >= edges[i]) & (pts[:, 2] < edges[i + 1]), :2]
        if len(xy) >= 8:
            try:
                areas[i] = ConvexHull(xy).volume
            except Exception:  # noqa: BLE001 - collinear points in a thin slab
                areas[i] = 0.0
    big = areas >= 0.6 * areas.max()
    below = np.nonzero(big)[0]
    if len(below):
        z_cut = float(edges[below[-1] + 1])  # top of the highest wide slab
        if 0.1 * height <= z1 - z_cut <= 0.6 * height:
            return z_cut, "step"
    return z1 - fallback_fraction * height, f"top {fallback_fraction:.2f} of the height"


def split_button(
    mesh: trimesh.Trimesh,
    collision: list[trimesh.Trimesh],
    gaussians: Gaussians,
    cap_fraction: float = 1.0 / 3.0,
) -> dict[str, Any]:
    """Cut one rigid button (object frame, z up) into a fixed base and a moving cap.

    Returns {"z_cut", "how", "T_base_cap" [4,4] (cap frame: origin at the cap's bottom centre, axes of the
    button's frame), "base": (mesh, parts, gaussians), "cap": (mesh, parts, gaussians) in their frames}."""
    z_cut, how = _cap_height(mesh, cap_fraction)
    base_mesh = _cut_mesh(mesh, z_cut, keep_below=True)
    cap_mesh = _cut_mesh(mesh, z_cut, keep_below=False)
    base_parts = [p for p in (_clip_convex(c, z_cut, True) for c in collision) if p is not None]
    cap_parts = [p for p in (_clip_convex(c, z_cut, False) for c in collision) if p is not None]
    if not cap_parts:  # the collision parts stop below the visual cap: the cap's own hull
        cap_parts = [cap_mesh.convex_hull]
    if not base_parts:
        base_parts = [base_mesh.convex_hull]
    lo, hi = cap_mesh.bounds
    origin = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, z_cut])
    T_base_cap = np.eye(4)
    T_base_cap[:3, 3] = origin

    # Gaussians: the cap's are above the cut AND over its footprint (the base's top rim lies at the cut height)
    from scipy.spatial import ConvexHull

    X = gaussians.means.detach().cpu().numpy().astype(np.float64)
    foot = cap_mesh.vertices[:, :2]
    eq = ConvexHull(foot).equations  # rows (n, d): n . x + d <= 0 inside
    over = (X[:, :2] @ eq[:, :2].T + eq[:, 2]).max(axis=1) <= 0.002
    on_cap = torch.from_numpy(over & (X[:, 2] > z_cut))
    cap_g = gaussians.select(on_cap)
    cap_g = cap_g.map(lambda t: t.clone())
    cap_g.means -= torch.as_tensor(origin, dtype=cap_g.means.dtype)
    cap_mesh = cap_mesh.copy()
    cap_mesh.apply_translation(-origin)
    cap_parts = [p.copy() for p in cap_parts]
    for p in cap_parts:
        p.apply_translation(-origin)
    return {
        "z_cut": z_cut,
        "how": how,
        "T_base_cap": T_base_cap,
        "base": (base_mesh, base_parts, gaussians.select(~on_cap)),
        "cap": (cap_mesh, cap_parts, cap_g),
    }


def _write_part(folder: Path, mesh: trimesh.Trimesh, parts: list[trimesh.Trimesh], g: Gaussians) -> None:
    folder.mkdir(parents=True)
    mesh.export(folder / "mesh.obj")
    write_ply(folder / "gaussians.ply", g)
    (folder / "collision").mkdir()
    for i, p in enumerate(parts):
        p.export(folder / "collision" / f"part_{i:02d}.obj")


# ---- the scene without the objects -------------------------------------------------------------------
def crop_scene(
    scene: Gaussians,
    placed_meshes: dict[str, trimesh.Trimesh],
    margin: float = 0.01,
    fill_spacing: float = 0.003,
    table_z: float = 0.0,
    placed_means: dict[str, np.ndarray] | None = None,
    means_margin: float = 0.005,
) -> tuple[Gaussians, dict[str, dict[str, int]]]:
    """The scene without the Gaussians within ``margin`` of any placed object mesh (base frame), under it, or
    within ``means_margin`` of the object's own opaque Gaussians (``placed_means[name]`` [M,3], base frame: they cover
    thin tips a reconstructed mesh can miss), plus flat Gaussians on the table where an object stood, coloured
    from the table Gaussians just around the hole.

    Returns (scene, {name: {"removed": n, "filled": n}})."""
    from scipy.spatial import cKDTree

    X = scene.means.detach().cpu().numpy().astype(np.float64)
    keep = np.ones(len(X), dtype=bool)
    holes: dict[str, np.ndarray] = {}
    info: dict[str, dict[str, int]] = {}
    for name, mesh in placed_meshes.items():
        lo, hi = mesh.bounds[0] - margin, mesh.bounds[1] + margin
        M = (placed_means or {}).get(name)
        tree = None
        if M is not None and len(M):
            M = M[np.all((M >= lo - 0.02) & (M <= hi + 0.02), axis=1)]  # the object's, not its floaters
            if len(M):
                tree = cKDTree(M)
                lo, hi = np.minimum(lo, M.min(axis=0) - means_margin), np.maximum(hi, M.max(axis=0) + means_margin)

        def zone(P: np.ndarray, mesh=mesh, tree=tree) -> np.ndarray:
            if not len(P):
                return np.zeros(0, dtype=bool)
            inside = trimesh.proximity.signed_distance(mesh, P) > -margin
            # under the object: the capture never saw it (a reconstruction's hollow underside included)
            up = np.tile([0.0, 0.0, 1.0], (len(P), 1))
            inside |= (P[:, 2] > table_z - margin) & mesh.ray.intersects_any(P, up)
            if tree is not None:
                inside |= tree.query(P, distance_upper_bound=means_margin)[0] < means_margin
            return inside

        near = np.nonzero(np.all((X >= lo) & (X <= hi), axis=1))[0]
        drop = near[zone(X[near])]
        keep[drop] = False
        info[name] = {"removed": int(len(drop)), "filled": 0}
        if fill_spacing > 0:  # grid points on the table inside the removed zone
            gx = np.arange(lo[0], hi[0] + 1e-9, fill_spacing)
            gy = np.arange(lo[1], hi[1] + 1e-9, fill_spacing)
            P = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)
            P3 = np.concatenate([P, np.full((len(P), 1), table_z)], axis=1)
            holes[name] = P[zone(P3)]
    out = scene.select(torch.from_numpy(keep))
    fills = [out]
    if holes:
        from ..gaussians.sh import SH_C0

        Xk = X[keep]
        op = out.opacities.detach().cpu().numpy()
        table = np.nonzero((np.abs(Xk[:, 2] - table_z) < 0.006) & (op > 0.5))[0]
        if len(table) >= 8:
            tree = cKDTree(Xk[table, :2])
            dc = out.sh[:, 0].detach().cpu().numpy()[table]
            for name, P in holes.items():
                if not len(P):
                    continue
                k = min(8, len(table))
                _, idx = tree.query(P, k=k)
                rgb = np.clip(dc[idx].mean(axis=1) * SH_C0 + 0.5, 0.0, 1.0)
                z = float(np.median(Xk[table[np.unique(idx)], 2]))
                n = len(P)
                r = 0.7 * fill_spacing
                f32 = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)
                g = Gaussians.from_activated(
                    f32(np.concatenate([P, np.full((n, 1), z)], axis=1)),
                    f32(np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))),
                    f32(np.tile([r, r, 0.1 * r], (n, 1))),
                    torch.full((n,), 0.95),
                    rgb=f32(rgb),
                    sh_degree=scene.sh_degree,
                )
                fills.append(g.to(dtype=out.means.dtype))
                info[name]["filled"] = n
    return Gaussians.concat(fills), info


# ---- the world ---------------------------------------------------------------------------------------
def world_from_reconstruction(
    world_dir: str | os.PathLike,
    head: CameraConfig,
    scene_ply: str | os.PathLike,
    object_dirs: dict[str, Path],
    options: ReconstructionOptions | None = None,
    log: Callable[[str], None] = lambda s: None,
    wrist: CameraConfig | None = None,
) -> WorldConfig:
    """Build ``world_dir`` (world.yaml, scene.ply, button parts, reconstruction.json) from the head camera, the
    scene splat and the object folders ``{name: folder}`` (see the module docstring). Returns the saved config.
    ``wrist``: the wrist camera as calibrated (default: the robot's own mount, ``default_wrist_camera``)."""
    opt = options or ReconstructionOptions()
    world_dir = Path(world_dir).resolve()
    world_dir.mkdir(parents=True, exist_ok=True)
    scene_ply = Path(scene_ply)
    names = list(object_dirs)
    report: dict[str, Any] = {"options": asdict(opt), "objects": {}}

    objects: list[ObjectConfig] = []
    articulated: list[ArticulatedConfig] = []
    placed: dict[str, trimesh.Trimesh] = {}
    means: dict[str, np.ndarray] = {}
    for name in names:
        folder = Path(object_dirs[name]).resolve()
        align = json.loads((folder / "align.json").read_text())
        if "sim3_obj_to_base" not in align:
            raise WorldConfigError(f"{folder / 'align.json'}: no sim3_obj_to_base; rerun the objects stage")
        placement = Sim3.from_json(align["sim3_obj_to_base"])
        density = float(align.get("mesh", {}).get("density", 500.0))
        collision = folder / "collision" if any((folder / "collision").glob("*.obj")) else None
        part = PartConfig(folder / "gaussians.ply", folder / "mesh.obj", collision)
        rec: dict[str, Any] = {"density": density}
        placement_found = placement
        mesh = load_mesh(part.mesh)
        where = mesh.copy()  # where the reconstruction is in the scene: what to cut out of it
        where.apply_transform(placement.matrix)
        if opt.snap_to_table:
            dz = opt.table_z - _placed_bottom(part, placement)
            placement = _lift(placement, dz)
            rec["snapped_mm"] = 1000 * dz
            if abs(dz) > 0.005:
                log(f"{name}: WARNING its reconstruction ends {1000 * -dz:+.1f} mm from the table; moved onto it "
                    f"(check objects/{name}/figure.png; `m2m objects` with more keyframes or iterations helps)")
            if abs(dz) > 0.002:  # cut out where it is and where it now stands (the space between is unseen object)
                moved = mesh.copy()
                moved.apply_transform(placement.matrix)
                where = trimesh.util.concatenate([where, moved]).convex_hull
        placed[name] = where
        g_obj = read_ply(part.gaussians)
        opaque = (g_obj.opacities > 0.5).cpu().numpy()
        means[name] = placement_found.apply(g_obj.means.detach().cpu().numpy().astype(np.float64)[opaque])
        if is_button(name, opt):
            pieces = split_button(mesh, load_collision_parts(part), g_obj, opt.cap_fraction)
            out = world_dir / "assets" / name
            with atomic_dir(out) as tmp:
                _write_part(tmp / "base", *pieces["base"])
                _write_part(tmp / "cap", *pieces["cap"])
            parts = {k: PartConfig(out / k / "gaussians.ply", out / k / "mesh.obj", out / k / "collision")
                     for k in ("base", "cap")}  # fmt: skip
            cap_mesh = pieces["cap"][0]
            travel = opt.button_travel
            articulated.append(
                ArticulatedConfig(
                    name=name,
                    kind="press_button",
                    base=parts["base"],
                    cap=parts["cap"],
                    placement=placement,
                    T_base_cap=pieces["T_base_cap"],
                    axis=tuple(float(a) for a in opt.button_axis),
                    travel=travel,
                    threshold=opt.button_threshold * travel,
                    stiffness=opt.button_stiffness,
                    cap_mass=float(np.clip(density * cap_mesh.volume * placement.scale**3, 0.005, 0.2)),
                    friction=opt.friction,
                )
            )
            rec.update(
                kind="press_button",
                cap_cut_height_m=pieces["z_cut"],
                cap_cut_from=pieces["how"],
                cap_height_m=float(cap_mesh.bounds[1, 2]),
                gaussians_base=len(pieces["base"][2]),
                gaussians_cap=len(pieces["cap"][2]),
            )
            log(f"{name}: press button, cap above {1000 * pieces['z_cut']:.1f} mm ({pieces['how']})")
        else:
            objects.append(ObjectConfig(name, part, placement, mass=None, density=density, friction=opt.friction))
            rec["kind"] = "object"
        report["objects"][name] = rec

    log(f"scene: removing the objects' Gaussians from {scene_ply}")
    scene, crop = crop_scene(
        read_ply(scene_ply), placed, opt.crop_margin, opt.fill_spacing, opt.table_z, means, opt.means_margin
    )
    out_scene = world_dir / "scene.ply"
    write_ply(out_scene, scene)
    for name, c in crop.items():
        report["objects"][name].update(scene_removed=c["removed"], scene_filled=c["filled"])
        log(f"{name}: {c['removed']} scene Gaussians removed, {c['filled']} table Gaussians filled in")

    cfg = WorldConfig(
        root=world_dir,
        robot=opt.robot,
        cameras={"head": head, "wrist": wrist or default_wrist_camera(robot=opt.robot.spec)},
        scene_gaussians=out_scene,
        objects=objects,
        articulated=articulated,
        lights=[
            LightConfig(dir=(-0.6, -0.8, -1.0), intensity=3.0),
            LightConfig(dir=(0.8, 0.5, -0.7), color=(0.95, 0.97, 1.0), intensity=1.2),
        ],
        table_z=opt.table_z,
        randomize=opt.randomize,
    )
    report["source"] = {"scene": str(scene_ply.resolve()), "objects": {n: str(Path(d).resolve()) for n, d in
                                                                       object_dirs.items()}}
    with atomic_write(world_dir / "reconstruction.json", "w", encoding="utf-8") as f:
        json.dump(report, f, indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    save_world(cfg)
    return cfg

