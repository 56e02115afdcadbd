"""``m2m bench train``: time-budgeted 3DGS training on a ``transforms.json`` data set (e.g. fox),
scored on held-out real frames (every 8th), plus a per-stage profile of one training step."""

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

from ..geometry.camera import load_transforms_json
from .budget import DENSIFY_FRACTION, budget_config
from .dataset import build_views
from .filter3d import FILTER_3D_VARIANCE
from .train import TrainConfig, View, init_gaussians_from_points, train, view_loss

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
    max_gaussians: int = 150_000,
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
    ended), init info and (``profile``) a step profile.
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
    g, metrics = train(views_train, views_eval, init, config, progress=progress)
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
    if profile:
        out["profile"] = profile_step(g, views_train, config)
    if tmp is not None:
        tmp.cleanup()
    return out


def profile_step(g, views: list[View], config: TrainConfig, repeats: int = 3) -> dict[str, float]:
    """Median milliseconds of the stages of one CPU training step on Gaussians ``g``, measured on the
    real code path (``view_loss`` with the cpu backend) by timing its parts in place: projection + SH
    forward and backward, raster forward and backward, the rest of the loss (L1 + SSIM) and of autograd,
    the densification statistics, Adam."""
    from .render import numba_cpu
    from .train import _make_optimizers, _make_strategy, _strategy_info, _to_gaussians, _to_params, scene_extent

    extent = scene_extent(views)
    params = _to_params(g, config.sh_degree, torch.device("cpu"))
    opts = _make_optimizers(params, config.lr, extent)
    strategy = _make_strategy(config)
    state = strategy.initialize_state(scene_scale=extent)
    spent = {"project": 0.0, "project_bwd": 0.0, "raster_fwd": 0.0, "raster_bwd": 0.0}

    def timed(fn, key):
        def wrapper(*args, **kwargs):
            t = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[key] += time.perf_counter() - t

        return wrapper

    originals = (numba_cpu.project, numba_cpu.RasterizeNumba.forward, numba_cpu.RasterizeNumba.backward,
                 numba_cpu.ProjectNumba.backward)  # fmt: skip
    numba_cpu.project = timed(originals[0], "project")
    numba_cpu.RasterizeNumba.forward = staticmethod(timed(originals[1], "raster_fwd"))
    numba_cpu.RasterizeNumba.backward = staticmethod(timed(originals[2], "raster_bwd"))
    numba_cpu.ProjectNumba.backward = staticmethod(timed(originals[3], "project_bwd"))
    rows: dict[str, list[float]] = {}
    try:
        for i in range(repeats + 1):
            v = views[i % len(views)]
            spent.update(project=0.0, project_bwd=0.0, raster_fwd=0.0, raster_bwd=0.0)
            info: dict = {}
            t0 = time.perf_counter()
            loss, _ = view_loss(_to_gaussians(params, config.sh_degree), v, config, info, backend="cpu")
            t1 = time.perf_counter()
            loss.backward()
            t2 = time.perf_counter()
            strategy.update(params, opts, state, _strategy_info(info, v, len(params["means"])), False, i)
            t3 = time.perf_counter()
            for o in opts.values():
                o.step()
                o.zero_grad(set_to_none=True)
            t4 = time.perf_counter()
            if i == 0:
                continue  # warm-up
            ms = {k: 1000.0 * val for k, val in spent.items()}
            row = {
                "projection_fwd_ms": ms["project"],
                "raster_fwd_ms": ms["raster_fwd"],
                "loss_fwd_ms": 1000.0 * (t1 - t0) - ms["project"] - ms["raster_fwd"],
                "backward_ms": 1000.0 * (t2 - t1),
                "raster_bwd_ms": ms["raster_bwd"],
                "projection_bwd_ms": ms["project_bwd"],
                "other_bwd_ms": 1000.0 * (t2 - t1) - ms["raster_bwd"] - ms["project_bwd"],
                "strategy_ms": 1000.0 * (t3 - t2),
                "optimizer_ms": 1000.0 * (t4 - t3),
                "total_ms": 1000.0 * (t4 - t0),
            }
            for k, val in row.items():
                rows.setdefault(k, []).append(float(val))
    finally:
        numba_cpu.project = originals[0]
        numba_cpu.RasterizeNumba.forward = staticmethod(originals[1])
        numba_cpu.RasterizeNumba.backward = staticmethod(originals[2])
        numba_cpu.ProjectNumba.backward = staticmethod(originals[3])
    res = {k: round(float(np.median(v)), 2) for k, v in rows.items()}
    res["gaussians"] = len(params["means"])
    res["threads"] = torch.get_num_threads()
    return res
