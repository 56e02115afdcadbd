"""Nothing lost: one writer per workspace, and a stage's (or an edit's) outputs committed all at once.

**The lock.** Every command that writes a workspace holds an advisory ``flock`` on the workspace folder
(released by the kernel when the process dies, so a killed run never leaves a stale lock). A second writer is
refused with the holder's pid, command and start time (``.m2m/holder.json``). Under the lock, leftovers of
killed runs (the hidden ``.<name>.tmp-*`` / ``.<name>.old-*`` of atomic writes) are removed.

**Runs side by side.** The policy stages (``train-policy``, ``eval-policy``: one output per name, never part of a
pipeline run) hold the lock only to start and to commit; in between each holds its own output's lock
(``.m2m/running/<name>.json``, flocked, naming its holder), so several trainings and evaluations of one
workspace run at once while a second run of the same output is refused. Every other writer is refused while
any of them runs (it would change what they read); short bookkeeping (their commits, ``m2m.yaml``) waits its turn.

**The transaction.** A stage runs on a staged view of the workspace (:meth:`Workspace.staged`): what it
writes lands in ``<ws>/.m2m/txn/<name>/staged/`` with the workspace's layout, what it reads comes from the
workspace. Only when the stage returned and its outputs exist is the staged set swapped in, one rename per
artifact (the old one moved aside, then deleted), under a journal: a kill during the swap is finished
(rolled forward) at the next start. A failed stage leaves the workspace as it was; a killed one leaves its
staging, which the next run with the same fingerprint resumes (scene checkpoints, finished objects, staged
episodes) and any other run discards.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import shutil
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from ..atomic import atomic_write
from ..workspace import Workspace, WorkspaceError

__all__ = ["OutputLock", "Transaction", "WorkspaceBusy", "holds_lock", "workspace_lock"]

# what atomic_write / atomic_dir leave behind when killed: ".<name>.tmp-<pid>-<hex>[.suffix]", ".<name>.old-..."
_LEFTOVER = re.compile(r"^\..+\.(tmp|old)-\d+-[0-9a-f]{8}(\.[A-Za-z0-9]+)?$")
_held: dict[Path, int] = {}  # workspaces this process holds the lock of, and how deep


class WorkspaceBusy(WorkspaceError):
    """Another command is writing the workspace."""


def _command() -> str:
    return "m2m " + " ".join(sys.argv[1:4]) if sys.argv and sys.argv[0].endswith(("m2m", "__main__.py")) else "python"


def holds_lock(ws: Workspace) -> bool:
    """Whether this process holds ``ws``'s lock now."""
    return bool(_held.get(ws.root.resolve()))


def _holder(path: Path) -> str:
    try:
        h = json.loads(path.read_text())
        return f"pid {h['pid']} (`{h['command']}`, since {h['since']})"
    except (OSError, ValueError, KeyError, TypeError):
        return "another process"


def _holder_info(command: str | None) -> str:
    return json.dumps({"pid": os.getpid(), "command": command or _command(),
                       "since": time.strftime("%Y-%m-%d %H:%M:%S")})  # fmt: skip


