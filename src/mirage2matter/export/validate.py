"""Check a LeRobot dataset (v3.0 or v2.1) against the format, with its own reader.

Deliberately shares no code with the writers (it reads the files with pyarrow and decodes the
videos with PyAV from the layout and the path templates in ``meta/info.json``), so a writer bug
cannot hide itself. ``validate(dataset_dir)`` returns a list of problems; empty means valid:

- info.json has the required fields and features; totals match the files;
- indices are contiguous: ``index`` 0..N-1, ``episode_index`` 0..E-1 in order, ``frame_index``
  0..L-1 within each episode, ``timestamp = frame_index / fps``, ``task_index`` names a task;
- each episode's metadata (length, data rows, dataset_from/to_index) agrees with the data;
- every video decodes, has the feature's size, and holds exactly one frame per data row (per
  episode: the frames inside its [from_timestamp, to_timestamp) slice);
- stats.json equals the stats recomputed from the data rows and the decoded video frames.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

_REQUIRED_INFO = ("codebase_version", "fps", "total_episodes", "total_frames", "total_tasks", "features",
                  "data_path", "video_path")  # fmt: skip
_INDEX_COLUMNS = ("timestamp", "frame_index", "episode_index", "index", "task_index")
_STAT_FIELDS = ("min", "max", "mean", "std", "count")
_MAX_REPORTED = 50


class _Problems(list):
    def add(self, msg: str) -> None:
        if len(self) < _MAX_REPORTED:
            self.append(msg)
        elif len(self) == _MAX_REPORTED:
            self.append("... (more problems not listed)")


def validate(dataset_dir: str | Path) -> list[str]:
    """Problems found in the dataset at ``dataset_dir`` (empty list: it is valid)."""
    root = Path(dataset_dir)
    problems = _Problems()
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        return [f"{info_path} not found: not a LeRobot dataset"]
    try:
        info = json.loads(info_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        return [f"{info_path}: unreadable JSON ({e})"]
    missing = [k for k in _REQUIRED_INFO if k not in info]
    if missing:
        return [f"meta/info.json lacks {', '.join(missing)}"]
    _check_info(info, problems)
    if problems:  # the layout itself is wrong: reading files by it would only add noise
        return list(problems)
    version = info["codebase_version"]
    try:
        if version == "v3.0":
            _check_v30(root, info, problems)
        elif version == "v2.1":
            _check_v21(root, info, problems)
        else:
            problems.add(f"codebase_version {version!r} is not supported (v3.0 or v2.1)")
    except Exception as e:  # a reader crash is a finding about the dataset, not a crash of the validator
        problems.add(f"could not read the dataset: {type(e).__name__}: {e}")
    return list(problems)


_DTYPES = {"float32": "f", "float64": "f", "int64": "i", "int32": "i", "bool": "b", "string": "OUS"}  # numpy kinds


def _check_info(info: dict, problems: _Problems) -> None:
    """info.json's own values: types and ranges a reader divides or indexes by."""
    for k in ("total_episodes", "total_frames", "total_tasks"):
        if isinstance(info[k], bool) or not isinstance(info[k], int) or info[k] < 0:
            problems.add(f"meta/info.json: {k} = {info[k]!r} is not a count")
    fps = info["fps"]
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not 0 < fps <= 1000:
        problems.add(f"meta/info.json: fps = {fps!r} is not a rate in (0, 1000]")
    if "chunks_size" in info and (isinstance(info["chunks_size"], bool) or not isinstance(info["chunks_size"], int)
                                  or info["chunks_size"] < 1):  # fmt: skip
        problems.add(f"meta/info.json: chunks_size = {info['chunks_size']!r} is not a positive count")
    if "robot_type" in info and not isinstance(info["robot_type"], str | None):
        problems.add(f"meta/info.json: robot_type = {info['robot_type']!r} is not text")
    feats = info["features"]
    if not isinstance(feats, dict) or not all(isinstance(f, dict) for f in feats.values()):
        problems.add("meta/info.json: features must map each name to {dtype, shape, names}")
        return
    for k, f in feats.items():
        shape = f.get("shape")
        if not (isinstance(shape, list) and shape and all(isinstance(d, int) and not isinstance(d, bool) and d > 0
                                                         for d in shape)):  # fmt: skip
            problems.add(f"meta/info.json: feature {k} shape {shape!r} is not a list of positive sizes")
        if f.get("dtype") not in (*_DTYPES, "video", "image"):
            problems.add(f"meta/info.json: feature {k} dtype {f.get('dtype')!r} is not one of "
                         f"{', '.join([*_DTYPES, 'video', 'image'])}")  # fmt: skip


