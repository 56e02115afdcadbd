"""Evaluation episodes on Ray workers (``m2m eval-policy --ray-address``), on a cluster that shares nothing with the
driver - as generation's workers (``datagen.ray_workers``):

- the job (the environment's configuration and how to open the policy, :class:`EvalJob`) goes into the object store
  once, with the files it reads as content (the world's, the policy checkpoints', a sample's ground truth:
  ``datagen.shipping``); each worker unpacks them on its own machine and builds its environment and policy once;
- the package reaches the workers through ``runtime_env`` and their version is checked before any episode runs
  (``ray_cluster``); a worker asks for a CPU and a GPU share when its splats or its policy run on CUDA;
- a worker runs one episode per seed (``evaluation.run_episode``: a function of the seed alone, so the records are a
  local run's) and returns its record (and pictures, for the episodes shown); the driver keeps the records
  (``on_episode``: the stage appends each to episodes.jsonl, so a killed evaluation resumes as a local one does);
- a worker that dies (its process or its node) is replaced and its episode runs again, up to ``max_retries`` times.

What may differ from a local run: the ``seconds`` / ``timings`` of each record (wall-clock), and a trained policy
with ``device auto`` runs on the CPU of a worker without a GPU share where a local run would use this machine's GPU.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from mirage2matter.datagen.worker import local_factory

from .datagen.shipping import ShippedFactory, pack_under, world_files
from .env.config import EnvConfig
from .errors import M2MError
from .evaluation import run_episode, summarize
from .policy.config import POLICY_FILE
from .progress import progress_bar
from .ray_cluster import (
    ActorCalls,
    ClusterError,
    RayOptions,
    RayResources,
    actor_info,
    actor_threads,
    connect_ray,
    m2m_env,
    splat_resources,
)

__all__ = ["EvalJob", "PolicyRecipe", "evaluate_on_ray"]


@dataclass(frozen=True)
class PolicyRecipe:
    """How to open the evaluated policy, on any machine: trained policies' folders (one, or several as an ensemble)
    or a callable (a ``module:function`` of a module installed where it runs, or a function of a ``.py`` file, which
    travels with the job).

    paths          folders of trained policies (absolute)
    function       ``module:function`` or ``file.py:function`` when ``paths`` is empty
    function_file  that ``file.py``, absolute (what shipping renames on a worker), else None
    how            load_policy's device / replan_every / ensemble_decay
    combine        an ensemble's combination
    check          the robot, rate and cameras the policy must match (``Policy.check_matches``)
    """

    paths: tuple[str, ...] = ()
    function: str | None = None
    function_file: str | None = None
    action_dim: int | None = None
    how: dict[str, Any] = field(default_factory=dict)
    combine: str = "mean"
    check: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def of_callable(cls, ref: str, action_dim: int | None) -> PolicyRecipe:
        module = ref.rpartition(":")[0]
        return cls(function=ref, function_file=str(Path(module).resolve()) if module.endswith(".py") else None,
                   action_dim=action_dim)  # fmt: skip

    def open(self) -> Any:
        from .policy import load_ensemble, load_policy, load_policy_callable

        if not self.paths:
            ref = self.function or ""
            if self.function_file is not None:
                ref = f"{self.function_file}:{ref.rpartition(':')[2]}"
            return load_policy_callable(ref, action_dim=self.action_dim)
        policy = (load_policy(self.paths[0], **self.how) if len(self.paths) == 1
                  else load_ensemble(list(self.paths), combine=self.combine, **self.how))  # fmt: skip
        policy.check_matches(**self.check)
        return policy

    def files(self) -> tuple[list[Path], list[Path]]:
        """(what opening it reads: each policy's deployable checkpoint (else its folder), a callable's file; the
        folders they lie under)."""
        files = [Path(p) / POLICY_FILE if (Path(p) / POLICY_FILE).is_file() else Path(p) for p in self.paths]
        files += [Path(self.function_file)] if self.function_file else []
        return files, [f.parent for f in files]


@dataclass(frozen=True, eq=False)
class EvalJob:
    """What an evaluation worker builds once (the environment, the policy) and how it runs an episode."""

    env: EnvConfig
    policy: PolicyRecipe
    camera: str | None = None
    max_episode_seconds: float | None = None

    def build(self) -> tuple[Any, Any]:
        from .env.twin_env import TwinEnv

        policy = self.policy.open()  # before the twin: a policy that does not open costs no build
        return TwinEnv.from_config(self.env), policy

    def files(self) -> tuple[list[Path], list[Path]]:
        """(the files the episodes read, the folders they lie under): the world's (under its workspace), the policy's,
        and the ground_truth renderer's sample (its ground_truth.json: the sample's world is built from it)."""
        policy_files, policy_homes = self.policy.files()
        files = world_files(self.env.world) + policy_files
        origins = [self.env.world.root.parent, *policy_homes]
        if self.env.ground_truth is not None:
            files.append(Path(self.env.ground_truth) / "ground_truth.json")
            origins.append(Path(self.env.ground_truth))
        return files, origins

    def portable(self) -> Any:
        """This job with its files as content (``datagen.shipping``), for workers on machines that do not see this
        one's disk; a file that cannot be read is a ShipError here, before any worker starts."""
        job = self
        if self.env.ground_truth is not None:  # absolute: shipping renames absolute paths only
            job = replace(self, env=replace(self.env, ground_truth=Path(self.env.ground_truth).resolve()))
        shipments = pack_under(*job.files())
        return ShippedFactory(job, shipments[0], shipments[1:]) if shipments else job

    def resources(self) -> RayResources:
        return splat_resources(self.env.hybrid.splat.backend, cuda=self.policy.how.get("device") == "cuda")


