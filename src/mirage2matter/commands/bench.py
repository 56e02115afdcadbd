"""``m2m bench render | train | datagen | splats | sim2real | policy-gap``: benchmarks, each printing one JSON line
last on stdout."""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

from .. import configure_threads
from ..atomic import atomic_write
from ..bench.render import RenderBenchConfig, bench_render
from ..configs import add_flags, from_flags, ranged
from ..stages.transaction import workspace_lock
from ..workspace import Workspace
from .args import backend, info

# The other benchmarks (and their Configs) load the generation and policy libraries: imported by the function that
# runs one, and by register() only for `m2m bench ...` (full), so that `m2m --help` and every other command load none.


@dataclass
class TrainBenchConfig:
    """bench train settings (``bench.train``'s).

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
    if full:  # the Configs' flags (this imports the generation and policy libraries)
        from ..bench.policy_gap import PolicyGapConfig
        from ..bench.sim2real import Sim2RealConfig
        from ..bench.splats import SplatsBenchConfig

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
    if full:
        add_flags(p, SplatsBenchConfig)
    p.set_defaults(func=_splats)

    s = bench_sub.add_parser(
        "sim2real", help="the paper's sim-to-real experiment on the sample: train on the reconstruction, test on "
        "the ground truth; markdown tables + JSON line last",
        description="In a workspace whose world was reconstructed from the bundled sample's video (`m2m demo -w WS "
        "--until world`): generate demos in the reconstruction, train policies, evaluate them in the sample's "
        "ground-truth world and in the reconstruction; the mesh-objects ablation and the data-scale curve. Each "
        "step is a stage run in the workspace (a killed bench resumes). Hours on a 2-core CPU.",
    )  # fmt: skip
    s.add_argument("-w", "--workspace", required=True, type=Path, help="workspace with the sample's world")
    if full:
        add_flags(s, Sim2RealConfig)
    s.set_defaults(func=_sim2real)

    g = bench_sub.add_parser(
        "policy-gap", help="policies' open-loop action error on expert episodes, hybrid vs ground-truth frames; "
        "JSON line last",
        description="Record the scripted expert's episodes of a task in the sample's reconstructed world, every "
        "observation rendered twice (hybrid, as the policy's demos were drawn: their robot look and supersampling; "
        "and the sample's ground truth; cached in <workspace>/evals/expert_pairs), then for each policy the mean "
        "|predicted chunk - expert's actions| in "
        "action-std units on each renderer's frames. Minutes where a closed-loop evaluation takes tens of minutes; "
        "on the sample the ground-truth error ranked nine grasp policies much as their closed-loop success did. "
        "It scores the expert's states only: compare policies of one training recipe with it, not recipes (a "
        "hue-band-augmented policy scored best and failed closed loop, in its own world too).",
    )  # fmt: skip
    g.add_argument("-w", "--workspace", required=True, type=Path, help="workspace with the sample's world")
    g.add_argument("--policy", nargs="+", required=True, metavar="POLICY",
                   help="policies: names under <workspace>/policies or folders that train-policy wrote (A,B,C: "
                        "one ensemble of them)")  # fmt: skip
    if full:
        add_flags(g, PolicyGapConfig)
    g.set_defaults(func=_policy_gap)


def _render(args: argparse.Namespace) -> int:
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
    from ..bench.train import bench_train

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
    from ..bench.datagen import BENCH_KEYS, bench_datagen
    from ..sim.tasks import parse_task
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
    from ..bench.sim2real import Sim2RealConfig, run_sim2real

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
    from ..bench.policy_gap import PolicyGapConfig, run_policy_gap

    gap = from_flags(PolicyGapConfig, args)
    configure_threads()
    result = run_policy_gap(Workspace(args.workspace), gap, args.policy, log=info)
    print(json.dumps(result), flush=True)
    return 0


def _splats(args: argparse.Namespace) -> int:
    from ..bench.splats import SplatsBenchConfig, run_splats

    cfg = from_flags(SplatsBenchConfig, args)
    threads = configure_threads()
    result = run_splats(Workspace(args.workspace), replace(cfg, backend=backend(cfg.backend)), threads, log=info)
    print(json.dumps(result), flush=True)
    return 0
