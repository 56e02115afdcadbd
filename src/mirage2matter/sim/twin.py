"""The Genesis twin of a world: robot at the origin, the table as the ground plane, objects as rigid bodies
with convex collision parts at their placements, press buttons as a fixed base plus a sprung prismatic cap,
and cameras at their calibrated mounts (head fixed in the base, wrist on the hand link). Gains, force limits and
the gripper come from the world's robot spec (``twin.spec``, see ``mirage2matter.robots``).

Object bodies are generated URDFs (one link: the textured mesh as visual, the convex parts as collision,
inertia from the watertight mesh) in the object frame scaled by the placement's scale, so a body's pose is
the rigid part of the object's current Sim3 (see ``world.config``). Genesis keeps its compiled kernels in
``~/.cache/quadrants`` and ``~/.cache/genesis``: the first build on a machine takes ~110 s, later ones ~15 s.

The scene (look, physics, the robot, cameras) is set up by ``sim.scene``, which converts Genesis' camera
conventions (OpenGL axes, vertical fov, centred principal point) at the border.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
import trimesh

from ..geometry.rotation import matrix_to_quat
from ..robots import RobotSpec
from ..robots.model import resolve_model
from ..world.config import ArticulatedConfig, LightConfig, ObjectConfig, PartConfig, WorldConfig
from ..world.validate import load_collision_parts, load_mesh, validate_world
from .scene import (
    SceneLook,
    add_camera,
    add_ground_plane,
    add_robot,
    ensure_genesis,
    new_scene,
    pos_quat,
    pose_from,
    render_K,
    render_view,
)

__all__ = ["CLOSED_MARGIN", "STOPPED_SPEED", "Twin", "TwinOptions"]

# A gripper command within this fraction of the gripper's range of ``gripper_closed`` counts as "closed" and
# squeezes with the spec's grasp force: a learned policy regresses "closed" only approximately.
CLOSED_MARGIN = 0.25
# Fingers closing slower than this (m/s) have stopped on something (free, they close at ~0.1-0.2 m/s).
STOPPED_SPEED = 0.01


@dataclass
class TwinOptions:
    """How to build the twin.

    backend        "cpu" (default) or "gpu"
    dt             physics step (s); substeps per step
    render         add the world's cameras (needed by :meth:`Twin.render_robot`; costs build time)
    camera_sizes   {camera name: (width, height)} of the Genesis cameras (default: the world's sizes)
    workdir        where generated URDFs go (default: a temporary folder)
    settle_s       physics time to let objects settle after a reset
    draw_scene     the cameras draw the plane, objects and buttons too (False: only the robot, whose mask is
                   then where the depth is finite: no segmentation pass; what hybrid frames need)
    draw_objects   with draw_scene False, the cameras draw the objects and buttons too (not the plane); the
                   "robot" layer is then robot + objects (hybrid frames with mesh objects: the ablation)
    """

    backend: str = "cpu"
    dt: float = 0.01
    substeps: int = 1
    render: bool = True
    camera_sizes: dict[str, tuple[int, int]] = field(default_factory=dict)
    workdir: Path | None = None
    settle_s: float = 0.1
    draw_scene: bool = True
    draw_objects: bool = False


def _rigid(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _rigid_part(T_base_obj: np.ndarray, scale: float) -> np.ndarray:
    """The body's pose: the rigid part of a placement's Sim3 [4,4] (its rotation block divided by ``scale``)."""
    return _rigid(T_base_obj[:3, :3] / scale, T_base_obj[:3, 3])


def _twin_look(cfg: WorldConfig) -> SceneLook:
    """The world's ambient light and lights (one light from above when it has none), no shadows, Genesis' background:
    the twin's cameras draw the robot (and objects) that hybrid frames composite over the splats."""
    return SceneLook(
        ambient=tuple(cfg.ambient),
        lights=tuple(cfg.lights) or (LightConfig(dir=(-0.5, -0.5, -1.0), color=(1.0, 1.0, 1.0), intensity=3.0),),
        background=None,
        shadow=False,
        near=0.01,
        far=20.0,
    )


def _inertial_xml(mesh: trimesh.Trimesh, mass: float, scale: float) -> str:
    """URDF <inertial> of a watertight mesh (object frame) scaled by ``scale`` with total ``mass``."""
    m = mesh.copy()
    m.apply_scale(scale)
    if m.is_volume and m.volume > 0:
        m.density = mass / m.volume
        com, inertia = m.center_mass, m.moment_inertia
    else:  # not watertight: a box of its bounds
        ext = m.extents
        com = m.bounds.mean(axis=0)
        inertia = np.diag([ext[1] ** 2 + ext[2] ** 2, ext[0] ** 2 + ext[2] ** 2, ext[0] ** 2 + ext[1] ** 2]) * mass / 12
    ixx, iyy, izz = (max(float(inertia[i, i]), 1e-8) for i in range(3))
    ixy, ixz, iyz = float(inertia[0, 1]), float(inertia[0, 2]), float(inertia[1, 2])
    return (
        f'<inertial><origin xyz="{com[0]:.6g} {com[1]:.6g} {com[2]:.6g}"/><mass value="{mass:.6g}"/>'
        f'<inertia ixx="{ixx:.6g}" iyy="{iyy:.6g}" izz="{izz:.6g}" ixy="{ixy:.6g}" ixz="{ixz:.6g}" iyz="{iyz:.6g}"/>'
        "</inertial>"
    )


def _geoms_xml(part: PartConfig, scale: float, origin: np.ndarray | None = None) -> str:
    """URDF visual (textured mesh) + one collision per convex part, the part collision files written beside."""
    s = f"{scale:.9g} {scale:.9g} {scale:.9g}"
    o = ""
    if origin is not None:
        rpy = _rpy(origin[:3, :3])
        t = origin[:3, 3]
        o = f'<origin xyz="{t[0]:.9g} {t[1]:.9g} {t[2]:.9g}" rpy="{rpy[0]:.9g} {rpy[1]:.9g} {rpy[2]:.9g}"/>'
    xml = f'<visual>{o}<geometry><mesh filename={quoteattr(str(part.mesh))} scale="{s}"/></geometry></visual>'
    files = sorted(part.collision.glob("*.obj")) if part.collision is not None else [part.mesh]
    for f in files:
        xml += f'<collision>{o}<geometry><mesh filename={quoteattr(str(f))} scale="{s}"/></geometry></collision>'
    return xml


def _rpy(R: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (R = Rz(y) Ry(p) Rx(r))."""
    pitch = math.asin(-max(-1.0, min(1.0, R[2, 0])))
    if abs(math.cos(pitch)) > 1e-9:
        roll = math.atan2(R[2, 1], R[2, 2])
        yaw = math.atan2(R[1, 0], R[0, 0])
    else:
        roll, yaw = math.atan2(-R[1, 2], R[1, 1]), 0.0
    return np.array([roll, pitch, yaw])


def _object_mass(o: ObjectConfig, mesh: trimesh.Trimesh) -> float:
    if o.mass is not None:
        return float(o.mass)
    vol = mesh.volume * o.placement.scale**3 if mesh.is_volume else float(np.prod(mesh.extents)) * 0.5
    return float(o.density) * vol


def object_urdf(o: ObjectConfig) -> str:
    """A one-link URDF of a free object in its (scaled) object frame."""
    mesh = load_mesh(o.part.mesh)
    s = o.placement.scale
    body = _inertial_xml(mesh, _object_mass(o, mesh), s) + _geoms_xml(o.part, s)
    return f'<robot name="{o.name}"><link name="{o.name}">{body}</link></robot>'


def button_urdf(a: ArticulatedConfig) -> str:
    """A fixed base link and a cap link on a prismatic joint along the press axis (q >= 0 pressed, up to
    ``travel``); the spring is set after the build (URDF has none)."""
    s = a.placement.scale
    base_mesh, cap_mesh = load_mesh(a.base.mesh), load_mesh(a.cap.mesh)
    T = np.asarray(a.T_base_cap, dtype=np.float64).copy()
    T[:3, 3] *= s
    rpy = _rpy(T[:3, :3])
    axis_cap = T[:3, :3].T @ (np.asarray(a.axis, dtype=np.float64) / np.linalg.norm(a.axis))  # in the cap frame
    base_mass = max(0.1, float(base_mesh.volume * s**3 * 600.0) if base_mesh.is_volume else 0.2)
    travel = a.travel * s
    return (
        f'<robot name="{a.name}">'
        f'<link name="{a.name}_base">{_inertial_xml(base_mesh, base_mass, s)}{_geoms_xml(a.base, s)}</link>'
        f'<link name="{a.name}_cap">{_inertial_xml(cap_mesh, a.cap_mass, s)}{_geoms_xml(a.cap, s)}</link>'
        f'<joint name="{a.name}_press" type="prismatic"><parent link="{a.name}_base"/><child link="{a.name}_cap"/>'
        f'<origin xyz="{T[0, 3]:.9g} {T[1, 3]:.9g} {T[2, 3]:.9g}" rpy="{rpy[0]:.9g} {rpy[1]:.9g} {rpy[2]:.9g}"/>'
        f'<axis xyz="{axis_cap[0]:.9g} {axis_cap[1]:.9g} {axis_cap[2]:.9g}"/>'
        f'<limit lower="0" upper="{travel:.9g}" effort="100" velocity="1"/><dynamics damping="2.0"/></joint>'
        "</robot>"
    )


@dataclass
class _Body:
    name: str
    entity: object
    kind: str  # "object" or "press_button"
    cfg: ObjectConfig | ArticulatedConfig
    footprint_radius: float  # xy radius of the placed collision parts around their xy centre
    centre_obj: np.ndarray  # [3] xy centre of the collision parts (body frame), z of the body origin


class Twin:
    """A built Genesis scene of a world. Use :meth:`build`; close with :meth:`close` (or a ``with`` block)."""

    def __init__(self) -> None:  # use Twin.build
        self.cfg: WorldConfig
        self.spec: RobotSpec  # the world's robot
        self.options: TwinOptions
        self.scene = None
        self.robot = None
        self.bodies: dict[str, _Body] = {}
        self.cameras: dict[str, object] = {}
        self.reset_info: dict = {}
        self.command: np.ndarray  # [n_arm + 1] the last control command: arm joint targets, gripper target

    # ---- construction ----------------------------------------------------------------------------
    @classmethod
    def build(cls, cfg: WorldConfig, options: TwinOptions | None = None) -> Twin:
        """Validate ``cfg`` (clear errors before Genesis starts), then build the Genesis scene."""
        validate_world(cfg)
        self = cls()
        self.cfg, self.options = cfg, options or TwinOptions()
        self.spec = spec = cfg.robot.spec
        opt = self.options
        gs = ensure_genesis(opt.backend)
        workdir = Path(opt.workdir) if opt.workdir else Path(tempfile.mkdtemp(prefix="m2m_twin_"))
        workdir.mkdir(parents=True, exist_ok=True)
        self._workdir = workdir

        look = _twin_look(cfg)
        self.scene = new_scene(look, dt=opt.dt, substeps=opt.substeps)
        draw = opt.draw_scene or not opt.render
        draw_objects = draw or opt.draw_objects
        self.plane = add_ground_plane(self.scene, cfg.table_z, visible=draw)
        mounts = tuple({c.mount for c in cfg.cameras.values() if c.mount != "base"})
        robot_file = str(resolve_model(cfg.robot.file, cfg.root))
        self.robot = add_robot(self.scene, spec, model=robot_file, ee_link=cfg.robot.ee_link, extra_links=mounts)

        for o in cfg.objects:
            path = workdir / f"{o.name}.urdf"
            path.write_text(object_urdf(o))
            pos, quat = pos_quat(_rigid_part(o.placement.matrix, o.placement.scale))
            ent = self.scene.add_entity(
                gs.morphs.URDF(
                    file=str(path), pos=tuple(pos), quat=tuple(quat), fixed=False, align=False,
                    convexify=True, decompose_object_error_threshold=float("inf"), visualization=draw_objects,
                ),
                material=gs.materials.Rigid(friction=o.friction),
            )  # fmt: skip
            self.bodies[o.name] = _Body(o.name, ent, "object", o, *self._footprint(o))
        for a in cfg.articulated:
            path = workdir / f"{a.name}.urdf"
            path.write_text(button_urdf(a))
            pos, quat = pos_quat(_rigid_part(a.placement.matrix, a.placement.scale))
            ent = self.scene.add_entity(
                gs.morphs.URDF(
                    file=str(path), pos=tuple(pos), quat=tuple(quat), fixed=True,
                    merge_fixed_links=False, convexify=True, decompose_robot_error_threshold=float("inf"),
                    visualization=draw_objects,
                ),
                material=gs.materials.Rigid(friction=a.friction),
            )  # fmt: skip
            self.bodies[a.name] = _Body(a.name, ent, a.kind, a, *self._footprint(a))

        if opt.render:
            for name, cam in cfg.cameras.items():
                w, h = opt.camera_sizes.get(name, (cam.width, cam.height))
                fy = cam.K[1, 1] * h / cam.height
                self.cameras[name] = add_camera(self.scene, w, h, fy, look.near, look.far)
        self.scene.build()

        robot = self.robot
        n_arm, n_fingers = spec.n_arm, len(spec.gripper_joints)
        dofs = [robot.get_joint(j).dofs_idx_local for j in (*spec.arm_joints, *spec.gripper_joints)]
        if robot.n_dofs != spec.n_dofs or [d for ds in dofs for d in ds] != list(range(spec.n_dofs)):
            raise ValueError(
                f"{robot_file}: Genesis loads {robot.n_dofs} dofs in another order than robot {spec.name!r}'s "
                f"{n_arm}-dof arm then {n_fingers} fingers ({[*spec.arm_joints, *spec.gripper_joints]})"
            )
        self.ee_link = robot.get_link(cfg.robot.ee_link)
        self.arm_dofs = np.arange(n_arm)
        self.finger_dofs = np.arange(n_arm, spec.n_dofs)
        kp, kv, force = (np.asarray(v, dtype=np.float64) for v in (spec.kp, spec.kv, spec.force_limit))
        robot.set_dofs_kp(kp[: robot.n_dofs])
        robot.set_dofs_kv(kv[: robot.n_dofs])
        robot.set_dofs_force_range(-force[: robot.n_dofs], force[: robot.n_dofs])
        lo, hi = (np.asarray(v, dtype=np.float64) for v in robot.get_dofs_limit())
        model = spec.limits_array()  # a joint the model leaves unlimited: the spec's finite range (planning bounds)
        self.joint_limits = (np.where(np.isfinite(lo), lo, model[:, 0]), np.where(np.isfinite(hi), hi, model[:, 1]))
        for b in self.bodies.values():
            if b.kind == "press_button":
                b.entity.set_dofs_stiffness(np.array([b.cfg.stiffness]))
        self._geom_owner = self._geom_owners()
        self._finger_owners = {f"robot:{link}" for link in spec.finger_links}
        self.home = np.concatenate([np.asarray(cfg.robot.home, dtype=np.float64), [spec.gripper_open] * n_fingers])
        self._initial = {name: self._body_pose(b) for name, b in self.bodies.items()}
        self.reset(seed=0, randomize=False)
        return self

    def _footprint(self, item: ObjectConfig | ArticulatedConfig) -> tuple[float, np.ndarray]:
        parts = []
        pieces = [(item.part, np.eye(4))] if isinstance(item, ObjectConfig) else [(item.base, np.eye(4))]
        for part, T in pieces:
            for m in load_collision_parts(part):
                parts.append(m.vertices @ T[:3, :3].T + T[:3, 3])
        V = np.concatenate(parts) * item.placement.scale
        lo, hi = V.min(axis=0), V.max(axis=0)
        c = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0])
        r = float(np.linalg.norm(V[:, :2] - c[:2], axis=1).max())
        return r, c

    def _geom_owners(self) -> np.ndarray:
        """Per global geom index: a label (entity name; robot links as 'robot:<link>'; the plane 'table')."""
        owners = np.empty(self.scene.rigid_solver.n_geoms, dtype=object)
        for g in self.plane.geoms:
            owners[g.idx] = "table"
        for g in self.robot.geoms:
            owners[g.idx] = f"robot:{g.link.name}"
        for b in self.bodies.values():
            for g in b.entity.geoms:
                owners[g.idx] = b.name if not g.link.name.endswith("_cap") else f"{b.name}:cap"
        return owners

    def close(self) -> None:
        """Free the Genesis scene."""
        if self.scene is not None:
            self.scene.destroy()
            self.scene = None

    def __enter__(self) -> Twin:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- state -----------------------------------------------------------------------------------
    @property
    def dt(self) -> float:
        return self.options.dt

    def robot_state(self) -> np.ndarray:
        """[n_dofs] joint positions: the arm joints (rad) then the finger joints."""
        return np.asarray(self.robot.get_qpos(), dtype=np.float64)[: self.spec.n_dofs].copy()

    def set_robot_state(self, q: np.ndarray) -> None:
        """Teleport the robot to ``q`` [n_dofs] (zero velocity) and hold it there (the control command too)."""
        q = np.asarray(q, dtype=np.float64)
        self.robot.set_qpos(q, zero_velocity=True)
        self.robot.control_dofs_position(q)
        self.command = np.concatenate([q[: self.spec.n_arm], q[self.spec.n_arm : self.spec.n_arm + 1]])

    def _body_pose(self, b: _Body) -> np.ndarray:
        return pose_from(b.entity.get_pos(), b.entity.get_quat())

    def object_poses(self) -> dict[str, np.ndarray]:
        """{name: T_base_obj [4,4] float64} of every body (physics poses); a press button adds
        ``"<name>/cap"`` (the cap's object frame). Gaussians at a pose: see ``world.config``."""
        out = {}
        for name, b in self.bodies.items():
            out[name] = self._body_pose(b)
            if b.kind == "press_button":
                cap = b.entity.links[1]
                out[f"{name}/cap"] = pose_from(cap.get_pos(), cap.get_quat())
        return out

    def object_speed(self, name: str) -> tuple[float, float]:
        """(linear m/s, angular rad/s) speed of body ``name``."""
        e = self.bodies[name].entity
        return float(np.linalg.norm(np.asarray(e.get_vel()))), float(np.linalg.norm(np.asarray(e.get_ang())))

    def button_travel(self, name: str) -> float:
        """How far (m, along the press axis) the button's cap is pressed in."""
        b = self.bodies[name]
        if b.kind != "press_button":
            raise ValueError(f"{name!r} is not a press button")
        return float(np.asarray(b.entity.get_qpos()).reshape(-1)[0])

    def T_base_link(self, link: str | None = None) -> np.ndarray:
        """[4,4] pose of a robot link (default: the end-effector link)."""
        lk = self.ee_link if link is None else self.robot.get_link(link)
        return pose_from(lk.get_pos(), lk.get_quat())

    # ---- reset -----------------------------------------------------------------------------------
    def sample_poses(
        self,
        rng: np.random.Generator,
        max_tries: int = 500,
        regions: dict[str, list[tuple[float, float, float, float]]] | None = None,
    ) -> dict[str, np.ndarray]:
        """Random start poses in the configured region (yaw about z, footprints apart by ``min_gap``).
        ``regions``: {name: [(x_min, x_max, y_min, y_max), ...]}: whole layouts are redrawn until each named
        object's centre lies in one of its boxes (so the others keep their usual spread around it)."""
        r = self.cfg.randomize
        names = [n for n, b in self.bodies.items() if b.kind == "object" or r.articulated]
        regions = regions or {}
        unknown = sorted(set(regions) - set(names))
        if unknown:
            raise ValueError(f"start regions for {unknown}: not objects placed at reset ({names})")
        if regions:  # a box a few % of the region needs ~1/fraction redraws
            max_tries = max(max_tries, 20000)
        for _ in range(max_tries):
            placed: list[tuple[np.ndarray, float]] = []
            poses = {}
            ok = True
            for name in names:
                b = self.bodies[name]
                T0 = self._initial[name]
                x, y = rng.uniform(*r.x), rng.uniform(*r.y)
                yaw = math.radians(rng.uniform(*r.yaw_deg)) if b.kind == "object" else 0.0
                c = np.array([x, y])
                if name in regions and not any(a <= x <= b_ and lo <= y <= hi for a, b_, lo, hi in regions[name]):
                    ok = False
                    break
                if any(np.linalg.norm(c - pc) < b.footprint_radius + pr + r.min_gap for pc, pr in placed):
                    ok = False
                    break
                Rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1.0]])
                R = Rz @ T0[:3, :3]
                centre_world = R @ b.centre_obj  # body-frame centre rotated into the base frame
                t = np.array([x - centre_world[0], y - centre_world[1], T0[2, 3]])
                poses[name] = _rigid(R, t)
                placed.append((c, b.footprint_radius))
            if ok:
                return poses
        where = f" with {regions} inside their start regions" if regions else ""
        raise RuntimeError(f"no non-overlapping placement of {names}{where} in the randomize region after "
                           f"{max_tries} tries")  # fmt: skip

    def reset(
        self,
        seed: int = 0,
        randomize: bool = True,
        regions: dict[str, list[tuple[float, float, float, float]]] | None = None,
    ) -> dict[str, np.ndarray]:
        """Robot home, gripper open, button released; objects at the world's placements, or (``randomize``)
        at random poses drawn from ``seed`` (``regions``: see :meth:`sample_poses`). Lets the objects settle;
        returns and records the start poses."""
        poses = self.sample_poses(np.random.default_rng(seed), regions=regions) if randomize else dict(self._initial)
        self.scene.reset()
        self.set_robot_state(self.home)
        for name, b in self.bodies.items():
            T = poses.get(name, self._initial[name])
            if b.kind == "object":
                b.entity.set_pos(T[:3, 3], zero_velocity=True)
                b.entity.set_quat(matrix_to_quat(T[:3, :3]), zero_velocity=True)
            else:
                b.entity.set_pos(T[:3, 3])
                b.entity.set_quat(matrix_to_quat(T[:3, :3]))
                b.entity.set_qpos(np.zeros(1))
        self.settle()
        self.reset_info = {"seed": int(seed), "randomized": bool(randomize), "poses": self.object_poses()}
        return self.reset_info["poses"]

    # ---- physics ---------------------------------------------------------------------------------
    def settle(self, max_s: float = 2.0, lin: float = 0.005, ang: float = 0.05) -> float:
        """Step (robot holding still) until every free object rests (speed < ``lin`` m/s and ``ang`` rad/s),
        at least ``options.settle_s`` and at most ``max_s`` seconds; a curved object placed upright may roll
        onto its side first. Returns the simulated time."""
        n_min = round(self.options.settle_s / self.dt)
        free = [b.entity for b in self.bodies.values() if b.kind == "object"]
        q = self.robot_state()
        n = 0
        while n < round(max_s / self.dt):
            self.step(q[: self.spec.n_arm], q[self.spec.n_arm])
            n += 1
            if n >= n_min and n % 5 == 0:
                v = max((float(np.linalg.norm(np.asarray(e.get_vel()))) for e in free), default=0.0)
                w = max((float(np.linalg.norm(np.asarray(e.get_ang()))) for e in free), default=0.0)
                if v < lin and w < ang:
                    break
        return n * self.dt

    # ---- control ---------------------------------------------------------------------------------
    @property
    def action_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) [n_arm + 1] of an action: the arm's joint limits (from the model), the gripper's range."""
        n_arm, spec = self.spec.n_arm, self.spec
        lo, hi = self.joint_limits
        g = sorted((spec.gripper_open, spec.gripper_closed))
        return np.append(lo[:n_arm], g[0]), np.append(hi[:n_arm], g[1])

    def gripper_closed(self, g: float) -> bool:
        """Whether gripper command ``g`` (m per finger) means "closed" (within :data:`CLOSED_MARGIN`)."""
        spec = self.spec
        span = spec.gripper_open - spec.gripper_closed  # signed: which way is open
        return (g - spec.gripper_closed) / span <= CLOSED_MARGIN

    def act(self, action: np.ndarray, substeps: int) -> None:
        """One control tick of ``substeps`` physics steps from ``action`` [n_arm + 1] (arm joint targets in rad,
        gripper target in m per finger; clipped to :attr:`action_limits`).

        The command moves linearly from the previous tick's (:attr:`command`) to ``action`` over the tick, the
        arm and gripper alike; the arm and the fingers track it under PD position control, except that once the
        gripper command has reached "closed" (:meth:`gripper_closed`) fingers stopped on something squeeze it
        with the spec's grasp force. So a gripper closes under position control (a finger driven by force alone
        crosses a 4 cm gap within a physics step and tunnels through thin objects) and then squeezes what it
        closed on; shut on nothing, it rests at closed."""
        n_arm, spec = self.spec.n_arm, self.spec
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (n_arm + 1,):
            raise ValueError(f"an action has {n_arm + 1} values (arm joints + gripper), got shape {a.shape}")
        a = np.clip(a, *self.action_limits)
        prev = self.command
        self._forget_warm_starts()
        for i in range(1, int(substeps) + 1):
            c = prev + (i / substeps) * (a - prev)
            if self.gripper_closed(c[n_arm]) and self._fingers_stopped_on_something():
                self.step(c[:n_arm], finger_force=spec.grasp_force)
            else:
                self.step(c[:n_arm], c[n_arm])
        self.command = a

    def _forget_warm_starts(self) -> None:
        """Drop what the physics carries between steps besides the state: the constraint solver's warm start and
        the collider's contact cache. Planning queries between ticks (``set_qpos``, collision checks) drop or
        change them; dropped at every tick's start, a tick depends on the state alone, so a recorded episode's
        actions replayed from its reset give back its states exactly (measured on every task: 0 rad, 0 m)."""
        solver = self.scene.rigid_solver
        solver.constraint_solver.reset()
        solver.collider.reset()
        # Planning's restore (``restoring``) recomputes the robot's link kinematics in another order than a
        # physics step does (1e-14 apart, which contacts amplify to centimetres): the same restore here at every
        # tick, so a tick sees the same numbers with or without planning before it.
        with self.restoring():
            pass

    def _fingers_stopped_on_something(self) -> bool:
        """Whether the fingers rest open (by more than half :data:`CLOSED_MARGIN`) and are not closing (slower than
        :data:`STOPPED_SPEED`): held apart by an object. Only then does a closed gripper squeeze: driven by force,
        fingers still closing slam shut (1.8 cm in one 10 ms step, measured) and empty ones are pushed through
        their soft joint limit (to -6 mm); position control brings those to closed."""
        spec = self.spec
        span = spec.gripper_open - spec.gripper_closed  # signed: which way is open
        q = float(np.mean(np.asarray(self.robot.get_dofs_position(self.finger_dofs), dtype=np.float64)))
        v = float(np.mean(np.asarray(self.robot.get_dofs_velocity(self.finger_dofs), dtype=np.float64)))
        opening = (q - spec.gripper_closed) / span  # fraction of the range
        closing_speed = -v * np.sign(span)
        return opening > 0.5 * CLOSED_MARGIN and closing_speed < STOPPED_SPEED

    def step(self, q_target: np.ndarray, finger: float | None = None, finger_force: float | None = None) -> None:
        """One physics step with the arm's PD target ``q_target`` [n_arm]; fingers to position ``finger`` (m per
        finger), or squeezed with ``finger_force`` (N per finger, closing) when given."""
        robot = self.robot
        if finger_force is not None:
            # A spring on the fingers' difference (RobotSpec.finger_coupling) stands in for the real gearing.
            f = abs(float(finger_force))
            ql, qr = np.asarray(robot.get_dofs_position(self.finger_dofs), dtype=np.float64)
            e = self.spec.finger_coupling * (ql - qr)
            forces = -np.clip([f + e, f - e], 0.0, 2.0 * f)
            robot.control_dofs_position(np.asarray(q_target, dtype=np.float64), self.arm_dofs)
            robot.control_dofs_force(forces, self.finger_dofs)
        else:
            q = np.concatenate([np.asarray(q_target, dtype=np.float64), [finger] * len(self.finger_dofs)])
            robot.control_dofs_position(q)
        self.scene.step()

    # ---- collision queries (planning) ------------------------------------------------------------
    @contextmanager
    def restoring(self) -> Iterator[None]:
        """Restore the robot's joint positions and velocities on exit (around kinematic queries)."""
        q = self.robot.get_qpos()
        v = self.robot.get_dofs_velocity()
        try:
            yield
        finally:
            self.robot.set_qpos(q, zero_velocity=False)
            self.robot.set_dofs_velocity(v)

    def colliding_pairs(self, q: np.ndarray) -> list[tuple[str, str]]:
        """Set the robot to ``q`` [n_dofs] (no physics) and list the colliding geometry owners (robot vs anything).

        The fingers touching each other are not a collision: closed on nothing, that is where they are. (Genesis drops
        geometry pairs that overlap at the model's zero pose, which took the Panda's finger pair out but not the
        UR5e + Franka hand's, whose zero pose holds the hand sideways: there closed fingers "collided", and a plan
        from a closed gripper was refused.)

        Leaves the robot at ``q``: wrap queries in :meth:`restoring`.
        """
        self.robot.set_qpos(np.asarray(q, dtype=np.float64), zero_velocity=True)
        pairs = self.robot.detect_collision()
        out = [(self._geom_owner[i], self._geom_owner[j]) for i, j in np.asarray(pairs).reshape(-1, 2)]
        return [p for p in out if not (p[0] in self._finger_owners and p[1] in self._finger_owners)]

    # ---- cameras ---------------------------------------------------------------------------------
    def camera(self, name: str) -> tuple[np.ndarray, np.ndarray, int, int]:
        """(T_base_cam [4,4] OpenCV axes, K [3,3], width, height) of camera ``name`` in the current state.

        Size and K are the twin's rendering ones (``TwinOptions.camera_sizes``, default the world's): with
        another size than the world's, K keeps the vertical field of view, square pixels and a centred
        principal point, exactly as Genesis renders it (and as the Gaussians must be rendered to match)."""
        if name not in self.cfg.cameras:
            raise KeyError(f"no camera {name!r}; cameras: {sorted(self.cfg.cameras)}")
        c = self.cfg.cameras[name]
        T_mount = np.eye(4) if c.mount == "base" else self.T_base_link(c.mount)
        w, h = self.options.camera_sizes.get(name, (c.width, c.height))
        K = np.asarray(c.K, dtype=np.float64).copy()
        if (w, h) != (c.width, c.height):
            K = render_K(K, c.width, c.height, w, h)
        return T_mount @ c.T_mount_cam, K, int(w), int(h)

    def render_robot(self, name: str, width: int | None = None, height: int | None = None) -> dict[str, np.ndarray]:
        """Genesis render from camera ``name``: {"rgb" uint8 [H,W,3], "depth" float32 [H,W] (planar, metres,
        inf where nothing), "robot_mask" bool [H,W]} at the size the twin's camera was built with."""
        if name not in self.cameras:
            raise KeyError(f"no rendering camera {name!r}; build the twin with TwinOptions(render=True)")
        cam = self.cameras[name]
        w, h = cam.res
        if (width is not None and width != w) or (height is not None and height != h):
            raise ValueError(
                f"camera {name!r} renders {w}x{h}; build the twin with TwinOptions(camera_sizes={{{name!r}: "
                f"({width}, {height})}}) for another size"
            )
        T_base_cam, *_ = self.camera(name)
        draw_scene = self.options.draw_scene
        rgb, depth, seg, _ = render_view(cam, T_base_cam, rgb=True, depth=True, segmentation=draw_scene)
        depth = np.array(depth, dtype=np.float32, copy=True)
        depth[depth >= 10.0] = np.inf
        if draw_scene:
            robot_ids = [k for k, v in self.scene.segmentation_idx_dict.items() if v == self.robot.idx]
            mask = np.isin(np.asarray(seg), robot_ids)
        else:
            mask = np.isfinite(depth)  # the robot is all the cameras draw
        return {"rgb": np.array(rgb, dtype=np.uint8, copy=True), "depth": depth, "robot_mask": mask}
