"""What the scripted tasks share: the executor that runs joint targets through the physics and records the
control ticks, the target's geometry, and the motions (planned joint moves, straight-line hand moves).

Numbers that belong to the robot (TCP offset, gripper opening, grasp force, limits) come from ``twin.spec``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh

from ...world.validate import load_mesh
from ..planning import cartesian_path, plan, time_parameterize
from ..twin import Twin

__all__ = ["Executor", "StepRecord", "line", "move_to", "placed", "placed_com", "surface_points", "topdown"]


@dataclass
class StepRecord:
    """One control tick: time (s), state [n_dofs] (arm joints, fingers), action [n_arm + 1] (arm targets,
    finger target), object poses {name: T_base_obj [4,4]}."""

    t: float
    state: np.ndarray
    action: np.ndarray
    object_poses: dict[str, np.ndarray]


class Executor:
    """Runs joint targets through the physics, recording at the control rate."""

    def __init__(self, twin: Twin, on_step: Callable[[StepRecord], None] | None, control_hz: float) -> None:
        self.twin = twin
        self.spec = twin.spec
        self.on_step = on_step
        self.spc = max(1, round(1.0 / (control_hz * twin.dt)))
        self.n = 0
        self.steps: list[StepRecord] = []
        self.q_cmd = twin.robot_state()[: self.spec.n_arm]
        self.finger = self.spec.gripper_open
        self.watch: Callable[[], None] | None = None

    def q_now(self) -> np.ndarray:
        """[n_dofs] the commanded arm joints with the fingers where they are."""
        return np.concatenate([self.q_cmd, self.twin.robot_state()[self.spec.n_arm :]])

    def follow(
        self,
        targets: np.ndarray,
        finger: float | np.ndarray,
        force: float | None = None,
        stop: Callable[[], bool] | None = None,
        check_every: int = 5,
    ) -> bool:
        """Step through arm targets [T,n_arm] with finger targets (one value or [T]); True if ``stop`` fired."""
        tw = self.twin
        fingers = np.broadcast_to(np.asarray(finger, dtype=np.float64), (len(targets),))
        for i, q in enumerate(targets):
            if self.n % self.spc == 0:
                k = min(i + self.spc, len(targets) - 1)
                self._record(targets[k], self.spec.gripper_closed if force is not None else fingers[k])
            self.q_cmd = q
            self.finger = float(fingers[i])
            tw.step(q, self.finger, force)
            self.n += 1
            if self.watch is not None:
                self.watch()
            if stop is not None and i % check_every == 0 and stop():
                return True
        return False

    def hold(self, seconds: float, finger: float, force: float | None = None, stop=None) -> bool:
        n = max(1, round(seconds / self.twin.dt))
        return self.follow(np.repeat(self.q_cmd[None], n, axis=0), finger, force, stop)

    def close(self, seconds: float = 0.4, squeeze_s: float = 0.2) -> None:
        """Close the fingers at ~0.1 m/s under position control (a free finger driven by force alone crosses
        a 4 cm gap within one physics step and tunnels through thin objects), then squeeze with the spec's
        grasp force."""
        n = max(1, round(seconds / self.twin.dt))
        ramp = np.linspace(self.finger, self.spec.gripper_closed, n + 1)[1:]
        self.follow(np.repeat(self.q_cmd[None], n, axis=0), ramp)
        self.hold(squeeze_s, self.spec.gripper_closed, force=self.spec.grasp_force)

    def _record(self, ahead: np.ndarray, finger_target: float) -> None:
        rec = StepRecord(
            t=self.n * self.twin.dt,
            state=self.twin.robot_state().astype(np.float32),
            action=np.concatenate([ahead, [finger_target]]).astype(np.float32),
            object_poses=self.twin.object_poses(),
        )
        self.steps.append(rec)
        if self.on_step is not None:
            self.on_step(rec)


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


def topdown(tcp: np.ndarray, closing_axis: np.ndarray, tcp_offset: float) -> np.ndarray:
    """T_base_ee with the approach (ee z) straight down, the TCP (``tcp_offset`` along the approach axis) at
    ``tcp`` and the fingers closing along ``closing_axis`` (xy)."""
    y = np.array([closing_axis[0], closing_axis[1], 0.0])
    y /= np.linalg.norm(y)
    z = np.array([0.0, 0.0, -1.0])
    x = np.cross(y, z)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = tcp - tcp_offset * z
    return T


# ---- motions -----------------------------------------------------------------------------------------
def move_to(
    ex: Executor, q_goal: np.ndarray, finger: float, allow=(), speed: float = 0.8, timeout: float = 3.0
) -> None:
    """A planned, collision-free joint move to ``q_goal`` [n_arm or n_dofs]."""
    tw = ex.twin
    path = plan(tw, ex.q_now(), q_goal, timeout=timeout, allow=allow)
    ex.follow(time_parameterize(path, tw.dt, speed, robot=tw.spec), finger)


def line(ex: Executor, T_from, T_to, finger, seconds, force=None, stop=None, allow=()) -> bool:
    """The end-effector along the straight line ``T_from`` -> ``T_to`` in ``seconds``; True if ``stop`` fired."""
    tw = ex.twin
    path = cartesian_path(tw, T_from, T_to, ex.q_now(), check_collision=False)
    targets = time_parameterize(path, tw.dt, through=True, duration=seconds, robot=tw.spec)
    return ex.follow(targets, finger, force, stop)
