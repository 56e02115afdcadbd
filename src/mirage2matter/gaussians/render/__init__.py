"""Rendering backends with one signature:
``render(gaussians, viewmat [4,4] world-to-camera, K [3,3], width, height, background) -> RenderOutput``.

- ``cpu``: numba tile rasterizer (forward and backward), the default without a GPU;
- ``cuda``: gsplat 1.5.3, chosen automatically when CUDA is available;
- ``reference``: a slow dense pure-torch renderer for tests.
``backend="auto"`` picks cuda if available, else cpu; the ``M2M_RENDER_BACKEND`` environment
variable overrides "auto".

``render`` is the one dispatch point, so the guards live here: an empty Gaussian set renders the
background on every backend without reaching a rasterizer (gsplat 1.5.3's ``fully_fused_projection``
dies with SIGFPE on N = 0, killing the process: an object pruned to nothing, a culled world part), and
a CUDA out-of-memory becomes a :class:`GpuOutOfMemory` that says what to lower.
"""

from __future__ import annotations

import os

import torch

from ...errors import M2MError
from ..model import Gaussians
from .gsplat_cuda import (
    cuda_available,
    cuda_unavailable_reason,
    render_gsplat,
    render_gsplat_batch,
    render_gsplat_cameras,
)
from .numba_cpu import render_numba
from .reference import render_reference
from .types import RenderOutput

BACKENDS = ("cpu", "cuda", "reference")


class BackendError(M2MError, ValueError):
    """A render backend that does not exist or cannot run here."""


class GpuOutOfMemory(M2MError, RuntimeError):
    """The GPU ran out of memory; the message says what to lower."""


def gpu_out_of_memory(what: str, n_gaussians: int, width: int, height: int, lower: str) -> GpuOutOfMemory:
    """A :class:`GpuOutOfMemory` for ``what`` (e.g. "rendering") of ``n_gaussians`` at ``width`` x ``height``,
    naming the memory the GPU has and ``lower`` (the settings that shrink the work, e.g. "--max-gaussians")."""
    total = ""
    try:
        free, size = torch.cuda.mem_get_info()
        total = f" ({free / 2**30:.1f} of {size / 2**30:.1f} GiB free)"
    except Exception:  # the query itself may fail on a GPU in a bad state; the message stands without it
        pass
    return GpuOutOfMemory(
        f"GPU out of memory {what} {n_gaussians:,} Gaussians at {width}x{height}{total}; lower {lower}, "
        "free the GPU of other processes, or use --backend cpu"
    )


def resolve_backend(backend: str = "auto") -> str:
    if backend == "auto":
        backend = os.environ.get("M2M_RENDER_BACKEND", "auto")
    if backend == "auto":
        return "cuda" if cuda_available() else "cpu"
    if backend not in BACKENDS:
        raise BackendError(f"unknown render backend {backend!r}; choose one of auto, {', '.join(BACKENDS)}")
    if backend == "cuda":
        why = cuda_unavailable_reason()
        if why is not None:
            raise BackendError(f"render backend 'cuda' needs a CUDA GPU, torch with CUDA and gsplat: {why}; use 'cpu'")
    return backend


def render(
    gaussians: Gaussians,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    backend: str = "auto",
    info: dict | None = None,
    antialias: bool = False,
) -> RenderOutput:
    """Render ``gaussians`` (world frame) from the camera with world-to-camera ``viewmat`` and
    intrinsics ``K`` (pixel centres at +0.5). ``background`` [3] is composited behind.

    ``antialias``: gsplat's "antialiased" mode (Mip-Splatting's 2D filter): each Gaussian's opacity is scaled by
    sqrt(det(cov2d) / det(cov2d + EPS2D I)), so the low-pass that widens a sub-pixel Gaussian keeps its energy
    instead of its peak. For rendering a scene smaller (farther, at a lower resolution) than it was trained:
    classic mode draws thin things fat there. No gradient on the cpu backend."""
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    backend = resolve_backend(backend)
    if len(gaussians) == 0:
        return _render_nothing(gaussians, width, height, background, info)
    if backend == "cpu":
        return render_numba(gaussians, viewmat, K, width, height, background, info, antialias)
    if backend == "cuda":
        try:
            return render_gsplat(gaussians, viewmat, K, width, height, background, info, antialias)
        except torch.cuda.OutOfMemoryError as e:
            lower = "the number of Gaussians (--max-gaussians) or the image size (--downscale / --size)"
            raise gpu_out_of_memory("rendering", len(gaussians), width, height, lower) from e
    return render_reference(gaussians, viewmat, K, width, height, background, antialias=antialias)


