"""gsplat CUDA backend (backend="cuda") against the numba CPU rasterizer and the dense reference,.

Needs a CUDA GPU, torch built with CUDA and gsplat (its kernels may be JIT-compiled on first use,
which can take minutes once per machine). Everything else skips. Outputs are compared on the CPU.
"""

import math

import pytest
import torch
from render_helpers import intrinsics, look_at, psnr

from fixtures.cuda import CUDA_MARKS
from fixtures.gaussians import random_gaussians
from mirage2matter.errors import M2MError
from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.render import render
from mirage2matter.gaussians.synthetic import orbit_cameras, tabletop_scene

pytestmark = CUDA_MARKS

BG = torch.tensor([0.2, 0.5, 0.8])
PARAMS = ("means", "quats", "log_scales", "logit_opacities", "sh")


def assert_depth_close(out, ref, rel: float):
    mask = ref.alpha.cpu() > 0.5
    assert mask.float().mean() > 0.05
    d_out, d_ref = out.depth.detach().cpu()[mask].double(), ref.depth.detach().cpu()[mask].double()
    mean_rel = ((d_out - d_ref).abs() / d_ref).mean().item()
    assert mean_rel <= rel, f"mean relative depth error {mean_rel:.3g} > {rel}"


@pytest.mark.parametrize(("n", "width", "height"), [(100_000, 224, 224), (20_000, 128, 96)])
def test_gsplat_matches_numba_on_tabletop(n, width, height):
    g = tabletop_scene(n, 3, seed=0)
    (V, K), *_ = orbit_cameras(1, width, height, seed=0)
    cpu = render(g, V, K, width, height, background=BG, backend="cpu")
    gpu = render(g.to("cuda"), V, K, width, height, background=BG.cuda(), backend="cuda")
    assert gpu.rgb.is_cuda and gpu.rgb.dtype == torch.float32
    assert gpu.rgb.shape == (height, width, 3) and gpu.alpha.shape == gpu.depth.shape == (height, width)
    assert psnr(gpu.rgb, cpu.rgb) >= 35.0
    assert psnr(gpu.alpha, cpu.alpha) >= 35.0
    assert_depth_close(gpu, cpu, rel=1e-2)
    assert cpu.alpha.mean() > 0.5  # the view really shows the scene


def test_gsplat_matches_reference_on_small_random_scene():
    g = random_gaussians(500, 3, seed=1)
    V, K = look_at([3.0, -2.0, 1.5], [0, 0, 0]), intrinsics(64, 48)
    ref = render(g.to(torch.float64), V, K, 64, 48, background=BG.double(), backend="reference")
    # CPU-resident Gaussians: the backend moves them to the GPU and returns CPU tensors of their dtype.
    gpu = render(g, V, K, 64, 48, background=BG, backend="cuda")
    assert gpu.rgb.device.type == "cpu" and gpu.rgb.dtype == torch.float32
    assert psnr(gpu.rgb, ref.rgb) >= 35.0 and psnr(gpu.alpha, ref.alpha) >= 35.0
    assert_depth_close(gpu, ref, rel=1e-2)
    assert ref.alpha.mean() > 0.1


def test_gsplat_empty_scene_renders_background():
    g = random_gaussians(1, 3, seed=0).select(slice(0, 0)).to("cuda")
    V, K = look_at([3.0, 0.0, 0.0], [0, 0, 0]), intrinsics(40, 24)
    out = render(g, V, K, 40, 24, background=BG.cuda(), backend="cuda")
    assert out.rgb.shape == (24, 40, 3) and out.rgb.is_cuda
    assert not out.alpha.any() and not out.depth.any()
    torch.testing.assert_close(out.rgb.cpu(), BG.expand(24, 40, 3), atol=1e-6, rtol=0)


