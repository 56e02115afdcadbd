"""Crash-safe episode staging: each finished attempt is committed on its own, then consolidated.

A generation run writes into ``<parent>/.<name>.staging/`` next to the dataset folder:

    run.json                      what is being generated (a fingerprint); a rerun must match it
    lock                          flock'ed by the running generator (two runs at once -> error)
    attempts/attempt-000012/      one committed attempt (built under a temporary name, renamed):
        result.json               seed, success, reason, task, length, stats, randomisation, ...
        frames.parquet            per-frame state / action / timestamp / frame_index (successes)
        observation.images.<cam>.mp4

An attempt folder exists completely or not at all (``atomic_dir``), so a run killed at any point
(SIGKILL included) resumes from the committed attempts without losing or duplicating one. The
dataset folder itself is built by :func:`consolidate` in a temporary sibling and swapped in whole,
after which the staging folder is removed; rerunning a consolidation that was killed redoes it.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_dir, atomic_write
from ..errors import M2MError
from .lerobot import write_dataset
from .spec import DatasetSpec, EpisodeData, video_key
from .staged import StagedEpisode
from .stats import to_json
from .video import decoded_image_stats, encode_video

_ATTEMPT_RE = re.compile(r"attempt-(\d{6})\Z")


class StagingError(M2MError, RuntimeError):
    """The staging area belongs to a different run, or another run holds it."""


def staging_dir_for(out_dir: Path) -> Path:
    out_dir = Path(out_dir)
    return out_dir.parent / f".{out_dir.name}.staging"


class Staging:
    """The staging folder of one dataset being generated; hold it with ``with Staging.open(...)``."""

    def __init__(self, root: Path, spec: DatasetSpec, fingerprint: dict[str, Any]):
        self.root = root
        self.spec = spec
        self.fingerprint = fingerprint
        self._lock_fd: int | None = None

    @classmethod
    def open(cls, out_dir: Path, spec: DatasetSpec, fingerprint: dict[str, Any]) -> Staging:
        """Create the staging area for ``out_dir`` or reopen one left by a killed run with the same
        fingerprint; a different fingerprint is refused (its attempts would be mixed into this run)."""
        root = staging_dir_for(out_dir)
        record = {"spec": spec.to_json(), "fingerprint": fingerprint}
        record = json.loads(json.dumps(record))  # normalise tuples/lists for comparison
        run_json = root / "run.json"
        if run_json.is_file():
            old = json.loads(run_json.read_text(encoding="utf-8"))
            if old != record:
                diff = sorted(k for k in set(old.get("fingerprint", {})) | set(record["fingerprint"])
                              if old.get("fingerprint", {}).get(k) != record["fingerprint"].get(k))  # fmt: skip
                raise StagingError(
                    f"{root} holds an unfinished run with different settings ({', '.join(diff) or 'spec'}); "
                    f"rerun with the same options to resume it, or delete {root} to start over"
                )
        else:
            (root / "attempts").mkdir(parents=True, exist_ok=True)
            with atomic_write(run_json, "w", encoding="utf-8") as f:
                json.dump(record, f, indent=2)
        staging = cls(root, spec, fingerprint)
        staging._lock()
        staging._remove_debris()
        return staging

    def _lock(self) -> None:
        fd = os.open(self.root / "lock", os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise StagingError(
                f"another generation run is writing {self.root} right now; wait for it or stop it"
            ) from None
        self._lock_fd = fd

    def close(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)  # releases the flock
            self._lock_fd = None

    def __enter__(self) -> Staging:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _remove_debris(self) -> None:
        # Temporaries of attempts that a killed worker never finished (we hold the lock: nobody else writes).
        for p in (self.root / "attempts").iterdir():
            if p.name.startswith(".") and p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            elif p.name.startswith("."):
                p.unlink(missing_ok=True)

    @property
    def attempts_dir(self) -> Path:
        return self.root / "attempts"

    def committed(self) -> dict[int, dict[str, Any]]:
        """attempt index -> result.json of every committed attempt."""
        out: dict[int, dict[str, Any]] = {}
        for p in sorted(self.attempts_dir.iterdir()):
            m = _ATTEMPT_RE.match(p.name)
            if m and (p / "result.json").is_file():
                out[int(m.group(1))] = json.loads((p / "result.json").read_text(encoding="utf-8"))
        return out

    def episodes(self, attempts: list[int]) -> list[StagedEpisode]:
        eps = []
        for a in attempts:
            d = self.attempts_dir / f"attempt-{a:06d}"
            result = json.loads((d / "result.json").read_text(encoding="utf-8"))
            if not result.get("success"):
                raise StagingError(f"attempt {a} did not succeed; it cannot become an episode")
            eps.append(StagedEpisode(d, result))
        return eps

    def remove(self) -> None:
        self.close()
        shutil.rmtree(self.root, ignore_errors=True)


def encode_attempt(
    spec: DatasetSpec,
    attempt: int,
    result: dict[str, Any],
    episode: EpisodeData | None,
) -> tuple[dict[str, Any], dict[str, bytes]]:
    """One attempt as content: (its result record, its files by name: frames.parquet and one MP4 per camera for a
    success, none for a failure). Encoded in a private temporary folder, so a worker on any machine can make it
    (the encoding is the costly part); :func:`write_attempt` puts it into the staging area."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    result = dict(result, attempt=attempt, success=episode is not None and bool(result.get("success", True)))
    files: dict[str, bytes] = {}
    if not result["success"]:
        return result, files
    assert episode is not None
    episode.check(spec)
    t = episode.length
    with tempfile.TemporaryDirectory(prefix="m2m-attempt-") as d:
        tmp = Path(d)
        table = pa.table({
            "observation.state": pa.FixedSizeListArray.from_arrays(
                pa.array(episode.state.astype(np.float32).ravel()), len(spec.state_names)),
            "action": pa.FixedSizeListArray.from_arrays(
                pa.array(episode.action.astype(np.float32).ravel()), len(spec.action_names)),
            "timestamp": pa.array((np.arange(t) / spec.fps).astype(np.float32)),
            "frame_index": pa.array(np.arange(t, dtype=np.int64)),
        })  # fmt: skip
        pq.write_table(table, tmp / "frames.parquet")
        image_stats = {}
        for cam in spec.cameras:
            key = video_key(cam)
            encode_video(tmp / f"{key}.mp4", episode.images[cam], spec.fps, spec.video)
            n, stats = decoded_image_stats(tmp / f"{key}.mp4")
            if n != t:
                raise RuntimeError(f"camera {cam}: the encoder wrote {n} frames for {t} given")
            image_stats[key] = to_json(stats)
        files = {p.name: p.read_bytes() for p in sorted(tmp.iterdir())}
    result.update(task=episode.task, length=t, image_stats=image_stats)
    return result, files


