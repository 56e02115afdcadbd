"""The paper's sim-to-real experiment on the bundled sample (``m2m bench sim2real``, issue 16).

The sample's "real world" is the textured-mesh scene that rendered its video (``ground_truth.json``); the
"simulator" is the world ``m2m demo`` reconstructed from that video. Policies are trained only on demonstrations
generated in the reconstruction (hybrid frames) and evaluated closed-loop in the ground-truth world (the env's
``ground_truth`` renderer) and, beside it, in the reconstruction itself:

- **main** (the paper's Tables 1-2): "grasp banana" from the largest demo count, "press button"; each trained with
  ``seeds`` training seeds and deployed as one ensemble (the mean of their action chunks), the first seed alone
  evaluated in the ground-truth world beside it (on the sample a training seed moved one grasp policy by up to 19
  points: 68-87 %, four seeds; the four as one 83 % of 200 episodes, README "Four seeds");
- **ablation** (Table 3): the same grasp with objects drawn from their meshes during generation (vertex-coloured
  from their Gaussians) instead of their Gaussians, at one demo count; evaluated in the ground-truth world and
  (with ``hybrid``) in its own world, the hybrid one with mesh objects: whether it learnt the task at all (on the
  sample it did not: 1 of 10 there, so its ground-truth figure is not the visual gap alone);
- **robot look**: the same grasp with the robot drawn from its model's meshes during generation (Genesis's render,
  composited) instead of its captured Gaussians, at one demo count; evaluated in the ground-truth world, which draws
  the robot as the capture filmed it, and (with ``hybrid``) in its own world: what drawing the robot as the camera saw
  it is worth to a policy (run only when the world has the robot's Gaussians);
- **data scale** (Table 4): the grasp policy from the first 50 / 150 / 300 demos of one generated set, one training
  seed each (the largest: the main policy's first seed), as is the ablation.

Every step is a stage run (``generate``, ``train_policy``, ``eval_policy``) in the workspace, so a killed bench
resumes where it was and a finished step is not redone. Where the time went is read from the stages' records.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .. import configure_threads
from ..configs import ranged
from ..datagen import task_slug
from ..errors import M2MError
from ..inputs import read_yaml
from ..policy.config import PolicyTrainConfig
from ..render.options import MAX_SUPERSAMPLE, supersample_problem
from ..stages import eval_policy, generate, get_stage, train_policy
from ..stages.base import StageRecord, finished_record, run_stage
from ..workspace import Workspace

__all__ = ["Sim2RealConfig", "markdown_tables", "run_sim2real"]

Log = Callable[[str], None]


@dataclass
class Sim2RealConfig:
    """bench sim2real settings.

    sample          the sample whose ground_truth.json is the "real world" (the workspace's world must be
                    reconstructed from its video: `m2m demo -w WS --until world`)
    task            the grasp task of the main policy, the ablation and the data-scale curve, with the scripted
                    expert's options: by default `--tie 2 --look 0.5` (the least wrist turn among equal grasps, a
                    0.5 s look from above first), the recipe measured at 80 % per seed on the sample (README)
    demos           demo counts of the data-scale curve (first N of one generated set); the largest trains the
                    main policy
    press_task      the second main task (empty: none)
    press_demos     demos of press_task
    ablation_demos  demos of the mesh-objects ablation and of its Gaussian twin (0: no ablation)
    robot_ablation_demos  demos of the mesh-robot ablation (`generate --robot-look mesh`) and of its Gaussian-robot
                    twin (0: none; skipped, said so, when the world has no robot Gaussians)
    oracle_demos    demos of the oracle: the same task drawn by the sample's ground-truth renderer (`generate
                    --renderer ground_truth`), trained like its hybrid twin of that demo count: how far the recipe goes
                    when the pictures are the real world's own (0: none; its generation is ~5x slower on the CPU)
    size            frame side of generation and evaluation (pixels)
    supersample     generation's splat layer drawn at s x the frame size and box-averaged down (`generate
                    --supersample`; the hybrid evaluations follow the datasets). 1 (off) by default: the recipe
                    above was measured without it; with the earlier expert, 4 lifted single grasp policies from 56 to
                    68 % (README), for twice the generation time
    workers         generation workers (Ray workers of generation and evaluation with ray_address)
    ray_address     generate and evaluate on Ray workers: auto, host:port, or local (a private Ray instance); the
                    evaluations then run one after another, each over the cluster (docs/guides/multi-machine.md)
    seeds           training seeds of each main policy (0, 1, ...), deployed as one ensemble; 1: a single policy
    parallel        a policy's seeds trained, and its evaluations run, this many at a time, side by side in child
                    processes with the cores shared out (on 2 cores two one-thread trainings of 4,000 steps took
                    28.5 min together, one alone with both cores about 22 min)
    steps           training steps per policy (0: train for `minutes` of wall-clock time instead)
    minutes         training budget per policy when steps is 0
    image_size      the policies' input side (pixels)
    episodes        evaluation episodes per policy and world
    hybrid          also evaluate the main policies in the reconstructed (hybrid) world
    seed            seed of the first evaluation episode
    """

    sample: Path = Path("samples/tabletop")
    task: str = "grasp banana --tie 2 --look 0.5"
    demos: tuple[int, ...] = ranged((50, 150, 300), ge=1, le=10**6)
    press_task: str = "press button"
    press_demos: int = ranged(150, ge=1, le=10**6)
    ablation_demos: int = ranged(150, ge=0, le=10**6)
    robot_ablation_demos: int = ranged(150, ge=0, le=10**6)
    oracle_demos: int = ranged(0, ge=0, le=10**6)
    size: int = ranged(128, ge=16, le=4096)
    supersample: int = ranged(1, ge=1, le=MAX_SUPERSAMPLE)
    workers: int = ranged(2, ge=1, le=256)
    seeds: int = ranged(4, ge=1, le=100)
    parallel: int = ranged(2, ge=1, le=64)
    steps: int = ranged(4000, ge=0, le=10**9)
    minutes: float = ranged(12.0, gt=0, le=100_000)
    image_size: int = ranged(PolicyTrainConfig.image_size, ge=16, le=512)
    episodes: int = ranged(eval_policy.Config.episodes, ge=1, le=10**6)
    hybrid: bool = True
    seed: int = ranged(eval_policy.Config.seed, ge=0, le=2**32 - 1)
    ray_address: str | None = None

    def validate(self) -> None:
        bad = []
        if not self.demos or min(self.demos) < 1:
            bad.append(f"demos must be positive counts, got {self.demos}")
        if self.ablation_demos and self.ablation_demos not in self.demos:
            bad.append(f"ablation_demos ({self.ablation_demos}) must be one of demos {self.demos} (its Gaussian twin)")
        if self.robot_ablation_demos and self.robot_ablation_demos not in self.demos:
            bad.append(f"robot_ablation_demos ({self.robot_ablation_demos}) must be one of demos {self.demos} (its "
                       "Gaussian-robot twin)")  # fmt: skip
        if self.oracle_demos and self.oracle_demos not in self.demos:
            bad.append(f"oracle_demos ({self.oracle_demos}) must be one of demos {self.demos} (its hybrid twin)")
        if min(self.episodes, self.workers, self.seeds, self.parallel) < 1 or self.size < 16 or self.minutes <= 0:
            bad.append("episodes, workers, seeds and parallel must be >= 1, size >= 16, minutes > 0")
        if self.steps < 0:
            bad.append(f"steps must be >= 0 (0: a minutes budget), got {self.steps}")

        if problem := supersample_problem(self.supersample):
            bad.append(problem)
        if not (Path(self.sample) / "ground_truth.json").is_file():
            bad.append(f"sample {self.sample}: no ground_truth.json (the bench needs a sample made by `m2m sample "
                       "make`, such as samples/tabletop)")  # fmt: skip
        if bad:
            raise M2MError("bench sim2real: " + "; ".join(bad))


