"""The workers as Ray actors, on a cluster that shares nothing with the driver.

- The package reaches the actors through Ray's ``runtime_env`` (``py_modules``: this package's folder, uploaded once
  by content, set where ``connect_ray`` joins the cluster; a caller that initialises Ray itself passes
  ``package_runtime_env()`` or has the package installed on every node), and each actor reports its version at
  start: a mismatch is an error before any episode runs.
- A run's job (its source factory; the world's files as content, :mod:`.shipping`) goes into the object store once;
  an actor fetches it when it starts and when the pool moves to the next run, not per attempt.
- An actor returns each attempt encoded; the driver commits it (``runner.commit``).
- An actor asks for what its source uses (``resources()`` of the factory: CPUs for physics, a GPU share for the
  GPU splat renderer), so Ray places it on a node that has it.
- An actor that dies mid-attempt (its process or its node) is replaced and the attempt runs again, up to
  ``RayOptions.max_retries`` times; nothing of it was committed.
"""

from __future__ import annotations

from typing import Any

from ..ray_cluster import ActorCalls, RayOptions, RayResources, actor_info, actor_threads, m2m_env, package_runtime_env
from ..ray_cluster import connect_ray as _connect
from .worker import Job, RunnerError, Server

__all__ = ["RayOptions", "RayResources", "RayWorkers", "connect_ray", "package_runtime_env"]


def _portable(job: Job) -> Job:
    """The job as a worker on another machine needs it: a factory that reads files carries them (``portable()``)."""
    portable = getattr(job.factory, "portable", None)
    return Job(portable(), job.key) if portable is not None else job


def _resources(job: Job) -> RayResources:
    ask = getattr(job.factory, "resources", None)
    return ask() if ask is not None else RayResources()


def _actor_class(ray):
    @ray.remote
    class Worker:
        """One worker: builds its source from the job it is started with (a one-element list: Ray leaves the
        reference unresolved there, so the job's content is fetched only here)."""

        def __init__(self, key: str, job_ref: list, num_cpus: float = 1.0):
            actor_threads(num_cpus)
            self.server = Server(ray.get(job_ref[0]))

        def ready(self) -> dict[str, Any]:
            return actor_info(ray)

        def run(self, key: str, job_ref: list, attempt: int, seed: int) -> dict[str, Any]:
            job = self.server_job(key, job_ref)
            return self.server.run(job, attempt, seed)

        def server_job(self, key: str, job_ref: list) -> Job:
            # the job this worker serves already: no fetch; another (a pool's next run): fetched once
            return Job(None, key) if key == self.server.key else ray.get(job_ref[0])

    return Worker


class RayWorkers:
    """One Ray actor per worker (a ``runner.WorkerPool`` backend); ``ray_cluster.ActorCalls`` hands the attempts
    out and runs a dead worker's attempt again."""

    name = "ray"

    def __init__(self, workers: int, address: str, options: RayOptions | None = None):
        self.n, self.address = workers, address
        self.options = options or RayOptions()
        self.calls: ActorCalls | None = None
        self.refs: dict[str, Any] = {}  # job key -> its object reference

    def _ref(self, job: Job):
        if job.key not in self.refs:
            self.refs = {job.key: self.ray.put(_portable(job))}  # the previous run's job is no longer needed
        return self.refs[job.key]

    def _new_actor(self):
        job, res = self.job, _resources(self.job)
        opts = {"num_cpus": res.num_cpus, "num_gpus": res.num_gpus, "max_restarts": 0,
                "runtime_env": {"env_vars": m2m_env()}}  # fmt: skip
        return self.cls.options(**opts).remote(job.key, [self._ref(job)], res.num_cpus)

    def start(self, job: Job) -> None:
        self.ray, self.job = connect_ray(self.address, self.n), job
        self.cls = _actor_class(self.ray)
        o = self.options
        self.calls = ActorCalls(self.ray, self._new_actor, self.n, _resources(job), o.max_retries, o.start_timeout_s,
                                RunnerError)  # fmt: skip
        self.calls.start()

    def submit(self, job: Job, attempt: int, seed: int) -> None:
        self.job = job  # a replacement actor starts on the run now going
        run = lambda actor: actor.run.remote(job.key, [self._ref(job)], attempt, seed)  # noqa: E731
        self.calls.submit(run, f"attempt {attempt}")

    def next_result(self) -> dict[str, Any]:
        try:
            return self.calls.next_result()[1]
        except RunnerError:
            raise
        except Exception as e:
            raise RunnerError(f"a Ray worker failed: {e}") from None

    def close(self) -> None:
        if self.calls is not None:
            self.calls.close()
        self.calls, self.refs = None, {}


def connect_ray(address: str, workers: int = 1):
    """``ray_cluster.connect_ray`` raising RunnerError (what generation's callers catch)."""
    return _connect(address, workers, RunnerError)
