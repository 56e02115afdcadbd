"""LeRobot v3.0 / v2.1 writers + staging + validator, on synthetic episodes (random arrays)."""

from __future__ import annotations

import json
from pathlib import Path

import av
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mirage2matter.export import (
    DatasetSpec,
    EpisodeData,
    Staging,
    StagingError,
    commit_attempt,
    consolidate,
    staging_dir_for,
    validate,
)
from mirage2matter.robots import DEFAULT_ROBOT, get_robot

ROBOT = get_robot(DEFAULT_ROBOT)
SPEC = DatasetSpec(
    ROBOT.state_names, ROBOT.action_names, ROBOT.robot_type, fps=10, cameras={"head": (48, 64), "wrist": (32, 32)}
)


def _frames(rng: np.random.Generator, t: int, h: int, w: int) -> np.ndarray:
    """Smooth moving pictures (a gradient and a bright square) that H.264 keeps close to the input."""
    yy, xx = np.mgrid[0:h, 0:w]
    base = rng.uniform(30, 200, 3)
    out = np.empty((t, h, w, 3), np.uint8)
    for i in range(t):
        im = base + 40 * np.stack([xx / w, yy / h, (xx + yy) / (h + w)], -1)
        x0 = (3 * i) % max(1, w - 8)
        im[8:16, x0 : x0 + 8] = 250
        out[i] = np.clip(im, 0, 255)
    return out


def synthetic_episode(seed: int, task: str = "grasp banana", spec: DatasetSpec = SPEC) -> EpisodeData:
    rng = np.random.default_rng(seed)
    t = int(rng.integers(6, 14))
    images = {c: _frames(rng, t, h, w) for c, (h, w) in spec.cameras.items()}
    # a smooth trajectory: each action is where the joints are one frame later (as a controller tracks it)
    state = np.cumsum(rng.normal(scale=0.15, size=(t, len(spec.state_names))), axis=0).astype(np.float32)
    action = rng.normal(scale=0.01, size=(t, len(spec.action_names))).astype(np.float32)
    n = min(len(spec.state_names), len(spec.action_names))
    action[:-1, :n] += state[1:, :n]
    return EpisodeData(task, images, state, action)


def _build(out: Path, fmt: str, seeds=(0, 1, 2, 3), failed=(2,)) -> dict[int, EpisodeData]:
    eps = {}
    with Staging.open(out, SPEC, {"format": fmt}) as st:
        for a in seeds:
            ep = None if a in failed else synthetic_episode(a, "press button" if a == 3 else "grasp banana")
            if ep is not None:
                eps[a] = ep
            commit_attempt(st.root, SPEC, a, {"seed": a, "reason": "" if ep else "dropped"}, ep)
        ok = [a for a, r in sorted(st.committed().items()) if r["success"]]
        consolidate(st, out, ok, fmt)
    return eps


def _decode(path: Path) -> list[tuple[float, np.ndarray]]:
    with av.open(str(path)) as c:
        s = c.streams.video[0]
        return [(float(f.pts * s.time_base), f.to_ndarray(format="rgb24")) for f in c.decode(s)]


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return 10 * np.log10(255.0**2 / max(mse, 1e-12))


