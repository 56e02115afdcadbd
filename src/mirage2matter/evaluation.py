"""Closed-loop evaluation: a policy (``obs -> action``) run for N episodes in a Gymnasium environment.

Any environment with the Gymnasium API works (``reset(seed=) -> (obs, info)``, ``step(a) -> (obs, reward,
terminated, truncated, info)``); here it is the twin (``mirage2matter/Twin-v0``) with either renderer. Success
is the environment's ``terminated``; the success rate comes with its 95 % Wilson score interval, which stays
inside [0, 1] and is honest at the small counts (50 episodes) a CPU affords.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import atomic_write
from .errors import EpisodeStalled
from .progress import progress_bar

__all__ = ["contact_sheet", "evaluate_policy", "frame_of", "run_episode", "summarize", "wilson_interval"]


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a success rate (95 % for z = 1.96); (0, 1) for no trials."""
    if n <= 0:
        return 0.0, 1.0
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def frame_of(obs: dict, camera: str | None = None) -> np.ndarray:
    """The picture of an observation: ``obs[camera]``, or (None) every ``observation.images.*`` side by side."""
    if camera is not None:
        return np.asarray(obs[camera])
    keys = sorted(k for k in obs if k.startswith("observation.images."))
    return np.concatenate([np.asarray(obs[k]) for k in keys], axis=1)


def evaluate_policy(
    env: Any,
    policy: Callable[[dict], np.ndarray],
    episodes: int,
    seed: int = 0,
    log: Callable[[str], None] = print,
    progress: bool = True,
    keep_frames: int = 2,
    camera: str | None = None,
    done: list[dict] | None = None,
    on_episode: Callable[[dict], None] | None = None,
    max_episode_seconds: float | None = None,
    clock: Callable[[], float] = time.perf_counter,
) -> tuple[dict[str, Any], list[list[np.ndarray]]]:
    """Run ``policy`` for ``episodes`` episodes (reset seeds ``seed .. seed + episodes - 1``); returns (summary,
    the pictures (:func:`frame_of` ``camera``) of the first ``keep_frames`` episodes run here). ``policy.reset()``
    is called before each episode when it has one. The summary holds the success rate, its Wilson interval and
    one record per episode (seed, success, steps, seconds, the env's last ``reason``). ``done``: records of
    episodes already run (a resumed evaluation: their seeds are not run again); ``on_episode(record)`` after
    each episode (to save it). Each record also holds the slowest step's seconds (``max_step_seconds``) and the
    env's per-part ``timings`` when it reports them, and ``start_xy`` {object: [x, y]} (its origin in the base frame,
    m) and ``start_yaw_deg`` {object: deg} (its x axis about the base's z) when the env reports its objects' start poses
    (``start_poses``, as TwinEnv does): which placements and headings fail.
    ``max_episode_seconds``: an episode still running after that
    much wall-clock time ends there as a failure with ``reason`` saying so and ``cut: true`` (the summary counts
    them in ``cut``): a world that renders pathologically slowly in one pose cannot hold an evaluation for hours.
    An env that raises :class:`~mirage2matter.errors.EpisodeStalled` (the ground-truth renderer stalled at every
    retry) ends that episode the same way, its reason saying so, and the evaluation goes on with the next seed."""
    rows = list(done or [])
    seen = {int(r["seed"]) for r in rows}
    kept: list[list[np.ndarray]] = []
    todo = [seed + i for i in range(episodes) if seed + i not in seen]
    bar = progress_bar(todo, desc="evaluation", unit="ep", disable=not progress, leave=False)
    for s in bar:
        row, frames = run_episode(env, policy, s, keep=len(kept) < keep_frames, camera=camera,
                                  max_episode_seconds=max_episode_seconds, clock=clock)  # fmt: skip
        if frames is not None:
            kept.append(frames)
        rows.append(row)
        if on_episode is not None:
            on_episode(row)
        bar.set_postfix(success=f"{sum(r['success'] for r in rows)}/{len(rows)}")
    return summarize(rows, log), kept


