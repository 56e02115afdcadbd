"""Every stage in order over one workspace: ``m2m demo`` (the bundled sample) and, later, ``m2m run``.

:class:`PipelineConfig` composes the stages' Configs; it is what a workspace's ``m2m.yaml`` holds (each
stage's section lists only what differs from its Config's defaults, or everything). ``run_pipeline`` runs
the stages through :func:`~.base.run_stage`, so a killed run resumes: finished stages whose config and input
content are unchanged are skipped.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..atomic import atomic_write
from ..configs import ConfigError, from_dict, to_dict
from ..inputs import read_yaml
from ..workspace import Workspace
from . import (
    PIPELINE,
    align,
    capture,
    eval_policy,
    generate,
    handeye,
    head_view,
    objects,
    scene,
    sfm,
    train_policy,
    world,
)
from .base import Log, run_stage
from .transaction import workspace_lock

__all__ = ["PipelineConfig", "run_pipeline"]

_HEADER = "# Mirage2Matter pipeline settings: one section per stage (see `m2m <stage> --help` for each field).\n"


@dataclass
class PipelineConfig:
    """Every stage's settings (``m2m.yaml``).

    capture    keyframes from the video or image folder
    sfm        camera poses and points
    align      metric alignment to the robot base (the board)
    handeye    the head camera's mount (hand-eye calibration)
    scene      scene 3D Gaussian Splatting
    head_view  the scene through the calibrated head camera, against a head photo
    objects    object splats, meshes and collision parts
    world      the world and its twin
    generate      demonstrations per task
    train_policy  a policy trained on the datasets (run on its own: ``m2m train-policy``)
    eval_policy   a policy run in the twin (run on its own: ``m2m eval-policy``)
    """

    capture: capture.Config = field(default_factory=capture.Config)
    sfm: sfm.Config = field(default_factory=sfm.Config)
    align: align.Config = field(default_factory=align.Config)
    handeye: handeye.Config = field(default_factory=handeye.Config)
    scene: scene.Config = field(default_factory=scene.Config)
    head_view: head_view.Config = field(default_factory=head_view.Config)
    objects: objects.Config = field(default_factory=objects.Config)
    world: world.Config = field(default_factory=world.Config)
    generate: generate.Config = field(default_factory=generate.Config)
    train_policy: train_policy.Config = field(default_factory=train_policy.Config)
    eval_policy: eval_policy.Config = field(default_factory=eval_policy.Config)

    @classmethod
    def load(cls, path: str | Path) -> PipelineConfig:
        """Read an ``m2m.yaml`` (paths relative to its folder); ConfigError names the file and the field."""
        path = Path(path)
        data = read_yaml(path, "pipeline settings (m2m.yaml)")
        try:
            return from_dict(cls, data, base_dir=path.parent.resolve())
        except ConfigError as e:
            raise ConfigError(f"{path}: {e}") from None

    def save(self, path: str | Path) -> Path:
        """Write every setting (defaults filled in) atomically; paths relative to the file's folder."""
        import yaml

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        text = yaml.safe_dump(to_dict(self, base_dir=path.parent), sort_keys=False, width=120)
        with atomic_write(path, "w", encoding="utf-8") as f:
            f.write(_HEADER + text)
        return path

    def stage_config(self, name: str) -> Any:
        return getattr(self, name)


def run_pipeline(
    ws: Workspace,
    cfg: PipelineConfig,
    log: Log = print,
    until: str | None = None,
    start: str | None = None,
    ground_truth: dict | None = None,
) -> dict[str, Any]:
    """Run (or resume) the stages from ``start`` through ``until`` (names; default: all); returns
    {"stages": {name: summary}, "seconds": ...}. ``ground_truth``: a sample's, compared with where it can."""
    names = [s.name for s in PIPELINE]
    lo = names.index(start) if start else 0
    hi = names.index(until) + 1 if until else len(names)
    if lo >= hi:
        raise ConfigError(f"--from {start} comes after --until {until}")
    chosen = PIPELINE[lo:hi]
    with workspace_lock(ws):  # one writer for the whole run
        return _run(ws, cfg, chosen, log, ground_truth)


def _run(ws: Workspace, cfg: PipelineConfig, chosen, log: Log, ground_truth: dict | None) -> dict[str, Any]:
    t_start = time.perf_counter()
    summaries: dict[str, Any] = {}
    for i, stage in enumerate(chosen, 1):
        tag = f"[{i}/{len(chosen)}] {stage.name}"
        log(f"{tag} ...")
        t0 = time.perf_counter()
        summary, skipped = run_stage(stage, ws, cfg.stage_config(stage.name), log, ground_truth=ground_truth)
        summaries[stage.name] = summary
        if skipped:
            log(f"{tag}: done earlier - {summary['line']}")
        else:
            dt = time.perf_counter() - t0
            log(f"{tag}: {summary['line']}  [{dt:.0f} s, total {time.perf_counter() - t_start:.0f} s]")
    return {"workspace": str(ws.root.resolve()), "stages": summaries, "seconds": time.perf_counter() - t_start,
            "config": to_dict(cfg)}  # fmt: skip
