"""Demonstration generation: episodes from the simulated world, hybrid-rendered, run in parallel
workers (processes or Ray) and written as a LeRobot dataset.

``generate(world, task, out, GenerateConfig(...))`` takes a loaded world and a parsed task (no workspace
paths); ``generate_dataset`` is the procedure behind it for any episode source."""

from .config import GenerateConfig, Randomization
from .dataset import GenerateError, RunConfig, check_output, generate_dataset
from .runner import Attempt, EpisodeSource, RunnerError, attempt_seed, connect_ray, run_attempts
from .simulated import BENCH_KEYS, bench_datagen, dataset_fingerprint, generate, task_slug

__all__ = [
    "BENCH_KEYS",
    "Attempt",
    "EpisodeSource",
    "GenerateConfig",
    "GenerateError",
    "Randomization",
    "RunConfig",
    "RunnerError",
    "attempt_seed",
    "bench_datagen",
    "check_output",
    "connect_ray",
    "dataset_fingerprint",
    "generate",
    "generate_dataset",
    "run_attempts",
    "task_slug",
]