def test_gsplat_gradients_match_reference():
    """Not a tight check (gsplat uses fast-math float32 kernels and atomics), but wrong conventions
    in the gradient (e.g. of the SH direction or the depth channel) are far beyond 1e-2."""
    g = random_gaussians(400, 3, seed=2)
    V, K = look_at([2.5, 2.0, 1.2], [0, 0, 0]), intrinsics(64, 48)
    rng = torch.Generator().manual_seed(0)
    W = [torch.randn(*s, generator=rng, dtype=torch.float64) for s in ((48, 64, 3), (48, 64), (48, 64))]

    def grads(gs: Gaussians, backend: str, device: str):
        gs = gs.to(device).map(lambda t: t.detach().clone().requires_grad_(True))
        dt = gs.means.dtype
        out = render(gs, V, K, 64, 48, background=BG.to(device, dt), backend=backend)
        w1, w2, w3 = (x.to(device, dt) for x in W)
        ((out.rgb * w1).sum() + (out.alpha * w2).sum() + (out.depth * w3).sum()).backward()
        return {k: getattr(gs, k).grad.detach().double().cpu() for k in PARAMS}

    g_gpu = grads(g, "cuda", "cuda")
    g_ref = grads(g.to(torch.float64), "reference", "cpu")
    errs = {k: ((g_gpu[k] - g_ref[k]).norm() / g_ref[k].norm()).item() for k in PARAMS}
    assert all(e <= 1e-2 for e in errs.values()), errs


@pytest.mark.parametrize("requires_grad", [False, True])
def test_gsplat_empty_scene_with_gradients_and_info(requires_grad):
    z = lambda *shape: torch.zeros(*shape, device="cuda", requires_grad=requires_grad)  # noqa: E731
    g = Gaussians(z(0, 3), z(0, 4), z(0, 3), z(0), z(0, 16, 3))
    info: dict = {}
    out = render(g, look_at([3.0, 0, 0], [0, 0, 0]), intrinsics(40, 24), 40, 24, BG.cuda(), "cuda", info)
    torch.testing.assert_close(out.rgb.detach().cpu(), BG.expand(24, 40, 3), atol=1e-6, rtol=0)
    assert info["mean2d"].shape == (0, 2)
    if requires_grad:
        (out.rgb.sum() + out.alpha.sum() + out.depth.sum()).backward()
        assert g.means.grad is not None and g.means.grad.shape == (0, 3)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_gsplat_tiny_sets_match_cpu(n):
    """One, two and three Gaussians: one seen, one behind the camera, one beyond the image."""
    g = random_gaussians(3, 3, seed=5, extent=0.3)
    g = Gaussians(torch.tensor([[0.0, 0.1, 0.0], [6.0, 0.0, 0.0], [0.0, 5.0, 0.0]]), g.quats,
                  torch.full((3, 3), math.log(0.6)), torch.full((3,), 3.0), g.sh).select(slice(0, n))  # fmt: skip
    V, K = look_at([3.0, 0, 0], [0, 0, 0]), intrinsics(40, 30)
    cpu = render(g, V, K, 40, 30, background=BG, backend="cpu")
    gg = g.to("cuda").map(lambda t: t.clone().requires_grad_(True))
    gpu = render(gg, V, K, 40, 30, background=BG.cuda(), backend="cuda")
    assert psnr(gpu.rgb, cpu.rgb) >= 35.0 and psnr(gpu.alpha, cpu.alpha) >= 35.0
    (gpu.rgb.sum() + gpu.alpha.sum()).backward()
    assert torch.isfinite(gg.means.grad).all() and gg.means.grad[0].abs().sum() > 0


def test_gsplat_out_of_memory_is_a_clear_error():
    """An image far beyond any GPU's memory (200k x 200k: 640 GB of output): an M2MError naming what to
    lower, and the process (and the GPU) still usable afterwards."""
    g = random_gaussians(100, 3, seed=0).to("cuda")
    with pytest.raises(M2MError, match="GPU out of memory rendering 100 Gaussians at 200000x200000.*lower"):
        render(g, look_at([3.0, 0, 0], [0, 0, 0]), intrinsics(200_000, 200_000), 200_000, 200_000, backend="cuda")
    out = render(g, look_at([3.0, 0, 0], [0, 0, 0]), intrinsics(40, 30), 40, 30, backend="cuda")
    assert out.alpha.max() > 0
