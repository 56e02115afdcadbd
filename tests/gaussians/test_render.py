"""The numba CPU rasterizer (backend="cpu") against the dense pure-torch reference and independent math.

The reference renders in float64 and the CPU backend in float32, so every comparison here crosses
two independent implementations (and precisions). Scenes are small: the reference is O(N*H*W).
"""

import functools
import math
import re

import numpy as np
import pytest
import torch
from render_helpers import intrinsics, look_at, psnr
from scipy.spatial.transform import Rotation

from fixtures.gaussians import random_gaussians
from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.render import BackendError, render, render_cameras
from mirage2matter.gaussians.synthetic import orbit_cameras, tabletop_scene

BG = torch.tensor([0.2, 0.5, 0.8])
PARAMS = ("means", "quats", "log_scales", "logit_opacities", "sh")
GRAD_RTOL = 1e-3


# ---- helpers -----------------------------------------------------------------------------------


def with_(g: Gaussians, **kw) -> Gaussians:
    return Gaussians(**{**g.tensors(), **kw})


def empty_gaussians(dtype=torch.float32, degree: int = 3) -> Gaussians:
    z = lambda *s: torch.zeros(*s, dtype=dtype)
    return Gaussians(z(0, 3), z(0, 4), z(0, 3), z(0), z(0, (degree + 1) ** 2, 3))


# ---- scenes: (Gaussians float32, viewmat, K, width, height, background) ---------------------------
@functools.cache
def scene(name: str):
    if name == "random":  # unstructured cloud seen from a few units away; quats not normalised
        g = random_gaussians(1000, 3, seed=1)
        scale = torch.from_numpy(np.random.default_rng(1).uniform(0.5, 2.0, (len(g), 1))).float()
        return with_(g, quats=g.quats * scale), look_at([3.0, -2.0, 1.5], [0, 0, 0]), intrinsics(96, 72), 96, 72, None
    if name == "tabletop":  # structured scene, downscaled orbit view
        (V, K), *_ = orbit_cameras(1, 96, 72, seed=0)
        return tabletop_scene(2000, 3, seed=0), V, K, 96, 72, BG
    if name == "opaque":  # large near-opaque Gaussians: alpha clamp at 0.999 and early stop at T_MIN
        g = random_gaussians(600, 3, seed=3)
        g = with_(g, log_scales=g.log_scales + 1.0, logit_opacities=torch.full_like(g.logit_opacities, 8.0))
        return g, look_at([3.0, -2.0, 1.5], [0, 0, 0]), intrinsics(64, 48), 64, 48, BG
    if name == "outside":  # camera inside a wide cloud: many Gaussians cross or lie beyond the borders
        K = np.array([[70.0, 0.0, 40.3], [0.0, 64.0, 20.7], [0.0, 0.0, 1.0]])  # fx != fy, off-centre
        return random_gaussians(600, 3, seed=4, extent=2.0), look_at([0.3, -1.0, 0.4], [0, 0, 0]), K, 77, 45, BG
    raise KeyError(name)


def small(name: str):
    """Cheaper variants for the gradient tests (the reference's backward is the slow part)."""
    g, V, K, w, h, bg = scene(name)
    if name == "random":
        return g.select(slice(0, 500)), V, intrinsics(64, 48), 64, 48, BG
    if name == "tabletop":
        (V, K), *_ = orbit_cameras(1, 64, 48, seed=0)
        return tabletop_scene(1000, 3, seed=0), V, K, 64, 48, BG
    return g, V, K, w, h, bg


def project_means(g: Gaussians, V, K) -> tuple[torch.Tensor, torch.Tensor]:
    """Independent pinhole projection: pixel coordinates [N,2] and camera z [N] (float64)."""
    V, K = torch.as_tensor(V, dtype=torch.float64), torch.as_tensor(K, dtype=torch.float64)
    p = g.means.double() @ V[:3, :3].T + V[:3, 3]
    uv = torch.stack([K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2], K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]], -1)
    return uv, p[:, 2]


def assert_images_match(out, ref, min_psnr: float = 60.0):
    assert out.rgb.shape == ref.rgb.shape and out.alpha.shape == ref.alpha.shape == ref.depth.shape
    p_rgb, p_alpha = psnr(out.rgb, ref.rgb), psnr(out.alpha, ref.alpha)
    assert p_rgb >= min_psnr, f"rgb PSNR {p_rgb:.1f} dB < {min_psnr}"
    assert p_alpha >= min_psnr, f"alpha PSNR {p_alpha:.1f} dB < {min_psnr}"
    mask = ref.alpha > 0.5
    assert mask.float().mean() > 0.05, "too little coverage for the depth check to mean anything"
    d_ref, d_out = ref.depth[mask].double(), out.depth.detach()[mask].double()
    err = (d_out - d_ref).abs().max().item()
    assert err <= 1e-4 * d_ref.max().item(), f"depth error {err:.3g} (max depth {d_ref.max():.3g})"


