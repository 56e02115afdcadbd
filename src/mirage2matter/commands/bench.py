"""``m2m bench render | train | datagen | splats | sim2real | policy-gap``: benchmarks, each printing one JSON line
last on stdout."""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from .. import configure_threads
from ..bench import RenderBenchConfig
from ..configs import add_flags, from_flags, ranged
from ..env.config import EpisodeSpec
from .args import backend, info
from .sim2real import Sim2RealConfig


@dataclass
class TrainBenchConfig:
    """bench train settings (``gaussians.bench_train``'s).

    minutes        training time
    downscale      1/F resolution
    poses          given poses or our own SfM
    work_dir       cache for the SfM used for initial points
    max_gaussians  most Gaussians (without it: the scene stage's, TrainConfig's)
    filter_3d      Mip-Splatting's 3D filter, a variance in squared pixels (default: train-scene's, 0.2; 0: off)
    """

    minutes: float = ranged(15.0, gt=0, metadata={"metavar": "M"})
    downscale: int = ranged(4, ge=1, metadata={"metavar": "F"})
    poses: Literal["given", "sfm"] = "given"
    work_dir: Path | None = field(default=None, metadata={"metavar": "DIR"})
    max_gaussians: int | None = ranged(None, ge=1000, metadata={"metavar": "N"})
    filter_3d: float | None = field(default=None, metadata={"parse": lambda text: _filter_variance(text),
                                                           "metavar": "V"})  # fmt: skip


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


@dataclass
class PolicyGapConfig:
    """bench policy-gap settings.

    task          the expert's task
    episodes      expert episodes
    seed          episode seed of the first
    size          frame side
    stride        compare every K-th step
    ground_truth  the sample folder (default: the workspace's capture's, e.g. samples/tabletop)
    """

    task: str = "grasp banana"
    episodes: int = ranged(10, ge=1, metadata={"metavar": "N"})
    seed: int = 2_000_000
    size: int = ranged(Sim2RealConfig.size, ge=16, metadata={"metavar": "PX"})  # sim2real's frames
    stride: int = ranged(2, ge=1, metadata={"metavar": "K"})
    ground_truth: Path | None = field(default=None, metadata={"metavar": "DIR"})


def datagen_config() -> type:
    """bench datagen's Config: the generate stage's with one task, defaults for a benchmark, and ``runs``
    (a function: the generate stage's Config imports the generation libraries)."""
    from ..stages import generate

    @dataclass
    class DatagenBenchConfig(generate.Config):
        """bench datagen settings (the generate stage's, one task, and these).

        runs   repetitions; the JSON line holds the medians over runs
        """

        task: tuple[str, ...] = ("grasp banana",)
        episodes: int = ranged(20, ge=1, le=10**6)
        runs: int = ranged(1, ge=1, le=1000)

    return DatagenBenchConfig


