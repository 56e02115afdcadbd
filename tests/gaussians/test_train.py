"""Losses against independent implementations, and 3DGS training end to end on a tiny synthetic scene."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from mirage2matter.gaussians.losses import l1, psnr, ssim
from mirage2matter.gaussians.render import render
from mirage2matter.gaussians.synthetic import orbit_cameras, tabletop_scene
from mirage2matter.gaussians.train import (
    TrainConfig,
    Trainer,
    View,
    downsample_view,
    init_gaussians_from_points,
    train,
    view_loss,
)

W, H = 64, 48


def _smooth_pair(seed: int, h: int = 40, w: int = 52) -> tuple[np.ndarray, np.ndarray]:
    """Two correlated images [h,w,3] in [0,1] with structure at several scales."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / 8.0
    base = 0.5 + 0.3 * np.sin(xx[..., None] + np.arange(3)) * np.cos(yy[..., None] * 0.7)
    a = np.clip(base + 0.1 * rng.random((h, w, 3)), 0, 1)
    b = np.clip(0.9 * a + 0.05 + 0.08 * rng.normal(size=a.shape), 0, 1)
    return a, b


# ---- losses ------------------------------------------------------------------------------------
def test_ssim_matches_skimage():
    metrics = pytest.importorskip("skimage.metrics")
    for seed in range(3):
        a, b = _smooth_pair(seed)
        ref = metrics.structural_similarity(
            a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=-1
        )
        ours = ssim(torch.from_numpy(a), torch.from_numpy(b))
        assert abs(float(ours) - ref) < 1e-4
        ours32 = ssim(torch.from_numpy(a).float(), torch.from_numpy(b).float())
        assert abs(float(ours32) - ref) < 1e-4
    assert float(ssim(torch.from_numpy(a), torch.from_numpy(a))) == pytest.approx(1.0, abs=1e-6)


def test_ssim_batch_layout_and_gradient():
    a, b = (torch.from_numpy(x).float() for x in _smooth_pair(0))
    batch = torch.stack([a, b]).permute(0, 3, 1, 2)
    mean_two = (ssim(a, b) + ssim(b, b)) / 2
    assert float(ssim(batch, torch.stack([b, b]).permute(0, 3, 1, 2))) == pytest.approx(float(mean_two), abs=1e-6)
    x = a.clone().requires_grad_()
    (1 - ssim(x, b)).backward()
    assert x.grad is not None and torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0


@pytest.mark.parametrize("masked", [False, True])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_cpu_ssim_matches_the_torch_formulation(masked, dtype):
    """The CPU SSIM (numba forward, closed-form backward) against the torch formulation differentiated by
    autograd: the same value and gradient, with and without a mask, for one image and a batch."""
    from mirage2matter.gaussians.losses import _as_batch, _mask_batch, _ssim_torch

    a, b = (torch.from_numpy(x).to(dtype) for x in _smooth_pair(3, h=37, w=45))
    mask = torch.ones(a.shape[:2], dtype=torch.bool)
    mask[:, 30:] = False
    mask[4:9, 3:12] = False
    m = mask if masked else None
    batch = (torch.stack([a, b]).permute(0, 3, 1, 2), torch.stack([b, a]).permute(0, 3, 1, 2),
             None if m is None else torch.stack([m, ~m]))  # fmt: skip
    for x_val, y_val, mm in ((a, b, m), batch):
        x1, x2 = x_val.clone().requires_grad_(), x_val.clone().requires_grad_()
        fast = ssim(x1, y_val, mask=mm)
        bx = _as_batch(x2)
        ref = _ssim_torch(bx, _as_batch(y_val), _mask_batch(mm, bx), 11, 1.5)
        assert fast.dtype == dtype and float(fast) == pytest.approx(float(ref), abs=1e-6)
        (2 * fast).backward()
        (2 * ref).backward()
        assert float((x1.grad - x2.grad).norm() / x2.grad.norm()) <= 1e-5


