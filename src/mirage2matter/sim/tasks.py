"""Scripted tasks with language instructions on a :class:`~mirage2matter.sim.twin.Twin`.

- ``grasp <object>``: a top-down antipodal grasp chosen on the object's mesh at its current pose (the slab
  between the fingers must fit the opening, centred as close to the centre of mass as it can), pre-grasp
  10 cm above, straight approach, close with a squeezing force, lift 15 cm, hold. Success: the object is
  >= 5 cm above its start height at the start of the hold and still after 1 s.
- ``press <button>``: closed fingertips over the cap's top, press along the axis until the cap has travelled
  past the button's threshold (or the fingertips reach travel + 3 mm), release. Success: the cap's largest
  travel exceeds the threshold.
- ``push <object> --direction dx,dy --distance d`` and ``pull ...``: closed fingers lowered beside the object
  on the side opposite the direction, then swept along it until the object's centre has moved ``d`` (closed
  loop on the object's pose), then lifted away. ``pull`` defaults its direction to the robot base (the
  fingers reach beyond the object and drag it back). Success: the final displacement is within ``tolerance``
  of ``d * direction``.

``run_task`` records a :class:`StepRecord` at ``control_hz`` and calls ``on_step`` with it (the twin is then
in that record's state, so a caller can render). Actions are the arm's joint targets 0.1 s ahead [7] and the
finger target (m per finger: 0.04 open, 0 closed) [1].
"""

from __future__ import annotations

import math
import re
import shlex
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import trimesh

from ..world.config import WorldConfig, WorldConfigError
from ..world.validate import load_mesh
from .planning import PlanningError, cartesian_path, collision_free, ik, plan, time_parameterize
from .twin import ARM_DOFS, GRIPPER_OPEN, Twin

__all__ = ["StepRecord", "TaskError", "TaskResult", "TaskSpec", "evaluate", "parse_task", "run_task"]

TASK_VERBS = ("grasp", "press", "push", "pull")
TCP_OFFSET = 0.1034  # Panda hand frame: point between the finger pads along the approach axis (m)
TIP_OFFSET = 0.1123  # fingertip ends (closed or open)
MAX_WIDTH = 0.072  # widest slab the open fingers (8 cm) take with margin
PAD_HALF = 0.012  # half the fingers' width across the closing axis, with margin
GRASP_FORCE = 20.0  # N per finger


class TaskError(ValueError):
    """An instruction that cannot run in this world (unknown verb, object, option)."""


@dataclass
class TaskSpec:
    """A parsed instruction. ``direction`` [2] (unit, base xy) and ``distance`` (m) for push / pull."""

    verb: str
    target: str
    direction: tuple[float, float] | None = None
    distance: float = 0.1
    tolerance: float = 0.02

    @property
    def instruction(self) -> str:
        """The language instruction of an episode."""
        name = self.target.replace("_", " ")
        if self.verb == "grasp":
            return f"pick up the {name}"
        if self.verb == "press":
            return f"press the {name}"
        where = _direction_words(self.direction) if self.direction is not None else "towards the robot"
        return f"{self.verb} the {name} {round(100 * self.distance)} cm {where}"

    @classmethod
    def parse(cls, text: str, cfg: WorldConfig | None = None) -> TaskSpec:
        """Same as :func:`parse_task`."""
        return parse_task(text, cfg)

    def to_json(self) -> dict:
        return {
            "verb": self.verb,
            "target": self.target,
            "direction": None if self.direction is None else list(self.direction),
            "distance": self.distance,
            "tolerance": self.tolerance,
            "instruction": self.instruction,
        }