def _run_stage(stage_name: str, ws: Workspace, cfg: Any, log: Log) -> tuple[dict[str, Any], float, bool]:
    """(summary, seconds: this run's, or the recorded run's when it was done earlier, done earlier)."""

    stage = get_stage(stage_name)
    t0 = time.perf_counter()
    summary, skipped = run_stage(stage, ws, cfg, log=log)
    seconds = time.perf_counter() - t0
    if skipped:
        rec = StageRecord(ws).data.get(stage.record_key(ws, cfg)) or {}
        seconds = float(rec.get("seconds") or 0.0)
        log(f"{stage.command}: done earlier - {summary['line']}")
    else:
        log(f"{stage.command}: {summary['line']} [{seconds / 60:.1f} min]")
    return summary, seconds, skipped


def _side_by_side(ws: Workspace, stage_name: str, cfgs: list[Any], parallel: int,
                  log: Log) -> list[tuple[dict, float, bool]]:  # fmt: skip
    """Runs of a policy stage (train_policy, eval_policy: each holds only its own output while it works, so they
    share the workspace), ``parallel`` at a time in child processes with the cores shared out; one at a time in
    this process when 1. Each run's (summary, seconds, done earlier), in order."""
    todo = [c for c in cfgs if not _done(ws, stage_name, c)]  # a resumed bench starts no process for those
    if parallel <= 1 or len(todo) <= 1:
        return [_run_stage(stage_name, ws, c, log) for c in cfgs]

    n = min(parallel, len(todo))
    threads = max(1, (os.cpu_count() or 1) // n)
    log(f"bench sim2real: {stage_name} {', '.join(c.name for c in todo)}, {n} side by side ({threads} thread(s) "
        "each)")  # fmt: skip
    # spawn: this process may already run torch's and OpenMP's threads, which a fork does not carry over safely
    with ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context("spawn")) as pool:
        jobs = {id(c): pool.submit(_child, str(ws.root), stage_name, c, threads) for c in todo}
        return [jobs[id(c)].result() if id(c) in jobs else _run_stage(stage_name, ws, c, log) for c in cfgs]