def test_l1_psnr_with_mask_match_numpy():
    a, b = _smooth_pair(1)
    mask = np.zeros(a.shape[:2], bool)
    mask[5:30, 7:45] = True
    ta, tb, tm = torch.from_numpy(a), torch.from_numpy(b), torch.from_numpy(mask)
    assert float(l1(ta, tb)) == pytest.approx(np.abs(a - b).mean(), rel=1e-9)
    assert float(l1(ta, tb, tm)) == pytest.approx(np.abs(a - b)[mask].mean(), rel=1e-9)
    assert float(psnr(ta, tb)) == pytest.approx(-10 * math.log10(((a - b) ** 2).mean()), rel=1e-9)
    assert float(psnr(ta, tb, tm)) == pytest.approx(-10 * math.log10(((a - b) ** 2)[mask].mean()), rel=1e-9)


def test_masked_ssim_ignores_pixels_outside_the_mask():
    a, b = (torch.from_numpy(x).float() for x in _smooth_pair(2))
    mask = torch.ones(a.shape[:2], dtype=torch.bool)
    mask[:, 30:] = False
    garbage = b.clone()
    garbage[:, 30:] = torch.rand_like(garbage[:, 30:])
    x = a.clone().requires_grad_()
    s = ssim(x, b, mask=mask)
    s.backward()
    assert float(ssim(a, garbage, mask=mask)) == float(s.detach())
    assert float(x.grad[:, 30:].abs().max()) == 0.0


# ---- training ----------------------------------------------------------------------------------
def _photos(n_views: int = 12) -> list[View]:
    """Ground-truth photos of a small tabletop scene rendered with the cpu backend."""
    gt = tabletop_scene(3000, sh_degree=1, seed=0)
    views = []
    for i, (vm, K) in enumerate(orbit_cameras(n_views, W, H, seed=0)):
        vm_t, K_t = torch.tensor(vm, dtype=torch.float32), torch.tensor(K, dtype=torch.float32)
        with torch.no_grad():
            img = render(gt, vm_t, K_t, W, H, torch.zeros(3), backend="cpu").rgb.clamp(0, 1)
        views.append(View(img, vm_t, K_t, name=f"view{i:02d}"))
    return views


def _init(n: int = 1000, seed: int = 0):
    """Points near the true surfaces (noisy subset of the ground-truth means) with grey colours."""
    gt = tabletop_scene(3000, sh_degree=1, seed=0)
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(gt), n, replace=False)
    pts = gt.means[idx].numpy() + rng.normal(0.0, 0.02, (n, 3))
    return init_gaussians_from_points(pts, rng.uniform(0.3, 0.7, (n, 3)), sh_degree=1)


def _config(**kw) -> TrainConfig:
    base = dict(
        iterations=240,
        sh_degree=1,
        sh_increase_every=100 / 240,
        eval_points=4,
        checkpoint_every=100,
        max_gaussians=3000,
        backend="cpu",
        seed=0,
    )
    base.update(kw)
    return TrainConfig(**base)


class _Interrupt(Exception):
    pass


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """One training run interrupted at step 130 (after the checkpoint at 100), then resumed."""
    views = _photos()
    held_out = [v for i, v in enumerate(views) if i % 8 == 0]
    train_views = [v for i, v in enumerate(views) if i % 8 != 0]
    ckpt = tmp_path_factory.mktemp("train") / "ckpt.pt"
    config = _config()
    losses: dict[int, float] = {}

    def stop_at_130(step, stats):
        losses[step] = stats["loss"]
        if step == 130:
            raise _Interrupt

    init = _init()
    with pytest.raises(_Interrupt):
        train(train_views, held_out, init, config, callback=stop_at_130, progress=False, checkpoint_path=ckpt)
    first = dict(losses)
    losses.clear()
    resumed: list[int] = []

    def log(step, stats):
        resumed.append(step)
        losses[step] = stats["loss"]

    g, metrics = train(
        train_views, held_out, init, config, callback=log, progress=True, checkpoint_path=ckpt, resume=True
    )
    return {"g": g, "metrics": metrics, "first": first, "second": dict(losses), "steps": resumed, "init": init}