@contextmanager
def workspace_lock(ws: Workspace, command: str | None = None, *, alongside: bool = False,
                   wait_s: float = 0.0) -> Iterator[None]:  # fmt: skip
    """Hold ``ws``'s writer lock (re-entrant within a process); :class:`WorkspaceBusy` names the holder.

    The lock is an exclusive ``flock`` on the workspace folder itself, so it needs no lock file (a failing
    command leaves the workspace's files as they were); ``.m2m/holder.json`` says who holds it. It is refused
    while a policy stage runs beside it (:class:`OutputLock`), unless ``alongside``: a short hold that may
    happen beside them (their start and commit, an ``m2m.yaml`` update). ``wait_s``: wait that long for
    another holder to finish before refusing."""
    key = ws.root.resolve()
    if _held.get(key):
        _held[key] += 1
        try:
            yield
        finally:
            _held[key] -= 1
        return
    if ws.root.exists() and not ws.root.is_dir():
        raise WorkspaceError(f"workspace {ws.root} exists and is not a folder; choose another with -w")
    created = not ws.root.exists()
    ws.root.mkdir(parents=True, exist_ok=True)
    fd = os.open(ws.root, os.O_RDONLY | os.O_DIRECTORY)
    holder = ws.state_dir / "holder.json"
    deadline = time.monotonic() + wait_s
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if time.monotonic() < deadline:
                time.sleep(0.2)
                continue
            os.close(fd)
            raise WorkspaceBusy(f"workspace {ws.root} is being written by {_holder(holder)}; wait for it to finish "
                                "(or stop it), then run again") from None  # fmt: skip
    _held[key] = 1
    try:
        running = [] if alongside else OutputLock.running(ws)
        if running:
            raise WorkspaceBusy(f"workspace {ws.root} is in use by {'; '.join(running)}; wait for "
                                f"{'them' if len(running) > 1 else 'it'} to finish (or stop "
                                f"{'them' if len(running) > 1 else 'it'}), then run again")  # fmt: skip
        ws.state_dir.mkdir(exist_ok=True)
        holder.write_text(_holder_info(command))
        _remove_leftovers(ws.root)
        yield
    finally:
        _held.pop(key, None)
        holder.unlink(missing_ok=True)
        # the state folder holds nothing between commands
        for d in (ws.state_dir / "running", ws.state_dir / "txn", ws.state_dir):
            with contextlib.suppress(OSError):
                d.rmdir()
        if created and not any(ws.root.iterdir()):  # a command that wrote nothing leaves no workspace behind
            with contextlib.suppress(OSError):
                ws.root.rmdir()
        os.close(fd)  # releases the flock


class OutputLock:
    """One running output of a policy stage (``name``: its transaction's), held from its start to its commit
    while the workspace lock is not: ``.m2m/running/<name>.json``, flocked (the kernel drops it when the process
    dies) and naming its holder. Acquire and release it holding the workspace lock (``alongside``)."""

    def __init__(self, ws: Workspace, name: str, command: str | None = None) -> None:
        self.path = ws.state_dir / "running" / f"{name}.json"
        self.command = command
        self.fd: int | None = None

    def acquire(self) -> OutputLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise WorkspaceBusy(f"{self.path.stem} is being run by {_holder(self.path)}; wait for it to finish (or "
                                "stop it), then run again") from None  # fmt: skip
        os.ftruncate(fd, 0)
        os.write(fd, _holder_info(self.command).encode())
        self.fd = fd
        return self

    def release(self, unlink: bool = True) -> None:
        """Drop the hold; ``unlink`` only holding the workspace lock (a file left behind is removed later)."""
        if self.fd is None:
            return
        if unlink:
            self.path.unlink(missing_ok=True)
        os.close(self.fd)
        self.fd = None

    @staticmethod
    def running(ws: Workspace) -> list[str]:
        """Who runs beside the lock's holder now ("<name>: pid ..."); files of killed runs are removed."""
        out = []
        folder = ws.state_dir / "running"
        for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
            fd = os.open(path, os.O_RDONLY)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                path.unlink(missing_ok=True)  # its process died: nothing holds it
            except BlockingIOError:
                out.append(f"{path.stem}: {_holder(path)}")
            finally:
                os.close(fd)
        return out


def _remove_leftovers(root: Path) -> None:
    """Hidden temporaries of atomic writes that a killed process left (the lock is held: none is live)."""
    for dirpath, dirnames, filenames in os.walk(root):
        if Path(dirpath) == root:
            dirnames[:] = [d for d in dirnames if d != ".m2m"]  # transactions are handled on their own
        for name in [*dirnames, *filenames]:
            if _LEFTOVER.match(name):
                p = Path(dirpath) / name
                shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
        dirnames[:] = [d for d in dirnames if not _LEFTOVER.match(d)]


