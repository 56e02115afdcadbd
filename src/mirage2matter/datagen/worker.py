"""What a worker does, wherever it runs (in the parent, a local process, a Ray actor): builds its episode source
once from a job's factory, runs attempts with it and encodes each into content (result record + files) that it
returns; it writes nothing on the parent's disk (``runner.commit`` does, in the parent)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ..errors import M2MError
from ..export.spec import DatasetSpec, EpisodeData
from ..export.staging import encode_attempt


class RunnerError(M2MError, RuntimeError):
    """A worker failed (crashed, raised, or Ray could not be reached); the message says which and why."""


@dataclass
class Attempt:
    """What one attempt produced: an episode (success) or a reason (failure), with the record of
    its randomisation and where its time went (seconds per stage)."""

    success: bool
    reason: str = ""
    episode: EpisodeData | None = None
    record: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)


class EpisodeSource(Protocol):
    spec: DatasetSpec

    def run(self, attempt: int, seed: int) -> Attempt: ...


SourceFactory = Callable[[], EpisodeSource]


def attempt_seed(seed: int, attempt: int) -> int:
    """The seed of attempt ``attempt`` of a run seeded ``seed`` (independent streams per attempt)."""
    return int(np.random.SeedSequence([int(seed), int(attempt)]).generate_state(1, np.uint32)[0])


def run_attempt(source: EpisodeSource, attempt: int, seed: int) -> dict[str, Any]:
    """Run and encode one attempt, in the worker: its result record and files (``runner.commit`` commits them)."""
    t0, cpu0 = time.time(), time.process_time()
    out = source.run(attempt, seed)
    t1 = time.time()
    result = {"seed": seed, "success": out.success, "reason": out.reason, "record": out.record,
              "timings": dict(out.timings)}  # fmt: skip
    result, files = encode_attempt(source.spec, attempt, result, out.episode if out.success else None)
    # CPU seconds of this process (its GL and numba threads included): the cost of an attempt however
    # busy the machine is with other work.
    return {"result": result, "files": files, "encode_s": time.time() - t1, "t_start": t0, "t_end": time.time(),
            "cpu_s": time.process_time() - cpu0, "worker": os.getpid()}  # fmt: skip


@dataclass(frozen=True)
class Job:
    """One run's attempts: the factory of its source and a key naming the run (a worker serving another key moves
    its source over)."""

    factory: SourceFactory
    key: str


def local_factory(factory: Any) -> Any:
    """The factory as this machine builds it: a shipped one (datagen/shipping.py) with its files unpacked here."""
    local = getattr(factory, "local", None)
    return local() if local is not None else factory


class Server:
    """A worker's source and the job it serves. A pool's workers serve one dataset's job after another: a source
    with ``retarget(factory) -> bool`` takes the next job's episodes over when it can (the simulator: the same world
    and frames, another task; nothing rebuilt), otherwise a new one is built from the job's factory."""

    def __init__(self, job: Job):
        self.source, self.key = local_factory(job.factory)(), job.key

    def run(self, job: Job, attempt: int, seed: int) -> dict[str, Any]:
        if job.key != self.key:
            factory = local_factory(job.factory)
            retarget = getattr(self.source, "retarget", None)
            if retarget is None or not retarget(factory):
                self.close()
                self.source = factory()
            self.key = job.key
        return run_attempt(self.source, attempt, seed)

    def close(self) -> None:
        close = getattr(self.source, "close", None)
        if close is not None:
            close()
