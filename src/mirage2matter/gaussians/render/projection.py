"""Differentiable EWA projection of 3D Gaussians to screen space, in torch.

Used by the CPU backend when gradients are needed (training): autograd differentiates this part
and the numba kernels differentiate the rasterization. The forward-only path uses the fused numba
projection instead; a test keeps the two in agreement.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..model import Gaussians
from ..sh import sh_to_rgb
from .conventions import ALPHA_MIN, EPS2D, FAR_PLANE, FOV_CLAMP, NEAR_PLANE


@dataclass
class Projected:
    """Per-Gaussian screen-space quantities; culled Gaussians have radius 0 and finite dummies."""

    mean2d: torch.Tensor  # [N,2] pixels
    conic: torch.Tensor  # [N,3] (a, b, c) of the inverse 2D covariance [[a, b], [b, c]]
    depth: torch.Tensor  # [N] camera z
    opacity: torch.Tensor  # [N]
    color: torch.Tensor  # [N,3]
    radius: torch.Tensor  # [N,2] box half-widths in pixels (no gradient)


def quat_scale_to_camera_factor(quats: torch.Tensor, log_scales: torch.Tensor, R_cw: torch.Tensor) -> torch.Tensor:
    """C [N,3,3] with camera-frame covariance C C^T = R_cw R(q) diag(s^2) R(q)^T R_cw^T."""
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    R = torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(-1, 3, 3)  # fmt: skip
    return R_cw @ (R * torch.exp(log_scales)[:, None, :])


def project(g: Gaussians, viewmat: torch.Tensor, K: torch.Tensor, width: int, height: int) -> Projected:
    dtype, dev = g.means.dtype, g.means.device
    viewmat = torch.as_tensor(viewmat, dtype=dtype, device=dev)
    K = torch.as_tensor(K, dtype=dtype, device=dev)
    R_cw, t_cw = viewmat[:3, :3], viewmat[:3, 3]
    p_c = g.means @ R_cw.T + t_cw
    z_raw = p_c[:, 2]
    in_depth = (z_raw > NEAR_PLANE) & (z_raw < FAR_PLANE)
    # Culled Gaussians get a harmless depth so no NaN/Inf reaches autograd (0 * inf = NaN).
    z = torch.where(in_depth, z_raw, torch.ones_like(z_raw))
    x, y = p_c[:, 0], p_c[:, 1]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    half_x, half_y = 0.5 * width / fx, 0.5 * height / fy
    u_c = torch.clamp(x / z, -(cx / fx + FOV_CLAMP * half_x), (width - cx) / fx + FOV_CLAMP * half_x)
    v_c = torch.clamp(y / z, -(cy / fy + FOV_CLAMP * half_y), (height - cy) / fy + FOV_CLAMP * half_y)
    # Rows of J C: J = [[fx/z, 0, -fx u_c/z], [0, fy/z, -fy v_c/z]] (u_c = tx/z)
    C = quat_scale_to_camera_factor(g.quats, g.log_scales, R_cw)
    rows_x = (fx / z)[:, None] * (C[:, 0] - u_c[:, None] * C[:, 2])
    rows_y = (fy / z)[:, None] * (C[:, 1] - v_c[:, None] * C[:, 2])
    cov_xx = (rows_x * rows_x).sum(-1) + EPS2D
    cov_xy = (rows_x * rows_y).sum(-1)
    cov_yy = (rows_y * rows_y).sum(-1) + EPS2D
    det = cov_xx * cov_yy - cov_xy * cov_xy
    ok_det = det > 0
    det_safe = torch.where(ok_det, det, torch.ones_like(det))
    conic = torch.stack([cov_yy / det_safe, -cov_xy / det_safe, cov_xx / det_safe], -1)
    mean2d = torch.stack([fx * x / z + cx, fy * y / z + cy], -1)
    opacity = torch.sigmoid(g.logit_opacities)
    campos = -R_cw.T @ t_cw
    color = sh_to_rgb(g.sh, g.means - campos)

    with torch.no_grad():
        op = opacity.clamp_min(ALPHA_MIN)
        extend = torch.sqrt(2.0 * torch.log(op / ALPHA_MIN)).clamp_max(3.33)
        rx = torch.ceil(extend * torch.sqrt(cov_xx.clamp_min(0)))
        ry = torch.ceil(extend * torch.sqrt(cov_yy.clamp_min(0)))
        u, v = mean2d[:, 0], mean2d[:, 1]
        keep = in_depth & ok_det & (opacity >= ALPHA_MIN)
        keep &= (u + rx > 0) & (u - rx < width) & (v + ry > 0) & (v - ry < height)
        radius = torch.where(keep[:, None], torch.stack([rx, ry], -1), torch.zeros_like(mean2d))
    return Projected(mean2d, conic, z, opacity, color, radius.detach())
