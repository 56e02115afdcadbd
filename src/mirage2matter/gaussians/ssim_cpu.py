"""SSIM on the CPU as one numba pass forward and one backward (the training loss's D-SSIM term).

``losses.ssim`` in torch builds the five Gaussian-filtered maps from ~50 shifted multiply-adds and
autograd differentiates all of them: on fox at 1/4 resolution (480x270) that was ~0.3 s forward and as
much backward per step on 2 cores, more than the rasterizer. Here the maps are filtered separably in
numba and the gradient is the closed form used by fused-SSIM implementations: with
S = (2 m1 m2 + C1)(2 s12 + C2) / ((m1^2 + m2^2 + C1)(s1^2 + s2^2 + C2)) per window,

    dS/dm1 = S (2 m2 / A1 - 2 m2 / A2 - 2 m1 / B1 + 2 m1 / B2),  dS/dE11 = -S / B2,  dS/dE12 = 2 S / A2

(A1, A2 the numerator's factors, B1, B2 the denominator's; E11 = filter(x^2), E12 = filter(x y)), and
d/dx = F^T(dS/dm1) + 2 x F^T(dS/dE11) + y F^T(dS/dE12), F^T the filter's transpose. Only the first
image gets a gradient (the second is the photo). ``losses.ssim`` dispatches here for CPU tensors and
keeps the torch formulation as the reference (tests compare the two, values and gradients).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange

__all__ = ["ssim_cpu"]

_C1 = 0.01**2
_C2 = 0.03**2


@njit(parallel=True, cache=True)
def _forward(a, b, mc, w, grads):
    """a, b [P,H,W] (already masked), mc [P,Ho,Wo] float32 weight of each window centre (1/n or 0), w [k]
    float64 taps. Returns the sum of weight * S; writes the per-window partials of that sum into grads
    [P,3,Ho,Wo] (d/dm1, d/dE11, d/dE12)."""
    P, H, W = a.shape
    k = w.shape[0]
    Ho, Wo = H - k + 1, W - k + 1
    hz = np.empty((P, 5, H, Wo))
    for row in prange(P * H):  # horizontal pass of the five maps
        p, i = row // H, row % H
        for j in range(Wo):
            s0 = s1 = s2 = s3 = s4 = 0.0
            for t in range(k):
                x, y = a[p, i, j + t], b[p, i, j + t]
                s0 += w[t] * x
                s1 += w[t] * y
                s2 += w[t] * x * x
                s3 += w[t] * y * y
                s4 += w[t] * x * y
            hz[p, 0, i, j], hz[p, 1, i, j], hz[p, 2, i, j], hz[p, 3, i, j], hz[p, 4, i, j] = s0, s1, s2, s3, s4
    rows = np.zeros(P * Ho)
    for row in prange(P * Ho):  # vertical pass, the SSIM map and its partials
        p, i = row // Ho, row % Ho
        acc = 0.0
        for j in range(Wo):
            m1 = m2 = e11 = e22 = e12 = 0.0
            for t in range(k):
                m1 += w[t] * hz[p, 0, i + t, j]
                m2 += w[t] * hz[p, 1, i + t, j]
                e11 += w[t] * hz[p, 2, i + t, j]
                e22 += w[t] * hz[p, 3, i + t, j]
                e12 += w[t] * hz[p, 4, i + t, j]
            a1 = 2.0 * m1 * m2 + _C1
            a2 = 2.0 * (e12 - m1 * m2) + _C2
            b1 = m1 * m1 + m2 * m2 + _C1
            b2 = (e11 - m1 * m1) + (e22 - m2 * m2) + _C2
            s = a1 * a2 / (b1 * b2)
            wt = mc[p, i, j]
            acc += wt * s
            grads[p, 0, i, j] = wt * s * (2.0 * m2 / a1 - 2.0 * m2 / a2 - 2.0 * m1 / b1 + 2.0 * m1 / b2)
            grads[p, 1, i, j] = -wt * s / b2
            grads[p, 2, i, j] = 2.0 * wt * s / a2
        rows[row] = acc
    return rows.sum()


@njit(parallel=True, cache=True)
def _backward(a, b, grads, w, scale, out):
    """out [P,H,W] = scale * (F^T g0 + 2 a F^T g1 + b F^T g2) for the partials grads [P,3,Ho,Wo]."""
    P, H, W = a.shape
    k = w.shape[0]
    Ho, Wo = H - k + 1, W - k + 1
    vt = np.empty((P, 3, H, Wo))
    for row in prange(P * H):  # the vertical pass transposed: image row i gathers window rows i-k+1 .. i
        p, i = row // H, row % H
        lo, hi = max(0, i - k + 1), min(Ho - 1, i)
        for j in range(Wo):
            g0 = g1 = g2 = 0.0
            for ii in range(lo, hi + 1):
                wt = w[i - ii]
                g0 += wt * grads[p, 0, ii, j]
                g1 += wt * grads[p, 1, ii, j]
                g2 += wt * grads[p, 2, ii, j]
            vt[p, 0, i, j], vt[p, 1, i, j], vt[p, 2, i, j] = g0, g1, g2
    for row in prange(P * H):  # the horizontal pass transposed, then through x^2 and x y
        p, i = row // H, row % H
        for j in range(W):
            g0 = g1 = g2 = 0.0
            lo, hi = max(0, j - k + 1), min(Wo - 1, j)
            for jj in range(lo, hi + 1):
                wt = w[j - jj]
                g0 += wt * vt[p, 0, i, jj]
                g1 += wt * vt[p, 1, i, jj]
                g2 += wt * vt[p, 2, i, jj]
            out[p, i, j] = scale * (g0 + 2.0 * a[p, i, j] * g1 + b[p, i, j] * g2)


class _SsimCpu(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x, y, center_weight, w):
        a, b = x.detach().numpy(), y.detach().numpy()
        grads = np.empty((a.shape[0], 3, *center_weight.shape[1:]), np.float64)
        value = _forward(a, b, center_weight, w, grads)
        ctx.save_for_backward(x, y)
        ctx.grads, ctx.w = grads, w
        return x.new_tensor(value)

    @staticmethod
    def backward(ctx, g):
        x, y = ctx.saved_tensors
        out = np.empty(x.shape, np.float64)
        _backward(x.detach().numpy(), y.detach().numpy(), ctx.grads, ctx.w, float(g), out)
        return torch.from_numpy(out).to(x.dtype), None, None, None


def ssim_cpu(a: torch.Tensor, b: torch.Tensor, m: torch.Tensor | None, taps: torch.Tensor) -> torch.Tensor:
    """SSIM of batches a, b [B,C,H,W] (CPU; only ``a`` is differentiated) with the valid-pixel mask m
    [B,1,H,W] bool or None and the normalised 1D window ``taps`` [k] (``losses.gaussian_window``): the value
    and conventions of ``losses.ssim``."""
    window = int(taps.shape[0])
    B, C, H, W = a.shape
    if m is not None:
        mf = m.to(a.dtype)
        a, b = a * mf, b * mf
    r = (window - 1) // 2
    Ho, Wo = H - window + 1, W - window + 1
    if m is None:
        center = np.full((B * C, Ho, Wo), 1.0 / (B * C * Ho * Wo), np.float32)
    else:
        mc = m[:, :, r : r + Ho, r : r + Wo].expand(B, C, Ho, Wo).reshape(B * C, Ho, Wo)
        n = int(mc.sum())
        if n == 0:
            return a.new_tensor(math.nan)
        center = (mc.to(torch.float32) / n).numpy()
    w = taps.to(torch.float64).numpy()
    x = a.reshape(B * C, H, W).contiguous()
    y = b.detach().reshape(B * C, H, W).contiguous()
    return _SsimCpu.apply(x, y, np.ascontiguousarray(center), w)
