"""Replaying recorded splat streams (env/splat_replay.py) on tiny synthetic streams: every recorded frame of every
episode is drawn once, from its own cameras, by both paths (generation's frame-by-frame one and the batched one)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from mirage2matter.env.splat_replay import replay_batched, replay_generation
from mirage2matter.render import SplatWorldBatch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "hybrid"))
from test_splat_batch import _world  # noqa: E402


def _stream(seed: int, frames: int) -> dict:
    """A recorded episode: part "a" moving sideways, the wrist camera's view marked with (seed, frame)."""
    poses = np.tile(np.eye(4), (frames, 2, 1, 1))
    poses[:, 0, :3, 3] = [(0.45, -0.1 + 0.01 * t, 0.15) for t in range(frames)]
    poses[:, 1, :3, 3] = (0.55, 0.08, 0.15)
    view = np.tile(np.eye(4), (frames, 1, 1))
    view[:, 2, 3] = 0.5
    view[:, 0, 3] = [seed + 0.001 * t for t in range(frames)]  # a fingerprint of (episode, frame)
    K = np.tile(np.array([[20.0, 0, 8], [0, 20.0, 8], [0, 0, 1]]), (frames, 1, 1))
    return {"parts": np.array(["a", "b"]), "static": np.array(["head"]), "poses": poses, "view.head": view.copy(),
            "K.head": K, "view.wrist": view, "K.wrist": K, "seed": seed, "success": True}  # fmt: skip


class _Spy:
    """A SplatWorldBatch stand-in that records which (episode, frame) each copy was asked to draw."""

    def __init__(self, batch: int):
        self.worlds = [None] * batch
        self.drawn: list[tuple[int, int]] = []

    def forget(self, b: int) -> None:
        pass

    def set_poses(self, poses) -> None:
        assert len(poses) == len(self)

    def __len__(self) -> int:
        return len(self.worlds)

    def render(self, views, Ks, w, h, background):
        assert views.shape == (len(self), 2, 4, 4) and Ks.shape == (len(self), 2, 3, 3)
        self.drawn += [(round(v[0, 0, 3]), round(1000 * (v[0, 0, 3] - round(v[0, 0, 3])))) for v in views]


def test_batched_replay_draws_every_frame_of_every_episode_once() -> None:
    streams = [_stream(1, 5), _stream(2, 3), _stream(3, 7)]
    spy = _Spy(2)
    r = replay_batched(spy, streams, demos=5, size=16)  # streams 1, 2, 3, 1, 2
    expected = 5 + 3 + 7 + 5 + 3
    assert r["frames"] == expected and r["demos"] == 5
    # B = 2 in lockstep: copy 0 runs episodes 1 (5 frames), 1 (5), 2 (3); copy 1 runs 2 (3), 3 (7): 13 calls
    assert len(spy.drawn) == 2 * 13
    from collections import Counter

    drawn, want = Counter(spy.drawn), Counter()
    for seed, n, times in ((1, 5, 2), (2, 3, 2), (3, 7, 1)):
        want.update({(seed, f): times for f in range(n)})
    assert all(drawn[k] >= v for k, v in want.items())  # every frame of every episode, as often as it was queued
    extra = drawn - want  # the idle copy is drawn at its last frame (not counted)
    assert sum(extra.values()) == 2 * 13 - expected and set(extra) <= {(1, 4), (2, 2), (3, 6)}


def test_both_paths_run_a_real_world_and_count_alike() -> None:
    streams = [_stream(1, 4), _stream(2, 6)]
    world = _world(backend="cpu")
    a = replay_generation(world, streams, demos=3, size=16)
    b = replay_batched(SplatWorldBatch(world, 2), streams, demos=3, size=16)
    assert a["frames"] == b["frames"] == 4 + 6 + 4
    assert a["seconds"] > 0 and b["seconds"] > 0


def test_served_replay_draws_every_frame_through_the_server(tmp_path) -> None:
    """replay_served: worker processes asking one splat server for their episodes' frames (generate
    --splat-server), every recorded frame drawn there once."""
    from test_composite import _blob

    from mirage2matter.env.splat_replay import replay_served
    from mirage2matter.gaussians.ply import write_ply
    from mirage2matter.render import SplatRenderOptions

    parts = {"scene": None, "parts": []}
    for name, color, seed in (("a", (0.9, 0.1, 0.1), 5), ("b", (0.1, 0.1, 0.9), 6)):
        write_ply(tmp_path / f"{name}.ply", _blob((0, 0, 0.02), color, seed=seed))
        parts["parts"].append([name, str(tmp_path / f"{name}.ply"), 1.0])
    r = replay_served(parts, SplatRenderOptions(backend="cpu"), [_stream(1, 4), _stream(2, 6)], demos=3, size=16,
                      workers=2)  # fmt: skip
    assert r["frames"] == r["server"]["frames"] == 4 + 6 + 4 and r["demos"] == 3
    assert 1 <= r["server"]["largest_batch"] <= 2 and r["seconds"] > 0


@pytest.mark.slow
def test_bench_splats_records_once_then_replays_without_the_simulator(sample_world_ws, tmp_path, capsys,
                                                                      monkeypatch) -> None:  # fmt: skip
    import json
    import shutil

    import mirage2matter.env.splat_replay as splat_replay
    import mirage2matter.env.twin_env as twin_env
    from mirage2matter.cli import main

    src = sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0)
    ws = tmp_path / "ws"
    shutil.copytree(src / "world", ws / "world")
    argv = ["bench", "splats", "-w", str(ws), "--episodes", "1", "--demos", "2", "--size", "48", "--batch", "1", "2",
            "--server", "2", "--runs", "1", "--backend", "cpu"]  # fmt: skip
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["backend"] == "cpu" and result["cameras"] == ["head", "wrist"] and result["size"] == 48
    assert [r.get("batch", r.get("server_workers")) for r in result["results"]] == [1, 2, 2]
    assert all(r["demos_per_min"] > 0 for r in result["results"]) and result["results"][2]["mean_batch"] >= 1
    (folder,) = (ws / "evals" / "splat_streams").glob("grasp_banana-48px-*")  # and the world's hash
    st = np.load(folder / "stream_3000000.npz")
    T = len(st["poses"])
    assert T == result["frames_per_demo"] and bool(st["success"]) and st["static"].tolist() == ["head"]
    assert set(st["parts"].tolist()) == {"banana", "croissant", "button", "button/cap"}
    assert st["poses"].shape == (T, 4, 4, 4) and st["view.wrist"].shape == (T, 4, 4) and st["K.head"].shape == (T, 3, 3)
    assert np.ptp(st["view.head"], axis=0).max() < 1e-9 and np.ptp(st["view.wrist"], axis=0).max() > 1e-2
    banana = st["parts"].tolist().index("banana")
    assert st["poses"][-1, banana, 2, 3] - st["poses"][0, banana, 2, 3] > 0.03  # the grasp lifted it

    def no_simulator(*a, **k):
        raise AssertionError("the replay needed the simulator")

    monkeypatch.setattr(splat_replay, "record_splat_streams", no_simulator)
    monkeypatch.setattr(twin_env, "resolve_world", no_simulator)
    assert main(argv) == 0
    again = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert again["gaussians"] == result["gaussians"] and again["frames_per_demo"] == T
