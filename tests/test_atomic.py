"""atomic_write / atomic_path: complete file or nothing, never a stray temporary."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mirage2matter import atomic
from mirage2matter.atomic import atomic_path, atomic_write


def _listing(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir())


def test_write_bytes_and_text(tmp_path: Path) -> None:
    with atomic_write(tmp_path / "a.bin") as f:
        f.write(b"\x00\x01payload")
    with atomic_write(tmp_path / "b.txt", "w", encoding="utf-8") as f:
        f.write("grüße\n")
    assert (tmp_path / "a.bin").read_bytes() == b"\x00\x01payload"
    assert (tmp_path / "b.txt").read_text(encoding="utf-8") == "grüße\n"
    assert _listing(tmp_path) == ["a.bin", "b.txt"]


def test_temp_name_and_target_untouched_until_commit(tmp_path: Path) -> None:
    target = tmp_path / "scene.ply"
    target.write_bytes(b"old")
    with atomic_write(target) as f:
        tmp = Path(f.name)
        assert tmp.parent == tmp_path
        assert tmp.name.startswith(f".scene.ply.tmp-{os.getpid()}-")
        f.write(b"new")
        f.flush()
        assert target.read_bytes() == b"old"  # readers still see the old artifact
    assert target.read_bytes() == b"new"
    assert not tmp.exists()


def test_body_may_close_the_file(tmp_path: Path) -> None:
    with atomic_write(tmp_path / "x") as f:
        f.write(b"abc")
        f.close()
    assert (tmp_path / "x").read_bytes() == b"abc"


@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
def test_exception_leaves_no_file_and_no_temp(tmp_path: Path, exc: type[BaseException]) -> None:
    with pytest.raises(exc):
        with atomic_write(tmp_path / "out.bin") as f:
            f.write(b"partial")
            raise exc()
    assert _listing(tmp_path) == []


def test_exception_keeps_previous_content(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    target.write_text("complete")
    with pytest.raises(ValueError):
        with atomic_write(target, "w") as f:
            f.write("half")
            raise ValueError("boom")
    assert target.read_text() == "complete"
    assert _listing(tmp_path) == ["out.json"]


@pytest.mark.parametrize("fail_at", ["fsync", "replace"])
def test_failing_commit_cleans_up(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fail_at: str) -> None:
    def broken(*args: object, **kwargs: object) -> None:
        raise OSError(5, "simulated I/O error")

    monkeypatch.setattr(atomic.os, fail_at, broken)
    with pytest.raises(OSError, match="simulated"):
        with atomic_write(tmp_path / "out.bin") as f:
            f.write(b"data")
    assert _listing(tmp_path) == []


def test_permissions_follow_umask(tmp_path: Path) -> None:
    mask = os.umask(0)
    os.umask(mask)
    with atomic_write(tmp_path / "m") as f:
        f.write(b"1")
    assert (tmp_path / "m").stat().st_mode & 0o777 == 0o666 & ~mask


def test_missing_directory_is_a_clear_error(tmp_path: Path) -> None:
    target = tmp_path / "nope" / "out.bin"
    with pytest.raises(FileNotFoundError, match="does not exist") as info:
        with atomic_write(target):
            pass
    assert str(target) in str(info.value)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        with atomic_path(target):
            pass


def test_target_is_a_directory(tmp_path: Path) -> None:
    (tmp_path / "d").mkdir()
    with pytest.raises(IsADirectoryError, match="directory"):
        with atomic_write(tmp_path / "d"):
            pass


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root ignores directory permissions")
def test_unwritable_directory_is_a_clear_error(tmp_path: Path) -> None:
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(PermissionError, match="not writable"):
            with atomic_write(ro / "x"):
                pass
    finally:
        ro.chmod(0o755)


@pytest.mark.parametrize("mode", ["rb", "ab", "r+b", "xb"])
def test_non_truncating_modes_rejected(tmp_path: Path, mode: str) -> None:
    with pytest.raises(ValueError, match="write mode"):
        with atomic_write(tmp_path / "x", mode):
            pass
    assert _listing(tmp_path) == []


def test_atomic_path_keeps_suffix_and_commits(tmp_path: Path) -> None:
    target = tmp_path / "preview.mp4"
    with atomic_path(target) as tmp:
        assert tmp.suffix == ".mp4" and tmp.parent == tmp_path and tmp.name.startswith(".preview.mp4.tmp-")
        assert tmp.exists()
        tmp.write_bytes(b"video")  # e.g. a library that opens the name itself
        assert not target.exists()
    assert target.read_bytes() == b"video"
    assert _listing(tmp_path) == ["preview.mp4"]


def test_atomic_path_exception_removes_partial_file(tmp_path: Path) -> None:
    target = tmp_path / "frame.png"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half a png")
            raise RuntimeError("encoder crashed")
    assert _listing(tmp_path) == []


def test_atomic_path_missing_temp_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="temporary"):
        with atomic_path(tmp_path / "a.txt") as tmp:
            tmp.unlink()
    assert _listing(tmp_path) == []


def test_unwritable_directory_reported_before_writing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Runs as root too, where real permission bits would not stop the write.
    monkeypatch.setattr(atomic.os, "access", lambda *a, **k: False)
    with pytest.raises(PermissionError, match="not writable") as info:
        with atomic_path(tmp_path / "x.png"):
            pass
    assert str(tmp_path) in str(info.value)
    assert _listing(tmp_path) == []


def test_atomic_dir_replaces_on_success_and_leaves_nothing_on_failure(tmp_path):
    from mirage2matter.atomic import atomic_dir

    out = tmp_path / "stage"
    with atomic_dir(out) as tmp:
        (tmp / "a.txt").write_text("first")
        assert not out.exists()  # nothing visible until the stage completes
    assert (out / "a.txt").read_text() == "first"
    with pytest.raises(RuntimeError):
        with atomic_dir(out) as tmp:
            (tmp / "a.txt").write_text("half")
            raise RuntimeError("killed mid-stage")
    assert (out / "a.txt").read_text() == "first"  # the old output survives a failed rerun
    with atomic_dir(out) as tmp:
        (tmp / "b.txt").write_text("second")
    assert sorted(p.name for p in out.iterdir()) == ["b.txt"]  # replaced whole, not merged
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stage"]  # no temporaries or old copies
