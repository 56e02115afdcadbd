"""Motion planning on a :class:`~mirage2matter.sim.twin.Twin`: inverse kinematics (Genesis' damped least
squares, position + orientation), joint-space paths (the straight segment when it is collision-free, else
OMPL 2.0.1 RRTConnect with the twin's collision checks as the validity checker, then shortcutting), and
time parameterisation (minimum-jerk segments within the robot spec's joint velocity and acceleration limits).

Collision checks set the robot's joints without stepping physics and ask Genesis for colliding geometry
pairs (~0.2-2 ms each); callers save and restore the robot state around planning (``Twin.set_robot_state``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable

import numpy as np

from ..errors import M2MError
from ..geometry.rotation import matrix_to_quat, rotation_angle
from ..robots import RobotSpec
from .twin import Twin

__all__ = [
    "PlanningError",
    "cartesian_path",
    "collision_free",
    "ik",
    "plan",
    "segment_free",
    "time_parameterize",
]


# Joint step (rad) at which a planned path is verified. A fingertip can graze the button's edge for only
# 0.001-0.007 rad of a segment: checked every 0.02 rad, 4 of 100 plans around the button touched it where the
# robot then moved, every 0.005 rad 2 of 100, every 0.001 rad none of 217 (plans take ~1-2 s longer).
DENSE_CHECK_STEP = 0.001
# RRTConnect is randomised: a path refused by the dense check is planned again (~15 % are refused)
_ATTEMPTS = 5


class PlanningError(M2MError, RuntimeError):
    """No path or no IK solution; the message says which target and why."""


def _allowed(pairs: Iterable[tuple[str, str]], allow: Iterable[str]) -> bool:
    allow = set(allow)
    for a, b in pairs:
        other = b if a.startswith("robot:") else a
        if other.startswith("robot:"):
            return False  # self-collision
        if other not in allow:
            return False
    return True


def collision_free(twin: Twin, q: np.ndarray, allow: Iterable[str] = ()) -> bool:
    """Whether the robot at ``q`` [n_dofs] touches nothing but the bodies named in ``allow``."""
    return _allowed(twin.colliding_pairs(q), allow)


def segment_free(
    twin: Twin, q0: np.ndarray, q1: np.ndarray, fingers: np.ndarray, allow: Iterable[str] = (), step: float = 0.04
) -> bool:
    """Whether the straight joint segment q0 -> q1 (arm [n_arm]) is collision-free, checked every ``step`` rad."""
    n = max(1, math.ceil(float(np.abs(q1 - q0).max()) / step))
    allow = tuple(allow)
    for s in np.linspace(0.0, 1.0, n + 1)[1:]:
        if not collision_free(twin, np.concatenate([q0 + s * (q1 - q0), fingers]), allow):
            return False
    return True


def ik(
    twin: Twin,
    T_base_ee: np.ndarray,
    q_init: np.ndarray,
    *,
    pos_tol: float = 0.002,
    rot_tol_deg: float = 1.0,
    attempts: int = 3,
    check_collision: bool = True,
    allow: Iterable[str] = (),
    seed: int = 0,
) -> np.ndarray:
    """Arm joints [n_arm] putting the end-effector link at ``T_base_ee`` [4,4] (position + orientation), near
    ``q_init`` [n_dofs]. Raises :class:`PlanningError` (in well under a second) when the pose is out of reach
    (``RobotSpec.reach`` from its shoulder), or every solution found collides."""
    T_base_ee = np.asarray(T_base_ee, dtype=np.float64)
    pos = T_base_ee[:3, 3]
    shoulder, reach = np.asarray(twin.spec.shoulder, dtype=np.float64), twin.spec.reach
    if np.linalg.norm(pos - shoulder) > reach:
        raise PlanningError(
            f"target {np.round(pos, 3).tolist()} is {np.linalg.norm(pos - shoulder):.2f} m from the robot's shoulder, "
            f"beyond its reach ({reach:.2f} m); move the object closer to the robot"
        )
    with twin.restoring():
        return _ik(twin, pos, matrix_to_quat(np.ascontiguousarray(T_base_ee[:3, :3])), q_init, pos_tol, rot_tol_deg,
                   attempts, check_collision, allow, seed)  # fmt: skip


def _ik(twin, pos, quat, q_init, pos_tol, rot_tol_deg, attempts, check_collision, allow, seed) -> np.ndarray:
    q_init = np.asarray(q_init, dtype=np.float64)
    n_arm = twin.spec.n_arm
    best = (math.inf, math.inf)
    collided = False
    for k in range(attempts):
        q, err = twin.robot.inverse_kinematics(
            link=twin.ee_link, pos=pos, quat=quat, init_qpos=q_init, max_samples=8 if k == 0 else 20,
            max_solver_iters=30, seed=seed + k, return_error=True,
        )  # fmt: skip
        q = np.asarray(q, dtype=np.float64)
        err = np.asarray(err, dtype=np.float64).reshape(-1)
        pe, re = float(np.linalg.norm(err[:3])), math.degrees(float(np.linalg.norm(err[3:])))
        if pe > pos_tol or re > rot_tol_deg:
            best = min(best, (pe, re))
            continue
        q_full = np.concatenate([q[:n_arm], q_init[n_arm:]])
        if check_collision and not collision_free(twin, q_full, allow):
            collided = True
            continue
        return q[:n_arm]
    if collided:
        raise PlanningError(f"every IK solution for the pose at {np.round(pos, 3).tolist()} collides")
    raise PlanningError(
        f"target pose at {np.round(pos, 3).tolist()} is unreachable for the robot (best IK error "
        f"{1000 * best[0]:.1f} mm / {best[1]:.1f} deg)"
    )


def _shortcut(
    twin: Twin, path: list[np.ndarray], fingers: np.ndarray, allow: tuple, rng: np.random.Generator
) -> tuple[list[np.ndarray], list[bool]]:
    """Random shortcutting: join two waypoints directly when the segment between them is free.

    Returns the path and, per segment, whether it is already verified at ``DENSE_CHECK_STEP`` (the shortcuts are;
    OMPL's own segments are not), so the final check does not walk a shortcut twice."""
    verified = [False] * (len(path) - 1)
    for _ in range(30):
        if len(path) <= 2:
            break
        i, j = sorted(rng.choice(len(path), size=2, replace=False))
        if j - i < 2:
            continue
        # coarse first (most shortcuts fail there, cheaply), then at the verification step
        if segment_free(twin, path[i], path[j], fingers, allow) and segment_free(
            twin, path[i], path[j], fingers, allow, step=DENSE_CHECK_STEP
        ):
            path = path[: i + 1] + path[j:]
            verified = verified[:i] + [True] + verified[j:]
    return path, verified


def plan(
    twin: Twin,
    q_start: np.ndarray,
    q_goal: np.ndarray,
    timeout: float = 3.0,
    *,
    allow: Iterable[str] = (),
    seed: int = 0,
) -> np.ndarray:
    """Collision-free joint path [K,n_arm] from ``q_start`` [n_dofs] (fingers held at its values) to ``q_goal``
    [n_arm or n_dofs].

    The straight segment when it is free; else RRTConnect (OMPL) within ``timeout`` seconds, simplified and
    shortcut. Restores the robot's state afterwards. Raises :class:`PlanningError` when start or goal collide,
    or no path is found in time.
    """
    q_start = np.asarray(q_start, dtype=np.float64)
    n_arm = twin.spec.n_arm
    fingers = q_start[n_arm:]
    a, b = q_start[:n_arm].copy(), np.asarray(q_goal, dtype=np.float64)[:n_arm].copy()
    allow = tuple(allow)
    with twin.restoring():
        for attempt in range(_ATTEMPTS):
            try:
                return _plan(twin, a, b, fingers, timeout, allow, seed + attempt)
            except _CoarsePath as e:
                if attempt == _ATTEMPTS - 1:
                    raise PlanningError(str(e)) from None
        raise AssertionError("unreachable")


class _CoarsePath(PlanningError):
    """A path OMPL accepted at its checking resolution that collides at ours."""


def _plan(twin: Twin, a: np.ndarray, b: np.ndarray, fingers: np.ndarray, timeout: float, allow: tuple, seed: int):
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    if not collision_free(twin, np.concatenate([a, fingers]), allow):
        raise PlanningError(f"the start configuration collides: {twin.colliding_pairs(np.concatenate([a, fingers]))}")
    if not collision_free(twin, np.concatenate([b, fingers]), allow):
        raise PlanningError(f"the goal configuration collides: {twin.colliding_pairs(np.concatenate([b, fingers]))}")
    if segment_free(twin, a, b, fingers, allow):
        return np.stack([a, b])
    ou.setLogLevel(ou.LogLevel.LOG_WARN)
    n_arm = len(a)
    lo, hi = twin.joint_limits
    space = ob.RealVectorStateSpace(n_arm)
    bounds = ob.RealVectorBounds(n_arm)
    for i in range(n_arm):
        bounds.setLow(i, float(lo[i]))
        bounds.setHigh(i, float(hi[i]))
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)

    def valid(state) -> bool:
        q = np.array([state[i] for i in range(n_arm)])
        return collision_free(twin, np.concatenate([q, fingers]), allow)

    ss.setStateValidityChecker(valid)
    si = ss.getSpaceInformation()
    # fraction of the space's extent (~0.04 rad here, as segment_free): at 0.01 (~0.2 rad) an edge could
    # pass through the button between two checked states; at 0.0005 the
    # dense check below refused 1 of 61 paths instead of 11 of 71, but planning took twice as long
    si.setStateValidityCheckingResolution(0.002)
    start, goal = space.allocState(), space.allocState()
    for i in range(n_arm):
        start[i], goal[i] = float(a[i]), float(b[i])
    ss.setStartAndGoalStates(start, goal)
    # OMPL seeds every sampler it creates from one global seed generator, seeded from the clock unless set: seeded
    # here, before this plan creates its samplers, the path is a function of the plan's seed (not of the clock, nor
    # of how many plans this process made before). OMPL reports re-seeding after its first RNG as an error; muted.
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    ou.RNG.setSeed(int(np.random.SeedSequence([0x0A1B, int(seed)]).generate_state(1)[0]) or 1)
    ou.setLogLevel(ou.LogLevel.LOG_WARN)
    ss.setPlanner(og.RRTConnect(si))
    t0 = time.perf_counter()
    solved = ss.solve(float(timeout))
    if not ss.haveExactSolutionPath():
        raise PlanningError(
            f"RRTConnect found no collision-free path in {time.perf_counter() - t0:.1f} s ({solved}); the goal "
            "may be enclosed by obstacles"
        )
    # to convergence, not for a time: a time-bounded simplification (it was 0.5 s; ~1.1 s either way on the sample's
    # pushes) stops at a different point in every run, and with it the path and the episode
    ss.simplifySolution()
    p = ss.getSolutionPath()
    path = [np.array([p.getState(k)[i] for i in range(n_arm)]) for k in range(p.getStateCount())]
    path, verified = _shortcut(twin, path, fingers, allow, np.random.default_rng(seed))
    # OMPL checks edges at its own resolution; accept the path only if every segment is free at ours
    # the first colliding segment is enough to refuse the path (each dense check walks its segment at 0.001 rad)
    bad = next(
        (
            k
            for k in range(len(path) - 1)
            if not verified[k] and not segment_free(twin, path[k], path[k + 1], fingers, allow, step=DENSE_CHECK_STEP)
        ),
        None,
    )
    if bad is not None:
        raise _CoarsePath(f"the planned path's segment {bad} collides when checked densely; try a longer timeout")
    return np.stack(path)