# ---- readers --------------------------------------------------------------------------------------
def _read_parquet(path: Path):
    import pyarrow.parquet as pq

    return pq.read_table(path)


def _column(table, name: str) -> np.ndarray:
    """A column as numpy: [N] for scalars, [N, D] for fixed or variable length lists."""
    import pyarrow as pa

    col = table.column(name).combine_chunks()
    if pa.types.is_list(col.type) or pa.types.is_fixed_size_list(col.type) or pa.types.is_large_list(col.type):
        flat = col.flatten().to_numpy(zero_copy_only=False)
        return flat.reshape(len(col), -1)
    return col.to_numpy(zero_copy_only=False)


def _decode(path: Path) -> Iterator[tuple[float, np.ndarray]]:
    """(time in seconds, uint8 [H,W,3]) of every frame of the first video stream."""
    import av

    with av.open(str(path)) as c:
        s = c.streams.video[0]
        for fr in c.decode(s):
            yield float(fr.pts * s.time_base), fr.to_ndarray(format="rgb24")


class _ImageStats:
    def __init__(self) -> None:
        self.n = 0
        self.px = 0
        self.s = np.zeros(3)
        self.ss = np.zeros(3)
        self.lo = np.full(3, np.inf)
        self.hi = np.full(3, -np.inf)

    def add(self, im: np.ndarray) -> None:
        x = im.reshape(-1, 3).astype(np.float64) / 255.0
        self.s += x.sum(0)
        self.ss += (x * x).sum(0)
        self.lo = np.minimum(self.lo, x.min(0))
        self.hi = np.maximum(self.hi, x.max(0))
        self.px += x.shape[0]
        self.n += 1

    def stats(self) -> dict[str, np.ndarray]:
        m = self.s / self.px
        return {"min": self.lo, "max": self.hi, "mean": m, "std": np.sqrt(np.maximum(self.ss / self.px - m * m, 0)),
                "count": np.array([self.n])}  # fmt: skip


def _vec_stats(x: np.ndarray) -> dict[str, np.ndarray]:
    x = x.astype(np.float64).reshape(len(x), -1)
    return {"min": x.min(0), "max": x.max(0), "mean": x.mean(0), "std": x.std(0), "count": np.array([len(x)])}


def _compare_stats(name: str, stored: Any, ref: dict[str, np.ndarray], problems: _Problems, atol: float) -> None:
    if not isinstance(stored, dict):
        problems.add(f"stats.json: no stats for {name}")
        return
    for k in _STAT_FIELDS:
        if k not in stored:
            problems.add(f"stats.json: {name} lacks {k}")
            continue
        got = np.asarray(stored[k], dtype=np.float64).ravel()
        want = np.asarray(ref[k], dtype=np.float64).ravel()
        if got.shape != want.shape:
            problems.add(f"stats.json: {name}/{k} has {got.size} values, expected {want.size}")
        elif not np.allclose(got, want, rtol=1e-5, atol=atol):
            problems.add(f"stats.json: {name}/{k} = {np.round(got, 6).tolist()} but the data give "
                         f"{np.round(want, 6).tolist()}")  # fmt: skip


# ---- shared checks ----------------------------------------------------------------------------------
def _split_features(info: dict, problems: _Problems) -> tuple[list[str], list[str]]:
    feats = info["features"]
    videos = [k for k, f in feats.items() if f.get("dtype") == "video"]
    data = [k for k, f in feats.items() if f.get("dtype") not in ("video", "image")]
    for k in _INDEX_COLUMNS:
        if k not in feats:
            problems.add(f"meta/info.json: features lack {k}")
    for k in videos:
        shape = feats[k].get("shape")
        if not (isinstance(shape, list) and len(shape) == 3 and shape[2] == 3):
            problems.add(f"meta/info.json: video feature {k} shape {shape} is not [height, width, 3]")
    return videos, data


