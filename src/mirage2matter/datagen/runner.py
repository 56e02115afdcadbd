"""Running episode attempts: in-process, in local worker processes, or on Ray.

An *episode source* is whatever turns (attempt index, seed) into an :class:`Attempt`; a worker
builds one source once (for the simulator: the Genesis twin and the splat world) and then runs
many attempts with it. Sources are made by a picklable zero-argument *factory* so the same code
runs in a worker process or a Ray actor.

Every attempt is committed to the staging area by the worker that ran it (export/staging.py), so
the parent only keeps counts. Which attempts run is fixed by the seeds alone: attempt k uses
``attempt_seed(seed, k)``, attempts are handed out in order, and a new one starts only while the
successes so far plus the attempts in flight are fewer than wanted. The attempts that run are then
always the shortest prefix 0..K-1 holding the wanted number of successes, whatever the runner,
the worker count or the timing, and a resumed run continues the same prefix.

A :class:`WorkerPool` keeps its workers across runs (one dataset per task): a worker built for one run serves the
next run's attempts by retargeting its source (``retarget``), so the start-up is paid once.
"""

from __future__ import annotations

import os
import queue
import time
import traceback
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..errors import M2MError
from ..export.spec import DatasetSpec, EpisodeData
from ..export.staging import commit_attempt
from ..processes import die_with_parent


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


def _run_and_commit(source: EpisodeSource, staging_root: Path, attempt: int, seed: int) -> dict[str, Any]:
    t0, cpu0 = time.time(), time.process_time()
    out = source.run(attempt, seed)
    t1 = time.time()
    result = {"seed": seed, "success": out.success, "reason": out.reason, "record": out.record,
              "timings": dict(out.timings)}  # fmt: skip
    committed = commit_attempt(staging_root, source.spec, attempt, result, out.episode if out.success else None)
    committed["timings"]["commit"] = time.time() - t1
    # CPU seconds of this process (its GL and numba threads included): the cost of an attempt however
    # busy the machine is with other work.
    committed.update(t_start=t0, t_end=time.time(), cpu_s=time.process_time() - cpu0, worker=os.getpid())
    return committed


# ---- backends: start(job) (blocks until every worker has built its source), submit, next_result -----------
@dataclass(frozen=True)
class Job:
    """One run's attempts: the factory of its source, the staging folder its attempts are committed to, and a key
    naming the run (a worker serving another key moves its source over)."""

    factory: SourceFactory
    staging_root: Path
    key: str


class _Server:
    """A worker's source and the job it serves. A pool's workers serve one dataset's job after another: a source
    with ``retarget(factory) -> bool`` takes the next job's episodes over when it can (the simulator: the same world
    and frames, another task; nothing rebuilt), otherwise a new one is built from the job's factory."""

    def __init__(self, job: Job):
        self.source, self.key = job.factory(), job.key

    def run(self, job: Job, attempt: int, seed: int) -> dict[str, Any]:
        if job.key != self.key:
            retarget = getattr(self.source, "retarget", None)
            if retarget is None or not retarget(job.factory):
                self.close()
                self.source = job.factory()
            self.key = job.key
        return _run_and_commit(self.source, job.staging_root, attempt, seed)

    def close(self) -> None:
        close = getattr(self.source, "close", None)
        if close is not None:
            close()