def register(sub: argparse._SubParsersAction, full: bool = True) -> None:
    bench = sub.add_parser("bench", help="benchmarks (prints one JSON line last on stdout)")
    bench_sub = bench.add_subparsers(dest="what", metavar="WHAT", required=True)
    b = bench_sub.add_parser(
        "render", help="time the renderer on a synthetic tabletop scene",
        description="Time render() on tabletop_scene(N) from V orbit cameras: W untimed warm-up renders, then R "
        "rounds of all V views. Progress goes to stderr; the last stdout line is JSON with backend, gaussians, "
        "width, height, sh_degree, cameras_per_call, ms_median (one call), ms_min, ms_max, ms_per_camera, runs.",
    )  # fmt: skip
    add_flags(b, RenderBenchConfig)
    b.set_defaults(func=_render)

    t = bench_sub.add_parser(
        "train", help="train 3DGS on a transforms.json capture for M minutes; held-out PSNR/SSIM as a JSON line last"
    )
    t.add_argument("--data", required=True, metavar="DIR", help="folder with transforms.json + images (e.g. fox)")
    add_flags(t, TrainBenchConfig)
    t.set_defaults(func=_train)

    d = bench_sub.add_parser(
        "datagen", help="demonstrations per minute on a workspace's world; JSON line last",
        description="Generate N episodes R times into throw-away folders; the last stdout line is JSON with "
        "demos_per_min (workers warm), success_rate, episodes, frames, workers, backend, ms_per_frame and "
        "round_trip_pct (the share of the workers' time between attempts: an episode shipped back and committed, the "
        "next handed out), medians. --ray-address local --workers N runs it on Ray, to set against the process "
        "runner (docs/guides/multi-machine.md).",
    )  # fmt: skip
    d.add_argument("-w", "--workspace", required=True, type=Path, help="workspace with world/world.yaml")
    if full:
        add_flags(d, datagen_config())
    d.set_defaults(func=_datagen)

    p = bench_sub.add_parser(
        "splats", help="generation's splat layer alone on a GPU or CPU, frame by frame vs batched episodes; JSON "
        "line last",
        description="Record the scripted expert's episodes of a task once (the parts' poses and the cameras' views "
        "at every frame; needs the simulator; cached in <workspace>/evals/splat_streams), then render the world's "
        "Gaussians along them again without the simulator: --batch 1 is generation's own path (one world, frame by "
        "frame, the head camera's background cached), B > 1 steps B episodes in lockstep with every camera of every "
        "episode in one render call. The last stdout line is JSON with demos per minute of the splat layer alone "
        "for each B (medians of --runs).",
    )  # fmt: skip
    p.add_argument("-w", "--workspace", required=True, type=Path, help="workspace with a composed world")
    add_flags(p, SplatsBenchConfig)
    p.set_defaults(func=_splats)

    from .sim2real import Sim2RealConfig

    s = bench_sub.add_parser(
        "sim2real", help="the paper's sim-to-real experiment on the sample: train on the reconstruction, test on "
        "the ground truth; markdown tables + JSON line last",
        description="In a workspace whose world was reconstructed from the bundled sample's video (`m2m demo -w WS "
        "--until world`): generate demos in the reconstruction, train policies, evaluate them in the sample's "
        "ground-truth world and in the reconstruction; the mesh-objects ablation and the data-scale curve. Each "
        "step is a stage run in the workspace (a killed bench resumes). Hours on a 2-core CPU.",
    )  # fmt: skip
    s.add_argument("-w", "--workspace", required=True, type=Path, help="workspace with the sample's world")
    add_flags(s, Sim2RealConfig)
    s.set_defaults(func=_sim2real)

    g = bench_sub.add_parser(
        "policy-gap", help="policies' open-loop action error on expert episodes, hybrid vs ground-truth frames; "
        "JSON line last",
        description="Record the scripted expert's episodes of a task in the sample's reconstructed world, every "
        "observation rendered twice (hybrid, as generation writes it, and the sample's ground truth; cached in "
        "<workspace>/evals/expert_pairs), then for each policy the mean |predicted chunk - expert's actions| in "
        "action-std units on each renderer's frames. Minutes where a closed-loop evaluation takes tens of minutes; "
        "on the sample the ground-truth error ranked nine grasp policies much as their closed-loop success did. "
        "It scores the expert's states only: compare policies of one training recipe with it, not recipes (a "
        "hue-band-augmented policy scored best and failed closed loop, in its own world too).",
    )  # fmt: skip
    g.add_argument("-w", "--workspace", required=True, type=Path, help="workspace with the sample's world")
    g.add_argument("--policy", nargs="+", required=True, metavar="POLICY",
                   help="policies: names under <workspace>/policies or folders that train-policy wrote (A,B,C: "
                        "one ensemble of them)")
    add_flags(g, PolicyGapConfig)
    g.set_defaults(func=_policy_gap)


def _render(args: argparse.Namespace) -> int:
    from ..bench import bench_render

    cfg = from_flags(RenderBenchConfig, args)
    cfg = replace(cfg, backend=backend(cfg.backend))
    cfg.validate()
    threads = configure_threads()
    info(f"bench render: {cfg.backend} backend, {threads} CPU thread(s)")
    result = bench_render(cfg, log=info)
    print(json.dumps(result), flush=True)  # machine-readable: always the last line on stdout
    return 0


