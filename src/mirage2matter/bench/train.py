"""``m2m bench train``: time-budgeted 3DGS training on a ``transforms.json`` data set (e.g. fox),
scored on held-out real frames (every 8th), plus a per-phase profile of the run's own ``Trainer.step()``."""

from __future__ import annotations

import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..gaussians.budget import DENSIFY_FRACTION, budget_config
from ..gaussians.dataset import build_views
from ..gaussians.filter3d import FILTER_3D_VARIANCE
from ..gaussians.train import TrainConfig, Trainer, init_gaussians_from_points, train
from ..geometry.camera import load_transforms_json

__all__ = ["bench_train", "profile_step"]


def _sfm_points_cached(cams, image_dir: Path, work_dir: Path, poses: str) -> tuple[np.ndarray, np.ndarray, dict, list]:
    """Points once per work dir: (points, colors uint8, info, cameras). For ``poses == "given"`` the
    points are triangulated with the given poses (no SfM) and ``cameras`` are the given ones; for
    ``"sfm"`` our SfM's cameras (with their own distortion) and points are used as they are."""
    from ..sfm.colmap import SfMConfig, run_sfm
    from ..sfm.known_poses import triangulate_known_poses

    if poses == "given":
        cache = work_dir / "points_given.npz"
        if cache.is_file():
            z = np.load(cache, allow_pickle=False)
            return z["points"], z["colors"], json.loads(str(z["info"])), cams
        # the images sit in one folder (image_dir); triangulate under their basenames there
        named = [replace(c, name=Path(c.name).name) for c in cams]
        tri = triangulate_known_poses(named, image_dir, work_dir / "sfm_known", SfMConfig(downscale=0.5))
        info = {"registered": tri.registered, "total": tri.total, "sfm_seconds": tri.seconds,
                "mean_reprojection_error": tri.mean_reprojection_error}  # fmt: skip
        np.savez(cache, points=tri.points, colors=tri.colors, info=json.dumps(info))
        return tri.points, tri.colors, info, cams
    sfm = run_sfm(image_dir, work_dir / "sfm_own", SfMConfig(downscale=0.5))
    info = {"registered": sfm.registered, "total": sfm.total, "sfm_seconds": sfm.seconds}
    return sfm.points, sfm.colors, info, sfm.cameras


def bench_train(
    data_dir: str | os.PathLike[str],
    minutes: float = 15.0,
    downscale: int = 4,
    poses: str = "given",
    work_dir: str | os.PathLike[str] | None = None,
    max_gaussians: int = TrainConfig.max_gaussians,  # the scene stage's
    densify_fraction: float = DENSIFY_FRACTION,
    backend: str = "auto",
    progress: bool = False,
    curve_points: int = 12,
    profile: bool = True,
    filter_3d: float = FILTER_3D_VARIANCE,
) -> dict[str, Any]:
    """Train on ``data_dir`` (``transforms.json`` + images) for ``minutes`` of training time at
    1/``downscale`` resolution and score the held-out views (every 8th, sorted by name).

    poses: ``"given"`` (transforms.json poses; initial points from our SfM mapped into that frame)
    or ``"sfm"`` (our SfM cameras and points, evaluated in the SfM frame).
    The training is ``budget_config``'s, the one ``m2m train-scene --minutes`` runs: it trains until the
    minutes are spent, densifying for the first ``densify_fraction`` of them. Returns psnr_heldout,
    ssim_heldout, iterations, gaussians, minutes, backend, curve, seconds_per_step, schedule (where it
    ended), init info and (``profile``) :func:`profile_step` of the run's :class:`Trainer` at its end.
    """
    if poses not in ("given", "sfm"):
        raise ValueError(f"poses must be 'given' or 'sfm', got {poses!r}")
    data_dir = Path(data_dir)
    tfile = data_dir / "transforms.json"
    if not tfile.is_file():
        raise FileNotFoundError(f"{tfile}: not found; bench train needs a transforms.json data set")
    cams = load_transforms_json(tfile)
    image_dir = (data_dir / cams[0].name).parent
    tmp = None
    if work_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="m2m-bench-train-")
        work_dir = tmp.name
    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    points, colors, init_info, cams_used = _sfm_points_cached(cams, image_dir, work_dir, poses)
    t_points = time.perf_counter() - t0
    views_train, views_eval = build_views(cams_used, image_dir, downscale)
    init = init_gaussians_from_points(points, np.asarray(colors, np.float64) / 255.0, sh_degree=3)

    config = TrainConfig(backend=backend, max_gaussians=max_gaussians, checkpoint_every=0, filter_3d=filter_3d)
    config = budget_config(minutes, config, densify_fraction=densify_fraction, curve_points=curve_points)
    # profiled: the run's last state (its final checkpoint), stepped on as the run stepped
    ckpt = work_dir / "checkpoint.pt" if profile else None
    _, metrics = train(views_train, views_eval, init, config, progress=progress, checkpoint_path=ckpt)
    out: dict[str, Any] = {
        "psnr_heldout": metrics["psnr"],
        "ssim_heldout": metrics["ssim"],
        "iterations": metrics["iterations"],
        "gaussians": metrics["gaussians"],
        "minutes": metrics["seconds"] / 60.0,
        "backend": metrics["backend"],
        "poses": poses,
        "downscale": downscale,
        "views": {"train": len(views_train), "heldout": len(views_eval)},
        "image_size": [views_train[0].width, views_train[0].height],
        "init": {"points": len(points), "seconds": t_points, **init_info},
        "seconds_per_step": metrics["seconds"] / max(metrics["iterations"], 1),
        "budget_used": metrics["seconds"] / config.max_seconds,
        "schedule": metrics["schedule"],
        "curve": metrics["curve"],
    }
    if ckpt is not None:
        trainer = Trainer(views_train, [], init, config)
        trainer.resume(ckpt)
        ckpt.unlink()
        out["profile"] = profile_step(trainer)
    if tmp is not None:
        tmp.cleanup()
    return out


