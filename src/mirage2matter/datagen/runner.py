"""Running episode attempts: in-process, in local worker processes, or on Ray.

An *episode source* is whatever turns (attempt index, seed) into an :class:`Attempt`; a worker
builds one source once (for the simulator: the Genesis twin and the splat world) and then runs
many attempts with it. Sources are made by a picklable zero-argument *factory* so the same code
runs in a worker process or a Ray actor.

A worker runs an attempt and encodes it (videos, frame table, record: ``export.staging.encode_attempt``) and returns
it as content; the parent commits it into the staging area (``write_attempt``), so workers write nothing on the
parent's disk and may run on other machines (Ray; the world reaches them as content, datagen/shipping.py).

Which attempts run is fixed by the seeds alone: attempt k uses
``attempt_seed(seed, k)``, attempts are handed out in order, and a new one starts only while the
successes so far plus the attempts in flight are fewer than wanted. The attempts that run are then
always the shortest prefix 0..K-1 holding the wanted number of successes, whatever the runner,
the worker count or the timing, and a resumed run continues the same prefix.

A :class:`WorkerPool` keeps its workers across runs (one dataset per task): a worker built for one run serves the
next run's attempts by retargeting its source (``retarget``), so the start-up is paid once.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import time
import traceback
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.reduction import ForkingPickler
from pathlib import Path
from typing import Any

from .. import configure_threads
from ..export.staging import write_attempt
from ..processes import die_with_parent
from .ray_workers import RayWorkers
from .worker import Attempt, EpisodeSource, Job, RunnerError, Server, SourceFactory, attempt_seed

__all__ = ["Attempt", "EpisodeSource", "Job", "RunStats", "RunnerError", "SourceFactory", "WorkerPool",
           "attempt_seed", "commit", "run_attempts"]


# ---- backends: start(job) (blocks until every worker has built its source), submit, next_result -----------
def commit(staging_root: Path, ran: dict[str, Any]) -> dict[str, Any]:
    """Commit an attempt a worker ran (``worker.run_attempt``) into the staging area, in the parent; returns its
    result record with where its time went (not written: the timings of the run that made it)."""
    t = time.time()
    committed = dict(write_attempt(staging_root, ran["result"], ran["files"]))
    committed["timings"] = {**committed.get("timings", {}), "commit": ran["encode_s"] + time.time() - t}
    committed.update(t_start=ran["t_start"], t_end=ran["t_end"] + time.time() - t, cpu_s=ran["cpu_s"],
                     worker=ran["worker"], worker_end=ran["t_end"])  # fmt: skip
    return committed


class _Inline:
    name = "inline"

    def __init__(self):
        self.pending: list[tuple[Job, int, int]] = []
        self.server: Server | None = None

    def start(self, job: Job) -> None:
        self.server = Server(job)

    def submit(self, job: Job, attempt: int, seed: int) -> None:
        self.pending.append((job, attempt, seed))

    def next_result(self) -> dict[str, Any]:
        return self.server.run(*self.pending.pop(0))

    def close(self) -> None:
        self.pending.clear()
        if self.server is not None:
            self.server.close()


def _worker_main(job, threads, tasks, results, parent) -> None:  # runs in a worker process
    die_with_parent(parent)  # also exits if the parent died before prctl took effect
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    os.environ.setdefault("LP_NUM_THREADS", str(threads))  # Mesa llvmpipe: one GL thread per core we own
    try:
        configure_threads(threads)
        server = Server(job)
        results.put(("ready", os.getpid(), None))
    except BaseException:
        results.put(("error", os.getpid(), traceback.format_exc()))
        return
    while True:
        item = tasks.get()
        if item is None:
            return
        job_or_key, attempt, seed = item
        this = job if isinstance(job_or_key, str) else job_or_key  # a key: the job this worker was spawned with
        try:
            results.put(("result", os.getpid(), server.run(this, attempt, seed)))
        except BaseException:
            results.put(("error", os.getpid(), traceback.format_exc()))
            return


class _Processes:
    """W spawned worker processes (spawn: Genesis and numba do not survive fork) fed by a queue."""

    name = "process"

    def __init__(self, workers: int):
        self.ctx = mp.get_context("spawn")
        self.n = workers
        self.tasks = self.ctx.Queue()
        self.results = self.ctx.Queue()
        self.procs: list = []

    def start(self, job: Job) -> None:
        self.job = job  # the workers hold it from their spawn on: its attempts travel as its key
        self._sendable: set[str] = set()
        threads = max(1, (os.cpu_count() or 1) // self.n)
        # a source that starts a child of its own (the ground-truth renderer's stall guard, processes.TimedWorker)
        # needs a worker that is not daemonic; it still dies with this process (die_with_parent), close() ends it
        daemon = not getattr(job.factory, "starts_children", False)
        for _ in range(self.n):
            args = (job, threads, self.tasks, self.results, os.getpid())
            p = self.ctx.Process(target=_worker_main, args=args, daemon=daemon)
            p.start()
            self.procs.append(p)
        ready = 0
        while ready < self.n:
            kind, pid, payload = self._get()
            if kind == "ready":
                ready += 1
            else:
                raise RunnerError(f"worker {pid} failed while starting:\n{payload}")

    def _get(self):
        while True:
            try:
                return self.results.get(timeout=1.0)
            except queue.Empty:
                dead = [p for p in self.procs if not p.is_alive()]
                if dead:
                    raise RunnerError(f"worker process {dead[0].pid} died (exit code {dead[0].exitcode}) "
                                      "without reporting an error; out of memory?") from None  # fmt: skip

    def submit(self, job: Job, attempt: int, seed: int) -> None:
        # The workers' own job goes by its key: its factory may hold what pickles only into a process as it is
        # spawned (a splat server's queues and shared buffers). Another job (a pool's next run) travels whole, checked
        # here once: the queue pickles in a feeder thread that drops what it cannot pickle, unseen, and the run would
        # wait for that attempt forever.
        if job.key == self.job.key:
            self.tasks.put((job.key, attempt, seed))
            return
        if job.key not in self._sendable:
            try:
                ForkingPickler.dumps(job)
            except Exception as e:
                raise RunnerError(f"this run's episode source cannot be sent to workers started for another run "
                                  f"({type(e).__name__}: {e}); give it workers of its own") from None  # fmt: skip
            self._sendable.add(job.key)
        self.tasks.put((job, attempt, seed))

    def next_result(self) -> dict[str, Any]:
        kind, pid, payload = self._get()
        if kind != "result":
            raise RunnerError(f"worker {pid} failed:\n{payload}")
        return payload

    def close(self) -> None:
        for _ in self.procs:
            self.tasks.put(None)
        for p in self.procs:
            p.join(timeout=10)
            if p.is_alive():
                p.kill()


class WorkerPool:
    """Workers (in-process, local processes, or Ray actors) kept for several runs, e.g. one dataset per task: each
    worker builds its source once, on the first run's job, and moves it to a later run's job (``Server``), so the
    runs pay one start-up (Genesis build, kernel and renderer warm-up) instead of one each. Starts on the first
    attempt handed to it (none at all when every dataset is already done); ``close`` (or leaving the ``with``)
    stops the workers. A run that fails closes the pool (its workers may still hold the failed run's attempts); a
    later run starts it again."""

    def __init__(self, workers: int = 1, ray_address: str | None = None):
        self.workers, self.ray_address = max(int(workers), 1), ray_address
        self.backend: Any = None

    @property
    def name(self) -> str:
        return "ray" if self.ray_address else "process" if self.workers > 1 else "inline"

    @property
    def running(self) -> bool:
        """Whether the workers are up (a run handed to it now pays no start-up)."""
        return self.backend is not None

    def start(self, job: Job) -> None:
        """Start the workers on ``job`` unless they are running."""
        if self.running:
            return
        if self.ray_address:
            backend: Any = RayWorkers(self.workers, self.ray_address)
        elif self.workers > 1:
            backend = _Processes(self.workers)
        else:
            backend = _Inline()
        try:
            backend.start(job)
        except BaseException:
            backend.close()
            raise
        self.backend = backend

    def submit(self, job: Job, attempt: int, seed: int) -> None:
        self.backend.submit(job, attempt, seed)

    def next_result(self) -> dict[str, Any]:
        return self.backend.next_result()

    def close(self) -> None:
        backend, self.backend = self.backend, None
        if backend is not None:
            backend.close()

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ---- the attempt loop ---------------------------------------------------------------------------------
@dataclass
class RunStats:
    backend: str
    workers: int
    startup_s: float  # building the sources (twins), before the first attempt
    wall_s: float  # from all workers ready to the last result
    results: dict[int, dict[str, Any]]  # every committed attempt (this run's and earlier ones')
    selected: list[int]  # the attempts that become episodes, in order
    new_attempts: int  # attempts run by this call


def run_attempts(
    factory: SourceFactory,
    staging,
    episodes: int,
    seed: int,
    max_attempts: int,
    workers: int = 1,
    ray_address: str | None = None,
    progress: Callable[[dict[str, Any]], None] | None = None,
    pool: WorkerPool | None = None,
) -> RunStats:
    """Run attempts until ``episodes`` successes (or ``max_attempts`` attempts) are committed in
    ``staging``; attempts already committed there (a killed earlier run) are not run again. ``pool``: workers
    kept across runs (then ``workers`` and ``ray_address`` are the pool's); None: this run's own, closed at its end."""
    done = staging.committed()
    own = pool is None
    if pool is None:
        pool = WorkerPool(workers, ray_address)
    job = Job(factory, uuid.uuid4().hex)

    def successes() -> int:
        return sum(1 for r in done.values() if r.get("success"))

    t0 = time.time()
    t_ready = None
    in_flight: set[int] = set()
    new = 0
    try:
        nxt = 0
        while True:
            while len(in_flight) < pool.workers and nxt < max_attempts and successes() + len(in_flight) < episodes:
                if nxt in done:
                    nxt += 1
                    continue
                if t_ready is None:
                    pool.start(job)  # a no-op for a shared pool already running: no start-up in this run
                    t_ready = time.time()
                pool.submit(job, nxt, attempt_seed(seed, nxt))
                in_flight.add(nxt)
                nxt += 1
            if not in_flight:
                break
            r = commit(Path(staging.root), pool.next_result())  # here, in the parent: workers write nothing
            in_flight.discard(r["attempt"])
            done[r["attempt"]] = r
            new += 1
            if progress is not None:
                progress(r)
    except BaseException:
        pool.close()  # a shared pool too: its workers may still hold this run's attempts
        raise
    if own:
        pool.close()
    t_end = time.time()
    if t_ready is None:
        t_ready = t_end
    ok = sorted(a for a, r in done.items() if r.get("success"))[:episodes]
    return RunStats(pool.name, pool.workers, t_ready - t0, t_end - t_ready, done, ok, new)
