"""Mip-Splatting's 3D filter: what it does to one Gaussian, the sampling rates it is sized by, and a model trained
with it (no Gaussian thinner than a training pixel; the scene seen closer than it was trained holds up)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from mirage2matter.gaussians.filter3d import apply_3d_filter, max_sampling_rate
from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.render import render
from mirage2matter.gaussians.synthetic import orbit_cameras, tabletop_scene
from mirage2matter.gaussians.train import TrainConfig, View, init_gaussians_from_points, train


def _gaussians(scales, logits) -> Gaussians:
    n = len(scales)
    return Gaussians(torch.zeros(n, 3), torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n),
                     torch.log(torch.tensor(scales, dtype=torch.float32)).requires_grad_(True),
                     torch.tensor(logits, dtype=torch.float32).requires_grad_(True), torch.zeros(n, 1, 3))  # fmt: skip


def test_the_filter_widens_each_gaussian_by_its_pixel_and_keeps_its_integral():
    g = _gaussians([[0.01, 0.02, 1e-4], [0.05, 0.05, 0.05], [1e-4, 1e-4, 1e-4]], [2.0, -1.0, 0.0])
    nu = torch.tensor([100.0, 100.0, 0.0])  # pixels per metre; 0: no view saw it
    f = apply_3d_filter(g, nu, 0.2)
    var_before, var_after = torch.exp(2 * g.log_scales), torch.exp(2 * f.log_scales)
    assert torch.allclose(var_after[:2] - var_before[:2], torch.full((2, 3), 0.2 / 100.0**2), rtol=1e-4)
    o, o_f = torch.sigmoid(g.logit_opacities).detach(), torch.sigmoid(f.logit_opacities).detach()
    integral = o * torch.exp(g.log_scales).prod(1)
    assert torch.allclose(o_f * torch.exp(f.log_scales).prod(1), integral, rtol=1e-4)
    assert float(o_f[0]) < 0.05 * float(o[0])  # a flat Gaussian (0.1 mm thick) fades as it widens
    assert float(o_f[1]) == pytest.approx(float(o[1]), rel=0.02)  # a 5 cm one barely changes (-1.2 %)
    assert torch.equal(f.log_scales[2], g.log_scales[2]) and float(f.logit_opacities[2].detach()) == pytest.approx(0.0)
    (f.log_scales.sum() + f.logit_opacities.sum()).backward()
    assert torch.isfinite(g.log_scales.grad).all() and torch.isfinite(g.logit_opacities.grad).all()
    with pytest.raises(ValueError, match="recompute"):
        apply_3d_filter(g, nu[:2])


class _Cam:
    def __init__(self, z_cam: float, f: float = 100.0, w: int = 64, h: int = 48):
        self.viewmat = torch.eye(4)
        self.viewmat[2, 3] = z_cam  # camera looking down +z from z = -z_cam
        self.K = torch.tensor([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])
        self.width, self.height = w, h


def test_the_sampling_rate_is_the_finest_of_the_views_that_hold_the_point():
    near, far = _Cam(1.0), _Cam(4.0)
    means = torch.tensor([[0.0, 0.0, 0.0],  # both see it: the near one's 100 / 1
                          [1.2, 0.0, 0.0],  # u = 152 px in the near view (outside +15 %), 32 + 24 in the far one
                          [0.0, 0.0, -5.0]])  # behind both: the coarsest rate of those seen  # fmt: skip
    nu = max_sampling_rate(means, [far, near])
    assert nu.tolist() == pytest.approx([100.0, 25.0, 25.0])
    assert max_sampling_rate(torch.tensor([[0.0, 0.0, -5.0]]), [near]).tolist() == [0.0]


def test_a_model_trained_with_the_filter_has_no_gaussian_thinner_than_its_pixel():
    """Training with the filter returns the filtered Gaussians (any renderer draws them as trained): each is at
    least as wide as its filter on every axis, and the training still fits the photos."""
    gt = tabletop_scene(3000, sh_degree=1, seed=0)
    views = []
    for vm, K in orbit_cameras(12, 48, 36, seed=0):
        vm_t, K_t = torch.tensor(vm, dtype=torch.float32), torch.tensor(K, dtype=torch.float32)
        with torch.no_grad():
            img = render(gt, vm_t, K_t, 48, 36, torch.zeros(3), backend="cpu").rgb.clamp(0, 1)
        views.append(View(img, vm_t, K_t))
    rng = np.random.default_rng(0)
    pts = gt.means[rng.choice(len(gt), 800, replace=False)].numpy() + rng.normal(0.0, 0.02, (800, 3))
    init = init_gaussians_from_points(pts, rng.uniform(0.3, 0.7, (800, 3)), sh_degree=1)
    cfg = TrainConfig(iterations=300, sh_degree=1, eval_points=0, checkpoint_every=0, max_gaussians=3000,
                      backend="cpu", seed=0, filter_3d=0.2)  # fmt: skip
    g, m = train(views, views[:2], init, cfg, progress=False)
    print("filtered training", round(m["initial"]["psnr"], 2), "->", round(m["psnr"], 2), "dB")  # 26.8 (25.8 without)
    assert m["psnr"] >= m["initial"]["psnr"] + 5.0 and m["psnr"] >= 21.0
    thinnest = torch.exp(g.log_scales).min(dim=1).values
    width = math.sqrt(0.2) / max_sampling_rate(g.means, views)  # the filter as of the last refresh: means moved a bit
    assert bool((thinnest >= 0.9 * width).all())
    plain = TrainConfig(iterations=300, sh_degree=1, eval_points=0, checkpoint_every=0, max_gaussians=3000,
                        backend="cpu", seed=0)  # fmt: skip
    g0, _ = train(views, views[:2], init, plain, progress=False)
    assert float((torch.exp(g0.log_scales).min(dim=1).values < 0.5 * width.mean()).float().mean()) > 0.05
    with pytest.raises(ValueError, match="filter_3d"):
        train(views, views[:2], init, TrainConfig(iterations=1, filter_3d=-1.0), progress=False)


def test_a_bad_filter_variance_is_a_clear_error_before_any_work(tmp_path, capsys):
    from mirage2matter.cli import main
    from mirage2matter.stages.scene import Config as SceneConfig
    from mirage2matter.workspace import WorkspaceError

    with pytest.raises(WorkspaceError, match=r"train-scene: filter_3d is a variance in squared pixels in \[0, 4\]"):
        SceneConfig(filter_3d=5.0).validate()
    SceneConfig(filter_3d=0.0).validate()
    for bad in ("-1", "nan", "abc"):  # before any SfM or training: the data folder does not even exist
        assert main(["bench", "train", "--data", str(tmp_path / "none"), "--filter-3d", bad]) == 2
        assert "--filter-3d" in capsys.readouterr().err