def write_attempt(staging_root: Path, result: dict[str, Any], files: dict[str, bytes]) -> dict[str, Any]:
    """Commit an encoded attempt (:func:`encode_attempt`) as ``attempts/attempt-NNNNNN``: built under a temporary
    name and renamed only when complete. Returns ``result``."""
    target = Path(staging_root) / "attempts" / f"attempt-{int(result['attempt']):06d}"
    with atomic_dir(target) as tmp:
        for name, data in files.items():
            if Path(name).name != name or name in ("result.json", "") or name.startswith("."):
                raise StagingError(f"attempt {result['attempt']}: refusing a file named {name!r}")  # a worker's bug
            (tmp / name).write_bytes(data)
        with atomic_write(tmp / "result.json", "w", encoding="utf-8") as f:
            json.dump(result, f, indent=1)
    return result


def commit_attempt(
    staging_root: Path,
    spec: DatasetSpec,
    attempt: int,
    result: dict[str, Any],
    episode: EpisodeData | None,
) -> dict[str, Any]:
    """Encode and commit one attempt (a success with its ``episode``, or a failure with ``episode=None``) in one
    process. Returns the result record as written (with length, task and decoded-video image stats added for
    successes)."""
    return write_attempt(staging_root, *encode_attempt(spec, attempt, result, episode))


def consolidate(
    staging: Staging,
    out_dir: Path,
    attempts: list[int],
    fmt: str,
    extra: Callable[[Path, list[StagedEpisode]], None] | None = None,
) -> dict[str, Any]:
    """Build the dataset from the committed ``attempts`` (in this order) in a temporary sibling of
    ``out_dir`` and swap it in; ``extra(tmp_dir, episodes)`` may add files (summary, preview) to it
    first. Then remove the staging area. Returns the dataset's info.json. Idempotent: a consolidation
    killed midway leaves the staging area intact and is simply run again."""
    episodes = staging.episodes(attempts)
    if not episodes:
        raise StagingError("no successful episodes to write; nothing was written")
    with atomic_dir(out_dir) as tmp:
        info = write_dataset(tmp, episodes, staging.spec, fmt)
        if extra is not None:
            extra(tmp, episodes)
    staging.remove()
    return info