def _check_rows(table, info: dict, data_feats: list[str], problems: _Problems) -> dict[str, np.ndarray]:
    """Column presence / shapes and dataset-wide index checks; returns the columns as numpy."""
    feats = info["features"]
    cols: dict[str, np.ndarray] = {}
    undeclared = [c for c in table.column_names if c not in feats]
    if undeclared:
        problems.add(f"data: column(s) {', '.join(undeclared)} not declared in meta/info.json features")
    for k in data_feats:
        if k not in table.column_names:
            problems.add(f"data: column {k} missing")
            continue
        arr = _column(table, k)
        want = int(np.prod(feats[k]["shape"]))
        got = 1 if arr.ndim == 1 else arr.shape[1]
        if got != want:
            problems.add(f"data: {k} has {got} values per frame, info.json says shape {feats[k]['shape']}")
        kind = _DTYPES.get(feats[k].get("dtype"), "")
        if arr.dtype.kind not in kind and not (kind == "f" and arr.dtype.kind in "iu"):
            problems.add(f"data: {k} holds {arr.dtype} values, info.json says {feats[k].get('dtype')}")
        if arr.dtype.kind in "f" and not np.isfinite(arr).all():
            problems.add(f"data: {k} holds NaN/Inf")
        cols[k] = arr
    if any(k not in cols for k in _INDEX_COLUMNS):
        return cols
    n = len(cols["index"])
    if n != info["total_frames"]:
        problems.add(f"data: {n} rows, info.json total_frames = {info['total_frames']}")
    if not np.array_equal(cols["index"], np.arange(n)):
        problems.add("data: index is not 0..N-1 in order")
    ep = cols["episode_index"]
    if n and (ep[0] != 0 or np.any(np.diff(ep) < 0) or np.any(np.diff(ep) > 1)):
        problems.add("data: episode_index does not run 0, 1, 2, ... contiguously in order")
    n_ep = len(np.unique(ep))
    if n_ep != info["total_episodes"]:
        problems.add(f"data: {n_ep} episodes, info.json total_episodes = {info['total_episodes']}")
    starts = np.flatnonzero(np.r_[True, np.diff(ep) != 0])
    expected_fi = np.arange(n) - np.repeat(starts, np.diff(np.r_[starts, n]))
    if not np.array_equal(cols["frame_index"], expected_fi):
        problems.add("data: frame_index does not restart at 0 and count up within each episode")
    ts = np.asarray(cols["timestamp"], np.float64)
    if not np.allclose(ts, expected_fi / float(info["fps"]), atol=1e-4):
        problems.add(f"data: timestamp is not frame_index / fps (fps {info['fps']})")
    ti = cols["task_index"]
    if n and (ti.min() < 0 or ti.max() >= info["total_tasks"]):
        problems.add(f"data: task_index outside 0..{info['total_tasks'] - 1}")
    for e in np.unique(ep):
        if len(np.unique(ti[ep == e])) != 1:
            problems.add(f"data: episode {e} has more than one task_index")
    _check_state_action(cols, info, problems)
    return cols


# A joint command names where the joint is one control tick later: the arm lags behind it by about one tick's
# motion (measured on the demo's datasets: median 0.02-0.04 rad, at most 0.24 rad at the Panda's speeds), so a
# frame off by more than this (or 6x the dataset's median) whose state also jumped by more than JUMP_TOL in the
# tick (a row out of order jumps about as far as it misses) holds a row out of order or state and action mixed up.
# Measured on 300 grasps: the arm missed the expert's fastest commands by up to 0.56 rad while moving at most
# 0.31 rad per tick.
STATE_ACTION_TOL = 0.3
JUMP_TOL = 0.45


def _check_state_action(cols: dict[str, np.ndarray], info: dict, problems: _Problems) -> None:
    """``action`` at frame t against ``observation.state`` at t + 1, over the entries both name (joint
    positions; the gripper command is named apart)."""
    feats = info["features"]
    if not {"observation.state", "action", "episode_index", "frame_index"} <= set(cols):
        return
    s_names, a_names = feats["observation.state"].get("names") or [], feats["action"].get("names") or []
    common = [n for n in a_names if isinstance(n, str) and n in s_names]
    S, A = np.asarray(cols["observation.state"], np.float64), np.asarray(cols["action"], np.float64)
    if not common or S.ndim != 2 or A.ndim != 2:
        return
    S = S[:, [s_names.index(n) for n in common]]
    A = A[:, [a_names.index(n) for n in common]]
    ep = cols["episode_index"]
    pairs = np.flatnonzero(ep[1:] == ep[:-1])  # rows t whose next row is the same episode's next frame
    if not len(pairs):
        return
    r = np.abs(A[pairs] - S[pairs + 1]).max(axis=1)
    tol = max(STATE_ACTION_TOL, 6 * float(np.median(r)))
    jump = np.abs(S[pairs + 1] - S[pairs]).max(axis=1)
    for i in np.flatnonzero((r > tol) & (jump > max(JUMP_TOL, tol)))[:5]:
        t = pairs[i]
        problems.add(
            f"data: episode {ep[t]} frame {cols['frame_index'][t]}: its action and the next frame's state disagree by "
            f"{r[i]:.3f} (> {tol:.3f}) in {', '.join(common)}; are rows out of order, or state and action from "
            "different steps?"
        )


