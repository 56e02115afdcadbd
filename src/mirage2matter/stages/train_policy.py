"""Stage ``train_policy`` (``m2m train-policy``): a visuomotor behaviour-cloning policy trained on the workspace's
LeRobot datasets -> ``policies/<name>/`` (policy.pt, summary.json, loss_curve.png; checkpoint.pt to resume).

Not part of ``m2m demo`` / the pipeline's default run (it is the user's experiment, tens of minutes); it has the
stages' shape, so a killed run resumes from its last checkpoint and a finished one with the same settings and
datasets is skipped. See ``mirage2matter.policy`` for the model and why it is not LeRobot's ACT.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from ..datagen import task_slug
from ..policy.config import POLICY_FILE, PolicyTrainConfig
from ..policy.data import PolicyError, dataset_meta
from ..robots import get_robot
from ..workspace import Workspace
from .base import Input, Log

__all__ = ["Config", "record_key", "dataset_dirs", "inputs", "outputs", "run", "writes"]


@dataclass
class Config(PolicyTrainConfig):
    """train-policy settings.

    datasets  datasets to train on: task instructions ("grasp banana") or folder names under
              <workspace>/datasets (default: every dataset there)
    name      the policy's folder: <workspace>/policies/<name>
    """

    datasets: tuple[str, ...] = ()
    name: str = "policy"

    def validate(self) -> None:
        bad = self.problems()
        if not self.name or Path(self.name).name != self.name or self.name.startswith("."):
            bad.append(f"name must be a plain folder name, got {self.name!r}")
        if bad:
            raise PolicyError("train-policy: " + "; ".join(bad))

    def trainer(self) -> PolicyTrainConfig:
        """The trainer's settings (everything but the workspace's choice of datasets and folder)."""
        return PolicyTrainConfig(**{f.name: getattr(self, f.name) for f in fields(PolicyTrainConfig)})


def dataset_dirs(ws: Workspace, cfg: Config) -> list[Path]:
    """The dataset folders ``cfg.datasets`` names (task instructions or folder names under datasets/)."""
    root = ws.committed.datasets_dir
    if not cfg.datasets:
        found = sorted(p.parent.parent for p in root.glob("*/meta/info.json"))
        if not found:
            raise PolicyError(f"{root}: no datasets to train on; run `m2m generate -w {ws.root} --task ...` first")
        return found
    out = []
    for name in cfg.datasets:
        p = root / name if (root / name / "meta" / "info.json").is_file() else root / task_slug(name)
        if not (p / "meta" / "info.json").is_file():
            have = sorted(q.parent.parent.name for q in root.glob("*/meta/info.json"))
            raise PolicyError(f"dataset {name!r}: no {p / 'meta' / 'info.json'}; datasets in {root}: "
                              f"{have or 'none'} (run `m2m generate -w {ws.root} --task {name!r}`)")  # fmt: skip
        out.append(p)
    return out


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    # info.json counts the episodes and frames; summary.json (ours) holds the generation's fingerprint
    files = []
    for d in dataset_dirs(ws, cfg):
        files.append(Input(d / "meta" / "info.json", made_by="generate"))
        if (d / "summary.json").is_file():
            files.append(Input(d / "summary.json", made_by="generate"))
    return files


def _check_robot(ws: Workspace, dirs: list[Path]) -> None:
    """Datasets of another robot than the world's are an error naming the dataset."""
    if not ws.committed.world_yaml.is_file():
        return
    from ..world import load_world

    spec = get_robot(load_world(ws.committed.world_yaml).robot.name)
    for d in dirs:
        meta, _ = dataset_meta(d)
        if tuple(meta.state_names) != tuple(spec.state_names) or tuple(meta.action_names) != tuple(spec.action_names):
            raise PolicyError(f"{d / 'meta' / 'info.json'}: a dataset of robot {meta.robot_type!r} "
                              f"({len(meta.state_names)} state / {len(meta.action_names)} action values), but this "
                              f"workspace's world has {spec.name!r} ({len(spec.state_names)} / {len(spec.action_names)}"
                              "); train on datasets generated in this world")  # fmt: skip


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    from ..policy import train_policy

    dirs = dataset_dirs(ws, cfg)
    _check_robot(ws, dirs)
    s = train_policy(dirs, ws.policy_dir(cfg.name), cfg.trainer(), log=log)
    val = s["loss"]["val"]
    line = (f"{s['episodes']['train']} training episodes ({s['frames']} frames) from {len(dirs)} dataset(s), "
            f"{s['steps']} steps in {s['seconds']['train'] / 60:.1f} min on {s['device']}; loss "
            f"{s['loss']['first']:.3f} -> {s['loss']['last']:.3f}" + (f", val {val:.3f}" if val is not None else ""))
    return {**s, "policy": str(ws.policy_dir(cfg.name)), "line": line}  # fmt: skip


def record_key(ws: Workspace, cfg: Config) -> str:
    return f"train_policy/{cfg.name}"


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    d = ws.policy_dir(cfg.name)
    return [d / POLICY_FILE, d / "summary.json"]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.policy_dir(cfg.name)]