def _done(ws: Workspace, stage_name: str, cfg: Any) -> bool:
    """Whether an identical run finished (run_stage would skip it)."""

    try:
        return finished_record(get_stage(stage_name), ws, cfg) is not None
    except M2MError:  # a missing input: the run itself says so
        return False


def _child(root: str, stage_name: str, cfg: Any, threads: int) -> tuple[dict[str, Any], float, bool]:
    configure_threads(threads)
    log = lambda m: print(f"[{cfg.name}] {m}", file=sys.stderr, flush=True)  # the child's lines on stderr
    return _run_stage(stage_name, Workspace(root), cfg, log)


def run_sim2real(ws: Workspace, cfg: Sim2RealConfig, log: Log = print) -> dict[str, Any]:
    """Run (or resume) the experiment in ``ws``; returns the JSON-ready result (tables in ``result["tables"]``)."""

    cfg.validate()
    if not ws.world_yaml.is_file():
        raise M2MError(f"{ws.world_yaml} not found: reconstruct the sample's world first (`m2m demo -w {ws.root} "
                       "--until world`)")  # fmt: skip
    scene = _scene_record(ws)
    if not scene["head_photo"]:
        log("bench sim2real: the scene was trained without the head camera's photo; on the sample, `m2m train-scene "
            f"--head-photo {Path(cfg.sample) / 'head_view.png'}` (then `m2m demo -w {ws.root} --until world`) lifted "
            "a grasp policy from 40 to 68 % of 50 ground-truth episodes (README)")
    seconds = {"generation": 0.0, "training": 0.0, "evaluation": 0.0}
    n_max, slug = max(cfg.demos), task_slug(cfg.task)
    mesh_slug, mesh_robot_slug, oracle_slug = f"{slug}_mesh_objects", f"{slug}_mesh_robot", f"{slug}_ground_truth"

    def gen(task: str, n: int, objects: str = "gaussians", out: str | None = None, robot_look: str = "auto",
            oracle: bool = False) -> dict:  # fmt: skip
        # the oracle's frames are the truth's: no hybrid setting (supersampling), local workers (generate refuses Ray)
        c = generate.Config(task=(task,), episodes=n, workers=cfg.workers, size=cfg.size, objects=objects,
                            ray_address=None if oracle else cfg.ray_address,
                            supersample=1 if oracle else cfg.supersample, robot_look=robot_look,
                            renderer="ground_truth" if oracle else "hybrid",
                            ground_truth=Path(cfg.sample).resolve() if oracle else None,
                            out=ws.dataset_dir(out) if out else None)  # fmt: skip
        s, dt, _ = _run_stage("generate", ws, c, log)
        seconds["generation"] += dt
        return s["tasks"][task]

    def train(dataset: str, n: int, names: list[str]) -> list[dict]:
        cs = [train_policy.Config(datasets=(dataset,), episodes=n, name=name, steps=cfg.steps, minutes=cfg.minutes,
                                  image_size=cfg.image_size, seed=seed) for seed, name in enumerate(names)]  # fmt: skip
        return side_by_side("train_policy", cs, "training")

    def evaluate(task: str, runs: list[tuple[str, str, str, str]], robot_look: str = "auto") -> list[dict]:
        """runs: (policy, report label, renderer, objects), side by side; the hybrid ones draw the robot as
        ``robot_look``."""
        cs = []
        for policy, label, renderer, objects in runs:
            # absolute: the stage records it in m2m.yaml, where a relative path would mean the workspace's folder
            sample = Path(cfg.sample).resolve() if renderer == "ground_truth" else None
            name = f"{label}-{renderer}" + ("-mesh_objects" if objects == "meshes" else "")
            cs.append(eval_policy.Config(policy=policy, task=task, renderer=renderer, episodes=cfg.episodes,
                                         seed=cfg.seed, size=cfg.size, ground_truth=sample, name=name,
                                         objects=objects, ray_address=cfg.ray_address,
                                         robot_look=robot_look if renderer == "hybrid" else "auto",
                                         workers=cfg.workers if cfg.ray_address else 1))  # fmt: skip
        keys = ("successes", "episodes", "success_rate", "wilson95", "mean_steps")
        return [{k: s[k] for k in keys} for s in side_by_side("eval_policy", cs, "evaluation")]

    def side_by_side(stage_name: str, cs: list[Any], part: str) -> list[dict]:
        t0 = time.perf_counter()
        # on Ray the cluster's workers run an evaluation's episodes side by side instead of child processes here
        parallel = 1 if cfg.ray_address and stage_name == "eval_policy" else cfg.parallel
        done = _side_by_side(ws, stage_name, cs, parallel, log)
        # wall-clock (runs side by side overlap), and the recorded time of a run done earlier
        seconds[part] += time.perf_counter() - t0 + sum(dt for _, dt, skipped in done if skipped)
        return [s for s, _, _ in done]

    rows: list[dict[str, Any]] = []

    def policy_row(kind: str, task: str, dataset: str, n: int, worlds: tuple[str, ...], objects: str = "gaussians",
                   seeds: int = 1, robot_look: str = "auto") -> dict:  # fmt: skip
        # seed 0 keeps the single policy's name, so a bench of one seed and one of several share it
        names = [f"{dataset}_{n}" + (f"_s{k}" if k else "") for k in range(seeds)]
        trained = train(dataset, n, names)
        deployed, label = ",".join(names), names[0] + (f"_x{seeds}" if seeds > 1 else "")
        row = {"kind": kind, "task": task, "dataset": dataset, "demos": n, "policy": deployed, "seeds": seeds,
               "train_minutes": round(sum(t["seconds"]["train"] for t in trained) / 60, 2),
               "train_steps": [t["steps"] for t in trained]}  # fmt: skip
        # its own world: the hybrid one with the objects drawn as in its demos
        runs = [(deployed, label, world, objects if world == "hybrid" else "gaussians") for world in worlds]
        if seeds > 1:  # the first seed alone: one policy's figure, and the data-scale curve's point
            runs.append((names[0], names[0], "ground_truth", "gaussians"))
        results = evaluate(task, runs, robot_look)
        row.update(zip(worlds, results[: len(worlds)], strict=True))
        if seeds > 1:
            row["ground_truth_single"] = results[-1]
        rows.append(row)
        return row

    # The headline first (a bench stopped early has it), then the second task, the curve, the ablation.
    main_worlds = ("ground_truth", "hybrid") if cfg.hybrid else ("ground_truth",)
    datasets = {slug: gen(cfg.task, n_max)}
    policy_row("main", cfg.task, slug, n_max, main_worlds, seeds=cfg.seeds)
    if cfg.press_task and cfg.press_demos:
        datasets[task_slug(cfg.press_task)] = gen(cfg.press_task, cfg.press_demos)
        policy_row("main", cfg.press_task, task_slug(cfg.press_task), cfg.press_demos, main_worlds, seeds=cfg.seeds)
    for n in sorted(cfg.demos):
        if n != n_max:
            policy_row("data_scale", cfg.task, slug, n, ("ground_truth",))
    if cfg.ablation_demos:
        datasets[mesh_slug] = gen(cfg.task, cfg.ablation_demos, objects="meshes", out=mesh_slug)
        policy_row("ablation", cfg.task, mesh_slug, cfg.ablation_demos, main_worlds, objects="meshes")
    if cfg.robot_ablation_demos and not _has_robot_gaussians(ws):
        log("bench sim2real: no robot-look ablation: the world has no robot Gaussians (its capture did not show the "
            "robot), so every demo already draws the mesh robot")  # fmt: skip
    elif cfg.robot_ablation_demos:
        datasets[mesh_robot_slug] = gen(cfg.task, cfg.robot_ablation_demos, out=mesh_robot_slug, robot_look="mesh")
        policy_row("robot_ablation", cfg.task, mesh_robot_slug, cfg.robot_ablation_demos, main_worlds,
                   robot_look="mesh")  # fmt: skip

    if cfg.oracle_demos:
        datasets[oracle_slug] = gen(cfg.task, cfg.oracle_demos, out=oracle_slug, oracle=True)
        policy_row("oracle", cfg.task, oracle_slug, cfg.oracle_demos, main_worlds)

    result = {
        "bench": "sim2real",
        "workspace": str(ws.root),
        "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in cfg.__dict__.items()},
        "scene": scene,
        "policies": rows,
        "datasets": {k: {"episodes": v.get("episodes"), "success_rate": v.get("success_rate"),
                         "demos_per_min": v.get("demos_per_min")} for k, v in datasets.items()},  # fmt: skip
        "minutes": {k: round(v / 60, 1) for k, v in seconds.items()},
    }
    result["tables"] = markdown_tables(result, cfg)
    return result