def _filter_variance(text: str) -> float:
    """--filter-3d's value, checked where training checks it (gaussians.filter3d), before any work."""
    from ..gaussians.filter3d import check_variance

    try:
        value = float(text)
        check_variance(value)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return value


def _train(args: argparse.Namespace) -> int:
    from ..gaussians.bench_train import bench_train

    cfg = from_flags(TrainBenchConfig, args)
    configure_threads()
    result = bench_train(
        args.data, minutes=cfg.minutes, downscale=cfg.downscale, poses=cfg.poses, work_dir=cfg.work_dir,
        progress=True, **({} if cfg.max_gaussians is None else {"max_gaussians": cfg.max_gaussians}),
        **({} if cfg.filter_3d is None else {"filter_3d": cfg.filter_3d}),
    )  # fmt: skip
    keys = ("psnr_heldout", "ssim_heldout", "iterations", "gaussians", "minutes", "budget_used", "backend")
    info(json.dumps(result.get("curve", []), separators=(",", ":")))
    print(json.dumps({k: result[k] for k in keys}))
    return 0


def _datagen(args: argparse.Namespace) -> int:
    from ..datagen import BENCH_KEYS, bench_datagen
    from ..sim.tasks import parse_task
    from ..stages.transaction import workspace_lock
    from ..workspace import Workspace
    from ..world import load_world

    cfg = from_flags(datagen_config(), args)
    cfg.validate()
    ws = Workspace(args.workspace)
    with workspace_lock(ws, "m2m bench datagen"):  # it writes throw-away datasets into the workspace
        world = load_world(ws.require(ws.world_yaml, "compose"))
        task = parse_task(cfg.task[0], world)
        result = bench_datagen(world, task, cfg.generation(ws), ws.datasets_dir, runs=cfg.runs, log=info)
    info(json.dumps(result))
    print(json.dumps({k: result[k] for k in BENCH_KEYS}))
    return 0


