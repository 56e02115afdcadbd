"""Stage ``eval_policy`` (``m2m eval-policy``): a policy run closed-loop in the workspace's twin
(``mirage2matter/Twin-v0``) for N episodes -> ``evals/<name>/``: summary.json (success rate with its 95 % Wilson
interval, where the time went), episodes.jsonl (seed, success, steps, seconds, reason per episode), rollout.mp4
(the first episodes, every camera side by side) and contact_sheet.png.

The policy is one trained here (a name under ``policies/``), a checkpoint folder, or any callable
``obs -> action`` named as ``module:function`` (e.g. a LeRobot checkpoint behind a few lines of your own). Two
observation renderers: ``hybrid`` (the reconstructed world, as generation renders it) and ``ground_truth`` (on a
sample: its own textured-mesh world, as its video was rendered; the sim-to-real analogue of issue 16). Episode
seeds start far from generation's (those are 32-bit hashes, ``datagen.runner.attempt_seed``), so the episodes are
unseen. A killed evaluation resumes at the episode it was on.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from ..atomic import atomic_write
from ..configs import ranged
from ..datagen import task_slug
from ..env.config import EnvError, EpisodeSpec, Randomization, hybrid_options, parse_start_region
from ..eval_workers import EvalJob, PolicyRecipe, evaluate_on_ray
from ..evaluation import contact_sheet, evaluate_policy
from ..inputs import read_yaml
from ..policy.config import POLICY_FILE
from ..policy.data import PolicyError, dataset_meta
from ..render.options import MAX_SUPERSAMPLE
from ..video import write_video
from ..workspace import Workspace
from .base import ADDED_LATER, Input, Log

__all__ = ["Config", "record_key", "inputs", "outputs", "run", "writes"]

EPISODES_FILE = "episodes.jsonl"


@dataclass
class Config:
    """eval-policy settings.

    policy          the policy: a name under <workspace>/policies, a policy folder, or module:function (obs -> action);
                    several names or folders joined by commas (A,B,C) run as one ensemble (``ensemble_combine``)
    task            the task instruction (default: the task of the datasets the policy was trained on, when one)
    renderer        observations: hybrid (the reconstructed world, as generation renders it) or ground_truth (a
                    sample's own world, as its video was rendered but with textures filtered trilinearly)
    ground_truth    the sample folder (with ground_truth.json) the ground_truth renderer draws (default: the folder
                    of the workspace's capture, when it is a sample)
    episodes        episodes to run
    seed            seed of the first episode (then seed + 1, ...)
    horizon         steps before an episode is truncated (a failure)
    max_episode_minutes  wall-clock limit of one episode (0: none); an episode past it ends as a failure marked
                    ``cut``. Normal episodes take 0.5-2 min on 2 cores; llvmpipe (the CPU OpenGL of the
                    ground_truth renderer) takes 1-45 s instead of 0.04 s per frame for some close views of
                    the sample's button (measured: its thin bottom wall band seen from the wrist camera)
    size            frame side in pixels (0: the frame size of the datasets the policy was trained on)
    name            the report's folder: <workspace>/evals/<name> (default: <policy>-<renderer>-<task>)
    video_episodes  episodes shown in rollout.mp4 and contact_sheet.png
    device          where a trained policy runs: auto, cpu, cuda
    ensemble_decay  a trained policy's temporal-ensembling weights exp(-m i) over its overlapping chunks (default:
                    the checkpoint's, 0.1; ACT's is 0.01; 0 averages them equally)
    ensemble_combine  how an ensemble's chunks become one: mean (averaged) or medoid (the member's chunk nearest the
                    others; three members or more)
    replan_every    run a trained policy's network every n steps and play its chunk open-loop in between, instead of
                    temporal ensembling (1 <= n <= its chunk length)
    objects         how the hybrid renderer draws objects: gaussians (the method) or meshes (the world a mesh-only
                    ablation policy was trained in, ``generate --objects meshes``)
    robot_look      how the hybrid renderer draws the robot: gaussians (its per-link Gaussians as the capture saw it),
                    mesh (Genesis's render of the model's meshes: the world a ``generate --robot-look mesh`` policy was
                    trained in), auto (as the datasets the policy was trained on were generated, else gaussians when
                    the world has them)
    supersample     the hybrid renderer's splat layer drawn at s x the frame size and box-averaged down (0: as the
                    datasets the policy was trained on were generated, ``generate --supersample``; 1 when unknown)
    start_region    boxes "object:x_min,x_max,y_min,y_max" (m, robot-base frame): every episode starts with that object
                    inside one of its boxes, as ``generate --start-region``: how a policy does where it used to fail
                    (the report's default name then ends in the boxes)
    ray_address     run the episodes on Ray workers: auto, host:port, or local (a private Ray instance); the same
                    records and success figures as here for the same seeds (docs/guides/multi-machine.md)
    workers         Ray workers (with ray_address), each running one episode at a time
    """

    policy: str = "policy"
    task: str | None = None
    renderer: Literal["hybrid", "ground_truth"] = "hybrid"
    ground_truth: Path | None = None
    episodes: int = ranged(50, ge=1, le=10**6)
    seed: int = ranged(1_000_000, ge=0, le=2**32 - 1)
    horizon: int = ranged(150, ge=1, le=10**6)
    max_episode_minutes: float = ranged(10.0, ge=0, le=100_000)
    size: int = ranged(0, ge=16, le=4096, off=0)
    name: str | None = None
    video_episodes: int = ranged(4, ge=0, le=1000)
    device: str = "auto"
    ensemble_decay: float | None = ranged(None, ge=0, le=100)
    ensemble_combine: Literal["mean", "medoid"] = "mean"
    replan_every: int | None = ranged(None, ge=1, le=1000)
    objects: Literal["gaussians", "meshes"] = "gaussians"
    robot_look: Literal["auto", "gaussians", "mesh"] = field(default="auto", metadata=ADDED_LATER)
    supersample: int = ranged(0, ge=0, le=MAX_SUPERSAMPLE)
    start_region: tuple[str, ...] = ()
    # how the episodes run, not what they are: a run resumes one made the other way
    ray_address: str | None = field(default=None, metadata={"fingerprint": "never"})
    workers: int = ranged(1, ge=1, le=256, metadata={"fingerprint": "never"})

    def randomization(self):
        """The episodes' randomisation: generation's defaults, with the start regions."""
        try:
            return Randomization(start_regions=tuple(parse_start_region(t) for t in self.start_region))
        except EnvError as e:
            raise PolicyError(str(e)) from None

    def validate(self) -> None:
        bad = []
        try:
            self.randomization()
        except PolicyError as e:
            bad.append(str(e))
        if self.ensemble_decay is not None and not self.ensemble_decay >= 0:
            bad.append(f"ensemble_decay must be >= 0, got {self.ensemble_decay}")
        if self.replan_every is not None and self.replan_every < 1:
            bad.append(f"replan_every must be >= 1, got {self.replan_every}")
        if self.episodes < 1:
            bad.append(f"episodes must be >= 1, got {self.episodes}")
        if self.horizon < 1:
            bad.append(f"horizon must be >= 1, got {self.horizon}")
        if not self.max_episode_minutes >= 0:
            bad.append(f"max_episode_minutes must be >= 0 (0: no limit), got {self.max_episode_minutes}")
        if self.size != 0 and self.size < 16:
            bad.append(f"size must be 0 (the datasets') or >= 16, got {self.size}")
        if self.objects != "gaussians" and self.renderer != "hybrid":
            bad.append(f"objects={self.objects} is how the hybrid renderer draws them; the {self.renderer} renderer "
                       "draws its own world: add --objects gaussians (a setting given once stays in the workspace's "
                       "m2m.yaml)")  # fmt: skip
        if self.robot_look != "auto" and self.renderer != "hybrid":
            bad.append(f"robot_look={self.robot_look} is how the hybrid renderer draws the robot; the "
                       f"{self.renderer} renderer draws its own world: add --robot-look auto")  # fmt: skip

        if not 0 <= self.supersample <= MAX_SUPERSAMPLE:
            bad.append(f"supersample must be from 0 (the datasets') or 1 (off) to {MAX_SUPERSAMPLE}, got "
                       f"{self.supersample}")  # fmt: skip
        if self.supersample > 1 and self.renderer != "hybrid":
            bad.append(f"supersample={self.supersample} is how the hybrid renderer draws its splats; the "
                       f"{self.renderer} renderer draws its own world: add --supersample 0")  # fmt: skip
        if self.workers > 1 and not self.ray_address:
            bad.append(f"workers={self.workers} are Ray workers: add --ray-address (local: a private Ray instance "
                       "here), or leave workers at 1")  # fmt: skip
        if self.video_episodes < 0:
            bad.append(f"video_episodes must be >= 0, got {self.video_episodes}")
        if self.name is not None and (not self.name or Path(self.name).name != self.name):
            bad.append(f"name must be a plain folder name, got {self.name!r}")
        if bad:
            raise PolicyError("eval-policy: " + "; ".join(bad))


# ---- what the config names --------------------------------------------------------------------------------------
def _is_callable_ref(ref: str) -> bool:
    return ":" in ref and not Path(ref).exists()


def _policy_dir(ws: Workspace, ref: str) -> Path:
    named = ws.committed.policy_dir(ref)
    if Path(ref).name == ref and (named / POLICY_FILE).is_file():
        return named
    p = Path(ref)
    if p.is_file():
        p = p.parent
    if not (p / POLICY_FILE).is_file():
        have = sorted(q.parent.name for q in ws.committed.policies_dir.glob(f"*/{POLICY_FILE}"))
        raise PolicyError(f"policy {ref!r}: neither a policy in {ws.committed.policies_dir} (have: "
                          f"{have or 'none'}; `m2m train-policy -w {ws.root}`), nor a folder with {POLICY_FILE}, nor "
                          "module:function")  # fmt: skip
    return p


def policy_paths(ws: Workspace, cfg: Config) -> list[Path]:
    """The trained policies' folders: one, several for an ensemble (``A,B,C``), none for a module:function."""
    if _is_callable_ref(cfg.policy):
        return []
    return trained_policy_dirs(ws, cfg.policy)


def trained_policy_dirs(ws: Workspace, ref: str) -> list[Path]:
    """The folders of the trained policies ``ref`` names: a name under the workspace's policies/ or a folder, or
    several joined by commas (an ensemble). PolicyError names what is missing."""
    refs = [r.strip() for r in ref.split(",")] if "," in ref and not Path(ref).exists() else [ref]
    if any(not r for r in refs) or len(set(refs)) != len(refs):
        raise PolicyError(f"policy {ref!r}: an ensemble names each trained policy once, joined by commas "
                          "(e.g. --policy A,B,C)")  # fmt: skip
    return [_policy_dir(ws, r) for r in refs]


def _trained_on(paths: list[Path]) -> list[Path]:
    """The dataset folders policies of ours were trained on (their summary.json), when they are still there."""
    out: list[Path] = []
    for path in paths:
        try:
            out += [Path(d) for d in json.loads((path / "summary.json").read_text())["datasets"] if Path(d) not in out]
        except (OSError, ValueError, KeyError, TypeError):
            pass
    return out


def task_of(ws: Workspace, cfg: Config) -> str:
    if cfg.task:
        return cfg.task
    tasks = set()
    for d in _trained_on(policy_paths(ws, cfg)):
        try:
            tasks.add(json.loads((d / "summary.json").read_text())["task"])
        except (OSError, ValueError, KeyError, TypeError):
            tasks.add(None)
    if len(tasks) == 1 and None not in tasks:
        return tasks.pop()
    raise PolicyError(f"eval-policy: which task? The policy {cfg.policy!r} was not trained on one task's dataset "
                      "of this workspace; give --task, e.g. --task 'grasp banana'")  # fmt: skip


def _size_of(ws: Workspace, cfg: Config) -> int:
    if cfg.size:
        return cfg.size
    for d in _trained_on(policy_paths(ws, cfg)):
        if (d / "meta" / "info.json").is_file():
            return dataset_meta(d)[1][1]
    return EpisodeSpec().size[0]


def _as_generated(ws: Workspace, cfg: Config, read: Callable[[dict], Any], default: Any) -> Any:
    """``read`` of the hybrid settings the policy's first readable training dataset was generated with (its
    fingerprint's ``source.hybrid``), else ``default``."""
    for d in _trained_on(policy_paths(ws, cfg)):
        try:
            return read(json.loads((d / "summary.json").read_text())["fingerprint"]["source"]["hybrid"])
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            continue
    return default


def supersample_of(ws: Workspace, cfg: Config) -> int:
    """The hybrid renderer's splat supersampling: the config's, else the one the policy's training datasets were
    generated with (their fingerprint), else 1; 1 for the ground_truth renderer (it draws its own world)."""
    if cfg.renderer != "hybrid":
        return 1
    if cfg.supersample:
        return cfg.supersample
    return _as_generated(ws, cfg, lambda hybrid: int(hybrid["splat"].get("supersample", 1)), 1)


def robot_look_of(ws: Workspace, cfg: Config) -> str:
    """How the hybrid renderer draws the robot: the config's, else as the policy's training datasets were generated
    (their fingerprint: no key is auto), else auto; auto for the ground_truth renderer (it draws its own world)."""
    if cfg.renderer != "hybrid":
        return "auto"
    if cfg.robot_look != "auto":
        return cfg.robot_look
    return _as_generated(ws, cfg, lambda hybrid: str(hybrid.get("robot_look", "auto")), "auto")


def ground_truth_dir(ws: Workspace, cfg: Any, command: str = "eval-policy") -> Path:
    """The sample folder the ground_truth renderer draws (``cfg.ground_truth``, else the folder of the workspace's
    capture when it is a sample); PolicyError naming ``command`` when there is none."""
    if cfg.ground_truth is not None:
        gt = Path(cfg.ground_truth)
    else:
        source = None
        path = ws.committed.config_file
        if path.is_file():  # m2m.yaml's capture.source, relative to its folder (not the pipeline: it imports us)
            capture = (read_yaml(path, "pipeline settings (m2m.yaml)") or {}).get("capture") or {}
            if isinstance(capture, dict) and isinstance(capture.get("source"), str):
                source = path.parent / capture["source"]
        gt = Path(source).parent if source is not None else None
        if gt is None or not (gt / "ground_truth.json").is_file():
            raise PolicyError(
                f"{command} --renderer ground_truth: this workspace's capture ({source or 'not recorded'}) has no "
                "ground truth: only a sample made by `m2m sample make` (such as samples/tabletop) has its own world "
                "to render. Use --renderer hybrid, or name the sample with --ground-truth DIR"
            )
    if not (gt / "ground_truth.json").is_file():
        raise PolicyError(f"{command} --ground-truth {gt}: no ground_truth.json there; give a sample folder "
                          "(samples/tabletop) or use --renderer hybrid")  # fmt: skip
    return gt


def report_name(ws: Workspace, cfg: Config) -> str:
    if cfg.name:
        return cfg.name
    paths = policy_paths(ws, cfg)
    who = "+".join(p.name for p in paths) if paths else task_slug(cfg.policy)
    who += "-medoid" if cfg.ensemble_combine == "medoid" else ""
    world = cfg.renderer + ("-mesh_objects" if cfg.objects == "meshes" else "")
    world += "-mesh_robot" if robot_look_of(ws, cfg) == "mesh" else ""
    ss = supersample_of(ws, cfg)
    world += f"-ss{ss}" if ss != 1 else ""
    # minus signs kept as "m": boxes y [-0.2, 0.1] and [-0.2, -0.1] are different reports
    world += f"-in-{task_slug(' '.join(cfg.start_region).replace('-', 'm'))}" if cfg.start_region else ""
    return f"{who}-{world}-{task_slug(task_of(ws, cfg))}"


# ---- the stage --------------------------------------------------------------------------------------------------
def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    files = [Input(ws.committed.world_yaml, made_by="compose")]
    files += [Input(p / POLICY_FILE, made_by="train-policy") for p in policy_paths(ws, cfg)]
    if cfg.renderer == "ground_truth":
        files.append(Input(ground_truth_dir(ws, cfg) / "ground_truth.json", field="ground_truth"))
    return files


def open_policy(ws: Workspace, cfg: Config, world: Any):
    """The policy, checked against the world's robot before anything is built (a policy of another robot, rate
    or cameras is an error naming its file)."""
    return policy_recipe(ws, cfg, world).open()


def policy_recipe(ws: Workspace, cfg: Config, world: Any):
    """How to open the policy (here or on a Ray worker, ``eval_workers.PolicyRecipe``); the settings checked."""
    spec = world.robot.spec
    episode = EpisodeSpec()  # the rate and cameras of the episodes it runs in (eval-policy sets the size alone)
    paths = policy_paths(ws, cfg)
    if not paths:
        if cfg.ensemble_decay is not None or cfg.replan_every is not None or cfg.ensemble_combine != "mean":
            raise PolicyError(f"eval-policy: ensemble_decay, ensemble_combine and replan_every set how policies "
                              f"trained by m2m train-policy run their chunks; {cfg.policy} is a callable: leave them "
                              "out")  # fmt: skip
        return PolicyRecipe.of_callable(cfg.policy, action_dim=len(spec.action_names))
    how = {"device": cfg.device, "replan_every": cfg.replan_every, "ensemble_decay": cfg.ensemble_decay}
    if len(paths) == 1 and cfg.ensemble_combine != "mean":
        raise PolicyError(f"eval-policy: ensemble_combine {cfg.ensemble_combine} combines several policies; "
                          f"{cfg.policy} is one: name several (A,B,C) or leave it out")  # fmt: skip
    check = {"robot_type": spec.robot_type, "state_names": spec.state_names, "action_names": spec.action_names,
             "fps": episode.fps, "cameras": [c for c in episode.cameras if c in world.cameras]}  # fmt: skip
    return PolicyRecipe(paths=tuple(str(p.resolve()) for p in paths), how=how, combine=cfg.ensemble_combine,
                        check=check)  # fmt: skip


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    from ..env.twin_env import TwinEnv, make_config

    task = task_of(ws, cfg)
    size = _size_of(ws, cfg)
    supersample, robot_look = supersample_of(ws, cfg), robot_look_of(ws, cfg)
    gt = ground_truth_dir(ws, cfg) if cfg.renderer == "ground_truth" else None
    # every check (the task, the renderer's ground truth, the policy against the robot) before the twin's build
    env_cfg = make_config(ws.committed.world_dir, task, renderer=cfg.renderer, size=size, horizon=cfg.horizon,
                          ground_truth=gt, hybrid=hybrid_options(cfg.objects, supersample, robot_look),
                          randomization=cfg.randomization())  # fmt: skip
    policy = open_policy(ws, cfg, env_cfg.world)
    out = ws.eval_dir(report_name(ws, cfg))
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    env = None if cfg.ray_address else TwinEnv.from_config(env_cfg)  # on Ray: each worker builds its own
    build_s = time.perf_counter() - t0
    try:
        rows_file = out / EPISODES_FILE
        done = []
        if rows_file.is_file():  # a killed run of these settings (the staging is keyed on them)
            done = [json.loads(line) for line in rows_file.read_text().splitlines() if line.strip()]
            log(f"eval-policy: resuming after {len(done)} episodes")

        def save(row: dict) -> None:
            with open(rows_file, "a", encoding="utf-8") as f:
                f.write(json.dumps(row) + "\n")

        log(f"eval-policy: {cfg.episodes} episodes of {task!r}, {cfg.renderer} frames at {size} px, seeds "
            f"{cfg.seed}..{cfg.seed + cfg.episodes - 1}, horizon {cfg.horizon}")  # fmt: skip
        t1 = time.perf_counter()
        limit = 60.0 * cfg.max_episode_minutes or None
        if env is None:
            summary, kept = _on_ray(ws, cfg, env_cfg, limit, done, save, log)
        else:
            summary, kept = evaluate_policy(env, policy, cfg.episodes, seed=cfg.seed, log=log,
                                            keep_frames=cfg.video_episodes, done=done, on_episode=save,
                                            max_episode_seconds=limit)  # fmt: skip
        eval_s = time.perf_counter() - t1
    finally:
        if env is not None:
            env.close()
    with atomic_write(rows_file, "w", encoding="utf-8") as f:  # in seed order
        f.writelines(json.dumps(r) + "\n" for r in summary["runs"])
    if kept:
        pad = lambda f: f[: f.shape[0] // 2 * 2, : f.shape[1] // 2 * 2]  # H.264 wants even sides
        write_video(out / "rollout.mp4", (pad(f) for ep in kept for f in [*ep, *[ep[-1]] * 5]), fps=env_cfg.fps)
        contact_sheet(kept, out / "contact_sheet.png")
    steps = sum(r["steps"] for r in summary["runs"])
    lo, hi = summary["wilson95"]
    result = {
        **{k: v for k, v in summary.items() if k != "runs"},
        "task": task,
        "renderer": cfg.renderer,
        **({"objects": cfg.objects} if cfg.objects != "gaussians" else {}),
        **({"supersample": supersample} if supersample != 1 else {}),
        **({"robot_look": robot_look} if robot_look != "auto" else {}),
        "policy": cfg.policy,
        "size": size,
        "seeds": [cfg.seed, cfg.seed + cfg.episodes - 1],
        **({"start_regions": list(cfg.start_region)} if cfg.start_region else {}),
        **(
            {
                "inference": {
                    "ensemble_decay": policy.ensemble_decay,
                    "replan_every": policy.replan_every,
                    **({"combine": policy.combine} if hasattr(policy, "combine") else {}),
                }
            }
            if hasattr(policy, "ensemble_decay")
            else {}
        ),  # fmt: skip
        "seconds": {
            "build": round(build_s, 1),
            "episodes": round(eval_s, 1),
            "per_step": round(eval_s / max(steps, 1), 4),
        },  # fmt: skip
        "files": {
            "episodes": EPISODES_FILE,
            **({"video": "rollout.mp4", "contact_sheet": "contact_sheet.png"} if kept else {}),
        },  # fmt: skip
        "report": str(out),
    }
    result["line"] = (f"{task!r} ({cfg.renderer}): {summary['successes']}/{summary['episodes']} = "
                      f"{100 * summary['success_rate']:.1f}% (95% CI {100 * lo:.0f}-{100 * hi:.0f}%), "
                      f"{summary['mean_steps']:.0f} steps per episode")  # fmt: skip
    with atomic_write(out / "summary.json", "w", encoding="utf-8") as f:
        json.dump({**result, "runs": summary["runs"]}, f, indent=1)

    return result


def _on_ray(ws: Workspace, cfg: Config, env_cfg: Any, limit: float | None, done: list[dict], save: Any,
            log: Log) -> tuple[dict[str, Any], list]:  # fmt: skip
    """The episodes on Ray workers (``eval_workers``): the same records, appended by ``save`` here as they come."""
    job = EvalJob(env_cfg, policy_recipe(ws, cfg, env_cfg.world), max_episode_seconds=limit)
    return evaluate_on_ray(job, cfg.episodes, cfg.ray_address, cfg.workers, seed=cfg.seed, log=log,
                           keep_frames=cfg.video_episodes, done=done, on_episode=save)  # fmt: skip


def record_key(ws: Workspace, cfg: Config) -> str:
    return f"eval_policy/{report_name(ws, cfg)}"


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    d = ws.eval_dir(report_name(ws, cfg))
    return [d / "summary.json", d / EPISODES_FILE]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.eval_dir(report_name(ws, cfg))]
