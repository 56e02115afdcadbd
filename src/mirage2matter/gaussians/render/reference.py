"""Slow, dense pure-torch reference renderer. Tests compare the fast backends against it.

Every Gaussian is evaluated at every pixel (memory N x H x W), so it is only for small scenes.
It follows gsplat's rules exactly (see conventions.py) and is differentiable end to end.
"""

from __future__ import annotations

import torch

from ..model import Gaussians
from ..sh import sh_to_rgb
from .conventions import ALPHA_MAX, ALPHA_MIN, EPS2D, FAR_PLANE, FOV_CLAMP, NEAR_PLANE, T_MIN
from .types import RenderOutput


def _quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """[N,4] wxyz (any norm) -> [N,3,3]."""
    w, x, y, z = (q / q.norm(dim=-1, keepdim=True)).unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(-1, 3, 3)  # fmt: skip


def render_reference(
    g: Gaussians,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    max_elements: int = 1 << 24,
    antialias: bool = False,
) -> RenderOutput:
    """Render ``g`` (world frame) from a camera with world-to-camera ``viewmat`` [4,4] and ``K`` [3,3];
    ``antialias``: gsplat's "antialiased" mode (opacities times sqrt(det(cov2d) / det(cov2d + EPS2D I)))."""
    dtype, dev = g.means.dtype, g.means.device
    viewmat = torch.as_tensor(viewmat, dtype=dtype, device=dev)
    K = torch.as_tensor(K, dtype=dtype, device=dev)
    R_cw, t_cw = viewmat[:3, :3], viewmat[:3, 3]

    # Covariance in the world, then in the camera: Sigma = R diag(s^2) R^T.
    M = _quat_to_rotmat(g.quats) * torch.exp(g.log_scales)[:, None, :]
    cov_c = R_cw @ (M @ M.transpose(1, 2)) @ R_cw.T
    p_c = g.means @ R_cw.T + t_cw
    x, y, z = p_c.unbind(-1)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]

    # Perspective Jacobian at a clamped point, so Gaussians far outside the view stay bounded.
    lim_x_pos = (width - cx) / fx + FOV_CLAMP * 0.5 * width / fx
    lim_x_neg = cx / fx + FOV_CLAMP * 0.5 * width / fx
    lim_y_pos = (height - cy) / fy + FOV_CLAMP * 0.5 * height / fy
    lim_y_neg = cy / fy + FOV_CLAMP * 0.5 * height / fy
    tx = z * torch.minimum(lim_x_pos, torch.maximum(-lim_x_neg, x / z))
    ty = z * torch.minimum(lim_y_pos, torch.maximum(-lim_y_neg, y / z))
    zero = torch.zeros_like(z)
    J = torch.stack([fx / z, zero, -fx * tx / z**2, zero, fy / z, -fy * ty / z**2], -1).reshape(-1, 2, 3)
    cov2d_raw = J @ cov_c @ J.transpose(1, 2)
    cov2d = cov2d_raw + EPS2D * torch.eye(2, dtype=dtype, device=dev)
    det = cov2d[:, 0, 0] * cov2d[:, 1, 1] - cov2d[:, 0, 1] * cov2d[:, 1, 0]
    keep = (z > NEAR_PLANE) & (z < FAR_PLANE) & (det > 0)
    idx = keep.nonzero().flatten()
    idx = idx[torch.argsort(z[idx].detach(), stable=True)]  # front to back

    mean2d = torch.stack([fx * x / z + cx, fy * y / z + cy], -1)[idx]
    cov2d, det, depth = cov2d[idx], det[idx], z[idx]
    conic_a, conic_b, conic_c = cov2d[:, 1, 1] / det, -cov2d[:, 0, 1] / det, cov2d[:, 0, 0] / det
    opacity = torch.sigmoid(g.logit_opacities[idx])
    if antialias:
        raw = cov2d_raw[idx]
        det_raw = raw[:, 0, 0] * raw[:, 1, 1] - raw[:, 0, 1] * raw[:, 1, 0]
        opacity = opacity * torch.sqrt(det_raw.clamp_min(0.0) / det)
    campos = -R_cw.T @ t_cw
    color = sh_to_rgb(g.sh[idx], g.means[idx] - campos)

    bg = (
        torch.zeros(3, dtype=dtype, device=dev)
        if background is None
        else torch.as_tensor(background).to(dtype=dtype, device=dev)
    )
    n = idx.numel()
    rows_per_chunk = max(1, min(height, max_elements // max(1, n * width)))
    rgb_rows, alpha_rows, depth_rows = [], [], []
    px = torch.arange(width, dtype=dtype, device=dev) + 0.5  # pixel centres at +0.5
    for r0 in range(0, height, rows_per_chunk):
        py = torch.arange(r0, min(height, r0 + rows_per_chunk), dtype=dtype, device=dev) + 0.5
        dx = mean2d[:, 0, None, None] - px[None, None, :]  # [n,1,W]
        dy = mean2d[:, 1, None, None] - py[None, :, None]  # [n,h,1]
        sigma = (
            0.5 * (conic_a[:, None, None] * dx * dx + conic_c[:, None, None] * dy * dy)
            + conic_b[:, None, None] * dx * dy
        )
        alpha = torch.clamp_max(opacity[:, None, None] * torch.exp(-sigma), ALPHA_MAX)
        alpha = torch.where((sigma >= 0) & (alpha >= ALPHA_MIN), alpha, torch.zeros_like(alpha))
        one_minus = 1.0 - alpha
        T_after = torch.cumprod(one_minus, dim=0)
        # A pixel stops at the first Gaussian that would take it to T <= T_MIN (that one is left out);
        # T only falls, so "T_after > T_MIN" keeps exactly the Gaussians before the stop.
        used = (T_after > T_MIN).to(dtype)
        T_before = torch.cat([torch.ones_like(T_after[:1]), T_after[:-1]], 0)
        weight = alpha * T_before * used  # [n,h,W]
        T_final = torch.prod(1.0 - alpha * used, dim=0)  # [h,W]
        rgb_rows.append(torch.einsum("nhw,nc->hwc", weight, color) + T_final[..., None] * bg)
        acc = 1.0 - T_final
        depth_rows.append(torch.einsum("nhw,n->hw", weight, depth) / acc.clamp_min(1e-10))
        alpha_rows.append(acc)
    return RenderOutput(torch.cat(rgb_rows, 0), torch.cat(alpha_rows, 0), torch.cat(depth_rows, 0))
