"""Demonstration generation: episodes from the simulated world, hybrid-rendered, run in parallel
workers (processes or Ray) and written as a LeRobot dataset.

``generate(world, task, out, GenerateConfig(...))`` takes a loaded world and a parsed task (no workspace
paths); ``generate_dataset`` is the procedure behind it for any episode source. Several tasks share one
``worker_pool(cfg)`` (``generate(..., pool=pool)``): their workers build the twin once."""

from .config import GenerateConfig, Randomization
from .dataset import GenerateError, RunConfig, check_output, generate_dataset
from .ray_workers import connect_ray
from .runner import Attempt, EpisodeSource, RunnerError, WorkerPool, attempt_seed, run_attempts
from .simulated import dataset_fingerprint, generate, task_slug, worker_pool

__all__ = [
    "Attempt",
    "EpisodeSource",
    "GenerateConfig",
    "GenerateError",
    "Randomization",
    "RunConfig",
    "RunnerError",
    "WorkerPool",
    "attempt_seed",
    "check_output",
    "connect_ray",
    "dataset_fingerprint",
    "generate",
    "generate_dataset",
    "run_attempts",
    "task_slug",
    "worker_pool",
]