def test_training_raises_held_out_psnr(trained):
    m = trained["metrics"]
    print("curve", [(c["step"], round(c["psnr"], 2), c["gaussians"]) for c in m["curve"]])
    assert m["iterations"] == 240
    assert m["psnr"] >= m["initial"]["psnr"] + 5.0  # observed 15.5 -> 23.2 dB
    assert m["psnr"] >= 21.0
    assert m["ssim"] > m["initial"]["ssim"]
    assert all(math.isfinite(c["psnr"]) for c in m["curve"])
    assert len(m["views"]) == 2


def test_densification_changes_count_within_cap(trained):
    n0, n = len(trained["init"]), len(trained["g"])
    assert n != n0
    assert n <= 3000
    assert max(c["gaussians"] for c in trained["metrics"]["curve"]) <= 3000
    trained["g"].check_finite("trained")


def test_resume_continues_from_checkpoint(trained):
    steps = trained["steps"]
    assert steps[0] == 101 and steps[-1] == 240  # resumed after the checkpoint at step 100
    first, second = trained["first"], trained["second"]
    before = np.mean([first[s] for s in range(81, 101)])
    just_after = np.mean([second[s] for s in range(101, 121)])
    end = np.mean([second[s] for s in range(221, 241)])
    assert just_after < 1.15 * before  # picks up where it was, not from scratch
    assert end < before
    curve_steps = [c["step"] for c in trained["metrics"]["curve"]]
    assert curve_steps == [0, 60, 120, 180, 240]


def test_a_resumed_trainer_steps_as_the_uninterrupted_one(tmp_path):
    """A Trainer stepped N times and checkpointed, a new Trainer resumed from the checkpoint and stepped M times:
    the same losses, Gaussians, Adam moments, densification statistics and schedule as one Trainer stepped N + M
    times. Densification, the 3D filter (its rates last refreshed before the checkpoint), coarse views and an
    opacity reset are on; the checkpoint falls between two refinements."""
    views = _photos(4)
    cfg = _config(iterations=40, refine_every=6, refine_start=0.1, refine_stop=0.8, coarse_fraction=0.3,
                  filter_3d=0.2, opacity_reset_every=0.5, eval_points=0)  # fmt: skip
    n, m = 17, 23
    whole = Trainer(views, views[:1], _init(400), cfg)
    expected = [whole.step()["loss"] for _ in range(n + m)]

    first = Trainer(views, views[:1], _init(400), cfg)
    losses = [first.step()["loss"] for _ in range(n)]
    first.save_checkpoint(tmp_path / "ckpt.pt")
    resumed = Trainer(views, views[:1], _init(400, seed=1), cfg)  # its own start is replaced by the checkpoint's
    assert resumed.resume(tmp_path / "ckpt.pt") and resumed.iteration == n
    assert not Trainer(views, [], _init(400), cfg).resume(tmp_path / "none.pt")
    losses += [resumed.step()["loss"] for _ in range(m)]

    assert losses == expected
    assert resumed.finished and whole.finished and resumed.iteration == n + m
    assert len(whole.schedule.refinements) >= 4 and resumed.schedule.refinements == whole.schedule.refinements
    assert resumed.params.keys() == whole.params.keys()
    for k in whole.params:
        assert torch.equal(resumed.params[k], whole.params[k]), k
        a, b = whole.optimizers[k].state_dict()["state"][0], resumed.optimizers[k].state_dict()["state"][0]
        assert all(torch.equal(a[s], b[s]) for s in ("exp_avg", "exp_avg_sq", "step")), k
    for k, v in whole.strategy_state.items():
        assert torch.equal(v, resumed.strategy_state[k]) if torch.is_tensor(v) else v == resumed.strategy_state[k], k
    assert torch.equal(whole.gaussians().means, resumed.gaussians().means)


