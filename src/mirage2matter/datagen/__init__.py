"""Demonstration generation: episodes from the simulated world, hybrid-rendered, run in parallel
workers (processes or Ray) and written as a LeRobot dataset."""

from .generate import GenerateError, RunConfig, check_output, generate_dataset
from .runner import Attempt, EpisodeSource, RunnerError, attempt_seed, connect_ray, run_attempts

__all__ = [
    "Attempt",
    "EpisodeSource",
    "GenerateError",
    "RunConfig",
    "RunnerError",
    "attempt_seed",
    "check_output",
    "connect_ray",
    "generate_dataset",
    "run_attempts",
]
