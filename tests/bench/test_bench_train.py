"""``m2m bench train`` times what the commands run: the Trainer's own step, through public names only."""

from __future__ import annotations

import ast
import inspect
import math
from pathlib import Path

import numpy as np
import torch

import mirage2matter.bench.train as bench_module
from mirage2matter.bench.train import bench_train, profile_step
from mirage2matter.gaussians.render import render
from mirage2matter.gaussians.synthetic import orbit_cameras, tabletop_scene
from mirage2matter.gaussians.train import TrainConfig, Trainer, View, init_gaussians_from_points
from mirage2matter.stages.scene import Config as SceneConfig


def test_bench_train_imports_nothing_private_and_patches_nothing():
    """No ``_name`` imported from the package's modules, and no attribute of anything assigned (a monkeypatched
    renderer would time another step than the command's)."""
    tree = ast.parse(Path(inspect.getfile(bench_module)).read_text())
    private, patched = [], []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("mirage2matter")):
            private += [f"{node.module}.{a.name}" for a in node.names if a.name.startswith("_")]
        targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
        if isinstance(node, ast.Assign | ast.AugAssign | ast.AnnAssign):
            patched += [ast.unparse(t) for t in targets if isinstance(t, ast.Attribute)]
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "setattr":
            patched.append(ast.unparse(node))
    assert not private, private
    assert not patched, patched


def test_bench_train_trains_with_the_scene_stages_defaults():
    default = inspect.signature(bench_train).parameters["max_gaussians"].default
    assert default == TrainConfig().max_gaussians == SceneConfig().max_gaussians


def test_profile_step_times_the_trainers_step():
    """The phases of Trainer.step() read by the profiler: the parts add up to their phase, and the phases to (about)
    the step."""
    w, h = 40, 30
    gt = tabletop_scene(1500, sh_degree=1, seed=0)
    views = []
    for vm, K in orbit_cameras(3, w, h, seed=0):
        vm_t, K_t = torch.tensor(vm, dtype=torch.float32), torch.tensor(K, dtype=torch.float32)
        with torch.no_grad():
            views.append(View(render(gt, vm_t, K_t, w, h, torch.zeros(3), backend="cpu").rgb.clamp(0, 1), vm_t, K_t))
    rng = np.random.default_rng(0)
    init = init_gaussians_from_points(gt.means[:300].numpy(), rng.uniform(0.3, 0.7, (300, 3)), sh_degree=1)
    trainer = Trainer(views, [], init, TrainConfig(iterations=10, sh_degree=1, backend="cpu", checkpoint_every=0))
    p = profile_step(trainer, repeats=2)
    assert trainer.iteration == 3 and p["gaussians"] == 300
    keys = ("projection_fwd_ms", "raster_fwd_ms", "loss_fwd_ms", "forward_ms", "backward_ms", "raster_bwd_ms",
            "projection_bwd_ms", "other_bwd_ms", "strategy_ms", "optimizer_ms", "total_ms")  # fmt: skip
    assert all(math.isfinite(p[k]) and p[k] >= 0 for k in keys), p
    assert p["projection_fwd_ms"] + p["raster_fwd_ms"] <= p["forward_ms"] + 1e-6
    assert p["forward_ms"] + p["backward_ms"] + p["optimizer_ms"] <= p["total_ms"] * 1.05, p
