"""``press <button>``: press a press button down past its threshold."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..planning import PlanningError, ik
from ..twin import Twin
from .base import SuccessMonitor, Task, TaskError, register_task
from .motion import Executor, line, move_to, surface_points, topdown

if TYPE_CHECKING:
    from ...world.config import WorldConfig

__all__ = ["PressMonitor", "PressTask"]


class PressMonitor(SuccessMonitor):
    """Success once button ``name``'s cap has travelled at least its ``threshold`` (at a tick's end)."""

    def __init__(self, twin: Twin, name: str, tick_s: float) -> None:
        super().__init__(tick_s)
        self.name, self.threshold = name, float(twin.bodies[name].cfg.threshold)
        self.info = {"travel_m": 0.0, "max_travel_m": 0.0, "threshold_m": self.threshold}

    def measure(self, twin: Twin) -> tuple[bool, str]:
        travel = twin.button_travel(self.name)
        best = max(self.info["max_travel_m"], travel)
        self.info = {"travel_m": travel, "max_travel_m": best, "threshold_m": self.threshold}
        mm = f"(threshold {1000 * self.threshold:.1f} mm)"
        if travel >= self.threshold:
            return True, f"{self.name} pressed {1000 * travel:.1f} mm {mm}"
        return False, f"{self.name} pressed only {1000 * best:.1f} mm {mm}"


@register_task
@dataclass(frozen=True)
class PressTask(Task):
    """**Task:** press ``target`` (a ``press_button`` of the world) and let it go.

    The policy: closed fingertips over the cap's top, press along the axis until the cap has travelled past the
    button's threshold (or the fingertips reach travel + 3 mm), release and lift 5 cm. Only buttons pressed
    downwards are supported.

    **Randomizations:** none of its own; the button's start pose is the twin's reset (``twin.reset(seed)``).

    **Success** (:class:`PressMonitor`, at every control tick): the cap's travel reaches the button's
    ``threshold``.
    """

    verb = "press"

    @property
    def instruction(self) -> str:
        return f"press the {self.target.replace('_', ' ')}"

    def check(self, world: WorldConfig) -> None:
        buttons = [a.name for a in world.articulated if a.kind == "press_button"]
        if self.target not in buttons:
            raise TaskError(f"no press button named {self.target!r} in the world; buttons: {buttons}")

    def monitor(self, twin: Twin, tick_s: float) -> PressMonitor:
        return PressMonitor(twin, self.target, tick_s)

    def run(self, ex: Executor) -> tuple[str, dict[str, Any]]:
        twin, spec, name = ex.twin, ex.spec, self.target
        a = twin.bodies[name].cfg
        closed = spec.gripper_closed
        cap_T = twin.object_poses()[f"{name}/cap"]
        pts, _ = surface_points(twin, name)  # the cap's surface (body frame of the cap)
        axis_base = twin.object_poses()[name][:3, :3] @ (np.asarray(a.axis) / np.linalg.norm(a.axis))
        top_local = pts[np.argmax(pts @ (cap_T[:3, :3].T @ -axis_base))]
        centre_local = np.array([pts[:, 0].mean(), pts[:, 1].mean(), top_local[2]])
        top = cap_T[:3, :3] @ centre_local + cap_T[:3, 3]
        if abs(axis_base[2]) < 0.9:
            axis = axis_base.round(2).tolist()
            return f"{name}: only buttons pressed downwards are supported (axis {axis})", {}
        q_now = twin.robot_state()
        # Closed fingers press with their tips; any hand yaw does, the one of the home pose moves the wrist least.
        tips = top + np.array([0, 0, spec.tip_depth])
        T_touch = topdown(tips, np.asarray(spec.home_closing_axis, dtype=np.float64), spec.T_ee_tcp)
        T_pre = T_touch.copy()
        T_pre[2, 3] += 0.08
        T_deep = T_touch.copy()
        T_deep[2, 3] -= a.travel * a.placement.scale + 0.003
        try:
            q_pre = ik(twin, T_pre, q_now)
        except PlanningError as e:
            return f"cannot reach above {name}: {e}", {}
        move_to(ex, np.concatenate([q_pre, [closed] * len(spec.gripper_joints)]), closed)
        line(ex, T_pre, T_touch, closed, 0.6)
        line(ex, T_touch, T_deep, closed, 0.6, stop=lambda: twin.button_travel(name) >= a.threshold + 0.001)
        ex.hold(0.3, closed)
        T_here = twin.T_base_link()
        T_up = T_here.copy()
        T_up[2, 3] = T_touch[2, 3] + 0.05
        line(ex, T_here, T_up, closed, 0.6)
        return "", {}
