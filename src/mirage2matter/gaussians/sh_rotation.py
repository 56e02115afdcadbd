"""Rotating SH coefficients with the scene (DESIGN.md section 2).

If a Gaussian is rotated by R, the colour it shows along direction ``R d`` must be the colour it
showed along ``d``. Each SH band l is closed under rotation, so there is a (2l+1)x(2l+1) matrix
D_l with ``Y_l(R^T e) = Y_l(e) D_l`` for all directions e (Y_l as a row). Then

    sum_k c'_k Y_k(e) = sum_k c_k Y_k(R^T e)   <=>   c'_l = D_l c_l   (per colour channel).

D_l is found by evaluating ``sh.sh_basis`` itself at fixed well-spread directions and solving the
(exactly consistent) linear system, so it matches that basis' signs and normalisation by
construction rather than by transcribing a Wigner-D convention.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch

from .sh import num_sh_bases, sh_basis, sh_degree_from_bases

_N_FIT_DIRS = 64  # >= 2l+1 = 7 for l = 3, with margin so the fit is well conditioned


def _band(band: int) -> slice:
    """Coefficient indices of SH band ``band`` (degree l): l^2 .. (l+1)^2 - 1."""
    return slice(band * band, (band + 1) ** 2)


@lru_cache(maxsize=1)
def _fit_dirs() -> torch.Tensor:
    """Fibonacci sphere, [M, 3] float64 (CPU): near-uniform, deterministic."""
    i = torch.arange(_N_FIT_DIRS, dtype=torch.float64) + 0.5
    z = 1.0 - 2.0 * i / _N_FIT_DIRS
    r = torch.sqrt(1.0 - z * z)
    phi = i * math.pi * (3.0 - math.sqrt(5.0))  # golden angle
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)


@lru_cache(maxsize=8)
def _band_pinv(degree: int) -> tuple[torch.Tensor, ...]:
    """Per band l = 1..degree: pinv(B_l(d)) [2l+1, M] float64 (CPU)."""
    basis = sh_basis(_fit_dirs(), degree)  # [M, K]
    return tuple(torch.linalg.pinv(basis[:, _band(b)]) for b in range(1, degree + 1))


def _as_rotation(R: torch.Tensor | np.ndarray, device: torch.device | None = None) -> torch.Tensor:
    if isinstance(R, np.ndarray):
        R = torch.from_numpy(np.array(R, dtype=np.float64))  # copy: the input may be read-only
    R = torch.as_tensor(R, dtype=torch.float64, device=device)
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"rotation must have shape [..., 3, 3], got {tuple(R.shape)}")
    return R


def sh_rotation_matrices(R: torch.Tensor | np.ndarray, degree: int) -> list[torch.Tensor]:
    """Per-band SH rotation matrices for rotation R.

    R [..., 3, 3] (numpy or torch; autograd flows through a torch R) -> list over bands l = 0..degree
    of float64 tensors [..., 2l+1, 2l+1] on R's device. ``c'_l = D_l @ c_l`` rotates band l.
    """
    num_sh_bases(degree)  # validates degree
    R = _as_rotation(R, R.device if isinstance(R, torch.Tensor) else None)
    out = [torch.ones(*R.shape[:-2], 1, 1, dtype=torch.float64, device=R.device)]
    if degree == 0:
        return out
    # Rows of d @ R are R^T d_i.
    basis_rot = sh_basis(_fit_dirs().to(R.device) @ R, degree)  # [..., M, K]
    for band, pinv in enumerate(_band_pinv(degree), start=1):
        out.append(pinv.to(R.device) @ basis_rot[..., _band(band)])
    return out


def sh_rotation_matrix(R: torch.Tensor | np.ndarray, degree: int) -> torch.Tensor:
    """Block-diagonal [..., K, K] float64 matrix of all bands, K = (degree+1)^2; ``sh' = D @ sh``."""
    blocks = sh_rotation_matrices(R, degree)
    k = num_sh_bases(degree)
    D = blocks[0].new_zeros(*blocks[0].shape[:-2], k, k)
    for band, block in enumerate(blocks):
        D[..., _band(band), _band(band)] = block
    return D


def rotate_sh(sh: torch.Tensor, R: torch.Tensor | np.ndarray) -> torch.Tensor:
    """SH coefficients of the rotated Gaussians: ``eval(sh', R d) == eval(sh, d)`` for every direction d.

    sh [..., K, 3] any float dtype/device; R [3, 3] or [..., 3, 3] (broadcast against sh's leading
    dims). Returns [..., K, 3] in sh's dtype/device; differentiable in sh (and in a torch R).
    Degree 0 (DC only) is rotation invariant and returned as is.
    """
    degree = sh_degree_from_bases(sh.shape[-2])
    if degree == 0:
        return sh
    D = sh_rotation_matrix(_as_rotation(R, sh.device), degree).to(sh.dtype)
    return D @ sh
