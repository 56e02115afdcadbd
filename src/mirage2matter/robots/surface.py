"""The robot's surface at a joint state: each link's meshes posed by forward kinematics, in the base frame.

A capture films the robot where it stood; with its joint state known (``capture_joints``) the links' surfaces are
known exactly in the base frame. They are what the capture's robot pixels and SfM points are tested against
(calib.robot_view): a second alignment target, the mask that keeps the robot out of the scene's Gaussians.

MuJoCo poses the model's geoms (its kinematics agree with Genesis' for the same file). The visual geoms are taken
(``contype = conaffinity = 0``: what a camera sees); a model with none (a URDF, whose visuals MuJoCo drops) gives
its collision geoms. Meshes and the primitive shapes (box, sphere, capsule, cylinder) are drawn; planes and height
fields are not part of a robot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .model import load_model, resolve_model
from .spec import RobotSpec, RobotSpecError

__all__ = ["CaptureJointsError", "LinkSurface", "check_capture_joints", "robot_surface", "sample_surface"]


class CaptureJointsError(RobotSpecError):
    """A capture joint state that does not fit the robot (length, limits, units); the message names the joint."""


@dataclass(frozen=True)
class LinkSurface:
    """One link's geometry at a joint state.

    link           the link (MuJoCo body) name
    vertices_link  [V,3] the link's own frame (m): what moves with it
    faces          [F,3] vertex indices (triangles)
    T_base_link    [4,4] the link's pose at the joint state
    face_rgb       [F,3] the model's colour of each face (its geom's material or rgba, 0..1): the mesh look
    fixed          no joint moves it (the base): its place says nothing about a joint state
    close_up       a camera on the robot sees it from centimetres: the link is rigid with a camera's mount link,
                   or it is a finger (in front of the wrist camera)
    """

    link: str
    vertices_link: np.ndarray
    faces: np.ndarray
    T_base_link: np.ndarray
    face_rgb: np.ndarray | None = None
    fixed: bool = False
    close_up: bool = False

    @property
    def vertices(self) -> np.ndarray:
        """[V,3] base frame (m)."""
        return self.vertices_link @ self.T_base_link[:3, :3].T + self.T_base_link[:3, 3]

    @property
    def area(self) -> float:
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())


def check_capture_joints(spec: RobotSpec, values: Sequence[float] | None, what: str = "capture_joints") -> np.ndarray:
    """The joint state [n_dofs] the robot had while the capture was filmed: ``values`` of its arm joints [n_arm]
    (the fingers open) or of all its joints [n_dofs] in radians (metres for sliding fingers); None: the spec's home.

    Refused (:class:`CaptureJointsError`, naming ``what`` and the joint): a wrong length, a value that is not finite,
    a value outside the joint's limits (by more than 1e-3), and a vector that reads as degrees."""
    if values is None:
        return spec.home_q(spec.gripper_open)
    q = np.asarray(values, dtype=np.float64).reshape(-1)
    names = (*spec.arm_joints, *spec.gripper_joints)
    if q.size not in (spec.n_arm, spec.n_dofs):
        raise CaptureJointsError(
            f"{what}: {q.size} values given; {spec.name} has {spec.n_arm} arm joints ({', '.join(spec.arm_joints)})"
            f" and {spec.n_dofs} joints with the fingers; give the arm's {spec.n_arm} joint angles in radians"
        )
    if not np.isfinite(q).all():
        bad = [names[i] for i in np.flatnonzero(~np.isfinite(q))]
        raise CaptureJointsError(f"{what}: {', '.join(bad)} not a finite number")
    if q.size == spec.n_arm:
        q = np.concatenate([q, [spec.gripper_open] * (spec.n_dofs - spec.n_arm)])
    lo, hi = (np.asarray(v, dtype=np.float64) for v in zip(*spec.joint_limits, strict=True))
    arm = q[: spec.n_arm]
    if np.abs(arm).max() > 2 * math.pi + 1e-6 and np.all(np.abs(np.radians(arm)) <= 2 * math.pi):
        raise CaptureJointsError(
            f"{what}: {np.round(arm, 3).tolist()} reads as degrees ({names[int(np.argmax(np.abs(arm)))]} = "
            f"{arm[int(np.argmax(np.abs(arm)))]:g}); give radians (e.g. {np.round(np.radians(arm), 4).tolist()})"
        )
    out = np.flatnonzero((q < lo - 1e-3) | (q > hi + 1e-3))
    if out.size:
        i = int(out[0])
        raise CaptureJointsError(
            f"{what}: {names[i]} = {q[i]:.4f} is outside its limits [{lo[i]:.4f}, {hi[i]:.4f}]"
            + (f" (and {out.size - 1} more joint(s))" if out.size > 1 else "")
            + "; check the joint order and units (radians)"
        )
    return np.clip(q, lo, hi)