def _check_stats(root: Path, cols: dict, video_stats: dict[str, _ImageStats], problems: _Problems) -> None:
    path = root / "meta" / "stats.json"
    if not path.is_file():
        problems.add("meta/stats.json not found")
        return
    stored = json.loads(path.read_text(encoding="utf-8"))
    for k, arr in cols.items():
        if len(arr):
            _compare_stats(k, stored.get(k), _vec_stats(arr), problems, atol=1e-6)
    for k, acc in video_stats.items():
        if acc.n:
            _compare_stats(k, stored.get(k), acc.stats(), problems, atol=1e-6)


def _check_video_frame(key: str, shape: list, im: np.ndarray, where: str, problems: _Problems) -> bool:
    if list(im.shape) != list(shape):
        problems.add(f"{where}: frames are {list(im.shape)}, feature {key} says {shape}")
        return False
    return True


# ---- v3.0 ---------------------------------------------------------------------------------------
def _check_v30(root: Path, info: dict, problems: _Problems) -> None:
    import pyarrow as pa

    videos, data_feats = _split_features(info, problems)
    fps = float(info["fps"])
    tasks_path = root / "meta" / "tasks.parquet"
    if not tasks_path.is_file():
        problems.add("meta/tasks.parquet not found")
        tasks: dict[int, str] = {}
    else:
        tt = _read_parquet(tasks_path)
        if not {"task_index", "task"} <= set(tt.column_names):
            problems.add(f"meta/tasks.parquet has columns {tt.column_names}, expected task_index and task")
            tasks = {}
        else:
            tasks = dict(zip(_column(tt, "task_index").tolist(), tt.column("task").to_pylist(), strict=True))
            if sorted(tasks) != list(range(len(tasks))):
                problems.add("meta/tasks.parquet: task_index is not 0..T-1")
            if len(tasks) != info["total_tasks"]:
                problems.add(
                    f"meta/tasks.parquet has {len(tasks)} tasks, info.json total_tasks = {info['total_tasks']}"
                )

    ep_files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    if not ep_files:
        problems.add("meta/episodes/chunk-*/file-*.parquet not found")
        return
    eps = pa.concat_tables([_read_parquet(p) for p in ep_files]).to_pylist()
    eps.sort(key=lambda r: r.get("episode_index", -1))
    if [r.get("episode_index") for r in eps] != list(range(len(eps))):
        problems.add("meta/episodes: episode_index is not 0..E-1")
    if len(eps) != info["total_episodes"]:
        problems.add(f"meta/episodes has {len(eps)} episodes, info.json total_episodes = {info['total_episodes']}")

    # Data files, in (chunk, file) order, as the episodes reference them.
    data_files = sorted({(r["data/chunk_index"], r["data/file_index"]) for r in eps})
    tables = []
    for c, f in data_files:
        p = root / info["data_path"].format(chunk_index=c, file_index=f)
        if not p.is_file():
            problems.add(f"{p.relative_to(root)} (referenced by meta/episodes) not found")
            return
        tables.append(_read_parquet(p))
    on_disk = sorted((root / "data").glob("chunk-*/file-*.parquet"))
    if len(on_disk) != len(data_files):
        problems.add(f"data/ holds {len(on_disk)} parquet files, meta/episodes references {len(data_files)}")
    table = pa.concat_tables(tables, promote_options="default") if tables else None
    if table is None:
        return
    cols = _check_rows(table, info, data_feats, problems)
    if "episode_index" not in cols:
        return
    ep_col, ti = cols["episode_index"], cols.get("task_index")

    for r in eps:
        e = r["episode_index"]
        rows = np.flatnonzero(ep_col == e)
        if len(rows) != r.get("length"):
            problems.add(f"episode {e}: meta length {r.get('length')}, data has {len(rows)} rows")
        if len(rows) and (rows[0] != r.get("dataset_from_index") or rows[-1] + 1 != r.get("dataset_to_index")):
            span = f"{r.get('dataset_from_index')}..{r.get('dataset_to_index')}"
            problems.add(f"episode {e}: dataset_from/to_index {span} but its rows are {rows[0]}..{rows[-1] + 1}")
        if ti is not None and len(rows) and tasks:
            t = tasks.get(int(ti[rows[0]]))
            if r.get("tasks") != [t]:
                problems.add(f"episode {e}: meta tasks {r.get('tasks')} but its task_index names {t!r}")

    # Videos: every frame decoded once; each episode's slice must hold exactly `length` frames.
    vstats = {}
    for key in videos:
        acc = _ImageStats()
        vstats[key] = acc
        shape = info["features"][key]["shape"]
        files = sorted({(r.get(f"videos/{key}/chunk_index"), r.get(f"videos/{key}/file_index")) for r in eps})
        total = 0
        for c, f in files:
            if c is None or f is None:
                problems.add(f"meta/episodes lacks videos/{key}/chunk_index or file_index")
                break
            p = root / info["video_path"].format(video_key=key, chunk_index=c, file_index=f)
            if not p.is_file():
                problems.add(f"{p.relative_to(root)} (referenced by meta/episodes) not found")
                continue
            times = []
            for t, im in _decode(p):
                if not _check_video_frame(key, shape, im, str(p.relative_to(root)), problems):
                    break
                times.append(t)
                acc.add(im)
            times_arr = np.asarray(times)
            total += len(times)
            in_file = [
                r for r in eps if (r.get(f"videos/{key}/chunk_index"), r.get(f"videos/{key}/file_index")) == (c, f)
            ]
            half = 0.5 / fps
            for r in in_file:
                t0, t1 = r[f"videos/{key}/from_timestamp"], r[f"videos/{key}/to_timestamp"]
                n = int(np.count_nonzero((times_arr >= t0 - half) & (times_arr < t1 - half)))
                if n != r["length"]:
                    problems.add(f"episode {r['episode_index']}: {key} has {n} frames in [{t0:.3f}, {t1:.3f}) s, "
                                 f"the data {r['length']} rows")  # fmt: skip
        if total != len(ep_col):
            problems.add(f"{key}: videos hold {total} frames, the data {len(ep_col)} rows")
    _check_stats(root, cols, vstats, problems)