def run_episode(
    env: Any,
    policy: Callable[[dict], np.ndarray],
    seed: int,
    keep: bool = False,
    camera: str | None = None,
    max_episode_seconds: float | None = None,
    clock: Callable[[], float] = time.perf_counter,
) -> tuple[dict[str, Any], list[np.ndarray] | None]:
    """One episode of :func:`evaluate_policy` (reset seed ``seed``): its record, and its pictures when ``keep``.
    A function of the env, the policy and the seed alone (``reset`` draws everything), so it runs the same episode
    wherever it runs (``eval_workers`` runs it on Ray workers)."""
    t0 = clock()
    steps, success, info, slowest, cut, stalled = 0, False, {}, 0.0, False, None
    frames: list[np.ndarray] | None = None
    try:
        obs, _ = env.reset(seed=seed)
    except EpisodeStalled as e:  # the env cannot show this episode's start: a failure, and on to the next
        cut, stalled = True, e
    start = getattr(getattr(env, "unwrapped", env), "start_poses", None)
    if hasattr(policy, "reset"):
        policy.reset()
    if keep and not cut:
        frames = [frame_of(obs, camera)]
    while not cut:
        t_step = clock()
        try:
            obs, _, terminated, truncated, info = env.step(np.asarray(policy(obs), dtype=np.float32))
        except EpisodeStalled as e:  # e.g. a renderer stalled at this state, its retries included
            steps += 1
            slowest = max(slowest, clock() - t_step)
            cut, stalled = True, e
            break
        now = clock()
        slowest = max(slowest, now - t_step)
        steps += 1
        if frames is not None:
            frames.append(frame_of(obs, camera))
        if terminated or truncated:
            success = bool(terminated)
            break
        if max_episode_seconds is not None and now - t0 > max_episode_seconds:
            cut = True
            break
    row = {"seed": seed, "success": success, "steps": steps, "seconds": round(clock() - t0, 2),
           "max_step_seconds": round(slowest, 3)}  # fmt: skip
    if isinstance(start, dict) and start:
        row["start_xy"] = {n: [round(float(T[0][3]), 4), round(float(T[1][3]), 4)] for n, T in start.items()}
        # the heading of the object's x axis (its footprint's long axis) about the base's z: which headings fail
        row["start_yaw_deg"] = {n: round(float(np.degrees(np.arctan2(T[1][0], T[0][0]))), 1)
                                for n, T in start.items()}  # fmt: skip
    timings = info.get("timings") if isinstance(info, dict) else None
    if timings is None:  # an episode cut short: the env's running totals
        timings = getattr(getattr(env, "unwrapped", env), "timings", None)
    if isinstance(timings, dict) and timings:
        row["timings"] = {k: round(float(v), 2) for k, v in timings.items()}
    if stalled is not None:
        row["cut"] = True
        row["reason"] = f"the environment stalled at step {steps} ({stalled}); counted as a failure"
    elif cut:
        row["cut"] = True
        row["reason"] = (f"wall-clock limit: still running after {max_episode_seconds:g} s at step {steps} "
                         f"(slowest step {slowest:.1f} s); counted as a failure")  # fmt: skip
    elif isinstance(info, dict) and info.get("reason"):
        row["reason"] = str(info["reason"])
    return row, frames


def summarize(rows: list[dict], log: Callable[[str], None] = print) -> dict[str, Any]:
    """The summary of an evaluation's episode records (any order; ``runs`` in seed order), logged in one line."""
    rows = sorted(rows, key=lambda r: r["seed"])
    n_ok = sum(bool(r["success"]) for r in rows)
    lo, hi = wilson_interval(n_ok, len(rows))
    summary = {
        "episodes": len(rows),
        "successes": n_ok,
        "success_rate": n_ok / max(len(rows), 1),
        "wilson95": [lo, hi],
        "mean_steps": float(np.mean([r["steps"] for r in rows])) if rows else 0.0,
        "mean_seconds": float(np.mean([r["seconds"] for r in rows])) if rows else 0.0,
        "cut": sum(bool(r.get("cut")) for r in rows),
        "runs": rows,
    }
    cut = f"; {summary['cut']} cut short (wall-clock limit or a stalled env; failures)" if summary["cut"] else ""
    log(f"evaluation: {n_ok}/{len(rows)} successes = {100 * summary['success_rate']:.1f}% "
        f"(95% Wilson interval {100 * lo:.1f}-{100 * hi:.1f}%){cut}")  # fmt: skip
    return summary


def contact_sheet(episodes: list[list[np.ndarray]], path: Path, columns: int = 8) -> None:
    """A grid image (PNG, written atomically): one row per episode, ``columns`` frames spread over it."""
    from PIL import Image

    rows = []
    for frames in episodes:
        pick = np.linspace(0, len(frames) - 1, min(columns, len(frames))).round().astype(int)
        row = [frames[k] for k in pick]
        row += [np.zeros_like(row[0])] * (columns - len(row))
        rows.append(np.concatenate(row, axis=1))
    with atomic_write(path, "wb") as f:
        Image.fromarray(np.concatenate(rows, axis=0)).save(f, format="PNG")