def _direction_words(d: tuple[float, float]) -> str:
    """Base frame seen from the robot: +x away ("forward"), +y left."""
    ang = math.degrees(math.atan2(d[1], d[0])) % 360
    names = ["forward", "forward-left", "left", "back-left", "back", "back-right", "right", "forward-right"]
    return names[int(((ang + 22.5) % 360) // 45)]


def parse_task(text: str, cfg: WorldConfig | None = None) -> TaskSpec:
    """Parse ``"grasp banana"``, ``"press button"``, ``"push croissant --direction 0,1 --distance 0.1"``,
    ``"pull croissant --distance 0.08 [--direction -1,0] [--tolerance 0.02]"``; with ``cfg``, check the
    target exists and suits the verb. Raises :class:`TaskError` naming what was wrong."""
    try:
        words = shlex.split(text.strip())
    except ValueError as e:
        raise TaskError(f"cannot parse task {text!r}: {e}") from None
    if len(words) < 2:
        raise TaskError(f"task {text!r}: expected '<verb> <object> [options]' with verb one of {TASK_VERBS}")
    verb, target, rest = words[0].lower(), words[1], words[2:]
    if verb not in TASK_VERBS:
        raise TaskError(f"unknown task {verb!r} in {text!r}; known tasks: {', '.join(TASK_VERBS)}")
    if target.lower() == "the" and rest:
        target, rest = rest[0], rest[1:]
    opts: dict[str, str] = {}
    i = 0
    while i < len(rest):
        key = rest[i]
        if not key.startswith("--") or i + 1 >= len(rest):
            raise TaskError(f"task {text!r}: expected '--option value' pairs after the object, got {rest[i:]}")
        opts[key[2:]] = rest[i + 1]
        i += 2
    allowed = {"direction", "distance", "tolerance"} if verb in ("push", "pull") else set()
    unknown = set(opts) - allowed
    if unknown:
        raise TaskError(
            f"task {text!r}: option(s) {sorted(unknown)} not allowed for {verb!r} (allowed: {sorted(allowed)})"
        )
    spec = TaskSpec(verb, target)
    if "direction" in opts:
        try:
            d = np.array([float(v) for v in re.split(r"[,\s]+", opts["direction"].strip()) if v], dtype=np.float64)
        except ValueError:
            d = np.zeros(0)
        if d.shape != (2,) or np.linalg.norm(d) < 1e-9:
            raise TaskError(f"task {text!r}: --direction must be two numbers 'dx,dy' (base frame), not all zero")
        spec.direction = tuple((d / np.linalg.norm(d)).tolist())
    for key in ("distance", "tolerance"):
        if key in opts:
            try:
                v = float(opts[key])
            except ValueError:
                raise TaskError(f"task {text!r}: --{key} must be a number in metres") from None
            if not (0.0 < v <= 0.5):
                raise TaskError(f"task {text!r}: --{key} {v} must be in (0, 0.5] metres")
            setattr(spec, key, v)
    if verb == "push" and spec.direction is None:
        spec.direction = (1.0, 0.0)
    if cfg is not None:
        objects = [o.name for o in cfg.objects]
        buttons = [a.name for a in cfg.articulated if a.kind == "press_button"]
        if verb == "press":
            if target not in buttons:
                raise TaskError(f"task {text!r}: no press button named {target!r} in the world; buttons: {buttons}")
        elif target not in objects:
            raise TaskError(f"task {text!r}: no object named {target!r} in the world; objects: {objects}")
    return spec


@dataclass
class StepRecord:
    """One control tick: time (s), state [9] (7 arm joints, 2 fingers), action [8] (arm targets, finger
    target), object poses {name: T_base_obj [4,4]}."""

    t: float
    state: np.ndarray
    action: np.ndarray
    object_poses: dict[str, np.ndarray]


@dataclass
class TaskResult:
    success: bool
    reason: str
    steps: list[StepRecord] = field(default_factory=list)
    info: dict = field(default_factory=dict)


class _Exec:
    """Runs joint targets through the physics, recording at the control rate."""

    def __init__(self, twin: Twin, on_step: Callable[[StepRecord], None] | None, control_hz: float) -> None:
        self.twin = twin
        self.on_step = on_step
        self.spc = max(1, round(1.0 / (control_hz * twin.dt)))
        self.n = 0
        self.steps: list[StepRecord] = []
        self.q_cmd = twin.robot_state()[:ARM_DOFS]
        self.finger = GRIPPER_OPEN
        self.watch: Callable[[], None] | None = None

    def follow(
        self,
        targets: np.ndarray,
        finger: float | np.ndarray,
        force: float | None = None,
        stop: Callable[[], bool] | None = None,
        check_every: int = 5,
    ) -> bool:
        """Step through arm targets [T,7] with finger targets (one value or [T]); True if ``stop`` fired."""
        tw = self.twin
        fingers = np.broadcast_to(np.asarray(finger, dtype=np.float64), (len(targets),))
        for i, q in enumerate(targets):
            if self.n % self.spc == 0:
                k = min(i + self.spc, len(targets) - 1)
                self._record(targets[k], 0.0 if force is not None else fingers[k])
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
        a 4 cm gap within one physics step and tunnels through thin objects), then squeeze with GRASP_FORCE."""
        n = max(1, round(seconds / self.twin.dt))
        ramp = np.linspace(self.finger, 0.0, n + 1)[1:]
        self.follow(np.repeat(self.q_cmd[None], n, axis=0), ramp)
        self.hold(squeeze_s, 0.0, force=GRASP_FORCE)

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
def _surface_points(twin: Twin, name: str) -> tuple[np.ndarray, np.ndarray]:
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


def _placed(twin: Twin, name: str) -> tuple[np.ndarray, np.ndarray]:
    pts, com = _surface_points(twin, name)
    T = twin.object_poses()[name]
    return pts @ T[:3, :3].T + T[:3, 3], T[:3, :3] @ com + T[:3, 3]


def _topdown(tcp: np.ndarray, closing_axis: np.ndarray) -> np.ndarray:
    """T_base_hand with the approach (hand z) straight down, fingers closing along ``closing_axis`` (xy)."""
    y = np.array([closing_axis[0], closing_axis[1], 0.0])
    y /= np.linalg.norm(y)
    z = np.array([0.0, 0.0, -1.0])
    x = np.cross(y, z)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = tcp - TCP_OFFSET * z
    return T


def grasp_candidates(
    points: np.ndarray, com: np.ndarray, table_z: float = 0.0
) -> list[tuple[float, np.ndarray, float]]:
    """Top-down antipodal grasps on a placed surface sample: [(score, tcp [3], yaw)], best (lowest) first.

    For each yaw (closing axis u) and offset along the finger axis v from the centre of mass, the surface
    points in the slab under the fingers (|v| <= PAD_HALF) must be one piece along u (no gap > 1 cm: the
    fingers close on material, not across a hollow) spanning at most MAX_WIDTH. The grasp centres on that span
    at the height where the slab is widest (the contact normals are horizontal there, so closing does not
    squeeze the object out), fingertips >= 3 mm over the table. Score: the centre of mass's offset along v
    (it twists the object about the closing axis while lifting) dominates; the offset along u and a wide span
    count a little.
    """
    out = []
    rel = points[:, :2] - com[:2]
    for yaw in np.radians(np.arange(0.0, 180.0, 10.0)):
        u = np.array([math.cos(yaw), math.sin(yaw)])
        v = np.array([-u[1], u[0]])
        pu, pv = rel @ u, rel @ v
        for off in np.arange(-0.06, 0.0601, 0.01):
            slab = np.abs(pv - off) <= PAD_HALF
            if slab.sum() < 30:
                continue
            su = np.sort(pu[slab])
            lo, hi = su[0], su[-1]
            width = hi - lo
            if width > MAX_WIDTH or np.diff(su).max() > 0.01:
                continue
            zs = points[slab, 2]
            z_top = float(zs.max())
            edges = np.arange(table_z, z_top + 0.003, 0.003)
            bins = np.digitize(zs, edges)
            spans = [np.ptp(pu[slab][bins == k]) if (bins == k).sum() >= 3 else 0.0 for k in range(1, len(edges) + 1)]
            z_wide = float(edges[int(np.argmax(spans))] + 0.0015)
            z = max(table_z + 0.012, min(z_wide, z_top - 0.005))
            centre = com[:2] + u * 0.5 * (lo + hi) + v * off
            score = abs(off) + 0.2 * abs(0.5 * (lo + hi)) + 0.3 * max(0.0, width - 0.05)
            out.append((float(score), np.array([centre[0], centre[1], z]), float(yaw)))
    out.sort(key=lambda c: c[0])
    return out


def _yaw_choices(yaw: float) -> list[float]:
    """The two hand yaws giving the same grasp (the fingers are symmetric), the home-like one first."""
    a, b = yaw, yaw + math.pi
    # The Panda's home hand frame has its closing axis (y) along base -y: prefer the yaw closer to that.
    key = lambda w: abs((w - (-math.pi / 2) + math.pi) % (2 * math.pi) - math.pi)
    return sorted([a, b], key=key)


# ---- the tasks ---------------------------------------------------------------------------------------
def _move_to(ex: _Exec, q_goal: np.ndarray, finger: float, allow=(), speed: float = 0.8, timeout: float = 3.0) -> None:
    tw = ex.twin
    q_now = np.concatenate([ex.q_cmd, tw.robot_state()[ARM_DOFS:]])
    path = plan(tw, q_now, q_goal, timeout=timeout, allow=allow)
    ex.follow(time_parameterize(path, tw.dt, speed), finger)


def _line(ex: _Exec, T_from, T_to, finger, seconds, force=None, stop=None, allow=()) -> bool:
    tw = ex.twin
    q_seed = np.concatenate([ex.q_cmd, tw.robot_state()[ARM_DOFS:]])
    path = cartesian_path(tw, T_from, T_to, q_seed, check_collision=False)
    return ex.follow(time_parameterize(path, tw.dt, through=True, duration=seconds), finger, force, stop)


def _grasp(twin: Twin, spec: TaskSpec, ex: _Exec) -> tuple[bool, str, dict]:
    name = spec.target
    points, com = _placed(twin, name)
    z0 = float(twin.object_poses()[name][2, 3])
    q_now = twin.robot_state()
    chosen = None
    tried = 0
    for _score, tcp, yaw in grasp_candidates(points, com, twin.cfg.table_z)[:12]:
        for w in _yaw_choices(yaw):
            tried += 1
            axis = np.array([math.cos(w), math.sin(w)])
            T_grasp = _topdown(tcp, axis)
            T_pre = T_grasp.copy()
            T_pre[2, 3] += 0.10
            T_lift = T_grasp.copy()
            T_lift[2, 3] += 0.10
            try:  # the whole approach and lift must be feasible, or the next candidate
                q_pre = ik(twin, T_pre, q_now)
                down = cartesian_path(twin, T_pre, T_grasp, np.concatenate([q_pre, q_now[ARM_DOFS:]]),
                                      check_collision=False)  # fmt: skip
                up = cartesian_path(twin, T_grasp, T_lift, np.concatenate([down[-1], q_now[ARM_DOFS:]]),
                                    check_collision=False)  # fmt: skip
            except PlanningError:
                continue
            with twin.restoring():  # the open fingers may touch the target, nothing else
                if not collision_free(twin, np.concatenate([down[-1], q_now[ARM_DOFS:]]), allow=(name,)):
                    continue
            chosen = (tcp, w, q_pre, down, up)
            break
        if chosen:
            break
    if chosen is None:
        return False, f"no reachable top-down grasp of {name} ({tried} tried)", {}
    tcp, w, q_pre, down, up = chosen
    _move_to(ex, q_pre, GRIPPER_OPEN, speed=0.6)
    ex.follow(time_parameterize(down, twin.dt, through=True, duration=0.8), GRIPPER_OPEN)
    ex.hold(0.15, GRIPPER_OPEN)  # let the arm's tracking error settle: a grasp off the widest height squeezes out
    ex.close()
    ex.follow(time_parameterize(up, twin.dt, through=True, duration=0.7), 0.0, force=GRASP_FORCE)
    rise0 = float(twin.object_poses()[name][2, 3]) - z0
    lowest = [rise0]

    def watch() -> None:
        lowest[0] = min(lowest[0], float(twin.object_poses()[name][2, 3]) - z0)

    ex.watch = watch
    ex.hold(1.0, 0.0, force=GRASP_FORCE)
    ex.watch = None
    info = {
        "grasp_tcp": tcp.tolist(),
        "grasp_yaw_deg": math.degrees(w),
        "lift_m": rise0,
        "min_lift_during_hold_m": lowest[0],
    }
    if rise0 < 0.05:
        return False, f"{name} rose only {100 * rise0:.1f} cm (needs 5 cm)", info
    if lowest[0] < 0.05:
        return False, f"{name} slipped during the 1 s hold (down to {100 * lowest[0]:.1f} cm)", info
    return True, f"{name} lifted {100 * rise0:.1f} cm and held 1 s", info


def _press(twin: Twin, spec: TaskSpec, ex: _Exec) -> tuple[bool, str, dict]:
    name = spec.target
    b = twin.bodies[name]
    a = b.cfg
    cap_T = twin.object_poses()[f"{name}/cap"]
    pts, _ = _surface_points(twin, name)  # the cap's surface (body frame of the cap)
    axis_base = twin.object_poses()[name][:3, :3] @ (np.asarray(a.axis) / np.linalg.norm(a.axis))
    top_local = pts[np.argmax(pts @ (cap_T[:3, :3].T @ -axis_base))]
    centre_local = np.array([pts[:, 0].mean(), pts[:, 1].mean(), top_local[2]])
    top = cap_T[:3, :3] @ centre_local + cap_T[:3, 3]
    if abs(axis_base[2]) < 0.9:
        return False, f"{name}: only buttons pressed downwards are supported (axis {axis_base.round(2).tolist()})", {}
    q_now = twin.robot_state()
    T_touch = _topdown(top + np.array([0, 0, TIP_OFFSET - TCP_OFFSET]), np.array([0.0, -1.0]))
    T_pre = T_touch.copy()
    T_pre[2, 3] += 0.08
    T_deep = T_touch.copy()
    T_deep[2, 3] -= a.travel * a.placement.scale + 0.003
    try:
        q_pre = ik(twin, T_pre, q_now)
    except PlanningError as e:
        return False, f"cannot reach above {name}: {e}", {}
    _move_to(ex, np.concatenate([q_pre, [0.0, 0.0]]), 0.0)
    _line(ex, T_pre, T_touch, 0.0, 0.6)
    best = [0.0]

    def watch() -> None:
        best[0] = max(best[0], twin.button_travel(name))

    ex.watch = watch
    _line(ex, T_touch, T_deep, 0.0, 0.6, stop=lambda: best[0] >= a.threshold + 0.001)
    ex.hold(0.3, 0.0)
    T_here = twin.T_base_link()
    T_up = T_here.copy()
    T_up[2, 3] = T_touch[2, 3] + 0.05
    _line(ex, T_here, T_up, 0.0, 0.6)
    ex.watch = None
    info = {"max_travel_m": best[0], "threshold_m": a.threshold}
    if best[0] >= a.threshold:
        return True, f"{name} pressed {1000 * best[0]:.1f} mm (threshold {1000 * a.threshold:.1f} mm)", info
    return False, f"{name} pressed only {1000 * best[0]:.1f} mm (threshold {1000 * a.threshold:.1f} mm)", info


def _push(twin: Twin, spec: TaskSpec, ex: _Exec) -> tuple[bool, str, dict]:
    name = spec.target
    start_c = _placed_com(twin, name)[1][:2].copy()  # displacement counts from the episode's start
    if spec.direction is None:  # pull towards the robot base
        d = -start_c / max(np.linalg.norm(start_c), 1e-9)
    else:
        d = np.asarray(spec.direction, dtype=np.float64)
    goal = start_c + spec.distance * d
    sweeps = 0
    for attempt in range(3):  # the sweep, then up to two corrective sweeps for what rolled or slid aside
        rem = goal - _placed_com(twin, name)[1][:2]
        if attempt > 0 and np.linalg.norm(rem) <= 0.5 * spec.tolerance:
            break
        direction = d if attempt == 0 else rem / np.linalg.norm(rem)
        try:
            _sweep(ex, name, goal, direction, speed=0.1 if attempt == 0 else 0.06)
        except PlanningError as e:
            if attempt == 0:
                return False, f"cannot reach the start of the {spec.verb}: {e}", {}
            break
        sweeps += 1
    ex.hold(0.2, 0.0)
    c = _placed_com(twin, name)[1][:2]
    disp = c - start_c
    err = float(np.linalg.norm(disp - spec.distance * d))
    info = {"displacement_m": disp.tolist(), "target_m": (spec.distance * d).tolist(), "error_m": err, "sweeps": sweeps}
    if err <= spec.tolerance:
        return True, f"{name} moved {100 * np.linalg.norm(disp):.1f} cm, {100 * err:.1f} cm from the target", info
    return False, f"{name} ended {100 * err:.1f} cm from the target (tolerance {100 * spec.tolerance:.1f} cm)", info


def _sweep(ex: _Exec, name: str, goal: np.ndarray, d: np.ndarray, speed: float) -> None:
    """Closed fingers lowered just behind the object (opposite ``d``), steered to ``goal``, lifted away, and
    the object left to come to rest."""
    twin = ex.twin
    points, com = _placed(twin, name)
    c0 = com[:2]
    back = float(((points[:, :2] - c0) @ d).min())  # most negative extent along d
    z_top = float(points[:, 2].max())
    start_xy = c0 + d * (back - 0.025)
    z_tcp = twin.cfg.table_z + 0.004 + (TIP_OFFSET - TCP_OFFSET)  # fingertips 4 mm over the table
    z_tcp = max(z_tcp, min(z_tcp + 0.01, z_top - 0.01))
    perp = np.array([-d[1], d[0]])
    q_now = np.concatenate([ex.q_cmd, twin.robot_state()[ARM_DOFS:]])
    error: PlanningError | None = None
    # Fingers closing across the motion make a 5 cm wide pusher; the other hand yaws are fallbacks for spots
    # (close to the base) where that wrist pose is out of reach.
    for axis in (perp, -perp, d, -d):
        T_low = _topdown(np.array([*start_xy, z_tcp]), axis)
        T_pre = T_low.copy()
        T_pre[2, 3] += max(z_top + 0.04, z_tcp + 0.05) - z_tcp  # hand above the object's top
        try:
            q_pre = ik(twin, T_pre, q_now)
            descent = cartesian_path(twin, T_pre, T_low, np.concatenate([q_pre, [0.0, 0.0]]), check_collision=False)
            break
        except PlanningError as e:
            error = e
    else:
        raise error
    _move_to(ex, np.concatenate([q_pre, [0.0, 0.0]]), 0.0)
    ex.follow(time_parameterize(descent, twin.dt, through=True, duration=0.5), 0.0)
    _steer(ex, name, T_low, goal, d, speed)
    T_here = twin.T_base_link()
    T_up = T_here.copy()
    T_up[2, 3] += max(0.04, z_top + 0.02 - (T_here[2, 3] - TCP_OFFSET))
    _line(ex, T_here, T_up, 0.0, 0.35)
    for _ in range(10):  # let a rolling object come to rest (<= 1 s)
        ex.hold(0.1, 0.0)
        b = twin.bodies[name].entity
        if np.linalg.norm(np.asarray(b.get_vel())) < 0.005:
            break


def _steer(ex: _Exec, name: str, T_start: np.ndarray, goal: np.ndarray, d: np.ndarray, speed: float = 0.1) -> None:
    """Closed-loop sweep: every control tick the pusher heads for the goal through the object's current centre
    of mass (aim direction from the centre to the goal, the pusher pulled onto the line behind the centre), so
    an object that turns or slides sideways is steered back. Stops when the centre has reached the goal
    along ``d`` or the sweep ran (distance + 8 cm) / speed."""
    tw = ex.twin
    tick = ex.spc * tw.dt
    T = T_start.copy()
    max_ticks = math.ceil((float(np.linalg.norm(goal - _placed_com(tw, name)[1][:2])) + 0.08) / (speed * tick))
    for _ in range(max_ticks):
        c = _placed_com(tw, name)[1][:2]
        rem = goal - c
        if float(rem @ d) <= 0.006 or float(np.linalg.norm(rem)) < 0.004:  # the arm lags ~5 mm
            break
        aim = rem / np.linalg.norm(rem)
        rel = T[:2, 3] - c
        lateral = rel - (rel @ aim) * aim
        step = speed * tick * aim - np.clip(0.5 * lateral, -0.01, 0.01)
        T[:2, 3] += step
        q_seed = np.concatenate([ex.q_cmd, tw.robot_state()[ARM_DOFS:]])
        q = ik(tw, T, q_seed, attempts=1, check_collision=False)
        ramp = ex.q_cmd + np.linspace(0.0, 1.0, ex.spc + 1)[1:, None] * (q - ex.q_cmd)
        ex.follow(ramp, 0.0)


def _placed_com(twin: Twin, name: str) -> tuple[np.ndarray, np.ndarray]:
    T = twin.object_poses()[name]
    _, com = _surface_points(twin, name)
    return T, T[:3, :3] @ com + T[:3, 3]


def run_task(
    twin: Twin,
    spec: TaskSpec,
    rng: np.random.Generator | None = None,
    on_step: Callable[[StepRecord], None] | None = None,
    control_hz: float = 10.0,
) -> TaskResult:
    """Run ``spec`` from the twin's current state (call ``twin.reset`` first). ``rng`` is reserved for
    randomised task choices (the scripted policies are deterministic). Planning failures end the episode as
    a failure with the planner's message."""
    try:
        parse_task(f"{spec.verb} {spec.target}", twin.cfg)
    except (TaskError, WorldConfigError) as e:
        raise TaskError(str(e)) from None
    ex = _Exec(twin, on_step, control_hz)
    t0 = time.perf_counter()
    fn = {"grasp": _grasp, "press": _press, "push": _push, "pull": _push}[spec.verb]
    try:
        ok, reason, info = fn(twin, spec, ex)
    except PlanningError as e:
        ok, reason, info = False, f"planning failed: {e}", {}
    info = {**info, "wall_s": time.perf_counter() - t0, "sim_s": ex.n * twin.dt}
    return TaskResult(bool(ok), reason, ex.steps, info)


def evaluate(twin: Twin, spec: TaskSpec, episodes: int, seed: int = 0, progress: bool = False) -> dict:
    """Run ``spec`` on ``episodes`` randomised starts (``twin.reset(seed + i)``). Returns a JSON-ready summary:
    success rate, timings (simulated and wall seconds per episode) and every episode's outcome."""
    from tqdm import tqdm

    rows = []
    it = range(episodes)
    bar = tqdm(it, desc=spec.instruction, unit="ep", disable=not progress, leave=False)
    for i in bar:
        t0 = time.perf_counter()
        twin.reset(seed=seed + i)
        reset_s = time.perf_counter() - t0
        r = run_task(twin, spec, np.random.default_rng(seed + i))
        rows.append(
            {
                "seed": seed + i,
                "success": r.success,
                "reason": r.reason,
                "sim_s": r.info["sim_s"],
                "wall_s": r.info["wall_s"] + reset_s,
                "steps": len(r.steps),
            }
        )
        bar.set_postfix(success=f"{sum(x['success'] for x in rows)}/{len(rows)}")
    n_ok = sum(x["success"] for x in rows)
    return {
        "task": spec.to_json(),
        "episodes": episodes,
        "successes": n_ok,
        "success_rate": n_ok / max(episodes, 1),
        "mean_sim_s": float(np.mean([x["sim_s"] for x in rows])) if rows else 0.0,
        "mean_wall_s": float(np.mean([x["wall_s"] for x in rows])) if rows else 0.0,
        "failures": [{"seed": x["seed"], "reason": x["reason"]} for x in rows if not x["success"]],
        "runs": rows,
    }