def render_cameras(
    gaussians: Gaussians,
    viewmats: torch.Tensor,
    Ks: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    backend: str = "auto",
    antialias: bool = False,
) -> RenderOutput:
    """``render`` from C cameras at once (viewmats [C,4,4] world-to-camera, Ks [C,3,3], one image size):
    rgb [C,H,W,3], alpha and depth [C,H,W]. The cuda backend makes one gsplat call for all of them (what a
    GPU needs at small sizes); the others render camera by camera, so every backend gives the same images."""
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    viewmats, Ks = torch.as_tensor(viewmats), torch.as_tensor(Ks)
    if viewmats.ndim != 3 or viewmats.shape[1:] != (4, 4) or Ks.shape != (len(viewmats), 3, 3):
        raise ValueError(f"render_cameras needs viewmats [C,4,4] and Ks [C,3,3], got {tuple(viewmats.shape)} "
                         f"and {tuple(Ks.shape)}")  # fmt: skip
    backend = resolve_backend(backend)
    if backend == "cuda" and len(gaussians) > 0 and len(viewmats) > 0:
        try:
            return render_gsplat_cameras(gaussians, viewmats, Ks, width, height, background, antialias)
        except torch.cuda.OutOfMemoryError as e:
            lower = "the number of Gaussians, the image size or the cameras per call"
            raise gpu_out_of_memory(f"rendering {len(viewmats)} cameras of", len(gaussians), width, height,
                                    lower) from e  # fmt: skip
    outs = [render(gaussians, vm, K, width, height, background, backend, antialias=antialias)
            for vm, K in zip(viewmats, Ks, strict=True)]
    if not outs:  # no cameras: empty stacks of the right shapes
        none = gaussians.means.new_zeros(0, height, width)
        return RenderOutput(none[..., None].expand(0, height, width, 3), none, none.clone())
    return RenderOutput(*(torch.stack([getattr(o, k) for o in outs]) for k in ("rgb", "alpha", "depth")))


def _render_nothing(
    g: Gaussians, width: int, height: int, background: torch.Tensor | None, info: dict | None
) -> RenderOutput:
    """What every backend renders of an empty set: the background, alpha 0, depth 0, on the Gaussians'
    device and dtype. The output still depends on the (empty) tensors, so ``backward`` gives each its
    empty gradient, as a rendered set would; ``info`` gets empty screen-space means and radii."""
    dev, dtype = g.means.device, g.means.dtype
    zero = sum(t.sum() for t in g.tensors().values()) * 0.0  # 0 with a graph to every tensor when they need it
    bg = torch.zeros(3, dtype=dtype, device=dev) if background is None else torch.as_tensor(background)
    rgb = bg.to(dev, dtype).expand(height, width, 3) + zero
    alpha = torch.zeros(height, width, dtype=dtype, device=dev) + zero
    if info is not None:
        info.update(mean2d=torch.zeros(0, 2, device=dev), radius=torch.zeros(0, 2, dtype=torch.int32, device=dev))
    return RenderOutput(rgb, alpha, alpha.clone())


__all__ = [
    "BACKENDS",
    "BackendError",
    "GpuOutOfMemory",
    "RenderOutput",
    "render",
    "render_cameras",
    "render_gsplat",
    "render_gsplat_batch",
    "render_gsplat_cameras",
    "render_numba",
    "render_reference",
    "resolve_backend",
    "gpu_out_of_memory",
]