def _primitive(kind: int, size: np.ndarray, mj) -> tuple[np.ndarray, np.ndarray] | None:
    import trimesh

    t = mj.mjtGeom
    if kind == int(t.mjGEOM_BOX):
        m = trimesh.creation.box(extents=2 * size[:3])
    elif kind == int(t.mjGEOM_SPHERE):
        m = trimesh.creation.icosphere(subdivisions=2, radius=size[0])
    elif kind == int(t.mjGEOM_CAPSULE):
        m = trimesh.creation.capsule(height=2 * size[1], radius=size[0], count=[16, 8])
    elif kind == int(t.mjGEOM_CYLINDER):
        m = trimesh.creation.cylinder(radius=size[0], height=2 * size[1], sections=16)
    else:
        return None
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def robot_surface(spec: RobotSpec, q: Sequence[float]) -> list[LinkSurface]:
    """The robot's link surfaces at joint state ``q`` [n_dofs] (or [n_arm], fingers open), base frame: one
    :class:`LinkSurface` per link that has geometry, in the model's body order."""
    import mujoco

    q = check_capture_joints(spec, q, "joint state")
    model = load_model(resolve_model(spec.model), meshes=True)
    data = mujoco.MjData(model)
    data.qpos[:] = 0.0
    data.qpos[: q.size] = q
    mujoco.mj_kinematics(model, data)
    visual = (model.geom_contype == 0) & (model.geom_conaffinity == 0)
    keep = visual if visual.any() else np.ones(model.ngeom, bool)
    parts: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for g in np.flatnonzero(keep):
        kind = int(model.geom_type[g])
        if kind == int(mujoco.mjtGeom.mjGEOM_MESH):
            m = int(model.geom_dataid[g])
            v = np.asarray(model.mesh_vert[model.mesh_vertadr[m] : model.mesh_vertadr[m] + model.mesh_vertnum[m]],
                           dtype=np.float64)  # fmt: skip
            f = np.asarray(model.mesh_face[model.mesh_faceadr[m] : model.mesh_faceadr[m] + model.mesh_facenum[m]],
                           dtype=np.int64)  # fmt: skip
        else:
            prim = _primitive(kind, np.asarray(model.geom_size[g]), mujoco)
            if prim is None:
                continue
            v, f = prim
        body = int(model.geom_bodyid[g])
        # the geom in its body's frame: geom pose relative to the body's, both from the same kinematics
        R_body, R_geom = data.xmat[body].reshape(3, 3), data.geom_xmat[g].reshape(3, 3)
        R = R_body.T @ R_geom
        t = R_body.T @ (data.geom_xpos[g] - data.xpos[body])
        mat = int(model.geom_matid[g])
        rgb = np.asarray(model.mat_rgba[mat][:3] if mat >= 0 else model.geom_rgba[g][:3], np.float64)
        parts.setdefault(body, []).append((v @ R.T + t, f, rgb))
    # the rigid groups (MuJoCo's weld ids: a body and its jointless children) that carry a camera of the robot
    mount_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, m.link) for _, m in spec.cameras]
    mounts = {int(model.body_weldid[b]) for b in mount_ids if b >= 0}
    out = []
    for body in sorted(parts):
        verts, faces, colours, n = [], [], [], 0
        for v, f, rgb in parts[body]:
            verts.append(v)
            faces.append(f + n)
            colours.append(np.tile(rgb, (len(f), 1)))
            n += len(v)
        T = np.eye(4)
        T[:3, :3] = data.xmat[body].reshape(3, 3)
        T[:3, 3] = data.xpos[body]
        fixed = int(model.body_weldid[body]) == 0  # welded to the world body: no joint above it
        name = model.body(body).name
        close = int(model.body_weldid[body]) in mounts or name in spec.finger_links
        out.append(LinkSurface(name, np.concatenate(verts), np.concatenate(faces), T, np.concatenate(colours), fixed,
                               close))  # fmt: skip
    if not out:
        raise RobotSpecError(f"{spec.name}: its model {spec.model} has no geometry to draw the robot from")
    return out


def sample_surface(links: Sequence[LinkSurface], spacing: float | Sequence[float], seed: int = 0,
                   frame: str = "base", with_faces: bool = False) -> tuple[np.ndarray, ...]:
    """Points on the links' surfaces, about one per ``spacing`` x ``spacing`` metres of area (one spacing, or one
    per link): (points [M,3] in the base frame, or each in its link's frame with ``frame="link"``; the index of each
    point's link in ``links`` [M]; with ``with_faces`` also the index of its face in its link [M]). Deterministic
    for a seed."""
    rng = np.random.default_rng(seed)
    spacings = np.broadcast_to(np.asarray(spacing, np.float64), (len(links),))  # one for all, or one per link
    pts, owner, face = [], [], []
    for i, (link, step) in enumerate(zip(links, spacings, strict=True)):
        verts = link.vertices if frame == "base" else link.vertices_link
        a, b, c = (verts[link.faces[:, k]] for k in range(3))
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        n = int(math.ceil(area.sum() / float(step) ** 2))
        if n == 0 or area.sum() <= 0:
            continue
        tri = rng.choice(len(area), size=n, p=area / area.sum())
        r1, r2 = rng.random(n), rng.random(n)
        s = np.sqrt(r1)
        p = (1 - s)[:, None] * a[tri] + (s * (1 - r2))[:, None] * b[tri] + (s * r2)[:, None] * c[tri]
        pts.append(p)
        owner.append(np.full(n, i))
        face.append(tri)
    out = (np.concatenate(pts), np.concatenate(owner))
    return (*out, np.concatenate(face)) if with_faces else out
