"""Child processes that do not outlive their parent (generation's workers, the splat server), and
:class:`TimedWorker`: one object in a child process whose every call has a time limit."""

from __future__ import annotations

import ctypes
import multiprocessing as mp
import os
import pickle
import signal
import traceback
from typing import Any

from .errors import M2MError

__all__ = ["TimedWorker", "WorkerError", "WorkerTimeout", "can_start_children", "die_with_parent"]


def die_with_parent(parent_pid: int | None = None) -> None:
    """Linux: SIGKILL this process when its parent dies (a killed generator must not leave workers or a renderer
    behind that would keep committing attempts, or holding a GPU, next to the rerun). Elsewhere: nothing. With
    ``parent_pid`` (the parent's ``os.getpid()``, passed down): exit at once if that parent is already gone (it
    died before the request took effect)."""
    try:

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    if parent_pid is not None and os.getppid() != parent_pid:
        os._exit(1)


def can_start_children() -> bool:
    """Whether this process may start child processes (a daemonic multiprocessing worker, such as generation's,
    may not)."""
    return not mp.current_process().daemon


class WorkerError(M2MError, RuntimeError):
    """A :class:`TimedWorker`'s child failed to start or died."""


class WorkerTimeout(M2MError, TimeoutError):
    """A :class:`TimedWorker` call ran past its limit; the child was killed (the next call starts a fresh one)."""


def _picklable(exc: BaseException) -> BaseException:
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # an exception that does not survive the pipe arrives as its text
        return RuntimeError(f"{type(exc).__name__}: {exc}")


def _work(factory: Any, args: tuple, kwargs: dict, conn: Any, parent_pid: int) -> None:
    die_with_parent(parent_pid)
    try:
        obj = factory(*args, **kwargs)
    except BaseException as exc:
        conn.send(("error", (_picklable(exc), traceback.format_exc())))
        return
    conn.send(("ready", None))
    try:
        while True:
            request = conn.recv()
            if request is None:
                break
            name, a, kw = request
            try:
                value = getattr(obj, name)
                conn.send(("ok", value(*a, **kw) if callable(value) else value))
            except Exception as exc:
                conn.send(("error", (_picklable(exc), traceback.format_exc())))
    except (EOFError, OSError):  # the parent went away
        pass
    finally:
        close = getattr(obj, "close", None)
        if callable(close):
            close()


class TimedWorker:
    """``factory(*args, **kwargs)`` built in a spawned child process; :meth:`call` runs one of its methods there
    (or reads an attribute) and returns the result, within ``timeout_s``.

    For work that can hang inside native code, where no signal reaches Python: llvmpipe held one ground-truth
    render for 460 s at one exact camera pose (``env/ground_truth.py``). A call that overruns kills the child and
    raises :class:`WorkerTimeout`; the next call builds a fresh one (the object's state is lost, so callers pass
    the whole state with each call). An exception in the child arrives as itself (its text when it cannot be
    pickled); a child that dies is a :class:`WorkerError`. Arguments, results and ``factory`` must pickle."""

    def __init__(self, factory: Any, args: tuple = (), kwargs: dict | None = None, *, name: str = "worker",
                 start_timeout_s: float = 900.0) -> None:  # fmt: skip
        self.factory, self.args, self.kwargs = factory, tuple(args), dict(kwargs or {})
        self.name, self.start_timeout_s = name, start_timeout_s
        self.proc: Any = None
        self._conn: Any = None
        self.restarts = 0  # children killed by a timeout

    def start(self) -> None:
        """Start the child (if none runs) and wait until it has built the object; its error is raised here."""
        if self.proc is not None:
            return

        if not can_start_children():
            raise WorkerError(f"the {self.name} process cannot start here: this process is a daemonic worker, which "
                              "may not have children (run the work in-process: no time limit)")  # fmt: skip
        ctx = mp.get_context("spawn")  # Genesis, numba and CUDA do not survive fork
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=_work, args=(self.factory, self.args, self.kwargs, child, os.getpid()),
                           daemon=True, name=self.name)  # fmt: skip
        proc.start()
        self.proc = proc  # only once started: close() after a failed start has nothing to stop
        child.close()
        self._conn = parent
        kind, payload = self._receive(self.start_timeout_s, "starting")
        if kind != "ready":
            self._kill()
            self._raise(payload)

    def call(self, method: str, *args: Any, timeout_s: float, **kwargs: Any) -> Any:
        """``getattr(obj, method)(*args, **kwargs)`` in the child (the attribute itself when not callable)."""
        self.start()
        self._conn.send((method, args, kwargs))
        kind, payload = self._receive(timeout_s, f"{method}()")
        if kind != "ok":
            self._raise(payload)
        return payload

    def _receive(self, timeout_s: float, what: str) -> tuple[str, Any]:
        try:
            ready = self._conn.poll(timeout_s)
            if ready:
                return self._conn.recv()
        except (EOFError, OSError):
            code = self._kill()
            raise WorkerError(f"the {self.name} process died while {what} (exit code {code})") from None
        self._kill()
        self.restarts += 1
        raise WorkerTimeout(f"the {self.name} process did not finish {what} within {timeout_s:g} s; it was stopped")

    def _raise(self, payload: tuple[BaseException, str]) -> None:
        exc, text = payload
        if not isinstance(exc, M2MError):  # an unexpected failure keeps the child's traceback
            exc.add_note(f"in the {self.name} process:\n{text}")
        raise exc

    def _kill(self) -> int | None:
        proc, self.proc = self.proc, None
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        if proc is None:
            return None
        proc.kill()
        proc.join(timeout=10)
        return proc.exitcode

    def close(self) -> None:
        """Stop the child (it closes its object); a child that does not stop within 30 s is killed."""
        if self.proc is None:
            return
        try:
            if self._conn is not None:  # None when the start failed before the pipe was kept
                self._conn.send(None)
                self.proc.join(timeout=30)
        except (OSError, BrokenPipeError):
            pass
        self._kill()

    def __enter__(self) -> TimedWorker:
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
