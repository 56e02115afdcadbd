"""LeRobot dataset writers: v3.0 (default) and v2.1 (for openpi), from staged episodes.

v3.0 (LeRobot ``CODEBASE_VERSION = "v3.0"``) packs many episodes per file:

    meta/info.json                              codebase_version, totals, fps, path templates, features
    meta/stats.json                             min / max / mean / std / count per feature
    meta/tasks.parquet                          task_index, indexed by the task string (pandas layout)
    meta/episodes/chunk-000/file-000.parquet    one row per episode: length, tasks, data and video
                                                file indices, dataset_from/to_index, video from/to
                                                timestamps, per-episode stats
    data/chunk-000/file-000.parquet             one row per frame
    videos/<video_key>/chunk-000/file-000.mp4   the episodes' frames back to back

v2.1 keeps one parquet and one mp4 per episode (``data/chunk-000/episode_000000.parquet``,
``videos/chunk-000/<video_key>/episode_000000.mp4``) with ``meta/episodes.jsonl``,
``meta/tasks.jsonl`` and ``meta/episodes_stats.jsonl``.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from .spec import INDEX_FEATURES, DatasetSpec
from .staged import StagedEpisode
from .stats import aggregate, from_json, to_json, vector_stats
from .video import concat_videos

FORMATS = ("lerobot-v3.0", "lerobot-v2.1")

CHUNKS_SIZE = 1000  # files per chunk folder (LeRobot's default)
DATA_FILE_MB = 100  # v3.0: start a new data file past this size
VIDEO_FILE_MB = 500  # v3.0: start a new video file past this size

V3_DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
V3_VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
V3_EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
V21_DATA_PATH = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
V21_VIDEO_PATH = "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"


def write_dataset(root: Path, episodes: list[StagedEpisode], spec: DatasetSpec, fmt: str) -> dict[str, Any]:
    """Write ``episodes`` (in order; episode_index = position) as a LeRobot dataset into the empty
    folder ``root``. Returns info.json's content."""
    if fmt == "lerobot-v3.0":
        return write_v30(root, episodes, spec)
    if fmt == "lerobot-v2.1":
        return write_v21(root, episodes, spec)
    raise ValueError(f"unknown dataset format {fmt!r}; choose one of {', '.join(FORMATS)}")


# ---- shared ------------------------------------------------------------------------------------
def _task_indices(episodes: list[StagedEpisode]) -> dict[str, int]:
    tasks: dict[str, int] = {}
    for ep in episodes:
        tasks.setdefault(ep.task, len(tasks))
    return tasks


def _episode_tables(episodes: list[StagedEpisode], tasks: dict[str, int]):
    """Each episode's frames with the dataset-wide columns added (episode_index, index, task_index)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    start = 0
    for e, ep in enumerate(episodes):
        t = pq.read_table(ep.frames_path)
        if t.num_rows != ep.length:
            raise ValueError(f"{ep.frames_path}: {t.num_rows} rows, result.json says {ep.length}")
        n = t.num_rows
        t = t.append_column("episode_index", pa.array(np.full(n, e, np.int64)))
        t = t.append_column("index", pa.array(np.arange(start, start + n, dtype=np.int64)))
        t = t.append_column("task_index", pa.array(np.full(n, tasks[ep.task], np.int64)))
        order = ["observation.state", "action", *INDEX_FEATURES]
        yield e, start, t.select(order)
        start += n


def _numeric_stats(table) -> dict[str, dict[str, np.ndarray]]:
    out = {}
    for name in ("observation.state", "action", *INDEX_FEATURES):
        col = table.column(name).combine_chunks()
        if name in ("observation.state", "action"):
            arr = col.flatten().to_numpy().reshape(len(col), -1)
        else:
            arr = col.to_numpy()
        out[name] = vector_stats(arr)
    return out


def _image_stats(ep: StagedEpisode, spec: DatasetSpec) -> dict[str, dict[str, np.ndarray]]:
    return {k: from_json(ep.result["image_stats"][k]) for k in spec.video_keys}


def _write_json(path: Path, obj: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=4), encoding="utf-8")


def _base_info(spec: DatasetSpec, episodes: list[StagedEpisode], tasks: dict[str, int], version: str):
    n_ep = len(episodes)
    return {
        "codebase_version": version,
        "robot_type": spec.robot_type,
        "total_episodes": n_ep,
        "total_frames": sum(ep.length for ep in episodes),
        "total_tasks": len(tasks),
    }


def _tasks_parquet(path: Path, tasks: dict[str, int]) -> None:
    """meta/tasks.parquet as pandas writes ``DataFrame({"task_index": ...}, index=Index(tasks, name="task"))``,
    so ``pd.read_parquet`` gives the task strings as the index (what LeRobot reads) without pandas here."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    names = list(tasks)
    df_meta = {
        "index_columns": ["task"],
        "column_indexes": [
            {
                "name": None,
                "field_name": None,
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": {"encoding": "UTF-8"},
            }
        ],  # fmt: skip
        "columns": [
            {
                "name": "task_index",
                "field_name": "task_index",
                "pandas_type": "int64",
                "numpy_type": "int64",
                "metadata": None,
            },
            {"name": "task", "field_name": "task", "pandas_type": "unicode", "numpy_type": "object", "metadata": None},
        ],  # fmt: skip
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.0",
    }
    schema = pa.schema([("task_index", pa.int64()), ("task", pa.string())],
                       metadata={b"pandas": json.dumps(df_meta).encode()})  # fmt: skip
    table = pa.table({"task_index": [tasks[n] for n in names], "task": names}, schema=schema)
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)


