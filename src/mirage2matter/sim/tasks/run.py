"""Running a task on the twin: one episode (:func:`run_task`) or a success rate over many (:func:`evaluate`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ...progress import progress_bar
from ..planning import PlanningError
from ..twin import Twin
from .base import Task
from .motion import Executor, StepRecord, clear_start

__all__ = ["TaskResult", "evaluate", "run_task"]


@dataclass
class TaskResult:
    """One episode: success, why, every recorded control tick, and the task's measurements (+ timings)."""

    success: bool
    reason: str
    steps: list[StepRecord] = field(default_factory=list)
    info: dict = field(default_factory=dict)


def run_task(
    twin: Twin,
    task: Task,
    rng: np.random.Generator | None = None,
    on_step: Callable[[StepRecord], None] | None = None,
    control_hz: float = 10.0,
    act: Callable[[np.ndarray], object] | None = None,
) -> TaskResult:
    """Run ``task``'s scripted policy from the twin's current state (call ``twin.reset`` first), one control tick
    at ``control_hz`` at a time: ``on_step`` gets each tick's record before the tick runs (the twin is then in
    the record's state, so a caller can render), ``act`` executes the action (default ``twin.act``; it must end
    in that call). Success is the task's monitor (:meth:`Task.monitor`) at any tick. ``rng`` draws the task's own
    random choices (e.g. a grasp's detour; None: a fixed seed, so a run is deterministic). From a start where the
    robot touches something (a policy left it there: ``generate --takeover``) the hand first rises clear
    (:func:`clear_start`), since the planner refuses such a start; those ticks are recorded. Raises TaskError when
    the twin's world has no target for the task; planning failures end the script with the planner's message."""
    task.check(twin.cfg)
    ex = Executor(twin, on_step, control_hz, act=act, rng=rng)
    ex.monitor = monitor = task.monitor(twin, ex.tick_s)
    t0 = time.perf_counter()
    try:
        clear_start(ex)
        note, info = task.run(ex)
    except PlanningError as e:
        note, info = f"planning failed: {e}", {}
    ok = monitor.success
    reason = monitor.reason if ok or not note else note
    info = {**info, **monitor.info, "wall_s": time.perf_counter() - t0, "sim_s": ex.n * twin.dt}
    return TaskResult(ok, reason, ex.steps, info)


def evaluate(twin: Twin, task: Task, episodes: int, seed: int = 0, progress: bool = False) -> dict:
    """Run ``task`` on ``episodes`` randomised starts (``twin.reset(seed + i)``). Returns a JSON-ready summary:
    success rate, timings (simulated and wall seconds per episode) and every episode's outcome."""
    rows = []
    bar = progress_bar(range(episodes), desc=task.instruction, unit="ep", disable=not progress, leave=False)
    for i in bar:
        t0 = time.perf_counter()
        twin.reset(seed=seed + i)
        reset_s = time.perf_counter() - t0
        r = run_task(twin, task, np.random.default_rng(seed + i))
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
        "task": task.to_json(),
        "episodes": episodes,
        "successes": n_ok,
        "success_rate": n_ok / max(episodes, 1),
        "mean_sim_s": float(np.mean([x["sim_s"] for x in rows])) if rows else 0.0,
        "mean_wall_s": float(np.mean([x["wall_s"] for x in rows])) if rows else 0.0,
        "failures": [{"seed": x["seed"], "reason": x["reason"]} for x in rows if not x["success"]],
        "runs": rows,
    }
