"""CUDA backend: gsplat 1.5.3's rasterization (classic 3DGS mode, or its antialiased mode on request; packed=False,
expected depth)."""

from __future__ import annotations

import functools

import torch

from ..model import Gaussians
from .conventions import EPS2D, FAR_PLANE, NEAR_PLANE
from .types import RenderOutput


def cuda_unavailable_reason() -> str | None:
    """None when the cuda backend can run here, else why it cannot (for an error message)."""
    if not torch.cuda.is_available():
        built = f"built with CUDA {torch.version.cuda}" if torch.version.cuda else "a CPU-only build"
        return f"torch sees no CUDA GPU (torch {torch.__version__}, {built})"
    return _gsplat_kernels_problem()


@functools.cache
def _gsplat_kernels_problem() -> str | None:
    # gsplat imports without CUDA and, with no CUDA toolkit to JIT-build its kernels, leaves them None:
    # the first render would then fail with "'NoneType' object has no attribute ...". Loading the kernels
    # here (the JIT build, ~1 min once per machine) turns that into a reason given before any work.
    try:
        import gsplat  # noqa: F401
    except Exception as e:  # ImportError, or a dependency gsplat needs (e.g. packaging) missing
        return f"gsplat does not import ({e!r}); pip install gsplat"
    try:
        from gsplat.cuda._backend import _C
    except Exception as e:  # a failed JIT build raises from torch.utils.cpp_extension
        return f"gsplat's CUDA kernels failed to build or load ({e!r})"
    if _C is None:
        return "gsplat found no CUDA toolkit to build its kernels (install one and set CUDA_HOME)"
    return None


def cuda_available() -> bool:
    return cuda_unavailable_reason() is None


def _rasterize(g: Gaussians, viewmats: torch.Tensor, Ks: torch.Tensor, width: int, height: int, background,
               antialias: bool = False):
    """gsplat's rasterization of ``g`` from C cameras (viewmats [C,4,4], Ks [C,3,3]) in one call:
    -> (renders [C,H,W,4] RGB + expected depth, alphas [C,H,W,1], meta), on the GPU."""
    return _rasterize_tensors(g.tensors(), g.sh_degree, viewmats, Ks, width, height, background, antialias)


def _rasterize_tensors(t: dict[str, torch.Tensor], sh_degree: int, viewmats: torch.Tensor, Ks: torch.Tensor,
                       width: int, height: int, background, antialias: bool = False):
    """:func:`_rasterize` of Gaussians given as their tensors (``Gaussians.tensors()`` names), each with the same
    leading batch dims ``[..., N, ...]`` (``[...]`` empty for one set) and cameras ``[..., C, 4, 4]``."""
    if not torch.cuda.is_available():
        raise RuntimeError("backend 'cuda' needs a CUDA GPU and torch with CUDA; use backend='cpu'")
    from gsplat import rasterization

    means = t["means"]
    dev = means.device if means.is_cuda else torch.device("cuda")
    gc = {k: v.to(dev, torch.float32) for k, v in t.items()}
    viewmats = torch.as_tensor(viewmats, dtype=torch.float32).to(dev)
    Ks = torch.as_tensor(Ks, dtype=torch.float32).to(dev)
    bg = None
    if background is not None:
        bg = torch.as_tensor(background, dtype=torch.float32).to(dev).expand(*viewmats.shape[:-2], 3)
    return rasterization(
        gc["means"],
        gc["quats"],
        torch.exp(gc["log_scales"]),
        torch.sigmoid(gc["logit_opacities"]),
        gc["sh"],
        viewmats,
        Ks,
        width,
        height,
        near_plane=NEAR_PLANE,
        far_plane=FAR_PLANE,
        eps2d=EPS2D,
        sh_degree=sh_degree,
        packed=False,
        render_mode="RGB+ED",
        backgrounds=bg,
        rasterize_mode="antialiased" if antialias else "classic",
    )


def _output(g: Gaussians, renders: torch.Tensor, alphas: torch.Tensor) -> RenderOutput:
    """gsplat's [..., H, W, 4] renders and [..., H, W, 1] alphas as a RenderOutput on ``g``'s device and dtype."""
    to = lambda t: t.to(g.means.device, g.means.dtype)
    return RenderOutput(to(renders[..., :3]), to(alphas[..., 0]), to(renders[..., 3]))


def render_gsplat_cameras(
    g: Gaussians,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    antialias: bool = False,
) -> RenderOutput:
    """C cameras (viewmats [C,4,4], Ks [C,3,3]) in one gsplat call: rgb [C,H,W,3], alpha and depth [C,H,W].
    One call amortises the per-call set-up that dominates small images (at 224x224 a camera alone leaves
    most of the GPU idle), e.g. the head and wrist views of a frame, or many episodes' frames."""
    renders, alphas, _ = _rasterize(g, viewmats, Ks, width, height, background, antialias)
    return _output(g, renders, alphas)


def render_gsplat_batch(
    tensors: dict[str, torch.Tensor],
    sh_degree: int,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    antialias: bool = False,
) -> RenderOutput:
    """B Gaussian sets of equal size N (``Gaussians.tensors()`` names, each ``[B, N, ...]``: e.g. one world posed
    for B episodes) from C cameras each (viewmats [B,C,4,4], Ks [B,C,3,3]) in one gsplat call: rgb [B,C,H,W,3],
    alpha and depth [B,C,H,W], float32 on the GPU."""
    renders, alphas, _ = _rasterize_tensors(tensors, sh_degree, viewmats, Ks, width, height, background, antialias)
    return RenderOutput(renders[..., :3].float(), alphas[..., 0].float(), renders[..., 3].float())


def render_gsplat(
    g: Gaussians,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    info: dict | None = None,
    antialias: bool = False,
) -> RenderOutput:
    """Render with gsplat on the GPU; the Gaussians are moved to CUDA if they are not there."""
    renders, alphas, meta = _rasterize(g, torch.as_tensor(viewmat)[None], torch.as_tensor(K)[None], width, height,
                                       None if background is None else torch.as_tensor(background)[None],
                                       antialias)  # fmt: skip
    if info is not None:
        # Same contract as the cpu backend: screen-space means with their gradient retained (here
        # gsplat's [1,N,2] layout; the rendering read that tensor, so only it receives .grad).
        mean2d = meta["means2d"]
        if mean2d.requires_grad:
            mean2d.retain_grad()
        info.update(mean2d=mean2d, radius=meta["radii"][0], meta=meta)
    return _output(g, renders[0], alphas[0])