# ---- 1. forward against the reference -------------------------------------------------------------
@pytest.mark.parametrize("name", ["random", "tabletop", "opaque", "outside"])
def test_forward_matches_reference(name):
    g, V, K, w, h, bg = scene(name)
    out = render(g, V, K, w, h, background=bg, backend="cpu")
    ref = render(g.to(torch.float64), V, K, w, h, background=bg, backend="reference")
    assert out.rgb.dtype == torch.float32 and ref.rgb.dtype == torch.float64
    assert out.rgb.shape == (h, w, 3)
    assert_images_match(out, ref)
    # Not trivially empty or saturated: the scene really covers part of the image.
    assert 0.1 < ref.alpha.mean().item() and ref.rgb.std().item() > 0.05


def test_outside_scene_really_crosses_the_borders():
    """Guards the 'outside' scene above: some Gaussians project off-image, some inside, some behind."""
    g, V, K, w, h, _ = scene("outside")
    uv, z = project_means(g, V, K)
    front = z > 0.01
    inside = front & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    assert inside.sum() > 20 and (front & ~inside).sum() > 100 and (~front).sum() > 20


def test_gaussians_straddling_the_image_border():
    """Large Gaussians centred on and beyond every edge and corner, only part of each visible."""
    w, h = 61, 37  # not multiples of 16: partial tiles on the right and bottom
    K = np.array([[50.0, 0.0, 30.0], [0.0, 52.0, 19.0], [0.0, 0.0, 1.0]])
    uv = [(-3, 18), (64, 18), (30, -4), (30, 41), (-2, -2), (63, 39), (-9, 39), (70, -6), (0.2, 36.9)]
    z = 2.0
    means = torch.tensor([[(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z] for u, v in uv])
    n = len(uv)
    rng = torch.Generator().manual_seed(0)
    g = Gaussians(
        means=means,
        quats=torch.randn(n, 4, generator=rng),
        log_scales=torch.log(torch.rand(n, 3, generator=rng) * 0.2 + 0.15),
        logit_opacities=torch.full((n,), 2.0),
        sh=torch.randn(n, 4, 3, generator=rng) * 0.3,
    )
    out = render(g, np.eye(4), K, w, h, background=BG, backend="cpu")
    ref = render(g.to(torch.float64), np.eye(4), K, w, h, background=BG, backend="reference")
    assert_images_match(out, ref)
    # every border row/column is touched
    for edge in (ref.alpha[0], ref.alpha[-1], ref.alpha[:, 0], ref.alpha[:, -1]):
        assert edge.max() > 0.3


def test_non_square_odd_size_background_and_offcentre_principal_point():
    g, V, _, _, _, _ = scene("random")
    w, h = 77, 45
    K = np.array([[80.0, 0.0, 35.2], [0.0, 71.0, 25.9], [0.0, 0.0, 1.0]])
    bg = torch.tensor([0.9, 0.1, 0.4])
    out = render(g, V, K, w, h, background=bg, backend="cpu")
    ref = render(g.to(torch.float64), V, K, w, h, background=bg, backend="reference")
    assert out.rgb.shape == (h, w, 3) and out.alpha.shape == (h, w) and out.depth.shape == (h, w)
    assert_images_match(out, ref)
    # The background shows where nothing is: rgb == bg * (1 - alpha) + (splat colour) -> == bg at alpha 0.
    empty = ref.alpha < 1e-12
    assert empty.sum() > 50
    torch.testing.assert_close(out.rgb[empty], bg.expand(int(empty.sum()), 3), atol=1e-6, rtol=0)


@pytest.mark.parametrize("degree", [0, 1, 2])
def test_lower_sh_degrees_match_reference(degree):
    g = random_gaussians(300, degree, seed=10 + degree)
    if degree > 0:  # strong view dependence so a wrong basis function shows
        rng = torch.Generator().manual_seed(degree)
        g = with_(g, sh=torch.cat([g.sh[:, :1], 0.3 * torch.randn(g.sh[:, 1:].shape, generator=rng)], 1))
    V, K = look_at([-2.5, 2.0, 1.0], [0, 0, 0]), intrinsics(64, 48)
    out = render(g, V, K, 64, 48, background=BG, backend="cpu")
    ref = render(g.to(torch.float64), V, K, 64, 48, background=BG, backend="reference")
    assert_images_match(out, ref)


@pytest.mark.parametrize("backend", ["cpu", "reference"])
@pytest.mark.parametrize("requires_grad", [False, True])
def test_empty_scene_renders_background(backend, requires_grad):
    dtype = torch.float32 if backend == "cpu" else torch.float64
    g = empty_gaussians(dtype).map(lambda t: t.requires_grad_(requires_grad))
    w, h = 40, 23
    out = render(g, look_at([3, 0, 0], [0, 0, 0]), intrinsics(w, h), w, h, background=BG, backend=backend)
    assert out.rgb.shape == (h, w, 3)
    assert torch.equal(out.alpha.detach(), torch.zeros(h, w, dtype=dtype))
    assert torch.equal(out.depth.detach(), torch.zeros(h, w, dtype=dtype))
    torch.testing.assert_close(out.rgb.detach(), BG.to(dtype).expand(h, w, 3), atol=1e-7, rtol=0)
    if requires_grad:
        (out.rgb.sum() + out.alpha.sum() + out.depth.sum()).backward()
        assert g.means.grad is not None and g.means.grad.shape == (0, 3)


@pytest.fixture
def fake_gpu(monkeypatch):
    """backend="cuda" resolves as on a machine with a GPU and gsplat; gsplat's renderer is replaced by a
    recorder, so a test sees what would have reached the GPU (and dies loudly if something should not)."""
    import mirage2matter.gaussians.render as render_mod

    calls: list[int] = []

    def gsplat_stand_in(g, *args, **kwargs):
        calls.append(len(g))
        if len(g) == 0:  # what gsplat 1.5.3 does: SIGFPE in fully_fused_projection, the process is gone
            raise AssertionError("an empty Gaussian set reached gsplat")
        return render(g, *args[:4], background=args[4] if len(args) > 4 else None, backend="cpu")

    monkeypatch.setattr(render_mod, "cuda_unavailable_reason", lambda: None)
    monkeypatch.setattr(render_mod, "render_gsplat", gsplat_stand_in)
    return calls


@pytest.mark.parametrize("requires_grad", [False, True])
def test_empty_scene_never_reaches_gsplat(fake_gpu, requires_grad):
    g = empty_gaussians().map(lambda t: t.requires_grad_(requires_grad))
    w, h = 40, 23
    info: dict = {}
    out = render(g, look_at([3, 0, 0], [0, 0, 0]), intrinsics(w, h), w, h, background=BG, backend="cuda", info=info)
    assert fake_gpu == []
    torch.testing.assert_close(out.rgb.detach(), BG.expand(h, w, 3), atol=0, rtol=0)
    assert not out.alpha.any() and not out.depth.any()
    assert info["mean2d"].shape == (0, 2) and info["radius"].shape == (0, 2)
    if requires_grad:
        (out.rgb.sum() + out.alpha.sum() + out.depth.sum()).backward()
        assert all(getattr(g, k).grad is not None and not getattr(g, k).grad.numel() for k in PARAMS)
    # and a set that is not empty does reach it
    render(random_gaussians(3, 3, seed=0), look_at([3, 0, 0], [0, 0, 0]), intrinsics(w, h), w, h, backend="cuda")
    assert fake_gpu == [3]


def test_training_pruned_to_nothing_keeps_running():
    """A training run whose every Gaussian is pruned (an object that was not there) ends with zero
    Gaussians and renders the background (test_render_cuda.py runs the same on a GPU)."""
    from mirage2matter.gaussians.train import TrainConfig, View, train

    V, K = torch.as_tensor(look_at([3, 0, 0], [0, 0, 0])).float(), torch.as_tensor(intrinsics(32, 24)).float()
    view = View(torch.full((24, 32, 3), 0.3), V, K)
    g = random_gaussians(50, 1, seed=0)
    g = with_(g, logit_opacities=torch.full_like(g.logit_opacities, -9.0))  # below prune_opa: all go
    cfg = TrainConfig(iterations=30, sh_degree=1, refine_start=0.0, refine_every=5, backend="cpu",
                      background=(0.3, 0.3, 0.3))  # fmt: skip
    out, metrics = train([view], [view], g, cfg, progress=False)
    assert len(out) == 0 and metrics["iterations"] == 30
    assert metrics["psnr"] > 100  # the background is the photo


@pytest.mark.parametrize("backend", ["cpu", "reference"])
@pytest.mark.parametrize("n", [1, 2, 3])
def test_tiny_sets_match_the_reference(backend, n):
    """One, two and three Gaussians: each seen, one of them behind the camera, one beyond the image."""
    g = random_gaussians(3, 3, seed=5, extent=0.3)
    g = with_(g, means=torch.tensor([[0.0, 0.1, 0.0], [6.0, 0.0, 0.0], [0.0, 5.0, 0.0]]),
              log_scales=torch.full((3, 3), math.log(0.6)), logit_opacities=torch.full((3,), 3.0))  # fmt: skip
    g = g.select(slice(0, n))
    V, K, w, h = look_at([3, 0, 0], [0, 0, 0]), intrinsics(40, 30), 40, 30
    ref = render(g.to(torch.float64), V, K, w, h, background=BG.double(), backend="reference")
    dtype = torch.float32 if backend == "cpu" else torch.float64
    gg = g.to(dtype).map(lambda t: t.clone().requires_grad_(True))
    out = render(gg, V, K, w, h, background=BG.to(dtype), backend=backend)
    assert_images_match(out, ref)
    (out.rgb.sum() + out.alpha.sum()).backward()
    assert torch.isfinite(gg.means.grad).all() and gg.means.grad[0].abs().sum() > 0
    assert not gg.means.grad[1:].any()  # behind the camera, beyond the image: no pixel, no gradient


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_scene_behind_the_camera_is_invisible(backend):
    dtype = torch.float32 if backend == "cpu" else torch.float64
    g = random_gaussians(300, 3, seed=2).to(dtype)
    w, h = 48, 32
    K = intrinsics(w, h)
    # Sanity: looking at the cloud shows it, so the empty image below is not an accident.
    seen = render(g, look_at([4.0, 0, 0], [0, 0, 0]), K, w, h, background=BG, backend=backend)
    assert seen.alpha.max() > 0.5
    # Now the camera sits at x=4 looking away (+x); the whole cloud (|x| <= 1) is behind it.
    g = g.map(lambda t: t.detach().requires_grad_(True))
    out = render(g, look_at([4.0, 0, 0], [8.0, 0, 0]), K, w, h, background=BG, backend=backend)
    assert torch.equal(out.alpha.detach(), torch.zeros(h, w, dtype=dtype))
    assert torch.equal(out.depth.detach(), torch.zeros(h, w, dtype=dtype))
    torch.testing.assert_close(out.rgb.detach(), BG.to(dtype).expand(h, w, 3), atol=1e-7, rtol=0)
    (out.rgb.sum() + out.alpha.sum() + out.depth.sum()).backward()
    for name in PARAMS:
        grad = getattr(g, name).grad
        assert grad is not None and torch.isfinite(grad).all() and not grad.any(), name


# ---- 2. gradients against the reference -----------------------------------------------------------
def loss_weights(h: int, w: int, seed: int = 0) -> tuple[torch.Tensor, ...]:
    rng = torch.Generator().manual_seed(seed)
    return tuple(torch.randn(*shape, generator=rng, dtype=torch.float64) for shape in ((h, w, 3), (h, w), (h, w)))


def render_grads(g: Gaussians, V, K, w, h, bg, backend: str, weights, info=None):
    """Gradients (float64) of L = sum(rgb*W1) + sum(alpha*W2) + sum(depth*W3) w.r.t. every parameter."""
    g = g.map(lambda t: t.detach().clone().requires_grad_(True))
    dt = g.means.dtype
    out = render(g, V, K, w, h, background=None if bg is None else bg.to(dt), backend=backend, info=info)
    W1, W2, W3 = (x.to(dt) for x in weights)
    loss = (out.rgb * W1).sum() + (out.alpha * W2).sum() + (out.depth * W3).sum()
    loss.backward()
    return {name: getattr(g, name).grad.double() for name in PARAMS}


def rel_err(a: torch.Tensor, b: torch.Tensor) -> float:
    return ((a - b).norm() / b.norm()).item()


@pytest.mark.parametrize("name", ["random", "tabletop", "opaque", "outside"])
def test_gradients_match_reference(name):
    g, V, K, w, h, bg = small(name)
    weights = loss_weights(h, w)
    g_cpu = render_grads(g, V, K, w, h, bg, "cpu", weights)
    g_ref = render_grads(g.to(torch.float64), V, K, w, h, bg, "reference", weights)
    errs = {k: rel_err(g_cpu[k], g_ref[k]) for k in PARAMS}
    for k in PARAMS:
        assert torch.isfinite(g_cpu[k]).all(), k
        assert g_ref[k].norm() > 1e-3, f"{k}: reference gradient ~0, the comparison would be vacuous"
    assert all(e <= GRAD_RTOL for e in errs.values()), errs

    # The check can fail: the gradient of a slightly different loss (weights perturbed by 2%) is far off.
    rng = torch.Generator().manual_seed(123)
    other = tuple(x * (1 + 0.02 * torch.randn(x.shape, generator=rng, dtype=x.dtype)) for x in weights)
    g_wrong = render_grads(g, V, K, w, h, bg, "cpu", other)
    wrong = {k: rel_err(g_wrong[k], g_ref[k]) for k in PARAMS}
    assert all(e > 10 * GRAD_RTOL for e in wrong.values()), wrong


# ---- 3. the grad path (numba projection with its backward) and the fused no-grad path --------------
@pytest.mark.parametrize("name", ["random", "tabletop", "outside", "dark"])
@pytest.mark.parametrize("degree", [0, 1, 3])
def test_numba_projection_matches_torch_projection(name, degree):
    """ProjectNumba (the training path's projection + SH, hand-written backward) against the torch projection
    differentiated by autograd: the same culling, outputs and input gradients. "outside" has Gaussians at the
    FOV clamp; "dark" has colours the clamp at 0 cuts."""
    from mirage2matter.gaussians.render.numba_projection import ProjectNumba
    from mirage2matter.gaussians.render.projection import project

    g, V, K, w, h, _ = scene("random" if name == "dark" else name)
    g = g.with_sh_degree(degree)
    if name == "dark":
        g = with_(g, sh=g.sh - 1.2 * (torch.arange(len(g)) % 2)[:, None, None])  # half of them below zero
    V64, K64 = np.asarray(V, np.float64), np.asarray(K, np.float64)
    gt, gn = (g.map(lambda t: t.detach().clone().requires_grad_(True)) for _ in range(2))
    ref = project(gt, torch.from_numpy(V64), torch.from_numpy(K64), w, h)
    out = ProjectNumba.apply(gn.means, gn.quats, gn.log_scales, gn.logit_opacities, gn.sh, V64, K64, w, h)
    keep = (ref.radius > 0).all(1)
    assert torch.equal(keep, (out[5] > 0).all(1)) and keep.sum() > 50
    assert (out[5] - ref.radius).abs().max() <= 1
    refs = (ref.mean2d, ref.conic, ref.depth, ref.opacity, ref.color)
    for a, b in zip(out[:5], refs, strict=True):
        torch.testing.assert_close(a[keep], b[keep].float(), rtol=1e-4, atol=1e-4 * float(b[keep].abs().max()))
    if name == "dark":
        assert (ref.color[keep] == 0).any()
    rng = torch.Generator().manual_seed(1)  # upstream gradients where the rasterizer would give them
    ws = [torch.randn(o.shape, generator=rng) * keep.reshape(-1, *[1] * (o.ndim - 1)) for o in out[:5]]
    sum((o * u).sum() for o, u in zip(refs, ws, strict=True)).backward()
    sum((o * u).sum() for o, u in zip(out[:5], ws, strict=True)).backward()
    for k in PARAMS:
        a, b = getattr(gn, k).grad, getattr(gt, k).grad
        assert float((a - b).norm() / b.norm()) <= 1e-4, k
        assert not a[~keep].any(), k  # culled Gaussians get no gradient


@pytest.mark.parametrize("name", ["random", "tabletop", "outside"])
def test_grad_and_nograd_paths_agree(name):
    g, V, K, w, h, bg = scene(name)
    info_fast: dict = {}
    with torch.no_grad():
        fast = render(g.map(lambda t: t.clone().requires_grad_(True)), V, K, w, h, bg, backend="cpu", info=info_fast)
    info_grad: dict = {}
    gg = g.map(lambda t: t.clone().requires_grad_(True))
    slow = render(gg, V, K, w, h, bg, backend="cpu", info=info_grad)
    assert slow.rgb.requires_grad and not fast.rgb.requires_grad
    assert psnr(fast.rgb, slow.rgb) >= 80 and psnr(fast.alpha, slow.alpha) >= 80
    mask = slow.alpha.detach() > 0.5
    torch.testing.assert_close(fast.depth[mask], slow.depth.detach()[mask], rtol=1e-5, atol=0)
    # Same culling, and the screen-space means of the visible Gaussians match an independent projection.
    r_fast, r_grad = info_fast["radius"], info_grad["radius"]
    assert r_fast.shape == r_grad.shape == (len(g), 2)
    visible = (r_grad > 0).all(1)
    assert torch.equal(visible, (r_fast > 0).all(1)) and visible.sum() > 50
    assert (r_fast - r_grad).abs().max() <= 1  # integral box half-widths; float rounding may flip a ceil
    uv, _ = project_means(g, V, K)
    for info in (info_fast, info_grad):
        torch.testing.assert_close(info["mean2d"].detach()[visible].double(), uv[visible], atol=2e-3, rtol=1e-5)


def test_info_mean2d_grad_and_absgrad():
    g, V, *_ = scene("random")
    w, h, bg = 64, 48, BG
    K = torch.tensor([[55.0, 0.0, 31.0], [0.0, 57.0, 25.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    weights = loss_weights(h, w, seed=7)
    info: dict = {}
    render_grads(g, V, K, w, h, bg, "cpu", weights, info=info)
    mean2d, absgrad = info["mean2d"], info["mean2d_absgrad"]
    assert mean2d.shape == (len(g), 2) and mean2d.grad is not None and mean2d.grad.shape == (len(g), 2)
    assert absgrad.shape == (len(g), 2)
    grad = mean2d.grad
    assert (absgrad >= 0).all()
    assert (absgrad >= grad.abs() * (1 - 1e-6)).all()
    assert (absgrad > 1.01 * grad.abs()).any()  # a sum of |.| per pixel, not |sum|
    culled = (info["radius"] == 0).all(1)
    assert not grad[culled].any() and not absgrad[culled].any()

    # Independent check of mean2d.grad: moving the principal point shifts every projected mean by
    # the same amount and (with no Gaussian at the FOV clamp) changes nothing else, so
    # dL/dcx = sum_i dL/du_i and dL/dcy = sum_i dL/dv_i. dL/dK comes from the reference's autograd.
    uv, z = project_means(g, V, K)
    lim_x = (K[0, 2] + 0.15 * w) / K[0, 0], (w - K[0, 2] + 0.15 * w) / K[0, 0]
    lim_y = (K[1, 2] + 0.15 * h) / K[1, 1], (h - K[1, 2] + 0.15 * h) / K[1, 1]
    xz, yz = (uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1]
    assert (z > 0.01).all() and (xz > -lim_x[0]).all() and (xz < lim_x[1]).all()
    assert (yz > -lim_y[0]).all() and (yz < lim_y[1]).all()
    K_ref = K.clone().requires_grad_(True)
    gd = g.to(torch.float64)
    out = render(gd, V, K_ref, w, h, background=bg.double(), backend="reference")
    W1, W2, W3 = weights
    ((out.rgb * W1).sum() + (out.alpha * W2).sum() + (out.depth * W3).sum()).backward()
    d_cx, d_cy = K_ref.grad[0, 2].item(), K_ref.grad[1, 2].item()
    sums = grad.double().sum(0)
    scale = absgrad.double().sum(0)  # the size of the cancelling terms
    assert abs(sums[0].item() - d_cx) <= 1e-4 * scale[0].item(), (sums, d_cx, d_cy)
    assert abs(sums[1].item() - d_cy) <= 1e-4 * scale[1].item(), (sums, d_cx, d_cy)


def test_single_gaussian_mean2d_grad_and_absgrad_analytic():
    """One Gaussian, camera at the origin, L = sum(alpha * W): the screen-space mean, dL/dmean2d and
    the per-pixel absolute-gradient sum, all computed here from the EWA formulas in float64."""
    w, h = 64, 48
    fx, fy, cx, cy = 60.0, 55.0, 33.3, 23.1
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    mean = np.array([0.12, -0.07, 2.0])
    q_wxyz = np.array([0.8, 0.3, -0.4, 0.33])
    scales = np.array([0.06, 0.1, 0.03])
    opacity = 0.8
    g = Gaussians(
        means=torch.tensor(mean[None], dtype=torch.float32),
        quats=torch.tensor(q_wxyz[None], dtype=torch.float32),
        log_scales=torch.log(torch.tensor(scales[None], dtype=torch.float32)),
        logit_opacities=torch.tensor([math.log(opacity / (1 - opacity))], dtype=torch.float32),
        sh=torch.zeros(1, 1, 3),
    )
    W = torch.randn(h, w, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    info: dict = {}
    gg = g.map(lambda t: t.clone().requires_grad_(True))
    out = render(gg, np.eye(4), K, w, h, backend="cpu", info=info)
    (out.alpha * W.float()).sum().backward()

    # independent EWA splat
    x, y, z = mean
    R = Rotation.from_quat(np.roll(q_wxyz, -1)).as_matrix()  # scipy wants xyzw
    cov3 = R @ np.diag(scales**2) @ R.T
    J = np.array([[fx / z, 0.0, -fx * x / z**2], [0.0, fy / z, -fy * y / z**2]])
    conic = np.linalg.inv(J @ cov3 @ J.T + 0.3 * np.eye(2))
    u, v = fx * x / z + cx, fy * y / z + cy
    px, py = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d = np.stack([u - px, v - py], -1)  # [h,w,2]
    cd = d @ conic  # conic symmetric
    alpha = opacity * np.exp(-0.5 * (cd * d).sum(-1))
    alpha = np.where(alpha >= 1 / 255, np.minimum(alpha, 0.999), 0.0)
    torch.testing.assert_close(out.alpha.detach().double(), torch.from_numpy(alpha), atol=1e-5, rtol=0)
    per_pixel = -(W.numpy() * alpha)[..., None] * cd  # dL/d(u, v) from each pixel
    grad, absgrad = per_pixel.sum((0, 1)), np.abs(per_pixel).sum((0, 1))

    np.testing.assert_allclose(info["mean2d"].detach().numpy()[0], [u, v], atol=1e-4, rtol=0)
    np.testing.assert_allclose(info["mean2d"].grad.numpy()[0], grad, atol=1e-3 * absgrad.max(), rtol=0)
    np.testing.assert_allclose(info["mean2d_absgrad"].numpy()[0], absgrad, rtol=1e-3, atol=0)
    assert absgrad.min() > 1e-2 and (absgrad > 2 * np.abs(grad)).any()  # non-trivial, with cancellation


# ---- errors and backend selection ----------------------------------------------------------------
def _tiny():
    return random_gaussians(5, 0, seed=0), look_at([3, 0, 0], [0, 0, 0]), intrinsics(16, 12)


def test_unknown_backend_names_the_choices():
    g, V, K = _tiny()
    with pytest.raises(ValueError, match="nope") as e:
        render(g, V, K, 16, 12, backend="nope")
    for choice in ("auto", "cpu", "cuda", "reference"):
        assert choice in str(e.value)


def test_environment_variable_overrides_auto(monkeypatch):
    g, V, K = _tiny()
    monkeypatch.setenv("M2M_RENDER_BACKEND", "nope")
    with pytest.raises(ValueError, match="nope"):
        render(g, V, K, 16, 12)  # backend="auto" reads the variable
    render(g, V, K, 16, 12, backend="cpu")  # an explicit backend ignores it


def test_cuda_backend_without_cuda_says_use_cpu(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    g, V, K = _tiny()
    with pytest.raises(BackendError, match="cpu"):
        render(g, V, K, 16, 12, backend="cuda")
    # and "auto" then falls back to the CPU rasterizer, which agrees with the reference
    monkeypatch.delenv("M2M_RENDER_BACKEND", raising=False)
    out = render(g, V, K, 16, 12)
    ref = render(g.to(torch.float64), V, K, 16, 12, backend="reference")
    assert out.rgb.dtype == torch.float32 and psnr(out.rgb, ref.rgb) >= 60


def test_cuda_backend_without_gsplat_kernels_says_why(monkeypatch):
    """A GPU but gsplat without its CUDA kernels (no toolkit to JIT-build them): gsplat would fail on the
    first render with "'NoneType' object has no attribute ..."; the backend says what is missing first."""
    from mirage2matter.commands.args import CliError, backend
    from mirage2matter.gaussians.render import gsplat_cuda

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(gsplat_cuda, "_gsplat_kernels_problem", lambda: "gsplat found no CUDA toolkit to build")
    g, V, K = _tiny()
    with pytest.raises(BackendError, match="no CUDA toolkit.*use 'cpu'"):
        render(g, V, K, 16, 12, backend="cuda")
    with pytest.raises(CliError, match="--backend cuda: .*no CUDA toolkit"):
        backend("cuda")
    monkeypatch.delenv("M2M_RENDER_BACKEND", raising=False)
    assert backend("auto") == "cpu"


def test_no_gpu_reason_names_the_torch_build(monkeypatch):
    from mirage2matter.gaussians.render import resolve_backend

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(BackendError, match=re.escape(f"torch sees no CUDA GPU (torch {torch.__version__}")):
        resolve_backend("cuda")


def test_gpu_out_of_memory_says_what_to_lower(fake_gpu, monkeypatch):
    import mirage2matter.gaussians.render as render_mod
    from mirage2matter.errors import M2MError

    def out_of_memory(*args, **kwargs):
        raise torch.cuda.OutOfMemoryError("CUDA out of memory. Tried to allocate 20.00 GiB")

    monkeypatch.setattr(render_mod, "render_gsplat", out_of_memory)
    g, V, K = _tiny()
    with pytest.raises(M2MError, match=r"GPU out of memory rendering 5 Gaussians at 16x12.*lower .*--max-gaussians"):
        render(g, V, K, 16, 12, backend="cuda")


@pytest.mark.parametrize("backend", ["cpu", "reference", "auto"])
@pytest.mark.parametrize(("width", "height"), [(0, 12), (16, 0), (-4, 12), (16, -1)])
def test_non_positive_image_size_raises(backend, width, height):
    g, V, K = _tiny()
    with pytest.raises(ValueError, match="size"):
        render(g, V, K, width, height, backend=backend)


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_render_cameras_equals_one_render_per_camera(backend):
    """The batched entry point (one gsplat call on a GPU) gives, on every backend, the per-camera images."""
    g = random_gaussians(200, 2, seed=3)
    cams = orbit_cameras(3, 40, 32, seed=2)
    V, K = torch.stack([torch.as_tensor(v) for v, _ in cams]), torch.stack([torch.as_tensor(k) for _, k in cams])
    out = render_cameras(g, V, K, 40, 32, background=BG, backend=backend)
    assert out.rgb.shape == (3, 32, 40, 3) and out.alpha.shape == out.depth.shape == (3, 32, 40)
    for i, (v, k) in enumerate(cams):
        one = render(g, v, k, 40, 32, background=BG, backend=backend)
        for name in ("rgb", "alpha", "depth"):
            torch.testing.assert_close(getattr(out, name)[i], getattr(one, name), atol=0, rtol=0)
    assert out.alpha.amax(dim=(1, 2)).min() > 0.1  # every camera sees the scene
    empty = render_cameras(empty_gaussians(degree=2), V, K, 40, 32, background=BG, backend=backend)
    assert not empty.alpha.any() and torch.equal(empty.rgb, BG.expand(3, 32, 40, 3))
    with pytest.raises(ValueError, match=r"viewmats \[C,4,4\] and Ks \[C,3,3\]"):
        render_cameras(g, V, K[:2], 40, 32, backend=backend)


# ---- antialiased mode -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["random", "tabletop", "outside"])
def test_antialiased_forward_matches_reference(name):
    g, V, K, w, h, bg = scene(name)
    out = render(g, V, K, w, h, background=bg, backend="cpu", antialias=True)
    ref = render(g.to(torch.float64), V, K, w, h, background=bg, backend="reference", antialias=True)
    assert_images_match(out, ref)
    classic = render(g, V, K, w, h, background=bg, backend="cpu")
    assert psnr(classic.rgb, out.rgb) < 50  # the mode changes the picture


def test_antialiased_sub_pixel_gaussian_keeps_its_energy_not_its_peak():
    """One Gaussian far smaller than a pixel: classic mode draws it as a 0.3 px^2 blob at full opacity (its
    footprint - the integral of alpha - swells to opacity * 2 pi sqrt(det(cov + 0.3 I))); the antialiased mode
    scales the opacity by sqrt(det(cov) / det(cov + 0.3 I)), so the footprint is the Gaussian's own."""
    s = 0.02  # world sigma; at focal 100 and depth 4: 0.5 px
    one = lambda *v: torch.tensor([v], dtype=torch.float64)
    g = Gaussians(one(0.0, 0.0, 0.0), one(1.0, 0.0, 0.0, 0.0), torch.full((1, 3), math.log(s), dtype=torch.float64),
                  one(0.0).reshape(1), torch.zeros(1, 1, 3, dtype=torch.float64))  # fmt: skip
    V = torch.eye(4, dtype=torch.float64)
    V[2, 3] = 4.0
    K = torch.tensor([[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]], dtype=torch.float64)
    var = (100.0 * s / 4.0) ** 2  # screen variance, px^2
    for backend in ("cpu", "reference"):
        classic = render(g, V, K, 64, 64, backend=backend).alpha.double().sum().item()
        aa = render(g, V, K, 64, 64, backend=backend, antialias=True).alpha.double().sum().item()
        # opacity sigmoid(0) = 0.5; a few % of the mass is in the tails below alpha 1/255, which are not drawn
        assert classic == pytest.approx(0.5 * 2 * math.pi * (var + 0.3), rel=0.04)
        assert aa == pytest.approx(0.5 * 2 * math.pi * var, rel=0.04)
        assert aa < 0.5 * classic


def test_antialiased_cpu_gradients_are_refused_clearly():
    g, V, K = _tiny()
    g = Gaussians(**{k: t.clone().requires_grad_(True) for k, t in g.tensors().items()})
    with pytest.raises(NotImplementedError, match="antialias=False"):
        render(g, V, K, 16, 12, backend="cpu", antialias=True)
    ref = render(g, V, K, 16, 12, backend="reference", antialias=True)
    ref.rgb.sum().backward()  # the reference is differentiable in either mode
    assert g.means.grad is not None
