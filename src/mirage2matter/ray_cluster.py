"""Joining a Ray cluster and starting actors on it, for every command that runs work there (``generate``'s
episode workers, ``eval-policy``'s evaluation workers).

- ``connect_ray``: ``local`` starts a private Ray instance on this machine, ``auto`` / ``host:port`` join a cluster
  (one that does not answer is an error within seconds, not a hang).
- The package reaches the actors by content through ``runtime_env`` (``package_runtime_env``), never as the
  driver's checkout path; each actor reports its version when it starts and a mismatch is an error
  (``start_actors``) before any work is handed out.
- ``RayResources``: what one actor asks for (CPUs, a GPU share), so Ray places it on a node that has it.
- ``m2m_env``: the driver's ``M2M_*`` settings, which actors on other nodes do not inherit.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from . import __version__, configure_threads
from .errors import M2MError

__all__ = ["ClusterError", "RayResources", "actor_info", "connect_ray", "m2m_env", "package_runtime_env",
           "splat_resources", "start_actors", "ActorCalls", "RayOptions", "actor_threads"]  # fmt: skip


class ClusterError(M2MError, RuntimeError):
    """Ray is missing, the cluster does not answer, or its actors cannot start (room, package, version)."""


@dataclass(frozen=True)
class RayResources:
    """What one actor asks Ray for: CPUs (physics, planning, encoding) and a GPU share (0: none)."""

    num_cpus: float = 1.0
    num_gpus: float = 0.0


GPU_SHARE = 0.25  # of one GPU per Ray worker rendering splats on CUDA: a few workers' small frames share a card


@dataclass(frozen=True)
class RayOptions:
    """max_retries: times a call (an attempt, an episode) runs again after its worker died; start_timeout_s: how long
    the actors may take to start (a cluster without room for them waits forever otherwise)."""

    max_retries: int = 3
    start_timeout_s: float = 600.0


def splat_resources(backend: str, cuda: bool = False) -> RayResources:
    """What a worker rendering splats with ``backend`` asks for: a CPU (physics, encoding), and a GPU share when
    it renders on CUDA (``backend``, or ``M2M_RENDER_BACKEND=cuda`` on the driver for "auto", which the workers get
    too: ``m2m_env``) or ``cuda`` says it needs one otherwise (a policy on the GPU): Ray then places it on a GPU
    node; "auto" asks for none."""
    gpu = cuda or (os.environ.get("M2M_RENDER_BACKEND", "auto") if backend == "auto" else backend) == "cuda"
    return RayResources(num_cpus=1.0, num_gpus=GPU_SHARE if gpu else 0.0)


def package_runtime_env() -> dict[str, Any]:
    """The ``runtime_env`` that ships this package to Ray workers by content (never the driver's path)."""
    return {"py_modules": [str(Path(__file__).resolve().parent)]}


def m2m_env() -> dict[str, str]:
    """The driver's own settings (M2M_RENDER_BACKEND, ...): workers on other nodes do not inherit its environment."""
    return {k: v for k, v in os.environ.items() if k.startswith("M2M_")}


def connect_ray(address: str, workers: int = 1, error: type[Exception] = ClusterError):
    """``local``: start a private Ray instance on this machine (``workers`` CPUs); ``auto`` or ``host:port``: join
    that cluster. A cluster that does not answer raises ``error`` (after at most ~10 s). The package travels to the
    workers by content (``package_runtime_env``). Ray already initialised (by the caller): used as it is."""
    try:
        import ray
    except ImportError:
        raise error("--ray-address needs the `ray` package (pip install ray)") from None
    if ray.is_initialized():
        return ray
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "ignore_reinit_error": True}
    if address == "local":
        kwargs["num_cpus"] = max(workers, 1)
    else:
        if address != "auto" and not _answers(address):
            raise error(f"no Ray cluster answers at {address}; start one with `ray start --head` "
                        "or use --ray-address local for a private instance")  # fmt: skip
        kwargs["address"] = address
    kwargs["runtime_env"] = package_runtime_env()
    try:
        ray.init(**kwargs)
    except (ConnectionError, RuntimeError, ValueError) as e:
        raise error(f"cannot reach a Ray cluster at {address!r}: {e}") from None
    return ray


def start_actors(ray, actors: list, timeout_s: float, resources: RayResources,
                 error: type[Exception] = ClusterError) -> list[dict[str, Any]]:  # fmt: skip
    """Wait until every actor (with a ``ready()`` method returning ``{"version": ...}``) has started; ``error`` when
    they do not start within ``timeout_s`` (no room for ``resources``), one fails while starting (its node cannot
    import the package, its job cannot be read there) or one runs another version of mirage2matter."""
    try:
        infos = ray.get([a.ready.remote() for a in actors], timeout=timeout_s)
    except ray.exceptions.GetTimeoutError:
        raise error(f"the Ray cluster did not start {len(actors)} worker(s) within {timeout_s:.0f} s; does it have "
                    f"the CPUs/GPUs they ask for ({resources})?") from None  # fmt: skip
    except Exception as e:
        raise error(f"a Ray worker failed while starting (can its node import mirage2matter?): {e}") from None
    _same_version(infos, error)
    return infos


