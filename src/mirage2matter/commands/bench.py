"""``m2m bench render | train | datagen | splats | sim2real | policy-gap``: benchmarks, each printing one JSON line
last on stdout."""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .. import configure_threads
from ..bench import RenderBenchConfig
from ..configs import add_flags, from_flags, ranged
from .args import backend, info, int_at_least, positive_float


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
    t.add_argument("--minutes", type=positive_float, default=15.0, metavar="M", help="training time (default 15)")
    t.add_argument("--downscale", type=int_at_least(1), default=4, metavar="F", help="1/F resolution (default 4)")
    t.add_argument("--poses", default="given", choices=("given", "sfm"), help="given poses or our own SfM")
    t.add_argument("--work-dir", metavar="DIR", help="cache for the SfM used for initial points")
    t.add_argument("--max-gaussians", type=int_at_least(1000), default=150_000, metavar="N")
    t.add_argument("--filter-3d", type=_filter_variance, default=None, metavar="V",
                   help="Mip-Splatting's 3D filter, a variance in squared pixels (default: train-scene's, 0.2; 0: off)")
    t.set_defaults(func=_train)

    d = bench_sub.add_parser(
        "datagen", help="demonstrations per minute on a workspace's world; JSON line last",
        description="Generate N episodes R times into throw-away folders; the last stdout line is JSON with "
        "demos_per_min (workers warm), success_rate, episodes, frames, workers, backend, ms_per_frame (medians).",
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
    p.add_argument("--task", default="grasp banana", help="the expert's task (default: grasp banana)")
    p.add_argument("--episodes", type=int_at_least(1), default=8, metavar="N", help="recorded episodes (default 8)")
    p.add_argument("--demos", type=int_at_least(1), default=64, metavar="D",
                   help="episodes replayed per run, the recorded ones in turn (default 64)")  # fmt: skip
    p.add_argument("--seed", type=int, default=3_000_000, help="episode seed of the first (default 3000000)")
    p.add_argument("--size", type=int_at_least(16), default=224, metavar="PX", help="frame side (default 224)")
    p.add_argument("--batch", type=int_at_least(1), nargs="+", default=[1, 16], metavar="B",
                   help="episodes per render call; 1 = generation's path (default: 1 16)")  # fmt: skip
    p.add_argument("--server", type=int_at_least(1), nargs="*", default=[], metavar="W",
                   help="also through a splat server (generate --splat-server) fed by W worker processes, for each W "
                   "given (default: none)")  # fmt: skip
    p.add_argument("--backend", default="auto", help="render backend: auto, cpu, cuda (default auto)")
    p.add_argument("--runs", type=int_at_least(1), default=3, metavar="R", help="repetitions (default 3)")
    p.add_argument("--export", type=Path, metavar="DIR",
                   help="instead of timing: write DIR, a workspace holding only the recorded episodes and the world's "
                   "Gaussians as generation draws them (SH 1, faint ones dropped; the sample's: 35 MB), for a GPU "
                   "machine without the simulator: there, bench splats -w DIR")  # fmt: skip
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
    g.add_argument("--task", default="grasp banana", help="the expert's task (default: grasp banana)")
    g.add_argument("--episodes", type=int_at_least(1), default=10, metavar="N", help="expert episodes (default 10)")
    g.add_argument("--seed", type=int, default=2_000_000, help="episode seed of the first (default 2000000)")
    g.add_argument("--size", type=int_at_least(16), default=128, metavar="PX", help="frame side (default 128)")
    g.add_argument("--stride", type=int_at_least(1), default=2, metavar="K", help="compare every K-th step")
    g.add_argument("--ground-truth", type=Path, metavar="DIR",
                   help="the sample folder (default: the workspace's capture's, e.g. samples/tabletop)")  # fmt: skip
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

    configure_threads()
    result = bench_train(
        args.data, minutes=args.minutes, downscale=args.downscale, poses=args.poses, work_dir=args.work_dir,
        max_gaussians=args.max_gaussians, progress=True,
        **({} if args.filter_3d is None else {"filter_3d": args.filter_3d}),
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

    configure_threads()
    ws = Workspace(args.workspace)
    cfg = eval_policy.Config(task=args.task, renderer="ground_truth", ground_truth=args.ground_truth)
    gt = eval_policy.ground_truth_dir(ws, cfg)
    world = make_config(ws.committed.world_dir, args.task, size=args.size).world  # the task and world, checked
    policies = {}
    for ref in args.policy:  # every policy opened and checked against the robot before the long recording
        if not eval_policy.policy_paths(ws, replace(cfg, policy=ref)):
            raise eval_policy.PolicyError(f"bench policy-gap: {ref!r} is a callable; it needs a trained policy (the "
                                          "error is in its action-std units)")  # fmt: skip
        policies[ref] = eval_policy.open_policy(ws, replace(cfg, policy=ref), world)
    seeds = list(range(args.seed, args.seed + args.episodes))
    # keyed on the world's description too: a world composed again (other objects, other placements) records anew
    world_id = hashlib.sha256(ws.committed.world_yaml.read_bytes()).hexdigest()[:8]
    folder = ws.evals_dir / "expert_pairs" / f"{task_slug(args.task)}-{args.size}px-{world_id}"
    episodes = load_or_record_pairs(folder, ws.committed.world_dir, args.task, gt, seeds, args.size, log=info)
    ok = sum(bool(e["success"]) for e in episodes)
    info(f"expert: {ok}/{len(episodes)} episodes succeeded (only those are compared)")
    if not ok:
        raise eval_policy.PolicyError(f"bench policy-gap: the scripted expert failed all {len(episodes)} episodes of "
                                      f"{args.task!r} in this world ({folder}); check it with `m2m task -w "
                                      f"{ws.root} {args.task!r}`")  # fmt: skip
    rows = {}
    for ref, policy in policies.items():
        err = open_loop_error(policy, episodes, stride=args.stride)
        rows[ref] = {**{k: round(v, 5) for k, v in err.items()}, "gap": round(err["ground_truth"] - err["hybrid"], 5)}
        info(f"{ref}: open-loop error hybrid {err['hybrid']:.4f}, ground truth {err['ground_truth']:.4f}")
    result = {"task": args.task, "episodes": len(episodes), "expert_successes": ok, "size": args.size,
              "stride": args.stride, "seeds": [seeds[0], seeds[-1]], "policies": rows}  # fmt: skip
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

    threads = configure_threads()
    ws = Workspace(args.workspace)
    world_yaml = ws.committed.world_yaml
    seeds = list(range(args.seed, args.seed + args.episodes))
    world_id = hashlib.sha256(world_yaml.read_bytes()).hexdigest()[:8]  # a world composed again records anew
    folder = ws.evals_dir / "splat_streams" / f"{task_slug(args.task)}-{args.size}px-{world_id}"
    streams, parts = load_or_record_streams(folder, ws.committed.world_dir, args.task, seeds, args.size, log=info)
    options = replace(HybridOptions().splat, backend=backend(args.backend))  # generation's splat settings
    if args.export is not None:
        from ..env.splat_replay import export_splat_bench

        rows = export_splat_bench(ws.committed, folder, parts, options, args.export)
        info(f"bench splats: {len(streams)} recorded episodes and {rows:,} Gaussians -> {args.export}")
        print(json.dumps({"export": str(args.export), "episodes": len(streams), "gaussians": rows}), flush=True)
        return 0
    world = SplatWorld.from_files(parts, options)  # the Gaussians alone: no simulator, no robot model
    dev = world.device
    name = torch.cuda.get_device_name(dev) if dev.type == "cuda" else f"cpu ({threads} threads)"
    frames_per_demo = float(np.mean([len(s["poses"]) for s in streams]))
    info(f"bench splats: {len(world):,} Gaussians on {name}, {len(streams)} recorded episodes of {frames_per_demo:.1f}"
         f" frames, {args.demos} replayed per run, {args.size} px")  # fmt: skip
    replay_generation(world, streams[:1], 1, args.size)  # warm-up: kernels compiled / loaded, caches allocated
    results = []

    def timed(label: dict, what: str, replay) -> None:
        """``args.runs`` runs of ``replay()`` -> one row of results: demos/min and ms per frame of the median run."""
        runs = []
        for _ in range(args.runs):
            r = replay()
            runs.append(r)
            batch = f", mean batch {r['server']['mean_batch']:.1f}" if "server" in r else ""
            info(f"{what}: {r['demos'] / r['seconds'] * 60:.1f} demos/min ({r['seconds']:.1f} s{batch})")
        secs = statistics.median(r["seconds"] for r in runs)
        row = {**label, "demos_per_min": round(args.demos / secs * 60, 1),
               "ms_per_frame": round(1000 * secs / runs[0]["frames"], 3)}  # fmt: skip
        if "server" in runs[0]:
            row["mean_batch"] = round(statistics.median(r["server"]["mean_batch"] for r in runs), 2)
        results.append({**row, "seconds": [round(r["seconds"], 2) for r in runs]})

    for b in args.batch:
        batch = None if b == 1 else SplatWorldBatch(world, b)
        if batch is not None:
            replay_batched(batch, streams[:1], 1, args.size)
        timed({"batch": b}, f"batch {b}", lambda batch=batch: replay_generation(world, streams, args.demos, args.size)
              if batch is None else replay_batched(batch, streams, args.demos, args.size))  # fmt: skip
        del batch
    for w in args.server:
        timed({"server_workers": w}, f"server, {w} workers",
              lambda w=w: replay_served(parts, options, streams, args.demos, args.size, w))  # fmt: skip
    cams = sorted(k[len("view.") :] for k in streams[0] if k.startswith("view."))
    print(json.dumps({"backend": dev.type, "device": name, "gaussians": len(world), "size": args.size,
                      "cameras": cams, "frames_per_demo": round(frames_per_demo, 1), "demos": args.demos,
                      "runs": args.runs, "results": results}), flush=True)  # fmt: skip
    return 0
