"""Scripted-expert episodes seen through both renderers, and a policy's open-loop action error on them.

A closed-loop success rate in the ground-truth world takes ~25 minutes per 50 episodes on a 2-core CPU, and two
trainings that differ only in their seed land 20 points apart. The open-loop error is a cheaper screen of the
visual sim-to-real gap: along the expert's own episodes (the states a good policy visits), how far the actions a
policy predicts from the ground-truth world's frames are from the expert's, against the same on the hybrid
frames it was trained on. On the sample, over nine grasp policies, the ground-truth error ranked them much as
their ground-truth success rates did (Spearman -0.72), the hybrid error did not (-0.38); see ``bench policy-gap``.
It scores the states the expert visits, not whether a policy stays near them: a policy trained with per-hue-band
colour gains had the lowest ground-truth error of any (0.065) and lost its way closed loop (1 of 16 episodes, 3 of
10 in its own world), so it ranks policies of one recipe, not recipes.

An episode record (``record_expert_pairs``) is a dict: ``hybrid.<camera>`` and ``ground_truth.<camera>``
uint8 [T+1, S, S, 3] (the observation before each step, and the last), ``state`` float32 [T+1, state_dim],
``action`` float32 [T, action_dim] (the expert's), ``success`` bool, ``seed`` int.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..configs import ranged
from ..datagen import task_slug
from ..env.config import GROUND_TRUTH_TEXTURE_FILTER, hybrid_options
from ..env.episode_cache import load_or_record_episodes
from ..env.lens import LensFrames
from ..policy.data import IMAGE_PREFIX, STATE_KEY
from ..stages import eval_policy
from ..workspace import Workspace
from .sim2real import Sim2RealConfig

__all__ = ["PolicyGapConfig", "load_or_record_pairs", "open_loop_error", "record_expert_pairs", "run_policy_gap"]

Log = Callable[[str], None]
RENDERERS = ("hybrid", "ground_truth")


def record_expert_pairs(
    world: str | Path, task: str, sample_dir: str | Path, seeds: Sequence[int], size: int, hybrid: Any = None
) -> list[dict[str, Any]]:
    """The scripted expert of ``task`` in the twin of ``world`` for each seed (the env's episode seed), every
    observation rendered by the hybrid renderer (what generation writes; ``hybrid``: its ``HybridOptions``, default
    the env's) and by the sample's ground truth."""
    from ..env.ground_truth import GroundTruthFrames
    from ..env.twin_env import TwinEnv

    env = TwinEnv(world, task, size=size, hybrid=hybrid)
    gt = LensFrames.like(env.renderer, env.config.size,
                         lambda size: GroundTruthFrames(env.twin, Path(sample_dir), env.config.cameras, size))
    try:
        return [_record_one(env, gt, int(seed)) for seed in seeds]
    finally:
        gt.close()
        env.close()


def _record_one(env: Any, gt: Any, seed: int) -> dict[str, Any]:
    from ..env.twin_env import STATE_KEY, image_key
    from ..sim.tasks import run_task

    cams = env.config.cameras
    frames: dict[str, list[np.ndarray]] = {f"{r}.{c}": [] for r in RENDERERS for c in cams}
    states: list[np.ndarray] = []
    actions: list[np.ndarray] = []

    def see(o: dict) -> None:
        g = gt.render()
        for c in cams:
            frames[f"hybrid.{c}"].append(o[image_key(c)])
            frames[f"ground_truth.{c}"].append(g[c])
        states.append(np.asarray(o[STATE_KEY], np.float32))

    def act(a: np.ndarray) -> None:
        o, *_ = env.step(a)
        actions.append(np.asarray(a, np.float32))
        see(o)

    see(env.reset(seed=seed)[0])
    res = run_task(env.twin, env.task, np.random.default_rng(env.draw.task_seed), control_hz=env.config.fps, act=act)
    episode: dict[str, Any] = {k: np.stack(v) for k, v in frames.items()}
    episode.update(state=np.stack(states), action=np.stack(actions).reshape(len(actions), -1),
                   success=bool(res.success), seed=seed)  # fmt: skip
    return episode


def load_or_record_pairs(
    folder: Path, world: str | Path, task: str, sample_dir: str | Path, seeds: Sequence[int], size: int, log: Log,
    hybrid: Any = None,
) -> list[dict[str, Any]]:
    """:func:`record_expert_pairs`, each episode cached as ``folder/pair_<seed>.npz`` (written atomically): a
    second call, or one with more seeds, records only what is missing."""
    record = lambda missing: record_expert_pairs(world, task, sample_dir, missing, size, hybrid)
    return load_or_record_episodes(folder, "pair", seeds, record, log, "expert episode(s) through both renderers")


def open_loop_error(policy: Any, episodes: Sequence[dict[str, Any]], stride: int = 2) -> dict[str, float]:
    """{renderer: mean |chunk - expert's actions| in the policy's action-std units} over every ``stride``-th step of
    the expert's successful ``episodes``: at each such step the policy predicts its chunk from that renderer's
    frames and the recorded state, compared with the expert's next actions (as many as the episode still has)."""
    errs: dict[str, list[float]] = {r: [] for r in RENDERERS}
    used = [ep for ep in episodes if ep["success"]]
    if not used:
        raise ValueError("no successful expert episode to compare against")
    std = np.asarray(policy.action_std, np.float64)
    for ep in used:
        actions = ep["action"]
        for r in RENDERERS:
            for t in range(0, len(actions), stride):
                obs = {IMAGE_PREFIX + c: ep[f"{r}.{c}"][t] for c in policy.meta.cameras}
                obs[STATE_KEY] = ep["state"][t]
                chunk = policy.predict_chunk(obs)
                k = min(len(chunk), len(actions) - t)
                errs[r].append(float(np.abs((chunk[:k] - actions[t : t + k]) / std).mean()))
    return {r: float(np.mean(v)) for r, v in errs.items()}


@dataclass
class PolicyGapConfig:
    """bench policy-gap settings.

    task          the expert's task
    episodes      expert episodes
    seed          episode seed of the first
    size          frame side
    stride        compare every K-th step
    ground_truth  the sample folder (default: the workspace's capture's, e.g. samples/tabletop)
    """

    task: str = "grasp banana"
    episodes: int = ranged(10, ge=1, metadata={"metavar": "N"})
    seed: int = 2_000_000
    size: int = ranged(Sim2RealConfig.size, ge=16, metadata={"metavar": "PX"})  # sim2real's frames
    stride: int = ranged(2, ge=1, metadata={"metavar": "K"})
    ground_truth: Path | None = field(default=None, metadata={"metavar": "DIR"})


def run_policy_gap(ws: Workspace, gap: PolicyGapConfig, policy_refs: list[str], log: Callable[[str], None] = print
                   ) -> dict[str, Any]:  # fmt: skip
    """Record (or load) the expert's episodes through both renderers and score each policy (``policy_refs``: names
    under the workspace's policies or folders) on them -> the JSON-ready result."""
    from ..env.twin_env import make_config

    cfg = eval_policy.Config(task=gap.task, renderer="ground_truth", ground_truth=gap.ground_truth)
    gt = eval_policy.ground_truth_dir(ws, cfg)
    world = make_config(ws.committed.world_dir, gap.task, size=gap.size).world  # the task and world, checked
    policies = {}
    for ref in policy_refs:  # every policy opened and checked against the robot before the long recording
        if not eval_policy.policy_paths(ws, replace(cfg, policy=ref)):
            raise eval_policy.PolicyError(f"bench policy-gap: {ref!r} is a callable; it needs a trained policy (the "
                                          "error is in its action-std units)")  # fmt: skip
        policies[ref] = eval_policy.open_policy(ws, replace(cfg, policy=ref), world)
    seeds = list(range(gap.seed, gap.seed + gap.episodes))
    # the hybrid frames as each policy's demos drew them (the robot's look, the splats' supersampling): policies
    # drawn alike share one recording
    drawn: dict[tuple[int, str], list[str]] = {}
    for ref in policy_refs:
        as_drawn = replace(cfg, policy=ref, renderer="hybrid")
        drawn.setdefault((eval_policy.supersample_of(ws, as_drawn), eval_policy.robot_look_of(ws, as_drawn)),
                         []).append(ref)  # fmt: skip
    # keyed on the world's description (a world composed again records anew) and on the ground truth drawn
    world_id = hashlib.sha256(ws.committed.world_yaml.read_bytes()).hexdigest()[:8]
    gt_id = hashlib.sha256((gt / "ground_truth.json").read_bytes()).hexdigest()[:8]
    rows, ok, n_episodes = {}, 0, 0
    for (supersample, look), refs in drawn.items():
        name = f"{task_slug(gap.task)}-{gap.size}px-{world_id}-gt{gt_id}-{GROUND_TRUTH_TEXTURE_FILTER}"
        name += ("-mesh_robot" if look == "mesh" else "") + (f"-ss{supersample}" if supersample > 1 else "")
        folder = ws.evals_dir / "expert_pairs" / name
        hybrid = hybrid_options(cfg.objects, supersample, look)
        episodes = load_or_record_pairs(folder, ws.committed.world_dir, gap.task, gt, seeds, gap.size, log=log,
                                        hybrid=hybrid)  # fmt: skip
        ok, n_episodes = sum(bool(e["success"]) for e in episodes), len(episodes)
        log(f"expert: {ok}/{n_episodes} episodes succeeded (only those are compared)")
        if not ok:
            raise eval_policy.PolicyError(f"bench policy-gap: the scripted expert failed all {n_episodes} episodes "
                                          f"of {gap.task!r} in this world ({folder}); check it with `m2m task -w "
                                          f"{ws.root} {gap.task!r}`")  # fmt: skip
        for ref in refs:
            err = open_loop_error(policies[ref], episodes, stride=gap.stride)
            gap_ = round(err["ground_truth"] - err["hybrid"], 5)
            rows[ref] = {**{k: round(v, 5) for k, v in err.items()}, "gap": gap_, "robot_look": look,
                         "supersample": supersample}  # fmt: skip
            log(f"{ref}: open-loop error hybrid {err['hybrid']:.4f}, ground truth {err['ground_truth']:.4f}")
    result = {"task": gap.task, "episodes": n_episodes, "expert_successes": ok, "size": gap.size,
              "stride": gap.stride, "seeds": [seeds[0], seeds[-1]], "policies": rows}  # fmt: skip
    return result
