"""What the scripted tasks share: the executor that turns their motions into control ticks, the target's
geometry, and the motions (planned joint moves, straight-line hand moves).

The control tick is the unit: a motion planned as dense joint targets (one per physics step) is sampled at the
tick ends, and every tick is one action [n_arm + 1] (arm joint targets, gripper target) executed by
:meth:`Twin.act <mirage2matter.sim.twin.Twin.act>` - the function a policy in the Gymnasium environment acts
through too - and recorded with the state at the tick's start, so recorded action t leads to state t + 1.

Numbers that belong to the robot (TCP offset, gripper opening, grasp force, limits) come from ``twin.spec``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import trimesh

from ...world.validate import load_mesh
from ..planning import cartesian_path, collision_free, plan, time_parameterize
from ..twin import Twin

__all__ = [
    "Executor", "StepRecord", "clear_start", "line", "move_to", "placed", "placed_com", "steps_per_tick",
    "surface_points", "tcp_pose", "tick_ends", "topdown",
]  # fmt: skip


@dataclass
class StepRecord:
    """One control tick.

    t             time (s) at the tick's start
    state         [n_dofs] float32 joint positions at the tick's start (arm joints, fingers)
    action        [n_arm + 1] float32 the tick's action (arm joint targets, gripper target), executed as recorded
    object_poses  {name: T_base_obj [4,4]} at the tick's start
    """

    t: float
    state: np.ndarray
    action: np.ndarray
    object_poses: dict[str, np.ndarray]


class TickMonitor(Protocol):
    """What the executor updates after every tick (a task's ``SuccessMonitor``)."""

    def update(self, twin: Twin) -> bool: ...


def steps_per_tick(twin: Twin, control_hz: float) -> int:
    """Physics steps per control tick at ``control_hz``."""
    return max(1, round(1.0 / (control_hz * twin.dt)))


def tick_ends(n_steps: int, substeps: int) -> np.ndarray:
    """Indices into ``n_steps`` dense (per physics step) targets where each control tick of ``substeps`` steps
    ends; a last, shorter piece ends at the final target."""
    ends = np.arange(substeps - 1, n_steps, substeps)
    if n_steps and (not len(ends) or ends[-1] != n_steps - 1):
        ends = np.append(ends, n_steps - 1)
    return ends


class Executor:
    """Runs a scripted task tick by tick: each action is recorded, then executed by ``act`` (default
    ``twin.act(action, substeps)``; generation passes the environment's ``step``, which ends in the same call),
    then the task's success monitor is updated. ``rng`` draws the task's own random choices (the episode's
    task seed in generation)."""

    def __init__(
        self,
        twin: Twin,
        on_step: Callable[[StepRecord], None] | None,
        control_hz: float,
        monitor: TickMonitor | None = None,
        act: Callable[[np.ndarray], object] | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.twin = twin
        self.rng = rng if rng is not None else np.random.default_rng(0)  # the task's own random choices
        self.spec = twin.spec
        self.on_step = on_step
        self.spc = steps_per_tick(twin, control_hz)  # physics steps per tick
        self.tick_s = self.spc * twin.dt
        self.monitor = monitor
        self._act = act if act is not None else (lambda a: twin.act(a, self.spc))
        self.n = 0  # physics steps run
        self.steps: list[StepRecord] = []

    @property
    def command(self) -> np.ndarray:
        """[n_arm + 1] the last tick's action (the twin's control command)."""
        return self.twin.command

    def q_now(self) -> np.ndarray:
        """[n_dofs] the commanded arm joints with the fingers where they are (within their joint limits: fingers
        squeezed shut press past them a little, and the planner refuses a start outside them)."""
        n_arm, (lo, hi) = self.spec.n_arm, self.twin.joint_limits
        fingers = np.clip(self.twin.robot_state()[n_arm:], lo[n_arm : self.spec.n_dofs], hi[n_arm : self.spec.n_dofs])
        return np.concatenate([self.command[:n_arm], fingers])

    def tick(self, action: np.ndarray) -> None:
        """One control tick: record (state now, action), execute the action, update the success monitor."""
        tw = self.twin
        a = np.asarray(action, dtype=np.float32).reshape(-1)  # as a dataset stores it, so a replay is exact
        rec = StepRecord(t=self.n * tw.dt, state=tw.robot_state().astype(np.float32), action=a.copy(),
                         object_poses=tw.object_poses())  # fmt: skip
        self.steps.append(rec)
        if self.on_step is not None:
            self.on_step(rec)
        self._act(a)
        self.n += self.spc
        if self.monitor is not None:
            self.monitor.update(tw)

    def follow(self, targets: np.ndarray, finger: float | np.ndarray, stop: Callable[[], bool] | None = None) -> bool:
        """Dense arm targets [T,n_arm] (one per physics step) with gripper targets (one value or [T]), as ticks
        towards the targets at the tick ends; True if ``stop`` (checked after every tick) fired."""
        targets = np.asarray(targets, dtype=np.float64)
        fingers = np.broadcast_to(np.asarray(finger, dtype=np.float64), (len(targets),))
        for k in tick_ends(len(targets), self.spc):
            self.tick(np.append(targets[k], fingers[k]))
            if stop is not None and stop():
                return True
        return False

    def hold(self, seconds: float, finger: float, stop: Callable[[], bool] | None = None) -> bool:
        """Keep the arm's command for ``seconds`` (at least one tick) with the gripper at ``finger``."""
        n = max(1, round(seconds / self.tick_s))
        arm = self.command[: self.spec.n_arm]
        for _ in range(n):
            self.tick(np.append(arm, finger))
            if stop is not None and stop():
                return True
        return False

    def close(self, seconds: float = 0.4, squeeze_s: float = 0.2) -> None:
        """Close the gripper at ~0.1 m/s (its command ramps to closed over ``seconds``: position control until
        the last moment, see ``Twin.act``), then squeeze with the spec's grasp force for ``squeeze_s``."""
        n = max(1, round(seconds / self.tick_s))
        arm = self.command[: self.spec.n_arm]
        for g in np.linspace(self.command[-1], self.spec.gripper_closed, n + 1)[1:]:
            self.tick(np.append(arm, g))
        self.hold(squeeze_s, self.spec.gripper_closed)


# ---- geometry of the target ---------------------------------------------------------------------
def surface_points(twin: Twin, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(points [N,3] on the object's mesh surface, centre of mass [3]) in its body frame (placement-scaled);
    for a press button, its cap's. Cached on the twin."""
    cache = twin.__dict__.setdefault("_surface_cache", {})
    if name not in cache:
        b = twin.bodies[name]
        mesh = load_mesh(b.cfg.part.mesh if b.kind == "object" else b.cfg.cap.mesh)
        s = b.cfg.placement.scale
        pts, _ = trimesh.sample.sample_surface(mesh, 3000, seed=0)
        com = mesh.center_mass if mesh.is_volume else mesh.bounds.mean(axis=0)
        cache[name] = (np.asarray(pts) * s, np.asarray(com) * s)
    return cache[name]


def placed(twin: Twin, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(surface points [N,3], centre of mass [3]) of body ``name`` at its current pose (base frame)."""
    pts, com = surface_points(twin, name)
    T = twin.object_poses()[name]
    return pts @ T[:3, :3].T + T[:3, 3], T[:3, :3] @ com + T[:3, 3]


def placed_com(twin: Twin, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(T_base_obj [4,4], centre of mass [3] in the base frame) of body ``name`` now."""
    T = twin.object_poses()[name]
    _, com = surface_points(twin, name)
    return T, T[:3, :3] @ com + T[:3, 3]


def topdown(tcp: np.ndarray, closing_axis: np.ndarray, T_ee_tcp: np.ndarray) -> np.ndarray:
    """T_base_ee [4,4] with the tool pointing straight down, its centre at ``tcp`` [3] and the fingers closing along
    ``closing_axis`` [2] (xy); ``T_ee_tcp`` [4,4] is the tool frame in the ee link (``RobotSpec.T_ee_tcp``: z the
    approach, y the closing axis)."""
    y = np.array([closing_axis[0], closing_axis[1], 0.0])
    y /= np.linalg.norm(y)
    z = np.array([0.0, 0.0, -1.0])
    x = np.cross(y, z)
    T_base_tcp = np.eye(4)
    T_base_tcp[:3, :3] = np.stack([x, y, z], axis=1)
    T_base_tcp[:3, 3] = tcp
    R, t = T_ee_tcp[:3, :3], T_ee_tcp[:3, 3]
    T_tcp_ee = np.eye(4)
    T_tcp_ee[:3, :3] = R.T
    T_tcp_ee[:3, 3] = -R.T @ t
    return T_base_tcp @ T_tcp_ee


def tcp_pose(twin: Twin) -> np.ndarray:
    """T_base_tcp [4,4]: the tool frame now (the ee link's pose times the spec's ``T_ee_tcp``)."""
    return twin.T_base_link() @ twin.spec.T_ee_tcp


# ---- motions -----------------------------------------------------------------------------------------
def move_to(
    ex: Executor, q_goal: np.ndarray, finger: float, allow=(), speed: float = 0.8, timeout: float = 3.0
) -> None:
    """A planned, collision-free joint move to ``q_goal`` [n_arm or n_dofs]."""
    tw = ex.twin
    path = plan(tw, ex.q_now(), q_goal, timeout=timeout, allow=allow)
    ex.follow(time_parameterize(path, tw.dt, speed, robot=tw.spec), finger)


def clear_start(ex: Executor, rise_m: float = 0.06, seconds: float = 0.6) -> bool:
    """From a start the planner refuses - the robot touching something, where a policy can leave it (its fingers on
    the object: ``generate --takeover``) - the hand ``rise_m`` straight up, opening, so every task's plans start
    collision-free. True if it moved; a clear start (every reset) is left alone and costs one collision query."""
    tw = ex.twin
    with tw.restoring():
        touching = not collision_free(tw, tw.robot_state())
    if not touching:
        return False
    T_now = tw.T_base_link()
    T_up = T_now.copy()
    T_up[2, 3] += rise_m
    line(ex, T_now, T_up, ex.spec.gripper_open, seconds)
    return True


def line(ex: Executor, T_from, T_to, finger, seconds, stop=None) -> bool:
    """The end-effector along the straight line ``T_from`` -> ``T_to`` in ``seconds``; True if ``stop`` fired."""
    tw = ex.twin
    path = cartesian_path(tw, T_from, T_to, ex.q_now(), check_collision=False)
    targets = time_parameterize(path, tw.dt, through=True, duration=seconds, robot=tw.spec)
    return ex.follow(targets, finger, stop)
