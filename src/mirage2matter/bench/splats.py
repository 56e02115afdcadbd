"""Generation's splat layer alone: the Gaussian world's part poses and camera views along scripted-expert episodes,
recorded once through the simulator, then rendered again without it.

The splat layer is where generation spends most of its time on a CPU (10 of 26 s per demo at 224 px on the
2-core development machine) and what a GPU takes over. Replaying recorded episodes measures it on any machine,
a GPU one without the simulator included, by the paths ``bench splats`` compares: the one generation runs
(one :class:`SplatWorld`, frame by frame, camera by camera, the head camera's background cached),
:class:`SplatWorldBatch` (B episodes in lockstep, every camera of every episode in one call), and the splat
server (``generate --splat-server``: W worker processes asking one server process for their frames, which it
batches as they come).

A stream (``record_splat_streams``) is a dict: ``parts`` [P] names, ``poses`` float64 [T,P,4,4] (``T_base_obj`` of
each part at each frame), ``view.<camera>`` [T,4,4] base-to-camera, ``K.<camera>`` [T,3,3] at the frame size,
``static`` [S] the cameras fixed in the base, ``seed`` and ``success``.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing as mp
import os
import shutil
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_dir, atomic_write
from ..configs import ConfigError, ranged
from ..datagen import task_slug
from ..env.config import EpisodeSpec, HybridOptions
from ..env.episode_cache import load_or_record_episodes
from ..env.hybrid import splat_parts
from ..render.splat_server import RemoteSplatLayer, SplatServer
from ..workspace import Workspace

__all__ = ["export_splat_bench", "load_or_record_streams", "record_splat_streams", "replay_batched",
           "replay_generation", "replay_served"]  # fmt: skip

Log = Callable[[str], None]


def record_splat_streams(world: str | Path, task: str, seeds: Sequence[int],
                         size: int | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """The scripted expert of ``task`` in the twin of ``world`` for each episode seed, with the splat layer's
    inputs at every recorded frame (the first observation and one per control tick, as generation records);
    ``size`` x ``size`` frames (None: the episode spec's, ``env.config.EpisodeSpec``)."""
    from ..env.twin_env import TwinEnv

    env = TwinEnv(world, task, size=size)
    try:
        return [_record_one(env, int(seed)) for seed in seeds]
    finally:
        env.close()


def _record_one(env: Any, seed: int) -> dict[str, Any]:
    from ..sim.tasks import run_task

    cams = env.config.cameras
    poses: list[dict[str, np.ndarray]] = []
    views: dict[str, list[np.ndarray]] = {c: [] for c in cams}
    Ks: dict[str, list[np.ndarray]] = {c: [] for c in cams}

    def see() -> None:
        p, v = env.renderer.splat_views()
        poses.append({k: np.asarray(T, np.float64) for k, T in p.items()})
        for c in cams:
            views[c].append(v[c][0])
            Ks[c].append(v[c][1])

    def act(a: np.ndarray) -> None:
        env.step(a)
        see()

    env.reset(seed=seed)
    see()
    res = run_task(env.twin, env.task, np.random.default_rng(env.draw.task_seed), control_hz=env.config.fps, act=act)
    names = sorted(poses[0])
    stream: dict[str, Any] = {"parts": np.array(names), "static": np.array(sorted(env.renderer.static_cameras)),
                              "poses": np.stack([np.stack([p[n] for n in names]) for p in poses]),
                              "seed": seed, "success": bool(res.success)}  # fmt: skip
    for c in cams:
        stream[f"view.{c}"], stream[f"K.{c}"] = np.stack(views[c]), np.stack(Ks[c])
    return stream


def load_or_record_streams(
    folder: Path, world_dir: Path, task: str, seeds: Sequence[int], size: int, log: Log
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """:func:`record_splat_streams`, each episode cached as ``folder/stream_<seed>.npz`` (written atomically), and
    the world's splat layer (``hybrid.splat_parts``) as ``folder/splat_parts.json``, its Gaussian files relative to
    ``world_dir``: a second call, or one on a machine with neither the simulator nor the robot's model (a GPU box
    given the world's Gaussians and this folder), reads them back. -> (streams, splat parts with absolute paths)."""


    world_dir = Path(world_dir).resolve()
    record = lambda missing: record_splat_streams(world_dir, task, missing, size)
    streams = load_or_record_episodes(folder, "stream", seeds, record, log,
                                      f"expert episode(s) of {task!r} (poses and camera views)")  # fmt: skip
    parts_file = folder / "splat_parts.json"
    if not parts_file.is_file():
        from ..env.twin_env import resolve_world

        desc = splat_parts(resolve_world(world_dir))
        rel = lambda p: None if p is None else os.path.relpath(p, world_dir)
        desc = {"scene": rel(desc["scene"]), "parts": [[n, rel(p), s] for n, p, s in desc["parts"]]}
        with atomic_write(parts_file, "w", encoding="utf-8") as f:
            json.dump(desc, f, indent=1)
    desc = json.loads(parts_file.read_text(encoding="utf-8"))
    at = lambda p: None if p is None else str(world_dir / p)
    parts = {"scene": at(desc["scene"]), "parts": [[n, at(p), s] for n, p, s in desc["parts"]]}
    return streams, parts


def export_splat_bench(ws: Any, streams_folder: Path, parts: dict[str, Any], options: Any, dest: Path) -> int:
    """Write ``dest``: a workspace holding only what ``bench splats`` replays from workspace ``ws`` (a
    ``Workspace``): its world.yaml, whose bytes name the recording, the recorded streams in ``streams_folder``, and
    the splat layer's PLYs, each at its own path relative to the workspace and cut to the rows generation draws
    (``render.splat_world.rendered_rows`` with ``options``), so a GPU machine without the simulator, given little
    room to copy to, renders the same frames. Built in a temporary folder and renamed. -> the Gaussians written."""

    from ..gaussians.ply import read_ply, write_ply
    from ..render.splat_world import rendered_rows

    dest = Path(dest)
    if dest.exists():
        raise ConfigError(f"bench splats --export: {dest} exists; remove it or name another folder")
    root = Path(ws.root).resolve()

    def within(path: Any) -> Path:
        """``path``'s place relative to the workspace (the copy keeps the layout that splat_parts.json names)."""
        rel = Path(os.path.relpath(Path(path).resolve(), root))
        if rel.parts[:1] == ("..",):
            raise ConfigError(f"bench splats --export: {path} lies outside the workspace {ws.root}; --export copies "
                              "only a world whose Gaussians and recordings are inside its workspace")  # fmt: skip
        return rel

    plys = [parts["scene"]] if parts["scene"] is not None else []
    plys = [(f, within(f)) for f in plys + [p for _, p, _ in parts["parts"]]]
    copies = [(ws.world_yaml, within(ws.world_yaml)), (streams_folder, within(streams_folder))]
    rows = 0
    with atomic_dir(dest) as tmp:
        for src, rel in copies:
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            (shutil.copytree if Path(src).is_dir() else shutil.copy2)(src, tmp / rel)
        for src, rel in plys:
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            g = rendered_rows(read_ply(src), options)
            write_ply(tmp / rel, g)
            rows += len(g)
    return rows


def _cameras(stream: dict[str, Any]) -> list[str]:
    return sorted(k[len("view.") :] for k in stream if k.startswith("view."))


def _episodes(streams: Sequence[dict[str, Any]], demos: int) -> list[dict[str, Any]]:
    """``demos`` episodes to replay: the streams in turn, as often as needed."""
    if not streams:
        raise ValueError("no recorded episodes to replay")
    return [streams[i % len(streams)] for i in range(demos)]


def replay_generation(splat: Any, streams: Sequence[dict[str, Any]], demos: int, size: int,
                      background=(0.0, 0.0, 0.0)) -> dict[str, float]:  # fmt: skip
    """Generation's splat layer (``HybridRenderer.render``'s splat calls) on ``demos`` recorded episodes: per
    episode the caches forgotten, per frame the parts posed and each camera rendered, static cameras through the
    cached background. -> {"seconds", "frames" (time steps, all cameras), "demos"}."""
    t0 = time.perf_counter()
    frames = 0
    for ep in _episodes(streams, demos):
        splat.reset_cache()
        splat.poses.clear()
        static, cams, names = set(ep["static"].tolist()), _cameras(ep), ep["parts"].tolist()
        for t in range(len(ep["poses"])):
            splat.set_poses(dict(zip(names, ep["poses"][t], strict=True)))
            for c in cams:
                draw = splat.render_static_camera if c in static else splat.render_camera
                draw(c, ep[f"view.{c}"][t], ep[f"K.{c}"][t], size, size, background)
            frames += 1
    return {"seconds": time.perf_counter() - t0, "frames": frames, "demos": demos}


def replay_batched(batch: Any, streams: Sequence[dict[str, Any]], demos: int, size: int,
                   background=(0.0, 0.0, 0.0)) -> dict[str, float]:  # fmt: skip
    """The same episodes through a :class:`SplatWorldBatch` of B copies: B episodes in lockstep, a copy taking the
    next episode when its own ends, every camera of every copy in one render call per time step (a copy with no
    episode left is drawn but not counted). -> {"seconds", "frames", "demos"}."""
    queue = _episodes(streams, demos)
    cams = _cameras(queue[0])
    B = len(batch)
    slots: list[tuple[dict[str, Any], int] | None] = [None] * B
    views = np.tile(np.eye(4), (B, len(cams), 1, 1))
    Ks = np.tile(np.eye(3), (B, len(cams), 1, 1))
    t0 = time.perf_counter()
    frames = 0
    while True:
        for b in range(B):
            if slots[b] is not None and slots[b][1] >= len(slots[b][0]["poses"]):
                slots[b] = None  # its episode has ended
            if slots[b] is None and queue:
                slots[b] = (queue.pop(0), 0)
                batch.forget(b)
        live = [b for b in range(B) if slots[b] is not None]
        if not live:
            break
        poses: list[dict | None] = [None] * B
        for b in live:
            ep, t = slots[b]
            poses[b] = dict(zip(ep["parts"].tolist(), ep["poses"][t], strict=True))
            for i, c in enumerate(cams):
                views[b, i], Ks[b, i] = ep[f"view.{c}"][t], ep[f"K.{c}"][t]
            slots[b] = (ep, t + 1)
        batch.set_poses(poses)
        batch.render(views, Ks, size, size, background)
        frames += len(live)
    return {"seconds": time.perf_counter() - t0, "frames": frames, "demos": demos}


def _served_client(handle: Any, episodes: list[dict[str, Any]], ready: Any, go: Any, done: Any) -> None:
    """A worker process of :func:`replay_served`: its episodes' frames asked of the server, one after the other."""
    layer = RemoteSplatLayer(handle)
    ready.put(layer.slot)
    go.wait()
    frames = 0
    for ep in episodes:
        layer.start_episode()
        cams, names = _cameras(ep), ep["parts"].tolist()
        views = np.stack([ep[f"view.{c}"] for c in cams], axis=1)  # [T,C,4,4]
        Ks = np.stack([ep[f"K.{c}"] for c in cams], axis=1)
        for t in range(len(ep["poses"])):
            layer.render(dict(zip(names, ep["poses"][t], strict=True)), views[t], Ks[t])
            frames += 1
    layer.close()
    done.put(frames)


def replay_served(parts: dict[str, Any], options: Any, streams: Sequence[dict[str, Any]], demos: int, size: int,
                  workers: int, background=(0.0, 0.0, 0.0), gather_ms: float = 2.0) -> dict[str, Any]:  # fmt: skip
    """The same episodes through a splat server (``render.splat_server``, what ``generate --splat-server`` runs):
    ``workers`` processes, each replaying its share of the episodes frame by frame as a generation worker asks for
    them (without the physics between frames: the server at its busiest). -> {"seconds" (from every worker ready to
    the last frame), "frames", "demos", "server": the server's statistics (mean batch...)}."""
    queue = _episodes(streams, demos)
    server = SplatServer(parts, options, slots=workers, cameras=len(_cameras(queue[0])), size=(size, size),
                         background=background, gather_ms=gather_ms)  # fmt: skip
    ctx = mp.get_context("spawn")
    ready, done, go = ctx.Queue(), ctx.Queue(), ctx.Event()
    with server as handle:
        procs = [ctx.Process(target=_served_client, args=(handle, queue[w::workers], ready, go, done), daemon=True)
                 for w in range(workers)]  # fmt: skip
        for p in procs:
            p.start()
        try:
            for _ in procs:
                ready.get(timeout=300)
            t0 = time.perf_counter()
            go.set()
            frames = sum(done.get(timeout=3600) for _ in procs)
            seconds = time.perf_counter() - t0
        finally:
            for p in procs:
                p.join(timeout=10)
                if p.is_alive():
                    p.kill()
        stats = server.close()
    return {"seconds": seconds, "frames": frames, "demos": demos, "server": stats}


@dataclass
class SplatsBenchConfig:
    """bench splats settings.

    task      the expert's task
    episodes  recorded episodes
    demos     episodes replayed per run, the recorded ones in turn
    seed      episode seed of the first
    size      frame side
    batch     episodes per render call; 1 = generation's path
    server    also through a splat server (generate --splat-server) fed by W worker processes, for each W given
    backend   render backend: auto, cpu, cuda
    runs      repetitions
    export    instead of timing: write DIR, a workspace holding only the recorded episodes and the world's Gaussians
              as generation draws them (SH 1, faint ones dropped; the sample's: 35 MB), for a GPU machine without the
              simulator: there, bench splats -w DIR
    """

    task: str = "grasp banana"
    episodes: int = ranged(8, ge=1, metadata={"metavar": "N"})
    demos: int = ranged(64, ge=1, metadata={"metavar": "D"})
    seed: int = 3_000_000
    size: int = ranged(EpisodeSpec.size[0], ge=16, metadata={"metavar": "PX"})
    batch: tuple[int, ...] = ranged((1, 16), ge=1, metadata={"metavar": "B"})
    server: tuple[int, ...] = ranged((), ge=1, metadata={"metavar": "W"})
    backend: str = "auto"
    runs: int = ranged(3, ge=1, metadata={"metavar": "R"})
    export: Path | None = field(default=None, metadata={"metavar": "DIR"})


def run_splats(ws: Workspace, cfg: SplatsBenchConfig, threads: int, log: Callable[[str], None] = print
               ) -> dict[str, Any]:  # fmt: skip
    """Record (or load) the expert's splat streams and time their replay (or export them: ``cfg.export``) -> the
    JSON-ready result."""
    import torch

    from ..render import SplatWorld, SplatWorldBatch

    world_yaml = ws.committed.world_yaml
    seeds = list(range(cfg.seed, cfg.seed + cfg.episodes))
    world_id = hashlib.sha256(world_yaml.read_bytes()).hexdigest()[:8]  # a world composed again records anew
    folder = ws.evals_dir / "splat_streams" / f"{task_slug(cfg.task)}-{cfg.size}px-{world_id}"
    streams, parts = load_or_record_streams(folder, ws.committed.world_dir, cfg.task, seeds, cfg.size, log=log)
    options = replace(HybridOptions().splat, backend=cfg.backend)  # generation's splat settings
    if cfg.export is not None:
        rows = export_splat_bench(ws.committed, folder, parts, options, cfg.export)
        log(f"bench splats: {len(streams)} recorded episodes and {rows:,} Gaussians -> {cfg.export}")
        return {"export": str(cfg.export), "episodes": len(streams), "gaussians": rows}
    world = SplatWorld.from_files(parts, options)  # the Gaussians alone: no simulator, no robot model
    dev = world.device
    name = torch.cuda.get_device_name(dev) if dev.type == "cuda" else f"cpu ({threads} threads)"
    frames_per_demo = float(np.mean([len(s["poses"]) for s in streams]))
    log(f"bench splats: {len(world):,} Gaussians on {name}, {len(streams)} recorded episodes of {frames_per_demo:.1f}"
         f" frames, {cfg.demos} replayed per run, {cfg.size} px")  # fmt: skip
    replay_generation(world, streams[:1], 1, cfg.size)  # warm-up: kernels compiled / loaded, caches allocated
    results = []

    def timed(label: dict, what: str, replay) -> None:
        """``cfg.runs`` runs of ``replay()`` -> one row of results: demos/min and ms per frame of the median run."""
        runs = []
        for _ in range(cfg.runs):
            r = replay()
            runs.append(r)
            batch = f", mean batch {r['server']['mean_batch']:.1f}" if "server" in r else ""
            log(f"{what}: {r['demos'] / r['seconds'] * 60:.1f} demos/min ({r['seconds']:.1f} s{batch})")
        secs = statistics.median(r["seconds"] for r in runs)
        row = {**label, "demos_per_min": round(cfg.demos / secs * 60, 1),
               "ms_per_frame": round(1000 * secs / runs[0]["frames"], 3)}  # fmt: skip
        if "server" in runs[0]:
            row["mean_batch"] = round(statistics.median(r["server"]["mean_batch"] for r in runs), 2)
        results.append({**row, "seconds": [round(r["seconds"], 2) for r in runs]})

    for b in cfg.batch:
        batch = None if b == 1 else SplatWorldBatch(world, b)
        if batch is not None:
            replay_batched(batch, streams[:1], 1, cfg.size)
        timed({"batch": b}, f"batch {b}", lambda batch=batch: replay_generation(world, streams, cfg.demos, cfg.size)
              if batch is None else replay_batched(batch, streams, cfg.demos, cfg.size))  # fmt: skip
        del batch
    for w in cfg.server:
        timed({"server_workers": w}, f"server, {w} workers",
              lambda w=w: replay_served(parts, options, streams, cfg.demos, cfg.size, w))  # fmt: skip
    cams = sorted(k[len("view.") :] for k in streams[0] if k.startswith("view."))
    return {"backend": dev.type, "device": name, "gaussians": len(world), "size": cfg.size, "cameras": cams,
            "frames_per_demo": round(frames_per_demo, 1), "demos": cfg.demos, "runs": cfg.runs, "results": results}