def cartesian_path(
    twin: Twin, T_start: np.ndarray, T_goal: np.ndarray, q_init: np.ndarray, step: float = 0.01, **ik_kwargs
) -> np.ndarray:
    """Joint waypoints [K,n_arm] moving the end-effector along the straight line T_start -> T_goal (orientation
    slerped), every ``step`` metres; each IK seeded with the previous solution. Raises PlanningError."""
    from scipy.spatial.transform import Rotation, Slerp

    T_start, T_goal = np.asarray(T_start, dtype=np.float64), np.asarray(T_goal, dtype=np.float64)
    dist = float(np.linalg.norm(T_goal[:3, 3] - T_start[:3, 3]))
    ang = float(rotation_angle(T_start[:3, :3].T @ T_goal[:3, :3]))
    n = max(1, math.ceil(max(dist / step, ang / math.radians(5.0))))
    slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([T_start[:3, :3], T_goal[:3, :3]])))
    q = np.asarray(q_init, dtype=np.float64).copy()
    n_arm = twin.spec.n_arm
    out = []
    with twin.restoring():
        for s in np.linspace(0.0, 1.0, n + 1)[1:]:
            T = np.eye(4)
            T[:3, :3] = slerp([s]).as_matrix()[0]
            T[:3, 3] = T_start[:3, 3] + s * (T_goal[:3, 3] - T_start[:3, 3])
            q[:n_arm] = ik(twin, T, q, attempts=1, **ik_kwargs)
            out.append(q[:n_arm].copy())
    jumps = np.abs(np.diff(np.stack([np.asarray(q_init)[:n_arm], *out]), axis=0)).max()
    if jumps > 0.5:
        raise PlanningError(f"the straight-line motion needs a joint jump of {jumps:.2f} rad (near a singularity)")
    return np.stack([np.asarray(q_init, dtype=np.float64)[:n_arm], *out])


