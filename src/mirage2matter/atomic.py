"""Atomic file writes: write to a temporary name in the target directory, then rename.

Every stage artifact goes through here (DESIGN.md section 3) so an interrupted run never leaves a
half-written file under its final name: a reader sees either the old file or the complete new
one. The temporary lives in the same directory because ``os.replace`` is only atomic within one
file system.
"""

from __future__ import annotations

import os
import secrets
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_path", "atomic_write"]


def _check_target(path: Path) -> None:
    """Fail early, with the path in the message, when ``path`` cannot be written."""
    parent = path.parent
    if not parent.exists():
        raise FileNotFoundError(f"cannot write {path}: directory {parent} does not exist")
    if not parent.is_dir():
        raise NotADirectoryError(f"cannot write {path}: {parent} is not a directory")
    if path.is_dir():
        raise IsADirectoryError(f"cannot write {path}: a directory of that name exists")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"cannot write {path}: directory {parent} is not writable")


def _temp_name(path: Path, keep_suffix: bool) -> Path:
    # The pid and random part keep concurrent writers of the same artifact apart; the leading
    # dot hides the temporary from globs such as "*.ply".
    tag = f"{os.getpid()}-{secrets.token_hex(4)}"
    suffix = path.suffix if keep_suffix else ""
    return path.with_name(f".{path.name}.tmp-{tag}{suffix}")


def _create_exclusive(path: Path, keep_suffix: bool) -> tuple[Path, int]:
    """Create a fresh temporary file next to ``path``; returns (temp path, open fd)."""
    for _ in range(100):
        tmp = _temp_name(path, keep_suffix)
        try:
            # 0o666 & ~umask, like open(); mkstemp's 0o600 would leak into the final artifact.
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        except OSError as e:
            raise type(e)(e.errno, f"cannot write {path}: creating temporary {tmp.name} failed: {e.strerror}") from e
        return tmp, fd
    raise FileExistsError(f"cannot write {path}: could not find a free temporary name")


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(directory: Path) -> None:
    # Makes the rename itself durable; not every platform / file system allows it, and the
    # rename has already happened, so failure here is not an error.
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _discard(tmp: Path) -> None:
    # Never let cleanup mask the exception that caused it.
    try:
        tmp.unlink()
    except OSError:
        pass


def _commit(tmp: Path, path: Path) -> None:
    os.replace(tmp, path)
    _fsync_dir(path.parent)


@contextmanager
def atomic_write(path: str | os.PathLike[str], mode: str = "wb", **open_kwargs: Any) -> Iterator[IO[Any]]:
    """Open a temporary file for writing; on success it replaces ``path`` atomically.

    ``mode`` is a write mode ("wb", "w", "wt", "w+b", ...); ``open_kwargs`` go to ``open``
    (e.g. ``encoding="utf-8"``, ``newline=""``). If the body raises, the temporary is removed
    and ``path`` is left untouched (old content or absent).

        with atomic_write(ws / "scene" / "metrics.json", "w", encoding="utf-8") as f:
            json.dump(metrics, f)
    """
    if not mode.startswith("w") or any(c in mode for c in "arx"):
        raise ValueError(f"atomic_write needs a truncating write mode such as 'wb' or 'w', got {mode!r}")
    path = Path(path)
    _check_target(path)
    tmp, fd = _create_exclusive(path, keep_suffix=False)
    os.close(fd)
    try:
        # Reopened by name (we created it exclusively) so that ``f.name`` is the temporary path.
        f = open(tmp, mode, **open_kwargs)
    except BaseException:
        _discard(tmp)
        raise
    try:
        with f:
            yield f
            if not f.closed:  # the body may have closed it itself
                f.flush()
                os.fsync(f.fileno())
            else:
                _fsync_file(tmp)
        _commit(tmp, path)
    except BaseException:
        # Also on KeyboardInterrupt: an interrupted stage must not leave debris behind.
        if not f.closed:
            f.close()
        _discard(tmp)
        raise


@contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary *path* next to ``path`` for libraries that want a filename.

    The temporary keeps ``path``'s suffix (``.png``, ``.mp4``, ...) so that libraries inferring
    the format from the name (PIL, ffmpeg, PyAV) pick the right one. It exists, empty, when
    yielded; the body must write it completely. On success it is fsynced and renamed onto
    ``path``; if the body raises, it is removed.

        with atomic_path(out / "preview.mp4") as tmp:
            write_video(tmp, frames)
    """
    path = Path(path)
    _check_target(path)
    tmp, fd = _create_exclusive(path, keep_suffix=True)
    os.close(fd)
    try:
        yield tmp
        if not tmp.is_file():
            raise FileNotFoundError(f"cannot write {path}: the temporary {tmp.name} was removed or is not a file")
        _fsync_file(tmp)
        _commit(tmp, path)
    except BaseException:
        _discard(tmp)
        raise


def replace_dir(tmp: str | os.PathLike[str], out_dir: str | os.PathLike[str]) -> None:
    """Move the finished folder ``tmp`` onto ``out_dir``; an existing ``out_dir`` is swapped out
    first and deleted after, so readers see either the old or the new folder, never a mix."""

    tmp, out_dir = Path(tmp), Path(out_dir)
    old = None
    if out_dir.exists():
        old = out_dir.with_name(f".{out_dir.name}.old-{os.getpid()}-{secrets.token_hex(4)}")
        os.replace(out_dir, old)
    os.replace(tmp, out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


@contextmanager
def atomic_dir(out_dir: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary sibling folder to build ``out_dir`` in. On success it replaces ``out_dir``
    (see :func:`replace_dir`); on any exception it is deleted, so a stage never leaves a half-built
    output folder behind."""

    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_dir.with_name(f".{out_dir.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}")
    tmp.mkdir()
    try:
        yield tmp
        replace_dir(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