class Transaction:
    """The staged outputs of one stage (or edit) ``name``: ``writes`` are the artifacts (relative to the
    workspace root) it may replace. Use ``begin`` -> work on ``staged_ws`` -> ``commit`` (or ``abort``), holding
    the workspace lock."""

    def __init__(self, ws: Workspace, name: str, writes: Sequence[Path]) -> None:
        self.ws = ws
        self.name = name
        self.writes = [Path(w) for w in writes]
        self.dir = ws.state_dir / "txn" / name
        self.staging = self.dir / "staged"
        self.journal = self.dir / "journal.json"
        self.resumed = False

    @property
    def staged_ws(self) -> Workspace:
        return self.ws.staged(self.staging, self.writes)

    def _read_journal(self) -> dict:
        try:
            return json.loads(self.journal.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {}

    def _write_journal(self, **data) -> None:
        with atomic_write(self.journal, "w", encoding="utf-8") as f:
            json.dump({"name": self.name, "writes": [str(w) for w in self.writes], **data}, f)

    @contextmanager
    def staging_of(self, fingerprint: str, resumable: bool = True) -> Iterator[Workspace]:
        """``begin`` -> yield the staged workspace -> ``commit`` when the block succeeds, ``abort`` when it raises.
        A KeyboardInterrupt (like a kill) keeps a ``resumable`` transaction's staging for the next run."""
        self.resumed = self.begin(fingerprint)
        try:
            yield self.staged_ws
        except KeyboardInterrupt:
            if not resumable:
                self.abort()
            raise
        except BaseException:
            self.abort()
            raise
        self.commit()

    def begin(self, fingerprint: str) -> bool:
        """Start (or resume) the transaction; True when a killed run's staging with this fingerprint is reused."""
        old = self._read_journal()
        if old.get("state") == "committing":  # killed while swapping in: finish it
            self._swap([Path(w) for w in old.get("writes", [])])
            old = {}
        resumed = old.get("fingerprint") == fingerprint and self.staging.is_dir()
        if not resumed:
            shutil.rmtree(self.dir, ignore_errors=True)
        for rel in self.writes:  # the folders the staged artifacts go in
            (self.staging / rel).parent.mkdir(parents=True, exist_ok=True)
        self._write_journal(state="running", fingerprint=fingerprint)
        return resumed

    def commit(self) -> None:
        """Swap every staged artifact in (crash-safe: the journal says to finish an interrupted swap)."""
        self._rename_paths()
        self._write_journal(state="committing")
        self._swap(self.writes)

    def _rename_paths(self) -> None:
        """The staged records (JSON / YAML) that name staged files name them where they will be after the swap."""
        roots = {str(self.staging.resolve()): str(self.ws.root.resolve()), str(self.staging): str(self.ws.root)}
        for p in self.staging.rglob("*"):
            if p.suffix not in (".json", ".jsonl", ".yaml") or not p.is_file() or p.stat().st_size > 16 << 20:
                continue
            text = p.read_text(encoding="utf-8", errors="surrogateescape")
            new = text
            for old, final in sorted(roots.items(), key=lambda kv: -len(kv[0])):
                new = new.replace(old, final)
            if new != text:
                with atomic_write(p, "w", encoding="utf-8", errors="surrogateescape") as f:
                    f.write(new)

    def abort(self) -> None:
        """Drop the staged outputs: the workspace stays as it was."""
        shutil.rmtree(self.dir, ignore_errors=True)

    def _swap(self, writes: list[Path]) -> None:
        trash = self.dir / "replaced"
        for rel in writes:
            new, final = self.staging / rel, self.ws.root / rel
            if not new.exists() and not new.is_symlink():
                continue  # not written this time (or already swapped in): keep what is there
            final.parent.mkdir(parents=True, exist_ok=True)
            if final.exists() or final.is_symlink():
                aside = trash / rel
                aside.parent.mkdir(parents=True, exist_ok=True)
                if aside.exists():
                    shutil.rmtree(aside) if aside.is_dir() else aside.unlink()
                os.replace(final, aside)
            os.replace(new, final)
        shutil.rmtree(self.dir, ignore_errors=True)