def _sim2real(args: argparse.Namespace) -> int:
    from ..atomic import atomic_write
    from ..workspace import Workspace
    from .sim2real import Sim2RealConfig, run_sim2real

    cfg = from_flags(Sim2RealConfig, args)
    configure_threads()
    ws = Workspace(args.workspace)
    result = run_sim2real(ws, cfg, log=info)
    report = ws.evals_dir / "sim2real.md"
    report.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(report, "w", encoding="utf-8") as f:
        f.write(result["tables"] + "\n")
    with atomic_write(ws.evals_dir / "sim2real.json", "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1)
    print(result["tables"])
    print(json.dumps({k: v for k, v in result.items() if k != "tables"}), flush=True)
    return 0


def _policy_gap(args: argparse.Namespace) -> int:
    import hashlib

    from ..datagen import task_slug
    from ..env.expert_pairs import load_or_record_pairs, open_loop_error
    from ..env.twin_env import make_config
    from ..stages import eval_policy
    from ..workspace import Workspace

    gap = from_flags(PolicyGapConfig, args)
    configure_threads()
    ws = Workspace(args.workspace)
    cfg = eval_policy.Config(task=gap.task, renderer="ground_truth", ground_truth=gap.ground_truth)
    gt = eval_policy.ground_truth_dir(ws, cfg)
    world = make_config(ws.committed.world_dir, gap.task, size=gap.size).world  # the task and world, checked
    policies = {}
    for ref in args.policy:  # every policy opened and checked against the robot before the long recording
        if not eval_policy.policy_paths(ws, replace(cfg, policy=ref)):
            raise eval_policy.PolicyError(f"bench policy-gap: {ref!r} is a callable; it needs a trained policy (the "
                                          "error is in its action-std units)")  # fmt: skip
        policies[ref] = eval_policy.open_policy(ws, replace(cfg, policy=ref), world)
    seeds = list(range(gap.seed, gap.seed + gap.episodes))
    # keyed on the world's description too: a world composed again (other objects, other placements) records anew
    world_id = hashlib.sha256(ws.committed.world_yaml.read_bytes()).hexdigest()[:8]
    folder = ws.evals_dir / "expert_pairs" / f"{task_slug(gap.task)}-{gap.size}px-{world_id}"
    episodes = load_or_record_pairs(folder, ws.committed.world_dir, gap.task, gt, seeds, gap.size, log=info)
    ok = sum(bool(e["success"]) for e in episodes)
    info(f"expert: {ok}/{len(episodes)} episodes succeeded (only those are compared)")
    if not ok:
        raise eval_policy.PolicyError(f"bench policy-gap: the scripted expert failed all {len(episodes)} episodes of "
                                      f"{gap.task!r} in this world ({folder}); check it with `m2m task -w "
                                      f"{ws.root} {gap.task!r}`")  # fmt: skip
    rows = {}
    for ref, policy in policies.items():
        err = open_loop_error(policy, episodes, stride=gap.stride)
        rows[ref] = {**{k: round(v, 5) for k, v in err.items()}, "gap": round(err["ground_truth"] - err["hybrid"], 5)}
        info(f"{ref}: open-loop error hybrid {err['hybrid']:.4f}, ground truth {err['ground_truth']:.4f}")
    result = {"task": gap.task, "episodes": len(episodes), "expert_successes": ok, "size": gap.size,
              "stride": gap.stride, "seeds": [seeds[0], seeds[-1]], "policies": rows}  # fmt: skip
    print(json.dumps(result), flush=True)
    return 0


def _splats(args: argparse.Namespace) -> int:
    import hashlib
    import statistics

    import torch

    from ..datagen import task_slug
    from ..env.config import HybridOptions
    from ..env.splat_replay import load_or_record_streams, replay_batched, replay_generation, replay_served
    from ..render import SplatWorld, SplatWorldBatch
    from ..workspace import Workspace

    cfg = from_flags(SplatsBenchConfig, args)
    threads = configure_threads()
    ws = Workspace(args.workspace)
    world_yaml = ws.committed.world_yaml
    seeds = list(range(cfg.seed, cfg.seed + cfg.episodes))
    world_id = hashlib.sha256(world_yaml.read_bytes()).hexdigest()[:8]  # a world composed again records anew
    folder = ws.evals_dir / "splat_streams" / f"{task_slug(cfg.task)}-{cfg.size}px-{world_id}"
    streams, parts = load_or_record_streams(folder, ws.committed.world_dir, cfg.task, seeds, cfg.size, log=info)
    options = replace(HybridOptions().splat, backend=backend(cfg.backend))  # generation's splat settings
    if cfg.export is not None:
        from ..env.splat_replay import export_splat_bench

        rows = export_splat_bench(ws.committed, folder, parts, options, cfg.export)
        info(f"bench splats: {len(streams)} recorded episodes and {rows:,} Gaussians -> {cfg.export}")
        print(json.dumps({"export": str(cfg.export), "episodes": len(streams), "gaussians": rows}), flush=True)
        return 0
    world = SplatWorld.from_files(parts, options)  # the Gaussians alone: no simulator, no robot model
    dev = world.device
    name = torch.cuda.get_device_name(dev) if dev.type == "cuda" else f"cpu ({threads} threads)"
    frames_per_demo = float(np.mean([len(s["poses"]) for s in streams]))
    info(f"bench splats: {len(world):,} Gaussians on {name}, {len(streams)} recorded episodes of {frames_per_demo:.1f}"
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
            info(f"{what}: {r['demos'] / r['seconds'] * 60:.1f} demos/min ({r['seconds']:.1f} s{batch})")
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
    print(json.dumps({"backend": dev.type, "device": name, "gaussians": len(world), "size": cfg.size,
                      "cameras": cams, "frames_per_demo": round(frames_per_demo, 1), "demos": cfg.demos,
                      "runs": cfg.runs, "results": results}), flush=True)  # fmt: skip
    return 0
