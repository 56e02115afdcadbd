"""Image augmentation for sim-to-real, on whole batches (one ``grid_sample`` and a few elementwise ops).

What differs between our hybrid renders and the real camera (or the ground-truth world) is mostly where the
camera sits by a few pixels, the exposure, white balance, saturation and noise; the geometry of the scene is
the same. So: a small random affine warp (shift, scale, rotation; DrQ's random shift generalised) and colour
jitter (brightness, contrast, saturation, hue, per-channel gain), softer or sharper focus, plus pixel noise.
Every random number comes from the caller's generator, so a resumed run draws exactly what an uninterrupted one
would.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..gaussians.losses import gaussian_window
from .config import AugmentConfig

__all__ = ["AugmentConfig", "augment", "drop_cameras"]


def _u(n: int, half: float, g: torch.Generator, device: torch.device) -> torch.Tensor:
    """[n] uniform in [-half, half] (drawn on the CPU generator, then moved: CUDA gets the same numbers)."""
    return ((torch.rand(n, generator=g) * 2 - 1) * half).to(device)


# YIQ: luma + a chroma plane in which a hue change is a rotation.
_RGB2YIQ = torch.tensor([[0.299, 0.587, 0.114], [0.596, -0.274, -0.322], [0.211, -0.523, 0.312]])
_YIQ2RGB = torch.linalg.inv(_RGB2YIQ)


def _gaussian5(device: torch.device) -> torch.Tensor:
    """[1, 1, 5, 5] Gaussian kernel, sigma 1 px, sums to 1."""
    t = gaussian_window(5, 1.0, device=device)
    return torch.outer(t, t).view(1, 1, 5, 5)


def _randconv(x: torch.Tensor, p: float, g: torch.Generator) -> torch.Tensor:
    """float [B, 3, S, S] -> the same with each image's textures remapped, with probability ``p``, by its own random
    3x3 filter over the colours (He-scaled normal weights), rescaled to the image's per-channel mean and std and
    blended back with a weight drawn in [0, 1]."""
    b, dev = x.shape[0], x.device
    on = torch.rand(b, generator=g) < p
    w = (torch.randn(b, 3, 3, 3, 3, generator=g) * math.sqrt(2.0 / 27.0)).to(dev)  # [B, out, in, 3, 3]
    keep = torch.rand(b, generator=g).to(dev).view(b, 1, 1, 1)
    idx = torch.nonzero(on).view(-1).to(dev)  # only the chosen images are filtered
    n = len(idx)
    if not n:
        return x
    xs = x[idx]
    padded = F.pad(xs, (1, 1, 1, 1), mode="replicate")  # [n, 3, S+2, S+2]
    y = F.conv2d(padded.reshape(1, n * 3, *padded.shape[2:]), w[idx].reshape(n * 3, 3, 3, 3), groups=n).view_as(xs)
    mx, sx = xs.mean(dim=(2, 3), keepdim=True), xs.std(dim=(2, 3), keepdim=True)
    my, sy = y.mean(dim=(2, 3), keepdim=True), y.std(dim=(2, 3), keepdim=True).clamp_min(1e-6)
    y = (y - my) / sy * sx + mx
    out = x.clone()
    out[idx] = keep[idx] * xs + (1.0 - keep[idx]) * y
    return out


HUE_BANDS = 12  # 30 degrees of chroma angle each: yellow and orange-brown fall in different bands


def _hue_band_gains(x: torch.Tensor, half: float, g: torch.Generator) -> torch.Tensor:
    """float [B, 3, S, S] -> the same with each image's colours of each hue band brightened / saturated by their own
    gains in [1 - half, 1 + half]: the chroma angle (YIQ) is split into ``HUE_BANDS`` bands, a pixel takes the gains
    of its two nearest band centres in proportion (no edges), and a pixel counts as coloured in proportion to its
    chroma (greys, the white robot, the black board: unchanged)."""
    b, dev = x.shape[0], x.device
    fwd = _RGB2YIQ.to(dev)
    yiq = torch.einsum("ij,bjhw->bihw", fwd, x)
    i, q = yiq[:, 1], yiq[:, 2]
    pos = torch.atan2(q, i) / (2 * math.pi) * HUE_BANDS % HUE_BANDS  # [B, S, S] in [0, bands)
    lo = pos.floor().long() % HUE_BANDS
    hi, frac = (lo + 1) % HUE_BANDS, pos - pos.floor()
    gains = 1.0 + _u(2 * b * HUE_BANDS, half, g, dev).view(2, b, HUE_BANDS)  # luma, chroma gains per band

    def at(k: torch.Tensor, which: int) -> torch.Tensor:
        return torch.gather(gains[which], 1, k.flatten(1)).view_as(pos)

    coloured = (torch.sqrt(i * i + q * q) / 0.1).clamp(max=1.0)  # chroma 0.1 and above: fully
    gy = 1.0 + coloured * ((1 - frac) * at(lo, 0) + frac * at(hi, 0) - 1.0)
    gc = 1.0 + coloured * ((1 - frac) * at(lo, 1) + frac * at(hi, 1) - 1.0)
    yiq = torch.stack([yiq[:, 0] * gy, i * gc, q * gc], 1)
    return torch.einsum("ij,bjhw->bihw", _YIQ2RGB.to(dev), yiq)


def augment(images: torch.Tensor, cfg: AugmentConfig, g: torch.Generator) -> torch.Tensor:
    """uint8 or float [B, 3, S, S] -> float [B, 3, S, S] in [0, 1], each image changed at random."""
    x = images.float() / 255.0 if images.dtype == torch.uint8 else images.float()
    b, dev = x.shape[0], x.device

    # geometry: one affine warp per image; border replication avoids black edges the real camera never shows
    ang = _u(b, math.radians(cfg.rotate_deg), g, dev)
    s = 1.0 + _u(b, cfg.scale, g, dev)
    tx, ty = _u(b, 2 * cfg.shift, g, dev), _u(b, 2 * cfg.shift, g, dev)  # grid units: the side spans 2
    cos, sin = torch.cos(ang) / s, torch.sin(ang) / s
    theta = torch.stack([torch.stack([cos, -sin, tx], -1), torch.stack([sin, cos, ty], -1)], 1)  # [B, 2, 3]
    grid = F.affine_grid(theta, list(x.shape), align_corners=False)
    x = F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)

    # sharpness: x + a (x - blur(x)), a in [-blur, sharpen]; a = -1 is the blur itself, a > 0 an unsharp mask
    if cfg.blur > 0 or cfg.sharpen > 0:
        a = (torch.rand(b, generator=g) * (cfg.blur + cfg.sharpen) - cfg.blur).to(dev).view(b, 1, 1, 1)
        soft = F.conv2d(F.pad(x, (2, 2, 2, 2), mode="replicate"), _gaussian5(dev).expand(3, 1, 5, 5), groups=3)
        x = x + a * (x - soft)

    # colour: a per-image 3x3 matrix in YIQ (saturation scales chroma, hue rotates it), then gain/brightness
    sat = 1.0 + _u(b, cfg.saturation, g, dev)
    h = _u(b, 2 * math.pi * cfg.hue, g, dev)
    m = torch.zeros(b, 3, 3, device=dev)
    m[:, 0, 0] = 1.0
    m[:, 1, 1], m[:, 1, 2] = sat * torch.cos(h), -sat * torch.sin(h)
    m[:, 2, 1], m[:, 2, 2] = sat * torch.sin(h), sat * torch.cos(h)
    fwd = _RGB2YIQ.to(dev)
    mat = _YIQ2RGB.to(dev) @ m @ fwd  # [B, 3, 3] acting on RGB
    gain = (1.0 + _u(3 * b, cfg.gain, g, dev).view(b, 3, 1)) * (1.0 + _u(b, cfg.brightness, g, dev).view(b, 1, 1))
    x = torch.einsum("bij,bjp->bip", gain * mat, x.flatten(2)).view_as(x)
    if cfg.hue_bands > 0:
        x = _hue_band_gains(x, cfg.hue_bands, g)
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    x = (x - mean) * (1.0 + _u(b, cfg.contrast, g, dev).view(b, 1, 1, 1)) + mean
    if cfg.randconv > 0:
        x = _randconv(x, cfg.randconv, g)
    if cfg.grayscale > 0:
        grey = (torch.rand(b, generator=g) < cfg.grayscale).to(dev).view(b, 1, 1, 1)
        luma = torch.einsum("c,bchw->bhw", _RGB2YIQ[0].to(dev), x)[:, None].expand_as(x)
        x = torch.where(grey, luma, x)
    if cfg.noise > 0:
        sigma = (torch.rand(b, generator=g) * cfg.noise).to(dev).view(b, 1, 1, 1)
        x = x + sigma * torch.randn(x.shape, generator=g).to(dev)
    return x.clamp(0.0, 1.0)


def drop_cameras(images: dict[str, torch.Tensor], p: float, g: torch.Generator) -> dict[str, torch.Tensor]:
    """{camera: float [B, 3, S, S]} -> the same with, for each sample with probability ``p``, one camera drawn
    uniformly set to mid-grey (0.5, what the encoders' [-1, 1] input maps to 0). A single camera is never blanked
    (nothing would be left to see); nothing is drawn then."""
    cams = list(images)
    if len(cams) < 2 or p <= 0:
        return images
    b = next(iter(images.values())).shape[0]
    on = torch.rand(b, generator=g) < p
    which = torch.randint(len(cams), (b,), generator=g)
    out = {}
    for i, c in enumerate(cams):
        blank = (on & (which == i)).to(images[c].device).view(b, 1, 1, 1)
        out[c] = torch.where(blank, torch.full_like(images[c], 0.5), images[c])
    return out
