"""``push <object>`` and ``pull <object>``: slide an object over the table with the closed fingers."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..planning import PlanningError, cartesian_path, ik, time_parameterize
from .base import Task, option, register_task, unit_xy
from .motion import Executor, line, move_to, placed, placed_com, topdown

__all__ = ["PullTask", "PushTask"]

_DIRECTION_HELP = "two numbers 'dx,dy' (base frame), not all zero"


def _direction_words(d: tuple[float, float]) -> str:
    """Base frame seen from the robot: +x away ("forward"), +y left."""
    ang = math.degrees(math.atan2(d[1], d[0])) % 360
    names = ["forward", "forward-left", "left", "back-left", "back", "back-right", "right", "forward-right"]
    return names[int(((ang + 22.5) % 360) // 45)]


@register_task
@dataclass(frozen=True)
class PushTask(Task):
    """**Task:** push ``target`` (a free object) ``distance`` metres along ``direction`` (base xy).

    The policy: the closed fingers lowered just behind the object (on the side opposite the direction), swept
    along it until the object's centre has moved ``distance`` (closed loop on the object's pose: every control
    tick the pusher heads for the goal through the object's current centre), then lifted away; up to two
    corrective sweeps for what rolled or slid aside.

    **Randomizations:** none of its own; the start poses are the twin's reset (``twin.reset(seed)``).

    **Success:** the final displacement of the object's centre of mass is within ``tolerance`` of
    ``distance * direction``.
    """

    verb = "push"
    direction: tuple[float, float] | None = option((1.0, 0.0), _DIRECTION_HELP)
    distance: float = option(0.1, "a number in metres", range=(0.0, 0.5))
    tolerance: float = option(0.02, "a number in metres", range=(0.0, 0.5))

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "direction", unit_xy(self.direction, "direction", _DIRECTION_HELP))

    @property
    def instruction(self) -> str:
        where = _direction_words(self.direction) if self.direction is not None else "towards the robot"
        return f"{self.verb} the {self.target.replace('_', ' ')} {round(100 * self.distance)} cm {where}"

    def run(self, ex: Executor) -> tuple[bool, str, dict[str, Any]]:
        twin, name = ex.twin, self.target
        start_c = placed_com(twin, name)[1][:2].copy()  # displacement counts from the episode's start
        if self.direction is None:  # towards the robot base
            d = -start_c / max(np.linalg.norm(start_c), 1e-9)
        else:
            d = np.asarray(self.direction, dtype=np.float64)
        goal = start_c + self.distance * d
        sweeps = 0
        for attempt in range(3):  # the sweep, then up to two corrective sweeps for what rolled or slid aside
            rem = goal - placed_com(twin, name)[1][:2]
            if attempt > 0 and np.linalg.norm(rem) <= 0.5 * self.tolerance:
                break
            direction = d if attempt == 0 else rem / np.linalg.norm(rem)
            try:
                _sweep(ex, name, goal, direction, speed=0.1 if attempt == 0 else 0.06)
            except PlanningError as e:
                if attempt == 0:
                    return False, f"cannot reach the start of the {self.verb}: {e}", {}
                break
            sweeps += 1
        ex.hold(0.2, ex.spec.gripper_closed)
        c = placed_com(twin, name)[1][:2]
        disp = c - start_c
        err = float(np.linalg.norm(disp - self.distance * d))
        info = {"displacement_m": disp.tolist(), "target_m": (self.distance * d).tolist(), "error_m": err,
                "sweeps": sweeps}  # fmt: skip
        return (*self.success(info), info)

    def success(self, info: dict[str, Any]) -> tuple[bool, str]:
        """Ended within ``tolerance`` of the target displacement."""
        name, err = self.target, info["error_m"]
        if err <= self.tolerance:
            moved = np.linalg.norm(info["displacement_m"])
            return True, f"{name} moved {100 * moved:.1f} cm, {100 * err:.1f} cm from the target"
        return False, f"{name} ended {100 * err:.1f} cm from the target (tolerance {100 * self.tolerance:.1f} cm)"


@register_task
@dataclass(frozen=True)
class PullTask(PushTask):
    """**Task:** pull ``target`` (a free object) ``distance`` metres, by default towards the robot base (the
    fingers reach beyond the object and drag it back); ``direction`` (base xy) pulls it elsewhere.

    The policy, randomizations and success test are :class:`PushTask`'s.
    """

    verb = "pull"
    direction: tuple[float, float] | None = option(None, _DIRECTION_HELP)


def _sweep(ex: Executor, name: str, goal: np.ndarray, d: np.ndarray, speed: float) -> None:
    """Closed fingers lowered just behind the object (opposite ``d``), steered to ``goal``, lifted away, and
    the object left to come to rest."""
    twin, spec = ex.twin, ex.spec
    closed = spec.gripper_closed
    fingers_closed = [closed] * len(spec.gripper_joints)
    points, com = placed(twin, name)
    c0 = com[:2]
    back = float(((points[:, :2] - c0) @ d).min())  # most negative extent along d
    z_top = float(points[:, 2].max())
    start_xy = c0 + d * (back - 0.025)
    z_tcp = twin.cfg.table_z + 0.004 + (spec.tip_offset - spec.tcp_offset)  # fingertips 4 mm over the table
    z_tcp = max(z_tcp, min(z_tcp + 0.01, z_top - 0.01))
    perp = np.array([-d[1], d[0]])
    q_now = ex.q_now()
    error: PlanningError | None = None
    # Fingers closing across the motion make a 5 cm wide pusher; the other hand yaws are fallbacks for spots
    # (close to the base) where that wrist pose is out of reach.
    for axis in (perp, -perp, d, -d):
        T_low = topdown(np.array([*start_xy, z_tcp]), axis, spec.tcp_offset)
        T_pre = T_low.copy()
        T_pre[2, 3] += max(z_top + 0.04, z_tcp + 0.05) - z_tcp  # hand above the object's top
        try:
            q_pre = ik(twin, T_pre, q_now)
            descent = cartesian_path(twin, T_pre, T_low, np.concatenate([q_pre, fingers_closed]), check_collision=False)
            break
        except PlanningError as e:
            error = e
    else:
        raise error
    move_to(ex, np.concatenate([q_pre, fingers_closed]), closed)
    ex.follow(time_parameterize(descent, twin.dt, through=True, duration=0.5, robot=spec), closed)
    _steer(ex, name, T_low, goal, d, speed)
    T_here = twin.T_base_link()
    T_up = T_here.copy()
    T_up[2, 3] += max(0.04, z_top + 0.02 - (T_here[2, 3] - spec.tcp_offset))
    line(ex, T_here, T_up, closed, 0.35)
    for _ in range(10):  # let a rolling object come to rest (<= 1 s)
        ex.hold(0.1, closed)
        b = twin.bodies[name].entity
        if np.linalg.norm(np.asarray(b.get_vel())) < 0.005:
            break


def _steer(ex: Executor, name: str, T_start: np.ndarray, goal: np.ndarray, d: np.ndarray, speed: float = 0.1) -> None:
    """Closed-loop sweep: every control tick the pusher heads for the goal through the object's current centre
    of mass (aim direction from the centre to the goal, the pusher pulled onto the line behind the centre), so
    an object that turns or slides sideways is steered back. Stops when the centre has reached the goal
    along ``d`` or the sweep ran (distance + 8 cm) / speed."""
    tw = ex.twin
    tick = ex.spc * tw.dt
    T = T_start.copy()
    max_ticks = math.ceil((float(np.linalg.norm(goal - placed_com(tw, name)[1][:2])) + 0.08) / (speed * tick))
    for _ in range(max_ticks):
        c = placed_com(tw, name)[1][:2]
        rem = goal - c
        if float(rem @ d) <= 0.006 or float(np.linalg.norm(rem)) < 0.004:  # the arm lags ~5 mm
            break
        aim = rem / np.linalg.norm(rem)
        rel = T[:2, 3] - c
        lateral = rel - (rel @ aim) * aim
        step = speed * tick * aim - np.clip(0.5 * lateral, -0.01, 0.01)
        T[:2, 3] += step
        q = ik(tw, T, ex.q_now(), attempts=1, check_collision=False)
        ramp = ex.q_cmd + np.linspace(0.0, 1.0, ex.spc + 1)[1:, None] * (q - ex.q_cmd)
        ex.follow(ramp, ex.spec.gripper_closed)
