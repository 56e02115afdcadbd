"""Least-squares similarity between corresponding point sets (Umeyama 1991)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from .sim3 import Sim3

# Second singular value of the cross-covariance below this fraction of the first: the rotation
# about the points' common line is undetermined.
DEGENERACY_RTOL = 1e-9


def _as_f64(a: Any, name: str) -> np.ndarray:
    if isinstance(a, torch.Tensor):
        a = a.detach().cpu().numpy()
    arr = np.asarray(a, dtype=np.float64)
    if not np.isfinite(arr).all():
        raise ValueError(f"umeyama: {name} has NaN/Inf entries")
    return arr


def umeyama(src: Any, dst: Any, with_scale: bool = True, weights: Any = None) -> Sim3:
    """Sim3 ``T`` minimising ``sum_i w_i |dst_i - T(src_i)|^2``.

    src, dst  [N, 3] corresponding points (numpy, torch or lists), N >= 3
    weights   [N] non-negative, optional (at least 3 positive)
    with_scale  False gives the best rigid transform (scale 1)

    Raises ValueError on mismatched shapes, too few points, or degenerate (coincident or
    collinear) configurations, where the rotation is not determined.
    """
    X, Y = _as_f64(src, "src"), _as_f64(dst, "dst")
    if X.ndim != 2 or X.shape[1] != 3 or X.shape != Y.shape:
        raise ValueError(f"umeyama: src and dst must both be [N, 3], got {X.shape} and {Y.shape}")
    n = X.shape[0]
    if weights is None:
        w = np.ones(n)
    else:
        w = _as_f64(weights, "weights")
        if w.shape != (n,):
            raise ValueError(f"umeyama: weights must have shape ({n},), got {w.shape}")
        if (w < 0).any():
            raise ValueError("umeyama: weights must be non-negative")
    if int((w > 0).sum()) < 3:
        raise ValueError(f"umeyama: need at least 3 point pairs (with positive weight), got {int((w > 0).sum())}")
    w = w / w.sum()

    mu_x, mu_y = w @ X, w @ Y
    Xc, Yc = X - mu_x, Y - mu_y
    var_x = float(w @ np.einsum("ij,ij->i", Xc, Xc))
    if var_x <= 0.0:
        raise ValueError("umeyama: all src points coincide; the transform is undetermined")
    cov = (Yc * w[:, None]).T @ Xc  # [3, 3] weighted cross-covariance, dst x src
    U, D, Vt = np.linalg.svd(cov)
    if D[0] <= 0.0 or D[1] <= DEGENERACY_RTOL * D[0]:
        raise ValueError(
            "umeyama: points are degenerate (coincident or collinear in src or dst); "
            f"cross-covariance singular values {D.tolist()} leave the rotation undetermined"
        )
    # Sign correction: the best orthogonal matrix may be a reflection; flip the weakest axis instead.
    S = np.ones(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2] = -1.0
    R = U @ np.diag(S) @ Vt
    scale = float(D @ S) / var_x if with_scale else 1.0
    if not scale > 0:
        raise ValueError(f"umeyama: fitted scale {scale:.3g} is not positive; are the correspondences right?")
    t = mu_y - scale * R @ mu_x
    return Sim3(scale, R, t)