def _has_robot_gaussians(ws: Workspace) -> bool:
    """Whether the workspace's world draws the robot from its captured Gaussians by default (``robot.gaussians``)."""
    robot = (read_yaml(ws.world_yaml, "the world (world.yaml)") or {}).get("robot")
    return isinstance(robot, dict) and bool(robot.get("gaussians"))


def _scene_record(ws: Workspace) -> dict[str, Any]:
    """What the policies' world was reconstructed with: the scene's held-out figure and its head photo (or None)."""
    try:
        m = json.loads(ws.scene_metrics.read_text())
    except (OSError, ValueError):
        return {"head_photo": None, "psnr_heldout": None}
    return {"head_photo": (m.get("config") or {}).get("head_photo"), "psnr_heldout": m.get("psnr_heldout")}


def _cell(e: dict | None) -> str:
    if not e:
        return "-"
    lo, hi = e["wilson95"]
    return f"{100 * e['success_rate']:.1f} % [{100 * lo:.0f}-{100 * hi:.0f}] ({e['successes']}/{e['episodes']})"


def _single(r: dict[str, Any]) -> dict[str, Any]:
    """A policy row as one training seed's: an ensemble's first seed alone (its ground-truth figure only)."""
    if "ground_truth_single" not in r:
        return r
    return {**r, "ground_truth": r["ground_truth_single"], "hybrid": None}


