"""The ``train-scene`` stage: scene 3DGS from the workspace's posed keyframes (DESIGN.md §3 stage 4).

Cameras and SfM points come from :meth:`Workspace.posed_capture` (robot-base frame after
``align-scene``), so the trained Gaussians live in the frame the simulator uses. Outputs in
``<ws>/scene/``: ``gaussians.ply``, ``metrics.json`` (held-out PSNR / SSIM, curve, timings),
``heldout.png`` (held-out keyframes: photo above render), ``checkpoint.pt`` + ``plan.json`` for
resuming. Same inputs and config as a finished run: skipped. Interrupted: resumed from the last
checkpoint (``plan.json`` pins the planned schedule so the resumed run is the same run).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import atomic_write
from .workspace import Workspace, WorkspaceError, fingerprint

__all__ = ["SceneConfig", "train_scene"]


@dataclass
class SceneConfig:
    """train-scene settings.

    minutes         training-time budget; the iteration count is planned from a measured step
    iterations      fixed iteration count instead of a budget (0: use ``minutes``)
    downscale       train and evaluate at 1/downscale resolution (area filter)
    holdout_every   every n-th keyframe (sorted by name) is held out for evaluation
    max_gaussians   cap on densification
    sh_degree       final SH degree (raised during training)
    backend         "auto" (cuda with gsplat, else the numba cpu rasterizer), "cpu", "cuda"
    """

    minutes: float = 10.0
    iterations: int = 0
    downscale: int = 2
    holdout_every: int = 8
    max_gaussians: int = 200_000
    sh_degree: int = 3
    backend: str = "auto"
    seed: int = 0
    checkpoint_every: int = 200

    def validate(self) -> None:
        if self.iterations < 0 or (self.iterations == 0 and not self.minutes > 0):
            raise ValueError("train-scene: give a positive --minutes budget or --iterations")
        if self.downscale < 1 or self.holdout_every < 0 or self.max_gaussians < 1000:
            raise ValueError(
                f"train-scene: downscale >= 1, holdout_every >= 0 and max_gaussians >= 1000, got {self.downscale}, "
                f"{self.holdout_every}, {self.max_gaussians}"
            )
        if not 0 <= self.sh_degree <= 3:
            raise ValueError(f"train-scene: sh_degree must be 0..3, got {self.sh_degree}")


def _heldout_sheet(g, views, config, backend: str, max_views: int = 4) -> np.ndarray:
    """Held-out photos (top row) above their renders (bottom row), uint8."""
    import torch

    from .gaussians.render import render

    tops, bottoms = [], []
    bg = torch.tensor(config.background, dtype=torch.float32)
    for v in views[:max_views]:
        with torch.no_grad():
            rgb = render(g, v.viewmat, v.K, v.width, v.height, bg, backend).rgb.clamp(0, 1)
        tops.append(v.image.numpy())
        bottoms.append(rgb.cpu().numpy())
    grid = np.concatenate([np.concatenate(tops, axis=1), np.concatenate(bottoms, axis=1)], axis=0)
    return (grid * 255 + 0.5).astype(np.uint8)


def train_scene(ws: Workspace | str | Path, config: SceneConfig | None = None, force: bool = False,
                progress: bool = True, log=print) -> dict[str, Any]:  # fmt: skip
    """Train the scene Gaussians of workspace ``ws``; returns the metrics written to
    ``scene/metrics.json`` (``skipped: True`` when an identical finished run is already there)."""
    from PIL import Image

    from .gaussians.budget import budgeted_config, estimate_step_seconds
    from .gaussians.dataset import build_views
    from .gaussians.ply import write_ply
    from .gaussians.render import resolve_backend
    from .gaussians.train import TrainConfig, init_gaussians_from_points, train

    ws = ws if isinstance(ws, Workspace) else Workspace(ws)
    config = config or SceneConfig()
    config.validate()
    posed = ws.posed_capture()
    if len(posed.points) < 100:
        raise WorkspaceError(f"{ws.sfm}: only {len(posed.points)} SfM points; rerun sfm with more keyframes / texture")
    key = fingerprint(
        asdict(config),
        ws.sfm / "sfm.json",
        ws.calib / "sim3_sfm_to_base.json",
        [c.name for c in posed.cameras],
    )
    out = ws.scene
    metrics_path = out / "metrics.json"
    if not force and metrics_path.is_file():
        old = json.loads(metrics_path.read_text())
        if old.get("fingerprint") == key and (out / "gaussians.ply").is_file():
            log(f"scene: up to date ({metrics_path}); pass --force to retrain")
            return {**old, "skipped": True}
    out.mkdir(parents=True, exist_ok=True)
    backend = resolve_backend(config.backend)

    t0 = time.perf_counter()
    views_train, views_eval = build_views(posed.cameras, posed.image_dir, config.downscale, config.holdout_every)
    init = init_gaussians_from_points(posed.points, posed.colors.astype(np.float64) / 255.0, config.sh_degree)
    base = TrainConfig(
        sh_degree=config.sh_degree, max_gaussians=config.max_gaussians, backend=backend, seed=config.seed,
        checkpoint_every=config.checkpoint_every,
    )  # fmt: skip

    # The plan (iterations and schedules) is made once per input fingerprint and pinned, so a resumed
    # run continues the same schedule instead of re-planning from a different step time.
    plan_path, ckpt = out / "plan.json", out / "checkpoint.pt"
    plan = json.loads(plan_path.read_text()) if plan_path.is_file() else {}
    resume = plan.get("fingerprint") == key and ckpt.is_file()
    if plan.get("fingerprint") == key:
        train_cfg = TrainConfig(**{f.name: plan["train_config"][f.name] for f in fields(TrainConfig)})
        train_cfg.background = tuple(train_cfg.background)
    else:
        if config.iterations:
            from dataclasses import replace

            train_cfg = replace(base, iterations=config.iterations, eval_every=max(1, config.iterations // 10))
        else:
            step_s = estimate_step_seconds(init, views_train, base)
            train_cfg = budgeted_config(step_s, config.minutes, base)
        ckpt.unlink(missing_ok=True)
        with atomic_write(plan_path, "w", encoding="utf-8") as f:
            json.dump({"fingerprint": key, "train_config": asdict(train_cfg)}, f, indent=1)
    if resume:
        log(f"scene: resuming from {ckpt}")
    log(
        f"scene: {len(views_train)} training + {len(views_eval)} held-out keyframes at "
        f"{views_train[0].width}x{views_train[0].height}, {len(init):,} initial Gaussians from SfM points, "
        f"{posed.frame} frame, {train_cfg.iterations} iterations planned ({backend})"
    )
    g, metrics = train(views_train, views_eval, init, train_cfg, progress=progress, checkpoint_path=ckpt,
                       resume=resume)  # fmt: skip

    write_ply(out / "gaussians.ply", g)
    if views_eval:
        sheet = _heldout_sheet(g, views_eval, train_cfg, backend)
        with atomic_write(out / "heldout.png", "wb") as f:
            Image.fromarray(sheet).save(f, format="PNG")
    result = {
        "fingerprint": key,
        "frame": posed.frame,
        "psnr_heldout": metrics["psnr"],
        "ssim_heldout": metrics["ssim"],
        "initial": metrics["initial"],
        "iterations": metrics["iterations"],
        "gaussians": metrics["gaussians"],
        "train_minutes": metrics["seconds"] / 60.0,
        "wall_minutes": (time.perf_counter() - t0) / 60.0,
        "backend": metrics["backend"],
        "views": {"train": len(views_train), "heldout": len(views_eval)},
        "image_size": [views_train[0].width, views_train[0].height],
        "per_view": metrics["views"],
        "curve": metrics["curve"],
        "config": asdict(config),
    }
    with atomic_write(metrics_path, "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1)
    ckpt.unlink(missing_ok=True)  # finished: the PLY and metrics are the result (checkpoints are ~3x the PLY)
    return result