def _actor_class(ray):
    @ray.remote
    class EvalWorker:
        """Builds the environment and the policy of the job it is started with (a one-element list: Ray leaves the
        reference unresolved there, so the job's content is fetched here), then runs one episode per call."""

        def __init__(self, job_ref: list, num_cpus: float):
            actor_threads(num_cpus)
            self.job = local_factory(ray.get(job_ref[0]))
            self.env, self.policy = self.job.build()

        def ready(self) -> dict[str, Any]:
            return actor_info(ray)

        def run(self, seed: int, keep: bool) -> tuple[dict[str, Any], np.ndarray | None]:
            row, frames = run_episode(self.env, self.policy, seed, keep=keep, camera=self.job.camera,
                                      max_episode_seconds=self.job.max_episode_seconds)  # fmt: skip
            return row, (np.stack(frames) if frames is not None else None)

    return EvalWorker


def evaluate_on_ray(
    job: EvalJob,
    episodes: int,
    address: str,
    workers: int = 1,
    seed: int = 0,
    log: Callable[[str], None] = print,
    progress: bool = True,
    keep_frames: int = 2,
    done: list[dict] | None = None,
    on_episode: Callable[[dict], None] | None = None,
    options: RayOptions | None = None,
) -> tuple[dict[str, Any], list[list[np.ndarray]]]:
    """:func:`evaluation.evaluate_policy` with its episodes on ``workers`` Ray workers at ``address`` (``local``,
    ``auto``, ``host:port``): the same summary and pictures (those of the first ``keep_frames`` episodes run by this
    call); ``on_episode(record)`` in this process as each episode comes back (in any order)."""
    options = options or RayOptions()
    rows = list(done or [])
    seen = {int(r["seed"]) for r in rows}
    todo = [seed + i for i in range(episodes) if seed + i not in seen]
    if not todo:
        return summarize(rows, log), []
    keep = set(todo[:keep_frames])
    portable = job.portable()  # the files read here, before Ray starts: a world no node can read fails now
    ray = connect_ray(address, workers)
    cls, res = _actor_class(ray), job.resources()
    ref = ray.put(portable)
    opts = {"num_cpus": res.num_cpus, "num_gpus": res.num_gpus, "max_restarts": 0,
            "runtime_env": {"env_vars": m2m_env()}}  # fmt: skip
    calls = ActorCalls(ray, lambda: cls.options(**opts).remote([ref], res.num_cpus), min(workers, len(todo)), res,
                       options.max_retries, options.start_timeout_s)  # fmt: skip
    frames: dict[int, list[np.ndarray]] = {}
    try:
        calls.start()
        log(f"evaluation: {len(todo)} episode(s) on {calls.n} Ray worker(s) at {address}")
        for s in todo:
            calls.submit(lambda actor, s=s: actor.run.remote(s, s in keep), f"episode {s}")
        bar = progress_bar(total=len(todo), desc="evaluation", unit="ep", disable=not progress, leave=False)
        for _ in todo:
            try:
                _, (row, pictures) = calls.next_result()
            except ray.exceptions.RayTaskError as e:  # the episode itself failed: as it would here
                cause = getattr(e, "cause", None)
                if isinstance(cause, M2MError):
                    raise cause from None
                raise ClusterError(f"an evaluation worker failed: {e}") from None
            if pictures is not None:
                frames[int(row["seed"])] = list(pictures)
            rows.append(row)
            if on_episode is not None:
                on_episode(row)
            bar.update(1)
            bar.set_postfix(success=f"{sum(r['success'] for r in rows)}/{len(rows)}")
        bar.close()
        if calls.rerun:
            log(f"evaluation: {calls.rerun} episode(s) ran again after their Ray worker died")
    finally:
        calls.close()
    return summarize(rows, log), [frames[s] for s in sorted(frames)]
