"""Rendering backends with one signature:
``render(gaussians, viewmat [4,4] world-to-camera, K [3,3], width, height, background) -> RenderOutput``.

- ``cpu``: numba tile rasterizer (forward and backward), the default without a GPU;
- ``cuda``: gsplat 1.5.3, chosen automatically when CUDA is available;
- ``reference``: a slow dense pure-torch renderer for tests.
``backend="auto"`` picks cuda if available, else cpu; the ``M2M_RENDER_BACKEND`` environment
variable overrides "auto".
"""

from __future__ import annotations

import os

import torch

from ...errors import M2MError
from ..model import Gaussians
from .gsplat_cuda import cuda_available, render_gsplat
from .numba_cpu import render_numba
from .reference import render_reference
from .types import RenderOutput

BACKENDS = ("cpu", "cuda", "reference")


class BackendError(M2MError, ValueError):
    """A render backend that does not exist or cannot run here."""


def resolve_backend(backend: str = "auto") -> str:
    if backend == "auto":
        backend = os.environ.get("M2M_RENDER_BACKEND", "auto")
    if backend == "auto":
        return "cuda" if cuda_available() else "cpu"
    if backend not in BACKENDS:
        raise BackendError(f"unknown render backend {backend!r}; choose one of auto, {', '.join(BACKENDS)}")
    if backend == "cuda" and not cuda_available():
        raise BackendError("render backend 'cuda' needs a CUDA GPU, torch with CUDA and gsplat; use 'cpu'")
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
) -> RenderOutput:
    """Render ``gaussians`` (world frame) from the camera with world-to-camera ``viewmat`` and
    intrinsics ``K`` (pixel centres at +0.5). ``background`` [3] is composited behind."""
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    backend = resolve_backend(backend)
    if backend == "cpu":
        return render_numba(gaussians, viewmat, K, width, height, background, info)
    if backend == "cuda":
        return render_gsplat(gaussians, viewmat, K, width, height, background, info)
    return render_reference(gaussians, viewmat, K, width, height, background)


__all__ = [
    "BACKENDS",
    "BackendError",
    "RenderOutput",
    "render",
    "render_gsplat",
    "render_numba",
    "render_reference",
    "resolve_backend",
]
