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

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .worker import Job, RunnerError, Server

__all__ = ["RayOptions", "RayResources", "RayWorkers", "connect_ray", "package_runtime_env"]


@dataclass(frozen=True)
class RayResources:
    """What one actor asks Ray for: CPUs (physics, planning, encoding) and a GPU share (0: none)."""

    num_cpus: float = 1.0
    num_gpus: float = 0.0


@dataclass(frozen=True)
class RayOptions:
    """max_retries: times an attempt runs again after its worker died; start_timeout_s: how long the actors may take
    to start (a cluster without room for them waits forever otherwise)."""

    max_retries: int = 3
    start_timeout_s: float = 600.0


def package_runtime_env() -> dict[str, Any]:
    """The ``runtime_env`` that ships this package to Ray workers by content (never the driver's path)."""
    import mirage2matter

    return {"py_modules": [str(Path(mirage2matter.__file__).parent)]}


def _portable(job: Job) -> Job:
    """The job as a worker on another machine needs it: a factory that reads files carries them (``portable()``)."""
    portable = getattr(job.factory, "portable", None)
    return Job(portable(), job.key) if portable is not None else job


def _m2m_env() -> dict[str, str]:
    """The driver's own settings (M2M_RENDER_BACKEND, ...): workers on other nodes do not inherit its environment."""
    return {k: v for k, v in os.environ.items() if k.startswith("M2M_")}


def _resources(job: Job) -> RayResources:
    ask = getattr(job.factory, "resources", None)
    return ask() if ask is not None else RayResources()


def _actor_class(ray):
    @ray.remote
    class Worker:
        """One worker: builds its source from the job it is started with (a one-element list: Ray leaves the
        reference unresolved there, so the job's content is fetched only here)."""

        def __init__(self, key: str, job_ref: list):
            os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
            from mirage2matter import configure_threads

            configure_threads(1)
            self.server = Server(ray.get(job_ref[0]))

        def ready(self) -> dict[str, Any]:
            import mirage2matter

            node = ray.get_runtime_context().get_node_id()
            return {"pid": os.getpid(), "version": mirage2matter.__version__, "node": node}

        def run(self, key: str, job_ref: list, attempt: int, seed: int) -> dict[str, Any]:
            job = self.server_job(key, job_ref)
            return self.server.run(job, attempt, seed)

        def server_job(self, key: str, job_ref: list) -> Job:
            # the job this worker serves already: no fetch; another (a pool's next run): fetched once
            return Job(None, key) if key == self.server.key else ray.get(job_ref[0])

    return Worker


class RayWorkers:
    """One Ray actor per worker (a ``runner.WorkerPool`` backend)."""

    name = "ray"

    def __init__(self, workers: int, address: str, options: RayOptions | None = None):
        self.n, self.address = workers, address
        self.options = options or RayOptions()
        self.futures: dict = {}  # future -> (actor, job, attempt, seed, tries)
        self.idle: list = []
        self.actors: list = []
        self.refs: dict[str, Any] = {}  # job key -> its object reference

    def _ref(self, job: Job):
        if job.key not in self.refs:
            self.refs = {job.key: self.ray.put(_portable(job))}  # the previous run's job is no longer needed
        return self.refs[job.key]

    def _new_actor(self, job: Job):
        res = _resources(job)
        opts = {"num_cpus": res.num_cpus, "num_gpus": res.num_gpus, "max_restarts": 0,
                "runtime_env": {"env_vars": _m2m_env()}}  # fmt: skip
        actor = self.cls.options(**opts).remote(job.key, [self._ref(job)])
        self.actors.append(actor)
        return actor

    def start(self, job: Job) -> None:
        import mirage2matter

        self.ray = connect_ray(self.address, self.n)
        self.cls = _actor_class(self.ray)
        for _ in range(self.n):
            self._new_actor(job)
        try:
            infos = self.ray.get([a.ready.remote() for a in self.actors], timeout=self.options.start_timeout_s)
        except self.ray.exceptions.GetTimeoutError:
            raise RunnerError(f"the Ray cluster did not start {self.n} worker(s) within "
                              f"{self.options.start_timeout_s:.0f} s; does it have the CPUs/GPUs they ask for "
                              f"({_resources(job)})?") from None  # fmt: skip
        except Exception as e:
            raise RunnerError(f"a Ray worker failed while starting (can its node import mirage2matter?): {e}") from None
        other = sorted({i["version"] for i in infos} - {mirage2matter.__version__})
        if other:
            raise RunnerError(f"Ray workers run mirage2matter {', '.join(other)}, this driver "
                              f"{mirage2matter.__version__}; install the same version on every node")  # fmt: skip
        self.idle = list(self.actors)

    def submit(self, job: Job, attempt: int, seed: int, tries: int = 0) -> None:
        actor = self.idle.pop() if self.idle else self._new_actor(job)
        self.futures[actor.run.remote(job.key, [self._ref(job)], attempt, seed)] = (actor, job, attempt, seed, tries)

    def next_result(self) -> dict[str, Any]:
        ray = self.ray
        while True:
            done, _ = ray.wait(list(self.futures), num_returns=1)
            actor, job, attempt, seed, tries = self.futures.pop(done[0])
            try:
                out = ray.get(done[0])
            except ray.exceptions.RayActorError as e:  # its process or node died: the attempt runs again
                self.actors.remove(actor)
                if tries >= self.options.max_retries:
                    raise RunnerError(f"attempt {attempt} lost its Ray worker {tries + 1} times; last: {e}") from None
                self.submit(job, attempt, seed, tries + 1)  # on a new actor (Ray places it where there is room)
                continue
            except Exception as e:
                raise RunnerError(f"a Ray worker failed: {e}") from None
            self.idle.append(actor)
            return out

    def close(self) -> None:
        for a in self.actors:
            self.ray.kill(a)
        self.actors, self.idle, self.futures, self.refs = [], [], {}, {}


def connect_ray(address: str, workers: int = 1):
    """``local``: start a private Ray instance on this machine; ``auto`` or ``host:port``: join that
    cluster. A cluster that does not answer raises RunnerError (after at most ~10 s). The package travels to the
    workers by content (``package_runtime_env``). Ray already initialised (by the caller): used as it is."""
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
    kwargs["runtime_env"] = package_runtime_env()
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