def test_v30_layout_content_and_validation(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    eps = _build(out, "lerobot-v3.0")
    assert validate(out) == []
    assert not staging_dir_for(out).exists()  # consolidated: the staging area is gone
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v3.0"
    assert info["total_episodes"] == 3 and info["total_tasks"] == 2
    assert info["total_frames"] == sum(e.length for e in eps.values())
    assert info["features"]["observation.images.head"]["shape"] == [48, 64, 3]
    assert info["features"]["observation.images.head"]["dtype"] == "video"
    assert info["features"]["observation.state"]["shape"] == [9]
    assert info["features"]["observation.state"]["names"] == list(ROBOT.state_names)
    assert info["robot_type"] == ROBOT.robot_type

    data = pq.read_table(out / "data" / "chunk-000" / "file-000.parquet")
    episodes = pq.read_table(out / "meta" / "episodes" / "chunk-000" / "file-000.parquet").to_pylist()
    tasks = pq.read_table(out / "meta" / "tasks.parquet")
    assert tasks.column("task").to_pylist() == ["grasp banana", "press button"]
    assert json.loads(tasks.schema.metadata[b"pandas"])["index_columns"] == ["task"]  # pandas reads the index
    state = np.asarray(data.column("observation.state").combine_chunks().flatten()).reshape(-1, 9)
    head = _decode(out / "videos" / "observation.images.head" / "chunk-000" / "file-000.mp4")
    for row, (a, ep) in zip(episodes, sorted(eps.items()), strict=True):
        lo, hi = row["dataset_from_index"], row["dataset_to_index"]
        assert hi - lo == ep.length == row["length"]
        np.testing.assert_array_equal(state[lo:hi], ep.state)  # exact, not re-quantised
        assert row["tasks"] == [ep.task]
        t0, t1 = (
            row["videos/observation.images.head/from_timestamp"],
            row["videos/observation.images.head/to_timestamp"],
        )
        frames = [im for t, im in head if t0 - 1e-3 <= t < t1 - 1e-3]
        assert len(frames) == ep.length
        # The right frames in the right slice: each decoded frame is close to its own input frame.
        for i, im in enumerate(frames):
            assert _psnr(im, ep.images["head"][i]) > 30, (a, i)


def test_v21_layout_and_validation(tmp_path: Path) -> None:
    out = tmp_path / "ds21"
    eps = _build(out, "lerobot-v2.1")
    assert validate(out) == []
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v2.1" and info["total_videos"] == 6
    lines = [json.loads(x) for x in (out / "meta" / "episodes.jsonl").read_text().splitlines()]
    assert [x["length"] for x in lines] == [e.length for _, e in sorted(eps.items())]
    assert len((out / "meta" / "episodes_stats.jsonl").read_text().splitlines()) == 3
    v = _decode(out / "videos" / "chunk-000" / "observation.images.wrist" / "episode_000002.mp4")
    assert len(v) == eps[3].length and v[0][0] == 0.0


def _rewrite_parquet(path: Path, fn) -> None:
    pq.write_table(fn(pq.read_table(path)), path)


def test_validator_finds_corruption(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    _build(out, "lerobot-v3.0")
    data = out / "data" / "chunk-000" / "file-000.parquet"
    meta = out / "meta"

    clean = {p: p.read_bytes() for p in (data, meta / "stats.json", meta / "info.json")}

    def restore():
        for p, b in clean.items():
            p.write_bytes(b)

    # A dropped data row: totals, the episode's length and the video frame count all disagree.
    _rewrite_parquet(data, lambda t: t.slice(0, t.num_rows - 1))
    problems = validate(out)
    assert any("total_frames" in p for p in problems)
    assert any("frames, the data" in p for p in problems)
    restore()

    # Stats that do not match the data.
    stats = json.loads((meta / "stats.json").read_text())
    stats["action"]["mean"][0] += 0.01
    (meta / "stats.json").write_text(json.dumps(stats))
    assert any("action/mean" in p for p in validate(out))
    restore()

    # A gap in the global index.
    def gap(t: pa.Table) -> pa.Table:
        idx = t.column("index").to_numpy().copy()
        idx[3:] += 1
        return t.set_column(t.schema.get_field_index("index"), "index", pa.array(idx))

    _rewrite_parquet(data, gap)
    assert any("index is not 0..N-1" in p for p in validate(out))
    restore()

    # Two frames of an episode swapped (state and action together): stats, counts and indices all still agree;
    # only the action no longer leads to the next state.
    def swap(t: pa.Table) -> pa.Table:
        for name in ("observation.state", "action"):
            col = t.column(name).to_pylist()
            col[1], col[5] = col[5], col[1]
            t = t.set_column(t.schema.get_field_index(name), name, pa.array(col, type=t.schema.field(name).type))
        return t

    _rewrite_parquet(data, swap)
    assert any("episode 0 frame 0: its action and the next frame's state disagree" in p for p in validate(out))
    restore()

    # info.json claiming a different frame size than the videos.
    info = json.loads((meta / "info.json").read_text())
    info["features"]["observation.images.wrist"]["shape"] = [64, 64, 3]
    (meta / "info.json").write_text(json.dumps(info))
    assert any("observation.images.wrist" in p and "frames are" in p for p in validate(out))
    restore()
    assert validate(out) == []

    assert validate(tmp_path / "nothing-here") == [f"{tmp_path / 'nothing-here' / 'meta' / 'info.json'} not found: "
                                                   "not a LeRobot dataset"]  # fmt: skip


def test_staging_resume_refuses_other_settings_and_second_writer(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    with Staging.open(out, SPEC, {"task": "grasp banana", "episodes": 3}) as st:
        commit_attempt(st.root, SPEC, 0, {"seed": 0}, synthetic_episode(0))
        with pytest.raises(StagingError, match="another generation run"):
            Staging.open(out, SPEC, {"task": "grasp banana", "episodes": 3})
    with pytest.raises(StagingError, match="different settings.*episodes"):
        Staging.open(out, SPEC, {"task": "grasp banana", "episodes": 5})
    # A worker killed while writing an attempt leaves only a hidden temporary; reopening clears it.
    debris = staging_dir_for(out) / "attempts" / ".attempt-000001.tmp-123-abcd"
    debris.mkdir()
    (debris / "frames.parquet").write_bytes(b"half")
    with Staging.open(out, SPEC, {"task": "grasp banana", "episodes": 3}) as st:
        assert not debris.exists()
        assert list(st.committed()) == [0]


def test_failed_commit_leaves_nothing(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    bad = synthetic_episode(0)
    bad.action = bad.action[:-1]  # wrong length
    with Staging.open(out, SPEC, {}) as st:
        with pytest.raises(ValueError, match="action must be"):
            commit_attempt(st.root, SPEC, 0, {"seed": 0}, bad)
        assert st.committed() == {}
        assert [p.name for p in st.attempts_dir.iterdir()] == []