def profile_step(trainer: Trainer, repeats: int = 3) -> dict[str, float]:
    """Median milliseconds of the phases of ``trainer``'s next steps (one warm-up step, then ``repeats``), read by
    ``torch.profiler`` from the labels :meth:`Trainer.step` puts on them: the forward pass (on the CPU backend
    projection and rasterisation apart, the rest is the loss), the backward pass (likewise), the densification
    statistics, Adam, and the whole step by the trainer's own clock. On CUDA the phases are launch times (the
    kernels run asynchronously); the whole step is not."""
    from torch.profiler import ProfilerActivity, profile

    trainer.step()  # warm-up
    seconds = []
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(repeats):
            seconds.append(trainer.step()["seconds"])
    spans: dict[str, list[float]] = {}  # event name -> its milliseconds in each step, in order
    for e in prof.events():
        if e.name in _PHASES:
            spans.setdefault(_PHASES[e.name], []).append(e.cpu_time_total / 1000.0)
    rows: dict[str, list[float]] = {k: v for k, v in spans.items() if len(v) == repeats}
    numba = all(k in rows for k in ("projection_fwd_ms", "raster_fwd_ms", "projection_bwd_ms", "raster_bwd_ms"))
    if numba:
        rows["loss_fwd_ms"] = [f - p - r for f, p, r in zip(rows["forward_ms"], rows["projection_fwd_ms"],
                                                                rows["raster_fwd_ms"], strict=True)]  # fmt: skip
        rows["other_bwd_ms"] = [b - p - r for b, p, r in zip(rows["backward_ms"], rows["projection_bwd_ms"],
                                                                 rows["raster_bwd_ms"], strict=True)]  # fmt: skip
    rows["total_ms"] = [1000.0 * s for s in seconds]
    res: dict[str, Any] = {k: round(float(np.median(v)), 2) for k, v in rows.items()}
    res["gaussians"] = len(trainer.params["means"])
    res["threads"] = torch.get_num_threads()
    return res


# the events profile_step reads: Trainer.step's phases and the CPU backend's autograd functions
_PHASES = {
    "trainer.forward": "forward_ms",
    "trainer.backward": "backward_ms",
    "trainer.densify": "strategy_ms",
    "trainer.adam": "optimizer_ms",
    "ProjectNumba": "projection_fwd_ms",
    "RasterizeNumba": "raster_fwd_ms",
    "ProjectNumbaBackward": "projection_bwd_ms",
    "RasterizeNumbaBackward": "raster_bwd_ms",
}
