"""Moving Gaussians by a similarity transform (DESIGN.md section 2)."""

from __future__ import annotations

import math

import torch

from ..geometry.rotation import matrix_to_quat, quat_multiply, quat_normalize
from ..geometry.sim3 import Sim3
from .model import Gaussians
from .sh_rotation import rotate_sh as _rotate_sh


def apply_sim3(g: Gaussians, sim3: Sim3, rotate_sh: bool = True) -> Gaussians:
    """Gaussians seen in the frame ``sim3`` maps into.

    means' = s R means + t;  quats' = q(R) * quats (normalised);  log_scales' = log_scales + log s;
    opacities unchanged (the same tensor);  SH bands rotated by R when ``rotate_sh`` (without it,
    view-dependent colour is wrong after any rotation). Covariances become s^2 R Sigma R^T.
    Pure torch ops on g's tensors: dtype and device are kept and autograd flows through.
    """
    means = sim3.apply(g.means)
    q_r = torch.as_tensor(matrix_to_quat(sim3.rotation), dtype=g.quats.dtype, device=g.quats.device)
    # |q_r| = 1, so normalising the product equals rotating the normalised input.
    quats = quat_normalize(quat_multiply(q_r.expand_as(g.quats), g.quats))
    log_scales = g.log_scales + math.log(sim3.scale)
    sh = _rotate_sh(g.sh, sim3.rotation) if rotate_sh else g.sh
    return Gaussians(means, quats, log_scales, g.logit_opacities, sh)
