"""Replaying recorded splat streams (bench/splats.py) on tiny synthetic streams: every recorded frame of every
episode is drawn once, from its own cameras, by both paths (generation's frame-by-frame one and the batched one)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from mirage2matter.bench.splats import replay_batched, replay_generation
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

    from mirage2matter.bench.splats import replay_served
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

    import mirage2matter.bench.splats as splat_replay
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

    exp = tmp_path / "for_a_gpu_box"  # --export: what a GPU machine without the simulator is given
    assert main(["bench", "splats", "-w", str(ws), "--episodes", "1", "--size", "48", "--export", str(exp)]) == 0
    capsys.readouterr()
    assert main([*argv[:3], str(exp), *argv[4:]]) == 0
    there = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert there["gaussians"] == result["gaussians"] and there["frames_per_demo"] == T


def test_export_keeps_what_generation_draws_and_nothing_half_written(tmp_path) -> None:
    """bench splats --export (bench/splats.export_splat_bench): a workspace with the recorded streams and the
    world's Gaussians cut to what generation draws (SH 1, faint ones dropped), at the same paths relative to world/,
    whose splat world renders the frames of the original one."""
    import json

    import torch
    from test_composite import H, K, W, _blob, _camera

    from mirage2matter.bench.splats import export_splat_bench
    from mirage2matter.configs import ConfigError
    from mirage2matter.gaussians.ply import read_ply, write_ply
    from mirage2matter.render import SplatRenderOptions, SplatWorld
    from mirage2matter.workspace import Workspace

    ws = tmp_path / "ws"
    (ws / "world").mkdir(parents=True)
    (ws / "objects" / "a").mkdir(parents=True)
    (ws / "world" / "world.yaml").write_text("name: test world\n")
    scene = _blob((0.5, 0.0, -0.05), (0.3, 0.3, 0.3), n=600, radius=0.12, seed=4, sh_degree=3)
    scene.logit_opacities[:200] = torch.logit(torch.tensor(0.01))  # faint: generation drops them
    write_ply(ws / "world" / "scene.ply", scene)
    write_ply(ws / "objects" / "a" / "gaussians.ply", _blob((0, 0, 0.02), (0.9, 0.1, 0.1), seed=5, sh_degree=3))
    streams = ws / "evals" / "splat_streams" / "task-16px-00000000"
    streams.mkdir(parents=True)
    np.savez(streams / "stream_1.npz", **_stream(1, 3))
    (streams / "splat_parts.json").write_text(json.dumps({"scene": "scene.ply",
                                                          "parts": [["a", "../objects/a/gaussians.ply", 1.0]]}))
    parts = {"scene": str(ws / "world" / "scene.ply"), "parts": [["a", str(ws / "objects/a/gaussians.ply"), 1.2]]}
    options = SplatRenderOptions(sh_degree=1, min_opacity=0.02, backend="cpu")  # generation's (env.config)

    dest = tmp_path / "export"
    assert export_splat_bench(Workspace(ws), streams, parts, options, dest) == 400 + 400
    assert (dest / "world" / "world.yaml").read_bytes() == (ws / "world" / "world.yaml").read_bytes()
    assert sorted(p.name for p in (dest / "evals" / "splat_streams" / streams.name).iterdir()) == [
        "splat_parts.json", "stream_1.npz"]  # fmt: skip
    cut = read_ply(dest / "world" / "scene.ply")
    assert cut.sh_degree == 1 and len(cut) == 400 and float(cut.opacities.min()) >= 0.02
    moved = {"scene": str(dest / "world" / "scene.ply"), "parts": [["a", str(dest / "objects/a/gaussians.ply"), 1.2]]}
    pose = np.eye(4)
    pose[:3, 3] = (0.45, 0.0, 0.15)
    frames = []
    for p in (parts, moved):
        world = SplatWorld.from_files(p, options)
        world.set_poses({"a": pose})
        frames.append(world.render(_camera((0.0, 0.0, 0.5)), K, W, H)[0])
    np.testing.assert_allclose(frames[0], frames[1], atol=1e-6)

    with pytest.raises(ConfigError, match="exists"):  # never over an earlier export
        export_splat_bench(Workspace(ws), streams, parts, options, dest)
    outside = tmp_path / "elsewhere.ply"
    write_ply(outside, _blob((0, 0, 0), (0.5, 0.5, 0.5), seed=7))
    with pytest.raises(ConfigError, match="outside the workspace"):
        export_splat_bench(Workspace(ws), streams, {**parts, "parts": [["b", str(outside), 1.0]]},
                           options, tmp_path / "second")  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere.ply", "export", "ws"]  # no half-written folder
