"""TimedWorker: an object in a child process, every call with a time limit (a hung call is stopped, not waited on)."""

from __future__ import annotations

import time
from types import SimpleNamespace

import pytest

from mirage2matter.errors import M2MError
from mirage2matter.processes import TimedWorker, WorkerError, WorkerTimeout


def test_calls_run_in_the_child_and_a_hung_call_is_stopped_and_the_next_starts_afresh() -> None:
    with TimedWorker(SimpleNamespace, kwargs={"sleep": time.sleep, "value": 7}, name="toy") as w:
        first = w.proc.pid
        assert w.call("value", timeout_s=30) == 7  # an attribute is read
        assert w.call("sleep", 0.0, timeout_s=30) is None
        t0 = time.perf_counter()
        with pytest.raises(WorkerTimeout, match="toy process did not finish sleep\\(\\) within 0.5 s"):
            w.call("sleep", 60.0, timeout_s=0.5)
        assert time.perf_counter() - t0 < 15.0  # stopped, not waited for
        assert w.proc is None and w.restarts == 1
        assert w.call("value", timeout_s=30) == 7  # a fresh child
        assert w.proc.pid != first
    assert w.proc is None


def test_errors_arrive_as_themselves_with_the_childs_traceback() -> None:
    with TimedWorker(SimpleNamespace, kwargs={"sleep": time.sleep}) as w:
        with pytest.raises(TypeError) as info:
            w.call("sleep", "a while", timeout_s=30)
        assert any("in the worker process" in n for n in getattr(info.value, "__notes__", []))
        with pytest.raises(AttributeError):
            w.call("missing", timeout_s=30)
        assert w.call("sleep", 0.0, timeout_s=30) is None  # the child survives its errors


def test_a_factory_that_fails_is_raised_at_start_and_leaves_no_child() -> None:
    w = TimedWorker(int, ("not a number",), name="toy")
    with pytest.raises(ValueError, match="not a number"):
        w.start()
    assert w.proc is None


def test_a_child_that_dies_is_a_clear_error() -> None:
    import os

    with TimedWorker(SimpleNamespace, kwargs={"exit": os._exit}, name="toy") as w:
        with pytest.raises(WorkerError, match="toy process died while exit\\(\\)") as info:
            w.call("exit", 3, timeout_s=30)
        assert isinstance(info.value, M2MError)


def _start_in_a_daemon(out) -> None:
    w = TimedWorker(SimpleNamespace, name="toy")
    try:
        w.start()
        out.put("started")
    except WorkerError as e:
        w.close()  # nothing to stop: the failed start kept no process
        out.put(f"{type(e).__name__}: {e} | proc={w.proc}")


def test_a_daemonic_worker_gets_a_clear_error_not_a_half_started_child() -> None:
    """Generation's workers are daemonic processes, which multiprocessing forbids children: a TimedWorker there says
    so (GroundTruthFrames then renders in-process), and closing it afterwards is safe."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    out = ctx.Queue()
    p = ctx.Process(target=_start_in_a_daemon, args=(out,), daemon=True)
    p.start()
    message = out.get(timeout=120)
    p.join(timeout=30)
    assert message.startswith("WorkerError: the toy process cannot start here: this process is a daemonic worker")
    assert message.endswith("proc=None")
