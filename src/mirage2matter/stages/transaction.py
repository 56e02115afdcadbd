"""Nothing lost: one writer per workspace, and a stage's (or an edit's) outputs committed all at once.

**The lock.** Every command that writes a workspace holds an advisory ``flock`` on the workspace folder
(released by the kernel when the process dies, so a killed run never leaves a stale lock). A second writer is
refused with the holder's pid, command and start time (``.m2m/holder.json``). Under the lock, leftovers of
killed runs (the hidden ``.<name>.tmp-*`` / ``.<name>.old-*`` of atomic writes) are removed.

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

__all__ = ["Transaction", "WorkspaceBusy", "workspace_lock"]

# what atomic_write / atomic_dir leave behind when killed: ".<name>.tmp-<pid>-<hex>[.suffix]", ".<name>.old-..."
_LEFTOVER = re.compile(r"^\..+\.(tmp|old)-\d+-[0-9a-f]{8}(\.[A-Za-z0-9]+)?$")
_held: dict[Path, int] = {}  # workspaces this process holds the lock of, and how deep


class WorkspaceBusy(WorkspaceError):
    """Another command is writing the workspace."""


def _command() -> str:
    return "m2m " + " ".join(sys.argv[1:4]) if sys.argv and sys.argv[0].endswith(("m2m", "__main__.py")) else "python"


@contextmanager
def workspace_lock(ws: Workspace, command: str | None = None) -> Iterator[None]:
    """Hold ``ws``'s writer lock (re-entrant within a process); :class:`WorkspaceBusy` names the holder.

    The lock is an exclusive ``flock`` on the workspace folder itself, so it needs no lock file (a failing
    command leaves the workspace's files as they were); ``.m2m/holder.json`` says who holds it."""
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
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        try:
            h = json.loads(holder.read_text())
            who = f"pid {h['pid']} (`{h['command']}`, since {h['since']})"
        except (OSError, ValueError, KeyError, TypeError):
            who = "another process"
        raise WorkspaceBusy(
            f"workspace {ws.root} is being written by {who}; wait for it to finish (or stop it), then run again"
        ) from None
    _held[key] = 1
    try:
        info = {"pid": os.getpid(), "command": command or _command(), "since": time.strftime("%Y-%m-%d %H:%M:%S")}
        ws.state_dir.mkdir(exist_ok=True)
        holder.write_text(json.dumps(info))
        _remove_leftovers(ws.root)
        yield
    finally:
        _held.pop(key, None)
        holder.unlink(missing_ok=True)
        for d in (ws.state_dir / "txn", ws.state_dir):  # the state folder holds nothing between commands
            with contextlib.suppress(OSError):
                d.rmdir()
        if created and not any(ws.root.iterdir()):  # a command that wrote nothing leaves no workspace behind
            with contextlib.suppress(OSError):
                ws.root.rmdir()
        os.close(fd)  # releases the flock


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