def _stats_json(numeric: dict, images: dict) -> dict[str, Any]:
    return {k: to_json(v) for k, v in {**images, **numeric}.items()}


def _groups(sizes: list[int], limit_bytes: int) -> list[list[int]]:
    """Split item indices into consecutive groups whose summed size stays under ``limit_bytes``
    (a single larger item gets a group of its own)."""
    groups: list[list[int]] = [[]]
    acc = 0
    for i, s in enumerate(sizes):
        if groups[-1] and acc + s > limit_bytes:
            groups.append([])
            acc = 0
        groups[-1].append(i)
        acc += s
    return groups


def _chunk_file(n: int) -> tuple[int, int]:
    return n // CHUNKS_SIZE, n % CHUNKS_SIZE


# ---- v3.0 --------------------------------------------------------------------------------------
def write_v30(root: Path, episodes: list[StagedEpisode], spec: DatasetSpec) -> dict[str, Any]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    tasks = _task_indices(episodes)
    rows: list[dict[str, Any]] = [{} for _ in episodes]
    tables = []
    per_ep_numeric = []
    for e, start, t in _episode_tables(episodes, tasks):
        tables.append(t)
        per_ep_numeric.append(_numeric_stats(t))
        rows[e].update({
            "episode_index": e, "tasks": [episodes[e].task], "length": t.num_rows,
            "dataset_from_index": start, "dataset_to_index": start + t.num_rows,
        })  # fmt: skip

    # Data files: consecutive episodes, a new file past DATA_FILE_MB.
    for f, group in enumerate(_groups([t.nbytes for t in tables], DATA_FILE_MB * 2**20)):
        chunk, file = _chunk_file(f)
        path = root / V3_DATA_PATH.format(chunk_index=chunk, file_index=file)
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.concat_tables([tables[e] for e in group]), path)
        for e in group:
            rows[e].update({"data/chunk_index": chunk, "data/file_index": file})

    # Video files per camera: the episodes' mp4s remuxed back to back.
    for key in spec.video_keys:
        sizes = [ep.video_path(key).stat().st_size for ep in episodes]
        for f, group in enumerate(_groups(sizes, VIDEO_FILE_MB * 2**20)):
            chunk, file = _chunk_file(f)
            path = root / V3_VIDEO_PATH.format(video_key=key, chunk_index=chunk, file_index=file)
            path.parent.mkdir(parents=True, exist_ok=True)
            spans = concat_videos([episodes[e].video_path(key) for e in group], path, spec.fps)
            for e, (t0, t1) in zip(group, spans, strict=True):
                rows[e].update({f"videos/{key}/chunk_index": chunk, f"videos/{key}/file_index": file,
                                f"videos/{key}/from_timestamp": t0, f"videos/{key}/to_timestamp": t1})  # fmt: skip

    image_stats = [_image_stats(ep, spec) for ep in episodes]
    for e in range(len(episodes)):
        for feat, st in {**image_stats[e], **per_ep_numeric[e]}.items():
            for k, v in st.items():
                rows[e][f"stats/{feat}/{k}"] = np.asarray(v).ravel().tolist()
        rows[e].update({"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0})
    ep_table = pa.Table.from_pylist(rows)
    ep_path = root / V3_EPISODES_PATH.format(chunk_index=0, file_index=0)
    ep_path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(ep_table, ep_path)

    _tasks_parquet(root / "meta" / "tasks.parquet", tasks)
    numeric = _numeric_stats(pa.concat_tables(tables))
    images = {k: aggregate([s[k] for s in image_stats]) for k in spec.video_keys}
    _write_json(root / "meta" / "stats.json", _stats_json(numeric, images))

    info = _base_info(spec, episodes, tasks, "v3.0")
    info.update({
        "chunks_size": CHUNKS_SIZE,
        "data_files_size_in_mb": DATA_FILE_MB,
        "video_files_size_in_mb": VIDEO_FILE_MB,
        "fps": spec.fps,
        "splits": {"train": f"0:{len(episodes)}"},
        "data_path": V3_DATA_PATH,
        "video_path": V3_VIDEO_PATH,
        "features": spec.features(),
    })  # fmt: skip
    _write_json(root / "meta" / "info.json", info)
    return info


# ---- v2.1 --------------------------------------------------------------------------------------
def write_v21(root: Path, episodes: list[StagedEpisode], spec: DatasetSpec) -> dict[str, Any]:
    import pyarrow.parquet as pq

    tasks = _task_indices(episodes)
    ep_lines, stats_lines = [], []
    all_numeric, image_stats = [], []
    for e, _, t in _episode_tables(episodes, tasks):
        chunk = e // CHUNKS_SIZE
        path = root / V21_DATA_PATH.format(episode_chunk=chunk, episode_index=e)
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(t, path)
        for key in spec.video_keys:
            vpath = root / V21_VIDEO_PATH.format(episode_chunk=chunk, video_key=key, episode_index=e)
            vpath.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(episodes[e].video_path(key), vpath)
        numeric = _numeric_stats(t)
        images = _image_stats(episodes[e], spec)
        all_numeric.append(numeric)
        image_stats.append(images)
        ep_lines.append({"episode_index": e, "tasks": [episodes[e].task], "length": t.num_rows})
        stats_lines.append({"episode_index": e, "stats": _stats_json(numeric, images)})

    meta = root / "meta"
    meta.mkdir(parents=True, exist_ok=True)
    (meta / "episodes.jsonl").write_text("".join(json.dumps(x) + "\n" for x in ep_lines), encoding="utf-8")
    (meta / "episodes_stats.jsonl").write_text("".join(json.dumps(x) + "\n" for x in stats_lines), encoding="utf-8")
    (meta / "tasks.jsonl").write_text("".join(json.dumps({"task_index": i, "task": s}) + "\n"
                                              for s, i in tasks.items()), encoding="utf-8")  # fmt: skip
    feats = list(all_numeric[0])
    numeric = {f: aggregate([s[f] for s in all_numeric]) for f in feats}
    images = {k: aggregate([s[k] for s in image_stats]) for k in spec.video_keys}
    _write_json(meta / "stats.json", _stats_json(numeric, images))

    n_ep = len(episodes)
    info = _base_info(spec, episodes, tasks, "v2.1")
    info.update({
        "total_videos": n_ep * len(spec.video_keys),
        "total_chunks": (n_ep + CHUNKS_SIZE - 1) // CHUNKS_SIZE,
        "chunks_size": CHUNKS_SIZE,
        "fps": spec.fps,
        "splits": {"train": f"0:{n_ep}"},
        "data_path": V21_DATA_PATH,
        "video_path": V21_VIDEO_PATH,
        "features": spec.features(),
    })  # fmt: skip
    _write_json(meta / "info.json", info)
    return info