def test_masked_pixels_do_not_influence_gradients():
    views = _photos(2)
    v = views[1]
    mask = torch.ones(H, W, dtype=torch.bool)
    mask[10:30, 20:50] = False
    blank, junk = v.image.clone(), v.image.clone()
    blank[~mask] = 0.0
    junk[~mask] = torch.rand(int((~mask).sum()), 3)
    config = _config(densify=False)
    grads = []
    for img in (blank, junk, v.image):
        g = _init(300).map(lambda t: t.clone().requires_grad_())
        loss, _ = view_loss(g, View(img, v.viewmat, v.K, mask if img is not v.image else None), config)
        loss.backward()
        grads.append(torch.cat([t.grad.flatten() for t in g.tensors().values()]))
    torch.testing.assert_close(grads[0], grads[1], rtol=1e-5, atol=1e-8)
    assert not torch.allclose(grads[0], grads[2], rtol=1e-3, atol=1e-6)  # the mask does something

    # and a few training steps (densification on) end in the same Gaussians
    finals = []
    for img in (blank, junk):
        view = View(img, v.viewmat, v.K, mask)
        cfg = _config(iterations=12, refine_every=5, refine_start=4 / 12)
        g, _ = train([view], [view], _init(300), cfg, progress=False)
        finals.append(g)
    assert len(finals[0]) == len(finals[1])
    for a, b in zip(finals[0].tensors().values(), finals[1].tensors().values(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_densification_statistics_match_gsplat():
    """The strategy's gradient statistics (our one-camera update) equal gsplat's own _update_state."""
    from gsplat.strategy import DefaultStrategy

    from mirage2matter.gaussians.train import _make_strategy, _strategy_info, _to_gaussians, _to_params, scene_extent

    views = _photos(3)
    params = _to_params(_init(500), 1, torch.device("cpu"))
    ours, theirs = _make_strategy(_config()), DefaultStrategy()
    states = [s.initialize_state(scene_scale=scene_extent(views)) for s in (ours, theirs)]
    for v in views:
        info: dict = {}
        loss, _ = view_loss(_to_gaussians(params, 1), v, _config(), info)
        loss.backward()
        sinfo = _strategy_info(info, v, 500)
        ours._update_state(params, states[0], sinfo)
        theirs._update_state(params, states[1], sinfo)
        for p in params.values():
            p.grad = None
    for key in ("grad2d", "count"):
        torch.testing.assert_close(states[0][key], states[1][key], rtol=1e-6, atol=1e-9)
    assert states[0]["count"].max() == 3 and (states[0]["count"] == 0).any()


def test_init_gaussians_from_points():
    grid = np.stack(np.meshgrid(*[np.arange(5.0) * 0.1] * 3, indexing="ij"), -1).reshape(-1, 3)
    g = init_gaussians_from_points(grid, np.full_like(grid, 0.25), sh_degree=2)
    assert len(g) == 125 and g.sh.shape == (125, 9, 3)
    interior = np.all((grid > 0.05) & (grid < 0.35), axis=1)
    torch.testing.assert_close(g.scales[torch.from_numpy(interior)], torch.full((27, 3), 0.1), rtol=1e-5, atol=0)
    torch.testing.assert_close(g.opacities, torch.full((125,), 0.1), rtol=1e-5, atol=0)
    torch.testing.assert_close(g.quats, torch.tensor([1.0, 0, 0, 0]).expand(125, 4))
    assert float(g.sh[:, 1:].abs().max()) == 0.0
    with pytest.raises(ValueError):
        init_gaussians_from_points(grid[:1], grid[:1])


def test_opacity_regulariser_pushes_opacities_to_zero_or_one():
    views = _photos(4)
    hazy = []
    for lam in (0.0, 0.5):
        g, _ = train(views, views[:1], _init(400), _config(iterations=60, densify=False, lambda_opacity=lam),
                     progress=False)  # fmt: skip
        o = torch.sigmoid(g.logit_opacities)
        hazy.append(float(((o > 0.1) & (o < 0.9)).float().mean()))
    assert hazy[1] < 0.6 * hazy[0], hazy


# ---- coarse views ------------------------------------------------------------------------------
def test_a_downsampled_view_is_the_scene_seen_at_that_resolution():
    """A photo at 2W x 2H downsampled by 2: a world point lands at half its pixel coordinates (pixel edges stay
    put), and the image is (up to the box filter) the render of its coarse camera, closer to it than to the
    render of that camera half a pixel off."""
    gt = tabletop_scene(3000, sh_degree=1, seed=0)
    vm, K = orbit_cameras(1, W, H, seed=0)[0]
    vm_t, K_t = torch.tensor(vm, dtype=torch.float32), torch.tensor(K, dtype=torch.float32)
    K2 = K_t.clone()
    K2[:2] *= 2
    mask = torch.ones(2 * H, 2 * W, dtype=torch.bool)
    mask[5, 7] = False  # one invalid fine pixel: its coarse pixel (2, 3) is invalid, no other
    allowed = torch.zeros(2 * H, 2 * W, dtype=torch.bool)
    allowed[9, 11] = True  # one fine pixel that may hold alpha: so may its coarse pixel (4, 5)
    with torch.no_grad():
        fine = render(gt, vm_t, K2, 2 * W, 2 * H, torch.zeros(3), backend="cpu").rgb.clamp(0, 1)
        coarse = downsample_view(View(fine, vm_t, K2, mask=mask, alpha_mask=allowed, background=fine), 2)
        assert (coarse.width, coarse.height) == (W, H) and torch.equal(coarse.viewmat, vm_t)
        point = vm_t[:3, :3] @ torch.tensor([0.05, -0.1, 0.2]) + vm_t[:3, 3]  # camera frame
        uv_fine, uv = (K2 @ point)[:2] / point[2], (coarse.K @ point)[:2] / point[2]
        assert torch.allclose(uv, uv_fine / 2) and torch.allclose(coarse.K, K_t)
        assert torch.equal(coarse.image, coarse.background)
        assert torch.allclose(coarse.image[1, 2], fine[2:4, 4:6].mean(dim=(0, 1)))
        assert not coarse.mask[2, 3] and int(coarse.mask.sum()) == W * H - 1
        assert coarse.alpha_mask[4, 5] and int(coarse.alpha_mask.sum()) == 1
        direct = render(gt, vm_t, K_t, W, H, torch.zeros(3), backend="cpu").rgb.clamp(0, 1)
        shifted = K_t.clone()
        shifted[:2, 2] += 0.5
        off = render(gt, vm_t, shifted, W, H, torch.zeros(3), backend="cpu").rgb.clamp(0, 1)
    right, wrong = float(psnr(direct, coarse.image)), float(psnr(off, coarse.image))
    print("coarse view PSNR", round(right, 2), "half a pixel off", round(wrong, 2))  # 29.8 and 28.8 dB
    assert right >= 27.0 and right >= wrong + 0.5
    assert downsample_view(coarse, 1) is coarse
    with pytest.raises(ValueError, match="leaves no pixels"):
        downsample_view(coarse, 100)


class _Below:
    """A constraint: no centre above z = top, no scale over cap (the scene's Gaussians would rise past it)."""

    def __init__(self, top: float, cap: float, every: int) -> None:
        self.top, self.cap, self.every, self.calls = top, cap, every, []

    def __call__(self, means, quats, log_scales):
        self.calls.append(len(means))
        return means.clamp(max=torch.tensor([np.inf, np.inf, self.top])), log_scales.clamp(max=math.log(self.cap))


def test_a_constraint_holds_every_few_steps_and_after_the_last():
    views = _photos()
    init = _init()
    top = float(np.quantile(init.means[:, 2].numpy(), 0.5))  # half the Gaussians start above it
    below = _Below(top, cap=0.01, every=25)
    g, metrics = train(views[1:], views[:1], init, _config(iterations=110, checkpoint_every=0), progress=False,
                       constraint=below)  # fmt: skip
    assert len(below.calls) == 5  # after steps 25, 50, 75, 100 and the last (110)
    assert float(g.means[:, 2].max()) <= top + 1e-6
    assert float(g.log_scales.max()) <= math.log(0.01) + 1e-6
    free, _ = train(views[1:], views[:1], init, _config(iterations=110, checkpoint_every=0), progress=False)
    assert float(free.means[:, 2].max()) > top + 0.01  # without it half stay above
    assert math.isfinite(metrics["psnr"])