def _gaussian_twin(rows: list[dict[str, Any]], task: str, demos: int) -> dict[str, Any]:
    """An ablation's twin: the policy row of ``task`` on ``demos`` of the method's demos, as one training seed's
    (empty when the bench trained none)."""
    return next((_single(r) for r in rows if r["kind"] in ("main", "data_scale") and r["task"] == task
                 and r["demos"] == demos), {})  # fmt: skip


def markdown_tables(result: dict[str, Any], cfg: Sim2RealConfig) -> str:
    """The paper's tables: success in the ground-truth ("real") world with its 95 % Wilson interval. The main
    policies as deployed (their seeds as one, and the first seed alone); the ablation and the data-scale curve
    compare single training seeds."""
    rows = result["policies"]
    out = ["Main (paper Tables 1-2): trained on hybrid demos of the reconstruction only", "",
           "| task | demos | policy | ground-truth world | reconstructed (hybrid) world |",
           "|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        if r["kind"] == "main":
            seeds = r.get("seeds", 1)
            who = f"{seeds} training seeds as one" if seeds > 1 else "one training seed"
            out.append(f"| {r['task']} | {r['demos']} | {who} | {_cell(r.get('ground_truth'))} | "
                       f"{_cell(r.get('hybrid'))} |")  # fmt: skip
            if seeds > 1:
                out.append(f"| {r['task']} | {r['demos']} | the first seed alone | "
                           f"{_cell(r.get('ground_truth_single'))} | - |")  # fmt: skip
    mesh = next((r for r in rows if r["kind"] == "ablation"), None)
    if mesh is not None:
        gs = _gaussian_twin(rows, cfg.task, cfg.ablation_demos)
        out += ["", f"Ablation (paper Table 3): {cfg.task}, {cfg.ablation_demos} demos, one training seed", "",
                "| objects in the demos | ground-truth world | its own world (hybrid, objects drawn as in its demos) |",
                "|---|---|---|",
                f"| 3DGS (the method) | {_cell(gs.get('ground_truth'))} | {_cell(gs.get('hybrid'))} |",
                f"| mesh only (vertex-coloured) | {_cell(mesh.get('ground_truth'))} | {_cell(mesh.get('hybrid'))} |"]
    mesh_robot = next((r for r in rows if r["kind"] == "robot_ablation"), None)
    if mesh_robot is not None:
        gs = _gaussian_twin(rows, cfg.task, cfg.robot_ablation_demos)
        out += ["", f"Robot look: {cfg.task}, {cfg.robot_ablation_demos} demos, one training seed", "",
                "| the robot in the demos | ground-truth world | its own world (hybrid, the robot drawn as in its "
                "demos) |", "|---|---|---|",
                f"| its captured Gaussians (the method) | {_cell(gs.get('ground_truth'))} | "
                f"{_cell(gs.get('hybrid'))} |",
                f"| the model's meshes (Genesis, composited) | {_cell(mesh_robot.get('ground_truth'))} | "
                f"{_cell(mesh_robot.get('hybrid'))} |"]  # fmt: skip
    oracle = next((r for r in rows if r["kind"] == "oracle"), None)
    if oracle is not None:
        gs = _gaussian_twin(rows, cfg.task, cfg.oracle_demos)
        out += ["", f"Oracle: {cfg.task}, {cfg.oracle_demos} demos, one training seed; the same recipe and motions, "
                "the demos drawn by the ground truth itself (the looks made perfect)", "",
                "| the demos' pictures | ground-truth world | reconstructed (hybrid) world |", "|---|---|---|",
                f"| the reconstruction's (the method) | {_cell(gs.get('ground_truth'))} | {_cell(gs.get('hybrid'))} |",
                f"| the ground truth's own (oracle) | {_cell(oracle.get('ground_truth'))} | "
                f"{_cell(oracle.get('hybrid'))} |"]  # fmt: skip
    scale = sorted((_single(r) for r in rows if r["task"] == cfg.task and r["kind"] in ("main", "data_scale")),
                   key=lambda r: r["demos"])  # fmt: skip
    out += ["", f"Data scale (paper Table 4): {cfg.task}, ground-truth world, one training seed", "",
            "| demos | success |", "|---|---|"]  # fmt: skip
    out += [f"| {r['demos']} | {_cell(r.get('ground_truth'))} |" for r in scale]
    m = result["minutes"]
    scene = result.get("scene") or {}
    drawn = f"with splat supersampling x{cfg.supersample}" if cfg.supersample > 1 else "without splat supersampling"
    out += ["", f"Demos drawn at {cfg.size} px {drawn}; the scene trained "
            + ("with" if scene.get("head_photo") else "without") + " the head camera's photo."]
    out += ["", f"Time on this machine: generation {m['generation']} min, training {m['training']} min, "
            f"evaluation {m['evaluation']} min"]  # fmt: skip
    return "\n".join(out)
