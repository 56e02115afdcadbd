import math

import numpy as np
import pytest
import torch

from mirage2matter.gaussians.sh import sh_basis
from mirage2matter.gaussians.sh_rotation import rotate_sh, sh_rotation_matrices, sh_rotation_matrix
from mirage2matter.geometry.rotation import axis_angle_to_matrix, random_rotation, rotvec_to_matrix


def _eval(sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Unclamped SH value per direction. sh [N, K, 3], dirs [N, 3] -> [N, 3] (no clamp, so nothing hides)."""
    degree = math.isqrt(sh.shape[-2]) - 1
    return torch.einsum("nk,nkc->nc", sh_basis(dirs, degree), sh)


def _random(n: int, degree: int, seed: int, dtype=torch.float64) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    sh = torch.randn(n, (degree + 1) ** 2, 3, generator=g, dtype=dtype)
    dirs = torch.randn(n, 3, generator=g, dtype=dtype)
    return sh, dirs / dirs.norm(dim=-1, keepdim=True)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rotated_sh_shows_same_colour_along_rotated_direction(degree, seed):
    R = random_rotation(seed=seed)
    sh, d = _random(500, degree, seed)
    Rt = torch.as_tensor(R)
    torch.testing.assert_close(_eval(rotate_sh(sh, R), d @ Rt.T), _eval(sh, d), atol=1e-10, rtol=0)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_without_rotation_colours_differ(degree):
    # The check above can fail: unrotated SH along the rotated direction gives other colours.
    R = axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), math.radians(30))
    sh, d = _random(500, degree, 3)
    Rt = torch.as_tensor(R)
    assert (_eval(sh, d @ Rt.T) - _eval(sh, d)).abs().max() > 0.1
    # Rotating by R^T (the wrong direction) is wrong as well.
    assert (_eval(rotate_sh(sh, R.T), d @ Rt.T) - _eval(sh, d)).abs().max() > 0.1


def test_band_zero_unchanged_and_bands_do_not_mix():
    R = random_rotation(seed=4)
    sh, _ = _random(50, 3, 4)
    out = rotate_sh(sh, R)
    torch.testing.assert_close(out[:, 0], sh[:, 0], atol=0, rtol=0)
    # Only band 2 non-zero in: only band 2 non-zero out.
    only2 = torch.zeros_like(sh)
    only2[:, 4:9] = sh[:, 4:9]
    out2 = rotate_sh(only2, R)
    assert out2[:, :4].abs().max() == 0 and out2[:, 9:].abs().max() == 0 and out2[:, 4:9].abs().max() > 0.1


def test_identity_is_a_no_op():
    sh, _ = _random(50, 3, 5)
    torch.testing.assert_close(rotate_sh(sh, np.eye(3)), sh, atol=1e-12, rtol=0)


def test_composition():
    R1, R2 = random_rotation(seed=6), random_rotation(seed=7)
    sh, _ = _random(100, 3, 6)
    torch.testing.assert_close(rotate_sh(rotate_sh(sh, R1), R2), rotate_sh(sh, R2 @ R1), atol=1e-10, rtol=0)
    # and R2 @ R1 != R1 @ R2 here, so the order is really being tested
    assert (rotate_sh(sh, R1 @ R2) - rotate_sh(sh, R2 @ R1)).abs().max() > 0.1


def test_band_matrices_are_orthogonal_and_shaped():
    R = random_rotation(seed=8)
    mats = sh_rotation_matrices(R, 3)
    assert [tuple(m.shape) for m in mats] == [(1, 1), (3, 3), (5, 5), (7, 7)]
    for m in mats:
        # The 3DGS basis is orthonormal on the sphere (up to one constant), so each D_l is orthogonal.
        torch.testing.assert_close(m @ m.T, torch.eye(m.shape[0], dtype=torch.float64), atol=1e-10, rtol=0)
    # Band 1 is the rotation itself in the (y, z, x) ordering with the basis signs (-y, z, -x).
    P = torch.tensor([[0, -1.0, 0], [0, 0, 1.0], [-1.0, 0, 0]], dtype=torch.float64)
    torch.testing.assert_close(mats[1], P @ torch.as_tensor(R) @ P.T, atol=1e-12, rtol=0)


def test_batched_rotations_and_dtype_device():
    Rs = random_rotation(10, seed=9)
    sh, d = _random(10, 2, 9, dtype=torch.float32)
    out = rotate_sh(sh, Rs)  # one rotation per Gaussian
    assert out.dtype == torch.float32 and out.shape == sh.shape and out.device == sh.device
    rd = torch.einsum("nij,nj->ni", torch.as_tensor(Rs, dtype=torch.float32), d)
    torch.testing.assert_close(_eval(out, rd), _eval(sh, d), atol=1e-5, rtol=0)
    assert sh_rotation_matrix(Rs, 2).shape == (10, 9, 9)


def test_gradients_flow_through_sh_and_rotation():
    sh, d = _random(20, 3, 10)
    sh.requires_grad_(True)
    rv = torch.tensor([0.2, -0.1, 0.3], dtype=torch.float64, requires_grad=True)
    out = rotate_sh(sh, rotvec_to_matrix(rv))
    _eval(out, d).sum().backward()
    assert sh.grad is not None and sh.grad.abs().sum() > 0
    assert rv.grad is not None and torch.isfinite(rv.grad).all() and rv.grad.abs().sum() > 0
