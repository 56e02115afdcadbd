"""CPU backend: numba tile rasterizer, forward and backward, wrapped for torch autograd.

Without gradients everything runs in numba (projection, SH colour, sort, binning, compositing).
With gradients, the projection runs in torch (projection.py) and ``RasterizeNumba`` supplies the
rasterization's backward, so the whole render is differentiable w.r.t. every Gaussian parameter.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from ..model import Gaussians
from . import numba_kernels as nk
from .projection import Projected, project
from .types import RenderOutput


def _np32(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).numpy())


def _tile_lists(mean2d, opacity, depth, radius, width: int, height: int):
    """Per-tile front-to-back Gaussian lists (offsets, ids) and each Gaussian's sigma_max [N]."""
    n = mean2d.shape[0]
    rect = np.empty((n, 4), np.int32)
    sigma_max = np.zeros(n, np.float32)
    nk.tile_rects(mean2d, radius, opacity, width, height, rect, sigma_max)
    valid = np.flatnonzero(rect[:, 0] <= rect[:, 1]).astype(np.int32)
    order = nk.argsort_by_depth(valid, depth.view(np.uint32))
    offsets, ids = nk.bin_tiles(order, rect, width, height)
    return offsets, ids, sigma_max


def _forward(mean2d, conic, opacity, color, depth, radius, width, height):
    offsets, ids, sigma_max = _tile_lists(mean2d, opacity, depth, radius, width, height)
    rgb = np.empty((height, width, 3), np.float32)
    dsum = np.empty((height, width), np.float32)
    T = np.empty((height, width), np.float32)
    last = np.empty((height, width), np.int32)
    with numba.parallel_chunksize(1):  # tiles differ a lot in cost: hand them out one at a time
        nk.rasterize_forward(
            offsets, ids, mean2d, conic, opacity, color, depth, radius, sigma_max, width, height, rgb, dsum, T, last
        )
    return rgb, dsum, T, last, (offsets, ids, sigma_max)


def _finish(rgb_acc, dsum, T, background, dtype) -> RenderOutput:
    """Background, accumulated alpha and expected depth from the raw sums (differentiable, torch)."""
    alpha = 1.0 - T
    rgb = rgb_acc
    if background is not None:
        bg = torch.as_tensor(background, dtype=rgb_acc.dtype, device=rgb_acc.device)
        rgb = rgb + T[..., None] * bg
    depth = dsum / alpha.clamp_min(1e-10)
    return RenderOutput(rgb.to(dtype), alpha.to(dtype), depth.to(dtype))


class RasterizeNumba(torch.autograd.Function):
    """(mean2d [N,2], conic [N,3], opacity [N], color [N,3], depth [N]) -> sums of w*rgb [H,W,3],
    of w*z [H,W], and final transmittance [H,W]. ``radius`` [N,2] (no gradient) culls and bounds."""

    @staticmethod
    def forward(ctx, mean2d, conic, opacity, color, depth, radius, width, height, stats):
        arrays = [_np32(t) for t in (mean2d, conic, opacity, color, depth, radius)]
        rgb, dsum, T, last, tiles = _forward(*arrays, width, height)
        ctx.arrays, ctx.buffers = arrays, (T, last, *tiles)
        ctx.size, ctx.stats = (width, height), stats
        return torch.from_numpy(rgb), torch.from_numpy(dsum), torch.from_numpy(T)

    @staticmethod
    def backward(ctx, v_rgb, v_dsum, v_T):
        mean2d, conic, opacity, color, depth, radius = ctx.arrays
        T, last, offsets, ids, sigma_max = ctx.buffers
        width, height = ctx.size
        n = mean2d.shape[0]
        chunks = max(1, nk.num_threads())
        g_mean2d = np.zeros((chunks, n, 2), np.float32)
        g_conic = np.zeros((chunks, n, 3), np.float32)
        g_opacity = np.zeros((chunks, n), np.float32)
        g_color = np.zeros((chunks, n, 3), np.float32)
        g_depth = np.zeros((chunks, n), np.float32)
        g_abs = np.zeros((chunks, n, 2), np.float32)
        nk.rasterize_backward(
            offsets, ids, mean2d, conic, opacity, color, depth, radius, sigma_max, width, height, T, last,
            _np32(v_rgb), _np32(v_dsum), _np32(v_T), chunks,
            g_mean2d, g_conic, g_opacity, g_color, g_depth, g_abs,
        )  # fmt: skip
        if ctx.stats is not None:
            ctx.stats["mean2d_absgrad"] = torch.from_numpy(g_abs.sum(0))
        out = [torch.from_numpy(a.sum(0)) for a in (g_mean2d, g_conic, g_opacity, g_color, g_depth)]
        return (*out, None, None, None, None)


def render_numba(
    g: Gaussians,
    viewmat: torch.Tensor | np.ndarray,
    K: torch.Tensor | np.ndarray,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    info: dict | None = None,
) -> RenderOutput:
    """Render on the CPU. Differentiable when any Gaussian tensor requires grad. When ``info`` is a
    dict it receives ``mean2d`` (the screen-space means, gradient retained), ``radius`` [N,2], and
    after backward ``mean2d_absgrad``: what 3DGS densification strategies read."""
    dtype = g.means.dtype
    viewmat64 = np.asarray(torch.as_tensor(viewmat).detach().cpu(), np.float64)
    K64 = np.asarray(torch.as_tensor(K).detach().cpu(), np.float64)
    needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in g.tensors().values())
    if needs_grad:
        p: Projected = project(g, torch.from_numpy(viewmat64), torch.from_numpy(K64), width, height)
        f32 = [t.to(torch.float32) for t in (p.mean2d, p.conic, p.opacity, p.color, p.depth)]
        if info is not None:
            f32[0].retain_grad()
            info.update(mean2d=f32[0], radius=p.radius)
        rgb, dsum, T = RasterizeNumba.apply(*f32, p.radius, width, height, info)
        return _finish(rgb, dsum, T, background, dtype)

    n = len(g)
    mean2d = np.empty((n, 2), np.float32)
    conic = np.empty((n, 3), np.float32)
    depth = np.empty(n, np.float32)
    opacity = np.empty(n, np.float32)
    color = np.empty((n, 3), np.float32)
    radius = np.empty((n, 2), np.float32)
    nk.project_fused(
        _np32(g.means), _np32(g.quats), _np32(g.log_scales), _np32(g.logit_opacities), _np32(g.sh),
        g.sh_degree, viewmat64, K64, width, height, mean2d, conic, depth, opacity, color, radius,
    )  # fmt: skip
    rgb, dsum, T, _, _ = _forward(mean2d, conic, opacity, color, depth, radius, width, height)
    if info is not None:
        info.update(mean2d=torch.from_numpy(mean2d), radius=torch.from_numpy(radius))
    return _finish(torch.from_numpy(rgb), torch.from_numpy(dsum), torch.from_numpy(T), background, dtype)
