"""Moving Gaussians by a similarity transform (DESIGN.md section 2)."""

from __future__ import annotations

import math

import numpy as np
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


def apply_rigid_batch(
    g: Gaussians, scale: float | np.ndarray, R: np.ndarray, t: np.ndarray
) -> dict[str, torch.Tensor]:
    """:func:`apply_sim3` of ``g`` for B poses at once: ``scale`` one float for all (an object's placement scale, the
    rigid physics pose varying) or [B] (copies drawn at their own scale); R [B,3,3], t [B,3] numpy -> {"means"
    [B,N,3], "quats" [B,N,4], "log_scales" [B,N,3], "sh" [B,N,K,3]} on g's device and dtype (opacities unchanged,
    not returned). The small per-pose matrices (sR, q(R), log s, the SH rotation) are made on the CPU and sent in one
    transfer: on a GPU, posing B copies of an object costs a handful of kernels, not a handful per copy. No autograd
    through R and t."""
    from .sh_rotation import sh_rotation_matrix

    R, t = np.asarray(R, np.float64), np.asarray(t, np.float64)
    B = len(R)
    s = np.broadcast_to(np.asarray(scale, np.float64), (B,))
    D = sh_rotation_matrix(R, g.sh_degree).numpy()  # [B,K,K]
    q = matrix_to_quat(R)  # [B,4]
    small = np.concatenate([(s[:, None, None] * R).reshape(B, 9), t, q, np.log(s)[:, None], D.reshape(B, -1)], axis=1)
    small = torch.as_tensor(small).to(g.means.device, g.means.dtype)
    sR, tt, qq, ls = small[:, :9].reshape(B, 3, 3), small[:, 9:12], small[:, 12:16], small[:, 16]
    Dk = small[:, 17:].reshape(D.shape)
    n = len(g)
    return {
        "means": g.means @ sR.transpose(1, 2) + tt[:, None],
        "quats": quat_normalize(quat_multiply(qq[:, None].expand(B, n, 4), g.quats.expand(B, n, 4))),
        "log_scales": g.log_scales + ls[:, None, None],
        "sh": torch.einsum("bij,njc->bnic", Dk, g.sh),
    }