class _Inline:
    name = "inline"

    def __init__(self):
        self.pending: list[tuple[Job, int, int]] = []
        self.server: _Server | None = None

    def start(self, job: Job) -> None:
        self.server = _Server(job)

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
        from .. import configure_threads

        configure_threads(threads)
        server = _Server(job)
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
        import multiprocessing as mp

        self.ctx = mp.get_context("spawn")
        self.n = workers
        self.tasks = self.ctx.Queue()
        self.results = self.ctx.Queue()
        self.procs: list = []

    def start(self, job: Job) -> None:
        self.job = job  # the workers hold it from their spawn on: its attempts travel as its key
        self._sendable: set[str] = set()
        threads = max(1, (os.cpu_count() or 1) // self.n)
        for _ in range(self.n):
            args = (job, threads, self.tasks, self.results, os.getpid())
            p = self.ctx.Process(target=_worker_main, args=args, daemon=True)
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
            from multiprocessing.reduction import ForkingPickler

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


class _Ray:
    """One Ray actor per worker; each builds its source once in its constructor."""

    name = "ray"

    def __init__(self, workers: int, address: str):
        self.n, self.address = workers, address
        self.futures: dict = {}
        self.idle: list = []

    def start(self, job: Job) -> None:
        self.ray = connect_ray(self.address, self.n)

        @self.ray.remote(num_cpus=1)
        class Worker:
            def __init__(self, job):
                os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
                from mirage2matter import configure_threads

                configure_threads(1)
                self.server = _Server(job)

            def ready(self) -> int:
                return os.getpid()

            def run(self, job, attempt, seed):
                return self.server.run(job, attempt, seed)

        self.actors = [Worker.remote(job) for _ in range(self.n)]
        try:
            self.ray.get([a.ready.remote() for a in self.actors])
        except Exception as e:
            raise RunnerError(f"a Ray worker failed while starting: {e}") from None
        self.idle = list(self.actors)

    def submit(self, job: Job, attempt: int, seed: int) -> None:
        actor = self.idle.pop()
        self.futures[actor.run.remote(job, attempt, seed)] = actor

    def next_result(self) -> dict[str, Any]:
        done, _ = self.ray.wait(list(self.futures), num_returns=1)
        actor = self.futures.pop(done[0])
        self.idle.append(actor)
        try:
            return self.ray.get(done[0])
        except Exception as e:
            raise RunnerError(f"a Ray worker failed: {e}") from None

    def close(self) -> None:
        for a in getattr(self, "actors", []):
            self.ray.kill(a)


class WorkerPool:
    """Workers (in-process, local processes, or Ray actors) kept for several runs, e.g. one dataset per task: each
    worker builds its source once, on the first run's job, and moves it to a later run's job (``_Server``), so the
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
            backend: Any = _Ray(self.workers, self.ray_address)
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


def connect_ray(address: str, workers: int = 1):
    """``local``: start a private Ray instance on this machine; ``auto`` or ``host:port``: join that
    cluster. A cluster that does not answer raises RunnerError (after at most ~10 s)."""
    try:
        import ray
    except ImportError:
        raise RunnerError("--ray-address needs the `ray` package (pip install ray)") from None
    if ray.is_initialized():
        return ray
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "ignore_reinit_error": True}
    if address == "local":
        kwargs["num_cpus"] = max(workers, 1)
    else:
        if address != "auto" and not _answers(address):
            raise RunnerError(f"no Ray cluster answers at {address}; start one with `ray start --head` "
                              "or use --ray-address local for a private instance")  # fmt: skip
        kwargs["address"] = address
    # Workers must import this package the way the driver does.
    src = str(Path(__file__).resolve().parents[2])
    kwargs["runtime_env"] = {"env_vars": {"PYTHONPATH": os.pathsep.join([src, os.environ.get("PYTHONPATH", "")])}}
    try:
        ray.init(**kwargs)
    except (ConnectionError, RuntimeError, ValueError) as e:
        raise RunnerError(f"cannot reach a Ray cluster at {address!r}: {e}") from None
    return ray


def _answers(address: str, timeout: float = 5.0) -> bool:
    import socket

    host, _, port = address.rpartition(":")
    if address.startswith("ray://"):
        host, _, port = address[len("ray://") :].rpartition(":")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout):
            return True
    except (OSError, ValueError):
        return False


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
    job = Job(factory, Path(staging.root), uuid.uuid4().hex)

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
            r = pool.next_result()
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