# ---- v2.1 ---------------------------------------------------------------------------------------
def _jsonl(path: Path, problems: _Problems) -> list[dict]:
    if not path.is_file():
        problems.add(f"{path.name} not found in meta/")
        return []
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def _check_v21(root: Path, info: dict, problems: _Problems) -> None:
    import pyarrow as pa

    videos, data_feats = _split_features(info, problems)
    meta = root / "meta"
    eps = sorted(_jsonl(meta / "episodes.jsonl", problems), key=lambda r: r.get("episode_index", -1))
    tasks = {r["task_index"]: r["task"] for r in _jsonl(meta / "tasks.jsonl", problems)}
    if len(tasks) != info["total_tasks"]:
        problems.add(f"meta/tasks.jsonl has {len(tasks)} tasks, info.json total_tasks = {info['total_tasks']}")
    if [r.get("episode_index") for r in eps] != list(range(len(eps))):
        problems.add("meta/episodes.jsonl: episode_index is not 0..E-1")
    if len(eps) != info["total_episodes"]:
        problems.add(
            f"meta/episodes.jsonl has {len(eps)} episodes, info.json total_episodes = {info['total_episodes']}"
        )
    chunks_size = int(info.get("chunks_size", 1000))
    tables = []
    vstats = {k: _ImageStats() for k in videos}
    for r in eps:
        e = r["episode_index"]
        p = root / info["data_path"].format(episode_chunk=e // chunks_size, episode_index=e)
        if not p.is_file():
            problems.add(f"{p.relative_to(root)} not found")
            continue
        t = _read_parquet(p)
        tables.append(t)
        if t.num_rows != r.get("length"):
            problems.add(f"episode {e}: episodes.jsonl length {r.get('length')}, parquet has {t.num_rows} rows")
        if "task_index" in t.column_names and t.num_rows:
            name = tasks.get(int(_column(t, "task_index")[0]))
            if r.get("tasks") != [name]:
                problems.add(f"episode {e}: episodes.jsonl tasks {r.get('tasks')} but its task_index names {name!r}")
        for key in videos:
            vp = root / info["video_path"].format(episode_chunk=e // chunks_size, video_key=key, episode_index=e)
            if not vp.is_file():
                problems.add(f"{vp.relative_to(root)} not found")
                continue
            n = 0
            for _, im in _decode(vp):
                if not _check_video_frame(key, info["features"][key]["shape"], im, str(vp.relative_to(root)), problems):
                    break
                vstats[key].add(im)
                n += 1
            if n != t.num_rows:
                problems.add(f"episode {e}: {key} has {n} frames, the parquet {t.num_rows} rows")
    if not tables:
        return
    cols = _check_rows(pa.concat_tables(tables, promote_options="default"), info, data_feats, problems)
    _check_stats(root, cols, vstats, problems)
