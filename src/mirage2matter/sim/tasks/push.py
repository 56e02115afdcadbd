"""``push <object>`` and ``pull <object>``: slide an object over the table with the closed fingers."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..planning import PlanningError, cartesian_path, ik, time_parameterize
from ..twin import Twin
from .base import SuccessMonitor, Task, option, register_task, unit_xy
from .motion import Executor, line, move_to, placed, placed_com, topdown

__all__ = ["PullTask", "PushTask", "SlideMonitor"]

_DIRECTION_HELP = "two numbers 'dx,dy' (base frame), not all zero"
# "At rest" for the success test: below these speeds (m/s, rad/s) a pushed object has stopped sliding or rolling.
_REST_LIN, _REST_ANG = 0.01, 0.2


class SlideMonitor(SuccessMonitor):
    """Success once body ``name``'s centre of mass is at rest within ``tolerance`` of its start + ``target_xy``
    (base xy, metres)."""

    def __init__(self, twin: Twin, name: str, target_xy: np.ndarray, tolerance: float, tick_s: float) -> None:
        super().__init__(tick_s)
        self.name, self.tolerance = name, float(tolerance)
        self.start_xy = placed_com(twin, name)[1][:2].copy()
        self.target_xy = np.asarray(target_xy, dtype=np.float64)
        self.info = {"displacement_m": [0.0, 0.0], "target_m": self.target_xy.tolist(),
                     "error_m": float(np.linalg.norm(self.target_xy))}  # fmt: skip

    def measure(self, twin: Twin) -> tuple[bool, str]:
        disp = placed_com(twin, self.name)[1][:2] - self.start_xy
        err = float(np.linalg.norm(disp - self.target_xy))
        lin, ang = twin.object_speed(self.name)
        self.info = {"displacement_m": disp.tolist(), "target_m": self.target_xy.tolist(), "error_m": err}
        tol = f"(tolerance {100 * self.tolerance:.1f} cm)"
        if err > self.tolerance:
            return False, f"{self.name} is {100 * err:.1f} cm from the target {tol}"
        if lin >= _REST_LIN or ang >= _REST_ANG:
            return False, f"{self.name} is {100 * err:.1f} cm from the target but still moving"
        return True, f"{self.name} moved {100 * np.linalg.norm(disp):.1f} cm, {100 * err:.1f} cm from the target {tol}"


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
    tick the pusher heads for the goal through the object's current centre), then lifted away; up to three
    corrective sweeps for what rolled or slid aside.

    **Randomizations:** none of its own; the start poses are the twin's reset (``twin.reset(seed)``).

    **Success** (:class:`SlideMonitor`, at every control tick): the object is at rest with the displacement of
    its centre of mass within ``tolerance`` of ``distance * direction``.
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

    def heading(self, twin: Twin) -> np.ndarray:
        """[2] unit xy direction of the slide from the twin's current state (``direction``, or towards the base)."""
        if self.direction is not None:
            return np.asarray(self.direction, dtype=np.float64)
        c = placed_com(twin, self.target)[1][:2]
        return -c / max(float(np.linalg.norm(c)), 1e-9)

    def monitor(self, twin: Twin, tick_s: float) -> SlideMonitor:
        return SlideMonitor(twin, self.target, self.distance * self.heading(twin), self.tolerance, tick_s)

    def run(self, ex: Executor) -> tuple[str, dict[str, Any]]:
        twin, name = ex.twin, self.target
        start_c = placed_com(twin, name)[1][:2].copy()  # displacement counts from the episode's start
        d = self.heading(twin)
        goal = start_c + self.distance * d
        sweeps = 0
        # The sweep, then up to three corrective sweeps for what rolled or slid aside (a third one took the sample's
        # croissant push from 46 to 47 successes in 50 with per-tick control: one ended 2.1 cm off after two).
        for attempt in range(4):
            rem = goal - placed_com(twin, name)[1][:2]
            if attempt > 0 and np.linalg.norm(rem) <= 0.5 * self.tolerance:
                break
            direction = d if attempt == 0 else rem / np.linalg.norm(rem)
            try:
                _sweep(ex, name, goal, direction, speed=0.1 if attempt == 0 else 0.06)
            except PlanningError as e:
                if attempt == 0:
                    return f"cannot reach the start of the {self.verb}: {e}", {}
                break
            sweeps += 1
        ex.hold(0.2, ex.spec.gripper_closed)
        return "", {"sweeps": sweeps}


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
    z_tcp = twin.cfg.table_z + 0.004 + spec.tip_depth  # fingertips 4 mm over the table
    z_tcp = max(z_tcp, min(z_tcp + 0.01, z_top - 0.01))
    perp = np.array([-d[1], d[0]])
    q_now = ex.q_now()
    error: PlanningError | None = None
    # Fingers closing across the motion make a 5 cm wide pusher; the other hand yaws are fallbacks for spots
    # (close to the base) where that wrist pose is out of reach.
    for axis in (perp, -perp, d, -d):
        T_low = topdown(np.array([*start_xy, z_tcp]), axis, spec.T_ee_tcp)
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
    T_up[2, 3] += max(0.04, z_top + 0.02 - (T_here @ spec.T_ee_tcp)[2, 3])
    line(ex, T_here, T_up, closed, 0.35)
    for _ in range(10):  # let a rolling object come to rest (<= 1 s)
        ex.hold(0.1, closed)
        if twin.object_speed(name)[0] < 0.005:
            break


def _steer(ex: Executor, name: str, T_start: np.ndarray, goal: np.ndarray, d: np.ndarray, speed: float = 0.1) -> None:
    """Closed-loop sweep: every control tick the pusher heads for the goal through the object's current centre
    of mass (aim direction from the centre to the goal, the pusher pulled onto the line behind the centre), so
    an object that turns or slides sideways is steered back. Stops when the centre has reached the goal
    along ``d`` or the sweep ran (distance + 8 cm) / speed."""
    tw = ex.twin
    tick = ex.tick_s
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
        ex.tick(np.append(q, ex.spec.gripper_closed))
