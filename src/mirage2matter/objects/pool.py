"""Objects reconstructed side by side, one worker process per object (up to ``ObjectsConfig.workers``).

Why: one object's work (matting, object 3DGS, short retrainings; small crops) keeps a 2-core CPU ~75 % busy (top:
~150 %), with serial Python between the parallel kernels. The demo workspace's three objects on that CPU
(`m2m run -w WS --from objects --until objects` on copies, alone): one after the other 757-766 s, two workers
595 s, three 548 s, and the files byte for byte the same (meshes, Gaussians). Each object's work is the same as in
one process (its folder, its seeds); its log lines come back to the stage's log, and an error in one stops the
others.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import queue
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from .. import configure_threads
from ..processes import die_with_parent
from .errors import ObjectsError

__all__ = ["object_workers", "process_objects"]

_lines: Any = None  # the worker's queue of log lines (set by _init_worker)


def object_workers(requested: int, n_objects: int) -> int:
    """Worker processes for ``n_objects``: ``requested``, or (0) one per object, at most two per core (an object keeps
    a core ~75 % busy) and one per 2 GiB of available memory (top: one holds ~1.1 GiB training the button); never
    more than the objects. The demo's three objects on 2 cores: 3 workers 548 s, 2 workers 595 s, one after the
    other 757-766 s."""
    if requested < 0:
        raise ObjectsError(f"objects.workers must be >= 0 (0: one per object, at most two per core), got {requested}")
    if requested == 0:
        requested = min(2 * (os.cpu_count() or 1), max(1, _available_bytes() // (2 << 30)))
    return max(1, min(n_objects, requested))


def _available_bytes() -> int:
    """Linux's MemAvailable (free plus reclaimable cache); elsewhere room for two workers."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 4 << 30


def _init_worker(lines: Any, threads: int, parent_pid: int) -> None:

    global _lines
    die_with_parent(parent_pid)  # a killed stage leaves no worker behind (it resumes from the objects written)
    _lines = lines
    configure_threads(threads)


def _process_one(target: Any, config: Any, cameras: list, images: list, folder: Path, lens: Any) -> dict[str, Any]:
    from .reconstruct import process_object

    return process_object(target, config, cameras, images, folder, _lines.put, progress=False, lens=lens)


def process_objects(
    jobs: list[tuple[Any, Path]],
    config: Any,
    cameras: list,
    images: list,
    log: Callable[[str], None],
    lens: list | None = None,
    workers: int = 1,
) -> dict[str, dict[str, Any]]:
    """``process_object`` for each ``(target, folder)``, ``workers`` at a time -> {name: summary} in ``jobs``' order.
    One worker: in this process, with progress bars. More: spawned processes (numba, torch and CUDA do not survive
    fork), ``ceil(cores / workers)`` threads each but at least 2 (as measured: 3 workers of 2 threads on 2 cores),
    log lines passed on as they come. A worker that dies (out of memory) is an :class:`ObjectsError`."""
    from .reconstruct import process_object

    if workers <= 1 or len(jobs) <= 1:
        return {t.name: process_object(t, config, cameras, images, folder, log, progress=True, lens=lens)
                for t, folder in jobs}  # fmt: skip

    ctx = mp.get_context("spawn")
    lines = ctx.Queue()
    cores = os.cpu_count() or 1
    threads = min(cores, max(2, math.ceil(cores / workers)))
    log(f"objects: {len(jobs)} objects, {workers} worker processes of {threads} threads")
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker,
                               initargs=(lines, threads, os.getpid()))  # fmt: skip
    try:
        pending = {pool.submit(_process_one, t, config, cameras, images, folder, lens): t.name for t, folder in jobs}
        out: dict[str, dict[str, Any]] = {}
        while pending:
            _drain(lines, log)
            done, _ = wait(pending, timeout=1.0, return_when=FIRST_COMPLETED)
            for future in done:
                out[pending.pop(future)] = future.result()  # a worker's error is raised here
        _drain(lines, log)
        pool.shutdown()
        return {t.name: out[t.name] for t, _ in jobs}
    except BrokenProcessPool:
        raise ObjectsError(f"an objects worker process died (out of memory?); with {workers} objects at once each "
                           "needs 1-2 GiB: set objects.workers lower (1: one at a time)") from None  # fmt: skip
    finally:  # on an error the other objects stop too (a rerun resumes from those already written)
        _stop(pool)


def _stop(pool: Any) -> None:
    procs = list((getattr(pool, "_processes", None) or {}).values())  # before shutdown forgets them
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:  # running work is not cancellable
        if proc.is_alive():
            proc.kill()
            proc.join(timeout=10)


def _drain(lines: Any, log: Callable[[str], None]) -> None:
    """Pass on the workers' log lines so far."""
    try:
        while True:
            log(lines.get_nowait())
    except queue.Empty:
        return
