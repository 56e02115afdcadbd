"""Stage ``generate``: scripted demonstrations of each task in the workspace's world, rendered as hybrid
frames (splats + the simulated robot) and written as LeRobot datasets -> ``datasets/<task>/``, each checked
by the independent reader (``m2m validate``). A killed run resumes at the episode it was on."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from ..configs import ranged
from ..datagen import GenerateConfig, GenerateError, RunConfig, dataset_fingerprint, generate, task_slug, worker_pool
from ..datagen.config import MAX_TAKEOVER_STEPS, Randomization, Takeover, takeover_steps_problem
from ..env.config import EnvError, EpisodeSpec, hybrid_options, parse_start_region
from ..export.validate import validate
from ..policy import PolicyError
from ..policy.config import POLICY_FILE
from ..render.options import MAX_SUPERSAMPLE, supersample_problem
from ..workspace import Workspace
from .base import ADDED_LATER, Input, Log
from .eval_policy import ground_truth_dir, trained_policy_dirs


@dataclass
class Config:
    """generate settings.

    task         one or more task instructions, e.g. "grasp banana", "press button",
                 "push croissant --direction 0,1 --distance 0.1"
    episodes     successful episodes wanted per task
    workers      parallel workers (local processes, or Ray actors with ray_address)
    ray_address  run the workers on Ray: auto, host:port, or local (a private Ray instance)
    format       dataset format (lerobot-v2.1 for openpi)
    seed         run seed: the same seed gives the same episodes
    size         square frame side of every camera (pixels)
    fps          control and video rate (Hz)
    out          dataset folder (one task only; default <workspace>/datasets/<task>)
    objects      how objects are drawn: gaussians (their 3DGS) or meshes (vertex-coloured meshes: the paper's
                 mesh-only ablation)
    object_shrink  each episode draws the objects' Gaussians at a random scale in [1 - object_shrink, 1] about
                 their base (physics unchanged; 0: off)
    table_texture  each episode re-colours the table's Gaussians: evened out (up to 2t), per-channel gain in
                 [1 - t, 1 + t] and a random grain of amplitude up to t, so a policy cannot use the reconstruction's
                 wood grain as a landmark (0: off)
    splat_server  draw every worker's splat layer in one process, batched: for a GPU, where one gsplat call serves
                 all the workers' episodes (the same episodes; every camera drawn whole; not with ray_address)
    supersample  draw the splat layer at s x the frame size and average each s x s block: Gaussians much smaller
                 than a pixel then add their area instead of swelling to the rasterizer's minimum footprint (at
                 128 px the reconstructed banana covers 1.8x its true area in the head camera, 1.2x with 4); the
                 splat time grows ~s^2 (1: off)
    robot_look   the robot in the frames: gaussians (its own per-link Gaussians as the capture saw it, posed by forward
                 kinematics in the same splat pass as the world), mesh (Genesis renders its model's meshes, composited
                 over the splats: the look before the capture's), auto (gaussians when the world has them)
    start_region  one or more boxes "object:x_min,x_max,y_min,y_max" (m, robot-base frame): every episode starts with
                 that object's centre inside one of its boxes (the rest of the layout as usual) - more demonstrations
                 where a policy fails, e.g. "banana:0.55,0.62,-0.3,-0.2"
    takeover     a trained policy (a name under policies/ or its folder; A,B: an ensemble) that acts first in every
                 episode; the scripted expert then takes over from wherever the policy left the robot and the objects,
                 and the episode is recorded from there: demonstrations of getting back on track from the states the
                 policy itself reaches (DAgger's data; the policy's own steps are not recorded)
    takeover_steps  lo,hi: the takeover's policy acts for a number of control ticks drawn in [lo, hi] per episode
    renderer     what draws the frames: hybrid (the reconstructed world: the method) or ground_truth (a sample's own
                 world, as its video was rendered, textures filtered trilinearly: demonstrations in the sim-to-real
                 bench's "real" pictures, an oracle for how far a recipe goes when the looks are perfect; slower on
                 the CPU)
    ground_truth  the sample folder (with ground_truth.json) the ground_truth renderer draws (default: the folder of
                 the workspace's capture, when it is a sample)
    """

    task: tuple[str, ...] = ()
    episodes: int = ranged(50, ge=1, le=10**6)
    workers: int = ranged(RunConfig.workers, ge=1, le=256)
    ray_address: str | None = None
    format: Literal["lerobot-v3.0", "lerobot-v2.1"] = RunConfig.format
    seed: int = ranged(RunConfig.seed, ge=0, le=2**32 - 1)
    size: int = ranged(EpisodeSpec.size[0], ge=8, le=4096)
    fps: int = ranged(EpisodeSpec.fps, ge=1, le=1000)
    out: Path | None = field(default=None, metadata={"output": True})  # written, not read
    objects: Literal["gaussians", "meshes"] = "gaussians"
    object_shrink: float = ranged(0.0, ge=0, lt=1)
    table_texture: float = ranged(0.0, ge=0, lt=1)
    splat_server: bool = False
    supersample: int = ranged(1, ge=1, le=MAX_SUPERSAMPLE)
    robot_look: Literal["auto", "gaussians", "mesh"] = field(default="auto", metadata=ADDED_LATER)
    start_region: tuple[str, ...] = ()
    takeover: str | None = None
    # within the approach: the sample's grasps take ~42 ticks, and with 10,60 a trained policy finished the task on its
    # own before the takeover in 3 of the first 5 attempts (nothing for the expert to correct)
    takeover_steps: tuple[int, int] = ranged(Takeover.steps, ge=0, le=MAX_TAKEOVER_STEPS, ordered=True)
    renderer: Literal["hybrid", "ground_truth"] = field(default="hybrid", metadata=ADDED_LATER)
    ground_truth: Path | None = field(default=None, metadata=ADDED_LATER)

    def validate(self) -> None:
        if not self.task:
            raise GenerateError('generate: no task; give one or more, e.g. --task "grasp banana"')
        if self.out is not None and len(self.task) != 1:
            raise GenerateError("generate: out names one dataset folder; give one task with it")
        if self.episodes < 1 or self.workers < 1 or self.size < 2 or self.fps < 1:
            raise GenerateError("generate: episodes, workers and fps must be >= 1, size >= 2")
        if self.size % 2:
            raise GenerateError(f"generate: size {self.size}: the simulator's cameras need an even width (224, 128...)")
        if not 0.0 <= self.object_shrink < 1.0:
            raise GenerateError(f"generate: object_shrink must be in [0, 1), got {self.object_shrink}")
        if not 0.0 <= self.table_texture < 1.0:
            raise GenerateError(f"generate: table_texture must be in [0, 1), got {self.table_texture}")

        bad_supersample = supersample_problem(self.supersample)
        if bad_supersample:
            raise GenerateError(f"generate: {bad_supersample}")
        self.start_regions()
        bad_steps = takeover_steps_problem(self.takeover_steps)
        if bad_steps:
            raise GenerateError(f"generate: {bad_steps}")
        if self.ground_truth is not None and self.renderer != "ground_truth":
            raise GenerateError("generate: ground_truth names the sample the ground_truth renderer draws; add "
                                "--renderer ground_truth, or leave it out")  # fmt: skip
        if self.takeover is not None and not self.takeover.strip():
            raise GenerateError("generate: takeover names no policy; give a trained policy (m2m train-policy), or "
                                "leave it out")  # fmt: skip

    def start_regions(self) -> tuple[tuple[str, float, float, float, float], ...]:
        try:
            return tuple(parse_start_region(t) for t in self.start_region)
        except EnvError as e:
            raise GenerateError(f"generate: {e}") from None

    def takeover_dirs(self, ws: Workspace) -> list[Path]:
        """The takeover's policy folders (none without one); GenerateError when a policy is missing."""
        if self.takeover is None:
            return []

        try:
            return trained_policy_dirs(ws, self.takeover)
        except PolicyError as e:
            raise GenerateError(f"generate --takeover: {e}") from None

    def ground_truth_dir(self, ws: Workspace | None) -> Path | None:
        """The sample the ground_truth renderer draws (None for hybrid frames); GenerateError when there is none.
        Without ``ws`` only a named sample (the default is the workspace capture's)."""
        if self.renderer != "ground_truth":
            return None
        if ws is None:
            if self.ground_truth is None:
                raise GenerateError("generate: the default ground-truth sample is the workspace's capture; none was "
                                    "given")  # fmt: skip
            return Path(self.ground_truth)
        try:
            return ground_truth_dir(ws, self, command="generate")
        except PolicyError as e:
            raise GenerateError(str(e)) from None

    def generation(self, ws: Workspace | None = None) -> GenerateConfig:
        """The generation settings; ``ws`` resolves a takeover's policies (required with one) and the default
        ground-truth sample."""
        takeover = None
        if self.takeover is not None:
            if ws is None:
                raise GenerateError("generate: a takeover's policies are looked up in a workspace; none was given")
            from ..policy import open_policies  # loads torch

            files = [Path(d) / POLICY_FILE for d in self.takeover_dirs(ws)]
            takeover = Takeover.of(files, self.takeover_steps, opener=open_policies)
        return GenerateConfig(
            run=RunConfig(episodes=self.episodes, seed=self.seed, workers=self.workers, ray_address=self.ray_address,
                          format=self.format),
            episode=EpisodeSpec(size=(self.size, self.size), fps=self.fps),
            randomization=Randomization(object_shrink=self.object_shrink, table_texture=self.table_texture,
                                        start_regions=self.start_regions()),
            hybrid=hybrid_options(self.objects, self.supersample, self.robot_look),
            splat_server=self.splat_server, takeover=takeover, ground_truth=self.ground_truth_dir(ws),
        )  # fmt: skip


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    files = [Input(ws.world_yaml, made_by="compose")]
    gt = cfg.ground_truth_dir(ws)
    if gt is not None:
        files.append(Input(gt / "ground_truth.json", field="ground_truth"))
    return files + [Input(p / POLICY_FILE, made_by="train-policy") for p in cfg.takeover_dirs(ws.committed)]


def _dataset_dir(ws: Workspace, cfg: Config, task: str) -> Path:
    return cfg.out if cfg.out is not None else ws.dataset_dir(task_slug(task))


def _finished(folder: Path, fingerprint: dict) -> dict | None:
    """The summary of a finished dataset in ``folder`` whose fingerprint is ``fingerprint``, else None."""
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if summary.get("fingerprint") != fingerprint or not (folder / "meta" / "info.json").is_file():
        return None
    return {**summary, "dataset": str(folder)}


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    from ..sim.tasks import parse_task
    from ..world import load_world

    world = load_world(ws.world_yaml)
    tasks = [parse_task(text, world) for text in cfg.task]  # every task checked before any generation
    generation = cfg.generation(ws.committed)  # once: a takeover's policies are read and hashed here
    per_task, lines = {}, []
    # one set of workers for every task: each builds its twin once (a splat server's run keeps its own)
    with worker_pool(generation) as pool:
        summaries = {}
        for text, task in zip(cfg.task, tasks, strict=True):
            done = _finished(_dataset_dir(ws.committed, cfg, text), dataset_fingerprint(world, task, generation))
            if done is not None:  # the same dataset is already in the workspace: left in place, not rewritten
                log(f"{text!r}: {done['dataset']} already holds this dataset")
                summaries[text] = done
            else:
                summaries[text] = generate(world, task, _dataset_dir(ws, cfg, text), generation, log=log, pool=pool)
    for text in cfg.task:
        s = summaries[text]
        problems = validate(s["dataset"])
        per_task[text] = {**s, "validation_problems": problems}
        rate = s.get("success_rate")
        lines.append(
            f"{text!r}: {s.get('episodes')} episodes"
            + ("" if rate is None else f", success {100 * rate:.0f}%")
            + (f", {s.get('demos_per_min')} demos/min" if s.get("demos_per_min") else "")
            + (", valid" if not problems else f", {len(problems)} PROBLEMS")
            + (f", frames drawn by {generation.ground_truth}'s ground truth" if generation.ground_truth else "")
        )
    n_ok = sum(not t["validation_problems"] for t in per_task.values())
    episodes = sum(int(t.get("episodes") or 0) for t in per_task.values())
    line = f"{len(per_task)} dataset(s), {episodes} episodes, {n_ok} of {len(per_task)} valid (an independent reader)"
    return {"tasks": per_task, "details": lines, "line": line}


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [_dataset_dir(ws, cfg, t) / "meta" / "info.json" for t in cfg.task]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [_dataset_dir(ws, cfg, t) for t in cfg.task]
