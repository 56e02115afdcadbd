"""Mip-Splatting's 3D smoothing filter (Yu et al., CVPR 2024, section 4.1): each Gaussian is convolved with an
isotropic Gaussian as wide as the finest pixel any training view sampled it at, so no Gaussian is thinner than
what the photos could resolve. Without it, 3DGS fits sub-pixel spikes that sparkle when the scene is seen closer
or at a higher resolution than it was trained at (the head photo at full size from a scene trained at half; a
wrist camera close to the table). Trained with it, the model learns under the same low-pass it is rendered with,
and the filtered Gaussians are ordinary ones: any renderer draws them.

The filter of Gaussian i has variance ``variance / nu_i^2`` (world units), where ``nu_i`` is the largest
sampling rate focal / depth (pixels per world unit) over the training views whose image (with a 15 % margin)
holds its centre; Gaussians no view sees get the widest filter of those seen.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from .config import FILTER_3D_VARIANCE
from .model import Gaussians

__all__ = ["FILTER_3D_VARIANCE", "apply_3d_filter", "check_variance", "max_sampling_rate"]



def check_variance(variance: float) -> None:
    """ValueError unless ``variance`` is a usable filter variance: 0 (off) to 4 squared pixels (a 2-pixel blur)."""
    if not 0 <= variance <= 4:
        raise ValueError(f"filter_3d is a variance in squared pixels in [0, 4] (0: off, {FILTER_3D_VARIANCE}: "
                         f"Mip-Splatting's), got {variance}")  # fmt: skip


def max_sampling_rate(means: torch.Tensor, views: Sequence) -> torch.Tensor:
    """[N] the largest focal / depth (pixels per world unit) over ``views`` (each with ``viewmat`` [4,4]
    world-to-camera, ``K`` [3,3], ``width``, ``height``) whose image, 15 % wider each way, holds the point
    ``means`` [N,3]; points no view holds get the smallest rate of those held (0 if none is)."""
    m = means.detach().to("cpu", torch.float64)
    nu = torch.zeros(len(m), dtype=torch.float64)
    for v in {id(v): v for v in views}.values():  # a view listed twice (the head photo, repeated) projects once
        vm = torch.as_tensor(v.viewmat, dtype=torch.float64).cpu()
        K = torch.as_tensor(v.K, dtype=torch.float64).cpu()
        pc = m @ vm[:3, :3].T + vm[:3, 3]
        z = pc[:, 2]
        zs = z.clamp_min(1e-9)
        u = pc[:, 0] / zs * K[0, 0] + K[0, 2]
        w = pc[:, 1] / zs * K[1, 1] + K[1, 2]
        W, H = float(v.width), float(v.height)
        inside = (z > 1e-6) & (u >= -0.15 * W) & (u <= 1.15 * W) & (w >= -0.15 * H) & (w <= 1.15 * H)
        nu = torch.where(inside, torch.maximum(nu, float(K[0, 0]) / zs), nu)
    seen = nu > 0
    if bool(seen.any()) and not bool(seen.all()):
        nu[~seen] = nu[seen].min()
    return nu.to(means.device, torch.float32)


def apply_3d_filter(g: Gaussians, nu: torch.Tensor, variance: float = FILTER_3D_VARIANCE) -> Gaussians:
    """``g`` convolved with its 3D filters (``nu`` [N] from :func:`max_sampling_rate`): each axis' variance
    grows by ``variance / nu^2`` and the opacity shrinks by sqrt(det before / det after), so a Gaussian's
    integral is kept. Differentiable in ``g``; Gaussians with ``nu`` 0 are left as they are."""
    if len(nu) != len(g):
        raise ValueError(f"the 3D filter has {len(nu)} sampling rates for {len(g)} Gaussians; recompute them")
    var = torch.where(nu > 0, variance / nu.clamp_min(1e-12) ** 2, torch.zeros_like(nu))[:, None]
    log_s2 = 2.0 * g.log_scales
    log_new = torch.log(torch.exp(log_s2) + var)
    log_coef = 0.5 * (log_s2 - log_new).sum(dim=1)  # log sqrt(det before / det after) <= 0
    # logit(sigmoid(x) c) computed stably: log(o c) - log(1 - o c)
    log_o = torch.nn.functional.logsigmoid(g.logit_opacities) + log_coef
    log_o = log_o.clamp(max=-1e-7)
    logit = log_o - torch.log(-torch.expm1(log_o))
    return Gaussians(g.means, g.quats, 0.5 * log_new, logit, g.sh)
