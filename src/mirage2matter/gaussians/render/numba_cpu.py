"""CPU backend: numba tile rasterizer, forward and backward, wrapped for torch autograd.

Without gradients everything runs in numba (projection, SH colour, sort, binning, compositing).
With gradients, ``ProjectNumba`` (numba_projection.py: projection + SH colour, hand-written backward,
tested against the torch projection.py) and ``RasterizeNumba`` supply the backward, so the whole render is
differentiable w.r.t. every Gaussian parameter.
"""

from __future__ import annotations

import numba
import numpy as np
import torch

from ..model import Gaussians
from . import numba_kernels as nk
from .numba_projection import ProjectNumba
from .types import RenderOutput


def project(g: Gaussians, viewmat64: np.ndarray, K64: np.ndarray, width: int, height: int):
    """Differentiable projection: (mean2d, conic, depth, opacity, color, radius) float32 tensors."""
    return ProjectNumba.apply(g.means, g.quats, g.log_scales, g.logit_opacities, g.sh, viewmat64, K64, width, height)


def _np32(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).numpy())


def _tile_lists(rec: np.ndarray, width: int, height: int):
    """Sort and bin records rec [N, REC_SIZE]: (offsets [n_tiles+1], ids [n_isect], recs [n_isect, REC_SIZE]),
    tile t's records front to back in recs[offsets[t]:offsets[t+1]]."""
    n = rec.shape[0]
    rect = np.empty((n, 4), np.int32)
    nk.tile_rects(rec, width, height, rect)
    visible = np.flatnonzero(rect[:, 0] <= rect[:, 1]).astype(np.int32)
    depth_bits = np.ascontiguousarray(rec[:, nk.REC_DEPTH]).view(np.uint32)
    order = nk.argsort_by_depth(visible, depth_bits)
    offsets, ids = nk.bin_tiles(order, rect, width, height, nk.num_threads())
    recs = np.empty((ids.shape[0], nk.REC_SIZE), np.float32)
    nk.gather_records(ids, rec.view(np.complex128), recs.view(np.complex128))
    return offsets, ids, recs


def _rasterize(rec: np.ndarray, width: int, height: int):
    """Sort, bin and composite records rec [N, REC_SIZE]. Returns the raw sums (rgb [H,W,3], depth
    [H,W]), final transmittance T [H,W], and what the backward pass needs."""
    offsets, ids, recs = _tile_lists(rec, width, height)
    rgb = np.empty((height, width, 3), np.float32)
    dsum = np.empty((height, width), np.float32)
    T = np.empty((height, width), np.float32)
    last = np.empty((height, width), np.int32)
    with numba.parallel_chunksize(1):  # tiles differ a lot in cost: hand them out one at a time
        nk.rasterize_forward(offsets, recs, width, height, rgb, dsum, T, last)
    return rgb, dsum, T, (last, offsets, ids, recs)


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
        rec = np.empty((mean2d.shape[0], nk.REC_SIZE), np.float32)
        nk.pack_records(*(_np32(t) for t in (mean2d, conic, opacity, color, depth, radius)), rec)
        rgb, dsum, T, saved = _rasterize(rec, width, height)
        ctx.saved, ctx.T, ctx.n = saved, T, rec.shape[0]
        ctx.size, ctx.stats = (width, height), stats
        return torch.from_numpy(rgb), torch.from_numpy(dsum), torch.from_numpy(T)

    @staticmethod
    def backward(ctx, v_rgb, v_dsum, v_T):
        last, offsets, ids, recs = ctx.saved
        width, height = ctx.size
        n = ctx.n
        chunks = max(1, nk.num_threads())
        g_mean2d = np.zeros((chunks, n, 2), np.float32)
        g_conic = np.zeros((chunks, n, 3), np.float32)
        g_opacity = np.zeros((chunks, n), np.float32)
        g_color = np.zeros((chunks, n, 3), np.float32)
        g_depth = np.zeros((chunks, n), np.float32)
        g_abs = np.zeros((chunks, n, 2), np.float32)
        nk.rasterize_backward(
            offsets, ids, recs, width, height, ctx.T, last,
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
    antialias: bool = False,
) -> RenderOutput:
    """Render on the CPU. Differentiable when any Gaussian tensor requires grad. When ``info`` is a
    dict it receives ``mean2d`` (the screen-space means, gradient retained), ``radius`` [N,2], and
    after backward ``mean2d_absgrad``: what 3DGS densification strategies read. ``antialias``: gsplat's
    "antialiased" mode (see ``render``), without gradients only."""
    dtype = g.means.dtype
    viewmat64 = np.asarray(torch.as_tensor(viewmat).detach().cpu(), np.float64)
    K64 = np.asarray(torch.as_tensor(K).detach().cpu(), np.float64)
    needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in g.tensors().values())
    if needs_grad:
        if antialias:
            raise NotImplementedError(
                "antialiased rendering has no gradient on the CPU backend; train with antialias=False (the "
                "classic mode 3DGS is trained in) and antialias only the renders"
            )
        mean2d, conic, depth, opacity, color, radius = project(g, viewmat64, K64, width, height)
        if info is not None:
            mean2d.retain_grad()
            info.update(mean2d=mean2d, radius=radius)
        rgb, dsum, T = RasterizeNumba.apply(mean2d, conic, opacity, color, depth, radius, width, height, info)
        return _finish(rgb, dsum, T, background, dtype)

    rec = np.empty((len(g), nk.REC_SIZE), np.float32)
    nk.project_fused(
        _np32(g.means), _np32(g.quats), _np32(g.log_scales), _np32(g.logit_opacities), _np32(g.sh),
        g.sh_degree, viewmat64, K64, width, height, rec, antialias,
    )  # fmt: skip
    rgb, dsum, T, _ = _rasterize(rec, width, height)
    if info is not None:
        radius = torch.from_numpy(rec[:, nk.REC_RADIUS_X : nk.REC_RADIUS_Y + 1].copy())
        info.update(mean2d=torch.from_numpy(rec[:, : nk.REC_MEAN_Y + 1].copy()), radius=radius)
    return _finish(torch.from_numpy(rgb), torch.from_numpy(dsum), torch.from_numpy(T), background, dtype)


def opacity_levels_numba(
    g: Gaussians, viewmat: np.ndarray, K: np.ndarray, width: int, height: int, levels: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(A [L,H,W], alpha [H,W]) float64: the opacity each pixel accumulates from the Gaussians (world frame) whose
    centres lie in front of camera depth ``levels`` [L] (ascending, metres), and from all of them; one pass of
    the rasterizer instead of one render per level."""
    levels = np.ascontiguousarray(levels, np.float64)
    A = np.zeros((len(levels), height, width))
    T = np.ones((height, width))
    if len(g):
        rec = np.empty((len(g), nk.REC_SIZE), np.float32)
        nk.project_fused(
            _np32(g.means), _np32(g.quats), _np32(g.log_scales), _np32(g.logit_opacities), _np32(g.sh[:, :1]),
            0, np.asarray(viewmat, np.float64), np.asarray(K, np.float64), width, height, rec, False,
        )  # fmt: skip
        offsets, _, recs = _tile_lists(rec, width, height)
        with numba.parallel_chunksize(1):
            nk.opacity_levels(offsets, recs, width, height, levels, A, T)
    return A, 1.0 - T
