"""Photometric losses and metrics for 3DGS training: L1, SSIM (Gaussian window) and PSNR.

Images are torch tensors in [0, 1], either one image [H,W,3] or a batch [B,3,H,W]. Every function
takes an optional valid-pixel ``mask`` ([H,W] or [B,H,W], bool): pixels outside it (e.g. the
invalid border left by undistortion) contribute neither to the value nor to the gradient.
"""

from __future__ import annotations

import math

import torch

__all__ = ["gaussian_window", "l1", "psnr", "ssim"]

_C1 = 0.01**2  # (K1 * data_range)^2 with data range 1, as in Wang et al. 2004
_C2 = 0.03**2


def _as_batch(img: torch.Tensor) -> torch.Tensor:
    """[H,W,3] -> [1,3,H,W]; [B,3,H,W] passes through."""
    if img.ndim == 3 and img.shape[-1] == 3:
        return img.permute(2, 0, 1)[None]
    if img.ndim == 4:
        return img
    raise ValueError(f"expected an image [H,W,3] or a batch [B,3,H,W], got shape {tuple(img.shape)}")


def _mask_batch(mask: torch.Tensor | None, like: torch.Tensor) -> torch.Tensor | None:
    """[H,W] or [B,H,W] -> bool [B,1,H,W] matching the batch ``like`` [B,C,H,W]."""
    if mask is None:
        return None
    m = mask.to(device=like.device, dtype=torch.bool)
    if m.ndim == 2:
        m = m[None]
    if m.ndim != 3 or m.shape[-2:] != like.shape[-2:]:
        raise ValueError(f"mask must be [H,W] or [B,H,W] matching images {tuple(like.shape)}, got {tuple(mask.shape)}")
    return m[:, None].expand(like.shape[0], 1, *like.shape[-2:])


def l1(img1: torch.Tensor, img2: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean absolute difference over the valid pixels (and channels). Returns a scalar."""
    a, b = _as_batch(img1), _as_batch(img2)
    m = _mask_batch(mask, a)
    diff = (a - b).abs()
    if m is None:
        return diff.mean()
    m = m.expand_as(diff)
    # where, not diff[m]: boolean indexing copies and its backward scatters (3x slower at 480x270)
    return torch.where(m, diff, 0.0).sum() / m.sum().clamp_min(1)


def psnr(img1: torch.Tensor, img2: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """PSNR in dB for data range 1, from the MSE over the valid pixels. Returns a scalar."""
    a, b = _as_batch(img1), _as_batch(img2)
    m = _mask_batch(mask, a)
    sq = (a - b) ** 2
    mse = sq.mean() if m is None else sq[m.expand_as(sq)].sum() / m.expand_as(sq).sum().clamp_min(1)
    return -10.0 * torch.log10(mse.clamp_min(1e-12))


def gaussian_window(window: int = 11, sigma: float = 1.5, dtype=torch.float32, device=None) -> torch.Tensor:
    """Normalised 1D Gaussian [window] centred on the middle tap."""
    x = torch.arange(window, dtype=torch.float64) - (window - 1) / 2
    w = torch.exp(-(x**2) / (2 * sigma**2))
    return (w / w.sum()).to(dtype=dtype, device=device)


def _blur(x: torch.Tensor, w1: torch.Tensor) -> torch.Tensor:
    """Separable 'valid' Gaussian filter over the last two axes: [..., H, W] -> [..., H-k+1, W-k+1].

    Written as k shifted multiply-adds per axis: on the CPU this is several times faster than
    torch's depthwise conv2d for images of this size, forward and backward."""
    k = w1.shape[0]
    w, h = x.shape[-1] - k + 1, x.shape[-2] - k + 1
    y = w1[0] * x[..., :, 0:w]
    for i in range(1, k):
        y = y + w1[i] * x[..., :, i : i + w]
    z = w1[0] * y[..., 0:h, :]
    for i in range(1, k):
        z = z + w1[i] * y[..., i : i + h, :]
    return z


def ssim(
    img1: torch.Tensor,
    img2: torch.Tensor,
    window: int = 11,
    sigma: float = 1.5,
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """Mean SSIM (Gaussian window ``window`` taps, std ``sigma``, data range 1). Differentiable.

    Computed only where the window lies fully inside the image ('valid' filtering), so the result
    equals ``skimage.metrics.structural_similarity(..., gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=1)``, which averages over the same region. With a
    ``mask``, both images are zeroed outside it first (so whatever lies there cannot matter) and the
    SSIM map is averaged over windows whose centre pixel is valid.
    """
    a, b = _as_batch(img1), _as_batch(img2)
    if a.shape != b.shape:
        raise ValueError(f"ssim needs images of equal shape, got {tuple(a.shape)} and {tuple(b.shape)}")
    if min(a.shape[-2:]) < window:
        raise ValueError(f"images {tuple(a.shape[-2:])} are smaller than the SSIM window ({window})")
    m = _mask_batch(mask, a)
    if a.device.type == "cpu" and not b.requires_grad and a.dtype in (torch.float32, torch.float64):
        from .ssim_cpu import ssim_cpu  # numba forward + closed-form backward; this function is its reference

        return ssim_cpu(a, b, m, gaussian_window(window, sigma, torch.float64))
    return _ssim_torch(a, b, m, window, sigma)


def _ssim_torch(a: torch.Tensor, b: torch.Tensor, m: torch.Tensor | None, window: int, sigma: float) -> torch.Tensor:
    """``ssim`` of batches [B,C,H,W] with the mask m [B,1,H,W] (or None) in torch ops, differentiated by
    autograd: the reference of the CPU path, and the path on a GPU."""
    if m is not None:
        a, b = a * m, b * m
    w1 = gaussian_window(window, sigma, a.dtype, a.device)
    # one pass over all five maps; C channels each
    c = a.shape[1]
    mu1, mu2, e11, e22, e12 = _blur(torch.cat([a, b, a * a, b * b, a * b], dim=1), w1).split(c, dim=1)
    s11 = e11 - mu1 * mu1
    s22 = e22 - mu2 * mu2
    s12 = e12 - mu1 * mu2
    smap = ((2 * mu1 * mu2 + _C1) * (2 * s12 + _C2)) / ((mu1 * mu1 + mu2 * mu2 + _C1) * (s11 + s22 + _C2))
    if m is None:
        return smap.mean()
    r = (window - 1) // 2
    mc = m[..., r : r + smap.shape[-2], r : r + smap.shape[-1]].expand_as(smap)
    n = mc.sum()
    if int(n) == 0:
        return smap.new_tensor(math.nan)
    return smap[mc].sum() / n
