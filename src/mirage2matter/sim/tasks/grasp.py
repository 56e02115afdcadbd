"""``grasp <object>``: pick an object up from the table."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..planning import PlanningError, cartesian_path, collision_free, ik, time_parameterize
from ..twin import Twin
from .base import SuccessMonitor, Task, option, register_task
from .motion import Executor, move_to, placed, tcp_pose, topdown

__all__ = ["GraspTask", "LiftMonitor", "grasp_candidates", "least_turn_first", "toward_home", "yaw_choices"]


class LiftMonitor(SuccessMonitor):
    """Success once body ``name`` has stayed >= ``lift_m`` above its start height (its frame's origin) for
    ``hold_s`` seconds of control ticks in a row."""

    def __init__(self, twin: Twin, name: str, tick_s: float, lift_m: float = 0.05, hold_s: float = 1.0) -> None:
        super().__init__(tick_s)
        self.name, self.lift_m, self.hold_s = name, lift_m, hold_s
        self.z0 = float(twin.object_poses()[name][2, 3])
        self.t = 0.0
        self.since: float | None = None  # when the current run of lifted ticks began
        self.info = {"lift_m": 0.0, "max_lift_m": 0.0, "held_s": 0.0}

    def measure(self, twin: Twin) -> tuple[bool, str]:
        self.t += self.tick_s
        rise = float(twin.object_poses()[self.name][2, 3]) - self.z0
        self.since = (self.since if self.since is not None else self.t) if rise >= self.lift_m else None
        held = 0.0 if self.since is None else self.t - self.since
        self.info = {"lift_m": rise, "max_lift_m": max(self.info["max_lift_m"], rise),
                     "held_s": max(self.info["held_s"], held)}  # fmt: skip
        cm = 100 * self.lift_m
        if held >= self.hold_s - 1e-9:
            return True, f"{self.name} lifted {100 * rise:.1f} cm and held {self.hold_s:g} s"
        if self.info["max_lift_m"] < self.lift_m:
            return False, f"{self.name} rose only {100 * self.info['max_lift_m']:.1f} cm (needs {cm:g} cm)"
        return False, f"{self.name} held >= {cm:g} cm up for only {self.info['held_s']:.1f} s of {self.hold_s:g} s"


@register_task
@dataclass(frozen=True)
class GraspTask(Task):
    """**Task:** pick up ``target`` (a free object) and hold it.

    The policy: a top-down antipodal grasp chosen on the object's mesh at its current pose
    (:func:`grasp_candidates`), pre-grasp 10 cm above, straight approach, close with the robot's grasp force,
    lift 10 cm, hold 1 s. (From a start touching something, :func:`run_task` first lifts the hand clear.)

    **Randomizations:** the start poses are the twin's reset (``twin.reset(seed)``). With ``--detour P``, a fraction
    P of the demonstrations first go to a pre-grasp 4-10 cm off the chosen one (random direction), pause 0.3 s
    there and then go on to the right one: recovery data, so a policy that reaches beside the object has seen
    how to correct from there (its cameras show the object off-centre), not only perfect approaches.
    With ``--slack D`` the hand turns up to D degrees less than the chosen grasp asks (towards its closing yaw at
    home, :func:`toward_home`), and the closing fingers square the object up: a smaller wrist turn whose
    jump where the two symmetric grasps swap is 2D smaller (the best grasp's turn is tried next if that fails).
    With ``--tie T`` the grasps scoring within T mm of the best count as equally good and the one needing the least
    wrist turn is tried first (:func:`least_turn_first`): on an elongated object many closing angles at the same
    spot score within a fraction of a millimetre, so without it the angle is whichever wins by rounding, and
    neighbouring start poses turned the hand up to 130 deg apart.
    With ``--look S`` the hand first goes 10 cm above the chosen grasp without turning and hovers there S seconds
    before it turns: the wrist camera sees the object from straight above before the turn a policy must copy.

    **Success** (:class:`LiftMonitor`, at every control tick): the object has stayed >= 5 cm above its start
    height for 1 s.
    """

    verb = "grasp"
    detour: float | None = option(None, "a fraction of the demonstrations", range=(0.0, 1.0), unit="")
    slack: float | None = option(None, "degrees the wrist turns less than the best grasp's yaw", range=(0.0, 60.0),
                                 unit="deg")  # fmt: skip
    tie: float | None = option(None, "millimetres of grasp score counted as a tie", range=(0.0, 10.0), unit="mm")
    look: float | None = option(None, "seconds hovering above the grasp before the wrist turns", range=(0.0, 2.0),
                                unit="s")  # fmt: skip

    @property
    def instruction(self) -> str:
        return f"pick up the {self.target.replace('_', ' ')}"

    def monitor(self, twin: Twin, tick_s: float) -> LiftMonitor:
        return LiftMonitor(twin, self.target, tick_s)

    def run(self, ex: Executor) -> tuple[str, dict[str, Any]]:
        twin, spec, name = ex.twin, ex.spec, self.target
        n_arm = spec.n_arm
        points, com = placed(twin, name)
        q_now = twin.robot_state()
        chosen = None
        tried = 0
        cands = grasp_candidates(points, com, twin.cfg.table_z, max_width=spec.max_grasp_width,
                                 pad_half_width=spec.pad_half_width, min_height=spec.min_grasp_height)  # fmt: skip
        if self.tie:
            cands = least_turn_first(cands, spec.home_closing_yaw, self.tie / 1000.0)
        for _score, tcp, yaw in cands[:12]:
            choices = yaw_choices(yaw, spec.home_closing_yaw)
            if self.slack:
                choices.insert(0, toward_home(choices[0], spec.home_closing_yaw, math.radians(self.slack)))
            for w in choices:
                tried += 1
                axis = np.array([math.cos(w), math.sin(w)])
                T_grasp = topdown(tcp, axis, spec.T_ee_tcp)
                T_pre = T_grasp.copy()
                T_pre[2, 3] += 0.10
                T_lift = T_grasp.copy()
                T_lift[2, 3] += 0.10
                try:  # the whole approach and lift must be feasible, or the next candidate
                    q_pre = ik(twin, T_pre, q_now)
                    down = cartesian_path(twin, T_pre, T_grasp, np.concatenate([q_pre, q_now[n_arm:]]),
                                          check_collision=False)  # fmt: skip
                    up = cartesian_path(twin, T_grasp, T_lift, np.concatenate([down[-1], q_now[n_arm:]]),
                                        check_collision=False)  # fmt: skip
                except PlanningError:
                    continue
                with twin.restoring():  # the open fingers may touch the target, nothing else
                    if not collision_free(twin, np.concatenate([down[-1], q_now[n_arm:]]), allow=(name,)):
                        continue
                chosen = (tcp, w, T_pre, q_pre, down, up)
                break
            if chosen:
                break
        if chosen is None:
            return f"no reachable top-down grasp of {name} ({tried} tried)", {}
        tcp, w, T_pre, q_pre, down, up = chosen
        opened, closed = spec.gripper_open, spec.gripper_closed
        info: dict[str, Any] = {}
        # drawn in every episode (the same number of draws), so a seed's episode does not depend on the option
        u, angle, radius = ex.rng.random(), ex.rng.uniform(0.0, 2.0 * math.pi), ex.rng.uniform(0.04, 0.10)
        if self.detour is not None and u < self.detour:
            T_off = T_pre.copy()
            T_off[:2, 3] += radius * np.array([math.cos(angle), math.sin(angle)])
            if _stop_at(ex, T_off, q_now, opened, 0.3):  # an unreachable detour leaves the plain approach
                info["detour_m"] = [round(radius * math.cos(angle), 4), round(radius * math.sin(angle), 4)]
        if self.look:  # above the grasp with the hand's yaw unchanged
            hand_axis = tcp_pose(twin)[:2, 1]
            T_look = topdown(tcp, hand_axis / np.linalg.norm(hand_axis), spec.T_ee_tcp)
            T_look[2, 3] += 0.10
            if _stop_at(ex, T_look, q_now, opened, self.look):
                info["look_s"] = self.look
        move_to(ex, q_pre, opened, speed=0.6)
        ex.follow(time_parameterize(down, twin.dt, through=True, duration=0.8, robot=spec), opened)
        ex.hold(0.15, opened)  # let the arm's tracking error settle: a grasp off the widest height squeezes out
        ex.close()
        ex.follow(time_parameterize(up, twin.dt, through=True, duration=0.7, robot=spec), closed)  # squeezing
        ex.hold(1.0, closed)
        return "", {"grasp_tcp": tcp.tolist(), "grasp_yaw_deg": math.degrees(w), **info}


def _stop_at(ex: Executor, T_base_ee: np.ndarray, q_now: np.ndarray, finger: float, seconds: float) -> bool:
    """Move the hand to ``T_base_ee`` [4,4] and hold ``seconds``; False (and no tick) if it is unreachable."""
    try:  # ik() and plan() fail before any tick
        move_to(ex, ik(ex.twin, T_base_ee, q_now), finger, speed=0.6)
    except PlanningError:
        return False
    ex.hold(seconds, finger)
    return True


def grasp_candidates(
    points: np.ndarray,
    com: np.ndarray,
    table_z: float = 0.0,
    *,
    max_width: float,
    pad_half_width: float,
    min_height: float,
) -> list[tuple[float, np.ndarray, float]]:
    """Top-down antipodal grasps on a placed surface sample: [(score, tcp [3], yaw)], best (lowest) first.

    For each yaw (closing axis u) and offset along the finger axis v from the centre of mass, the surface
    points in the slab under the fingers (|v| <= ``pad_half_width``) must be one piece along u (no gap > 1 cm:
    the fingers close on material, not across a hollow) spanning at most ``max_width``. The grasp centres on
    that span at the height where the slab is widest (the contact normals are horizontal there, so closing does
    not squeeze the object out), the TCP at least ``min_height`` over the table. Score: the centre of mass's
    offset along v (it twists the object about the closing axis while lifting) dominates; the offset along u and
    a wide span count a little.
    """
    out = []
    rel = points[:, :2] - com[:2]
    for yaw in np.radians(np.arange(0.0, 180.0, 10.0)):
        u = np.array([math.cos(yaw), math.sin(yaw)])
        v = np.array([-u[1], u[0]])
        pu, pv = rel @ u, rel @ v
        for off in np.arange(-0.06, 0.0601, 0.01):
            slab = np.abs(pv - off) <= pad_half_width
            if slab.sum() < 30:
                continue
            su = np.sort(pu[slab])
            lo, hi = su[0], su[-1]
            width = hi - lo
            if width > max_width or np.diff(su).max() > 0.01:
                continue
            zs = points[slab, 2]
            z_top = float(zs.max())
            edges = np.arange(table_z, z_top + 0.003, 0.003)
            bins = np.digitize(zs, edges)
            spans = [np.ptp(pu[slab][bins == k]) if (bins == k).sum() >= 3 else 0.0 for k in range(1, len(edges) + 1)]
            z_wide = float(edges[int(np.argmax(spans))] + 0.0015)
            z = max(table_z + min_height, min(z_wide, z_top - 0.005))
            centre = com[:2] + u * 0.5 * (lo + hi) + v * off
            score = abs(off) + 0.2 * abs(0.5 * (lo + hi)) + 0.3 * max(0.0, width - 0.05)
            out.append((float(score), np.array([centre[0], centre[1], z]), float(yaw)))
    out.sort(key=lambda c: c[0])
    return out


def _turn(yaw: float, to_yaw: float) -> float:
    """The shorter signed turn (rad, in [-pi, pi)) from ``yaw`` to ``to_yaw``."""
    return (to_yaw - yaw + math.pi) % (2 * math.pi) - math.pi


def toward_home(yaw: float, home_yaw: float, slack: float) -> float:
    """Hand yaw ``yaw`` (rad) turned towards ``home_yaw`` by at most ``slack`` (rad): no turn within ``slack`` of it."""
    return yaw + max(-slack, min(slack, _turn(yaw, home_yaw)))


def least_turn_first(
    cands: list[tuple[float, np.ndarray, float]], home_yaw: float, tie: float
) -> list[tuple[float, np.ndarray, float]]:
    """``cands`` (best score first, as :func:`grasp_candidates` returns them) with those scoring within ``tie`` of
    the best ordered by the wrist turn from ``home_yaw`` (rad) their nearer symmetric yaw needs, least first; the
    rest keep their order after them."""
    if not cands:
        return []
    n = sum(1 for c in cands if c[0] <= cands[0][0] + tie)

    def turn(c: tuple[float, np.ndarray, float]) -> float:
        return abs(_turn(yaw_choices(c[2], home_yaw)[0], home_yaw))

    return sorted(cands[:n], key=turn) + list(cands[n:])


def yaw_choices(yaw: float, home_yaw: float) -> list[float]:
    """The two hand yaws giving the same grasp (the fingers are symmetric), the one closer to ``home_yaw`` (the
    closing axis' yaw at home: the least wrist rotation) first."""
    return sorted([yaw, yaw + math.pi], key=lambda w: abs(_turn(w, home_yaw)))