def _same_version(infos: list[dict[str, Any]], error: type[Exception]) -> None:
    other = sorted({i["version"] for i in infos} - {__version__})
    if other:
        raise error(f"Ray workers run mirage2matter {', '.join(other)}, this driver {__version__}; "
                    "install the same version on every node")  # fmt: skip


class ActorCalls:
    """``n`` actors made by ``make()`` (each with a ``ready()``: ``actor_info``), each running one call at a time.
    A call whose actor died (its process, or its whole node) is run again first by the next idle actor, up to
    ``max_retries`` times; a replacement actor is asked for too, and used once Ray has found room for it (a call
    pinned to an actor that cannot start would wait forever after its node is gone). A call's own exception is
    raised by ``next_result`` as Ray raises it."""

    def __init__(self, ray, make: Callable[[], Any], n: int, resources: RayResources, max_retries: int,
                 start_timeout_s: float, error: type[Exception] = ClusterError):  # fmt: skip
        self.ray, self.make, self.n, self.resources = ray, make, n, resources
        self.max_retries, self.start_timeout_s, self.error = max_retries, start_timeout_s, error
        self.actors: list = []
        self.idle: list = []
        self.starting: dict = {}  # a replacement's ready() future -> the actor
        self.backlog: list = []  # (call, tag, tries) waiting for an idle actor
        self.futures: dict = {}  # future -> (actor, call, tag, tries)
        self.rerun = 0  # calls run again after their actor died

    def start(self) -> None:
        """Start the ``n`` actors and check them (``start_actors``)."""
        self.actors = [self.make() for _ in range(self.n)]
        start_actors(self.ray, self.actors, self.start_timeout_s, self.resources, self.error)
        self.idle = list(self.actors)

    def submit(self, call: Callable[[Any], Any], tag: Any) -> None:
        """Run ``call(actor) -> future`` on the next idle actor; ``next_result`` returns ``(tag, its value)``."""
        self.backlog.append((call, tag, 0))
        self._dispatch()

    def _dispatch(self) -> None:
        while self.backlog and self.idle:
            actor = self.idle.pop()
            call, tag, tries = self.backlog.pop(0)
            self.futures[call(actor)] = (actor, call, tag, tries)

    def next_result(self) -> tuple[Any, Any]:
        ray = self.ray
        while True:
            if not self.futures and not self.starting:
                raise self.error("every Ray worker died and none could be started again")
            timeout = None if self.futures else self.start_timeout_s
            done, _ = ray.wait([*self.futures, *self.starting], num_returns=1, timeout=timeout)
            if not done:
                raise self.error(f"no Ray worker could be started again within {self.start_timeout_s:.0f} s (does "
                                 f"the cluster still have the CPUs/GPUs they ask for, {self.resources}?)")  # fmt: skip
            if done[0] in self.starting:  # a replacement started: it takes the backlog's first call
                actor = self.starting.pop(done[0])
                try:
                    info = ray.get(done[0])
                except ray.exceptions.RayActorError:  # it died before it started (its node went too)
                    self.actors.remove(actor)
                    continue
                _same_version([info], self.error)
                self.idle.append(actor)
                self._dispatch()
                continue
            actor, call, tag, tries = self.futures.pop(done[0])
            try:
                value = ray.get(done[0])
            except ray.exceptions.RayActorError as e:  # its process or node died: the call runs again
                self.actors.remove(actor)
                if tries >= self.max_retries:
                    raise self.error(f"{tag} lost its Ray worker {tries + 1} times; last: {e}") from None
                self.backlog.insert(0, (call, tag, tries + 1))
                self.rerun += 1
                if len(self.actors) < self.n:
                    new = self.make()
                    self.actors.append(new)
                    self.starting[new.ready.remote()] = new
                self._dispatch()
                continue
            self.idle.append(actor)
            self._dispatch()
            return tag, value

    def close(self) -> None:
        for a in self.actors:
            self.ray.kill(a)
        self.actors, self.idle, self.starting, self.backlog, self.futures = [], [], {}, [], {}


def actor_threads(num_cpus: float) -> None:
    """In an actor, before it builds anything: as many threads as the CPUs it asked for (torch, numba, and Mesa's
    llvmpipe, which otherwise starts one GL thread per core of the node), idle threads sleeping - as a local worker
    process is given its share of the cores."""
    n = max(1, int(num_cpus))
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    os.environ.setdefault("LP_NUM_THREADS", str(n))
    configure_threads(n)


def actor_info(ray) -> dict[str, Any]:
    """What an actor's ``ready()`` reports: its process, mirage2matter version and node."""
    node = ray.get_runtime_context().get_node_id()
    return {"pid": os.getpid(), "version": __version__, "node": node}


def _answers(address: str, timeout: float = 5.0) -> bool:
    host, _, port = address.rpartition(":")
    if address.startswith("ray://"):
        host, _, port = address[len("ray://") :].rpartition(":")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout):
            return True
    except (OSError, ValueError):
        return False