def _min_jerk(s: np.ndarray) -> np.ndarray:
    return 10 * s**3 - 15 * s**4 + 6 * s**5


def time_parameterize(
    path: np.ndarray,
    dt: float,
    speed: float = 0.5,
    *,
    robot: RobotSpec,
    duration: float | None = None,
    through: bool = False,
) -> np.ndarray:
    """Joint targets [T,n_arm] every ``dt`` seconds along ``path`` [K,n_arm].

    Default: a minimum-jerk segment per path segment (rest at each waypoint), each as short as
    ``speed`` x ``robot``'s joint velocity and acceleration limits allow. ``through``: one minimum-jerk profile
    over the whole polyline's arc length (for dense Cartesian paths), lasting ``duration`` seconds if given.
    """
    path = np.asarray(path, dtype=np.float64)
    vmax = speed * np.asarray(robot.velocity_limit, dtype=np.float64)
    amax = speed * np.asarray(robot.acceleration_limit, dtype=np.float64)

    def seg_time(d: np.ndarray) -> float:
        d = np.abs(d)
        return float(max(np.max(1.875 * d / vmax), np.max(np.sqrt(5.77 * d / amax)), dt))

    if len(path) < 2:
        return path[:1].copy()
    if through:
        seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        T = duration if duration is not None else seg_time(np.abs(np.diff(path, axis=0)).sum(axis=0))
        n = max(1, math.ceil(T / dt))
        s = _min_jerk(np.linspace(0.0, 1.0, n + 1)[1:]) * arc[-1]
        return np.stack([np.interp(s, arc, path[:, j]) for j in range(path.shape[1])], axis=1)
    out = []
    for q0, q1 in zip(path[:-1], path[1:], strict=True):
        T = seg_time(q1 - q0) if duration is None else duration / (len(path) - 1)
        n = max(1, math.ceil(T / dt))
        s = _min_jerk(np.linspace(0.0, 1.0, n + 1)[1:])
        out.append(q0 + s[:, None] * (q1 - q0))
    return np.concatenate(out)
