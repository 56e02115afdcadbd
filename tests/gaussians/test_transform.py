import math

import numpy as np
import pytest
import torch

from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.sh import sh_basis
from mirage2matter.gaussians.transform import apply_sim3
from mirage2matter.geometry.rotation import axis_angle_to_matrix, quat_to_matrix
from mirage2matter.geometry.sim3 import Sim3

SIM3 = Sim3(1.3, axis_angle_to_matrix(np.array([1.0, 2.0, -0.5]), math.radians(50.0)), [0.2, -0.7, 1.5])


def _gaussians(n: int = 64, degree: int = 3, dtype=torch.float64, seed: int = 0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    return Gaussians(
        means=torch.randn(n, 3, generator=g, dtype=dtype),
        quats=torch.randn(n, 4, generator=g, dtype=dtype) * 2.0,  # deliberately not normalised
        log_scales=torch.randn(n, 3, generator=g, dtype=dtype) * 0.5 - 2.0,
        logit_opacities=torch.randn(n, generator=g, dtype=dtype),
        sh=torch.randn(n, (degree + 1) ** 2, 3, generator=g, dtype=dtype) * 0.3,
    )


def _cov(g: Gaussians) -> torch.Tensor:
    R = quat_to_matrix(g.quats)
    return R @ torch.diag_embed(torch.exp(2 * g.log_scales)) @ R.transpose(-1, -2)


def test_means_scales_opacity_match_hand_computation():
    g = _gaussians()
    out = apply_sim3(g, SIM3)
    sR = torch.tensor(SIM3.scale * SIM3.rotation)
    torch.testing.assert_close(out.means, g.means @ sR.T + torch.tensor(SIM3.translation), atol=1e-12, rtol=0)
    torch.testing.assert_close(out.log_scales, g.log_scales + math.log(1.3), atol=1e-12, rtol=0)
    torch.testing.assert_close(out.scales, g.scales * 1.3, atol=1e-12, rtol=1e-12)
    assert out.logit_opacities is g.logit_opacities


def test_quats_are_normalised_and_rotate_orientations():
    g = _gaussians()
    out = apply_sim3(g, SIM3)
    torch.testing.assert_close(out.quats.norm(dim=-1), torch.ones(len(g), dtype=torch.float64), atol=1e-12, rtol=0)
    R = torch.tensor(SIM3.rotation)
    torch.testing.assert_close(quat_to_matrix(out.quats), R @ quat_to_matrix(g.quats), atol=1e-12, rtol=0)


def test_covariance_transforms_as_s2_R_sigma_RT():
    g = _gaussians()
    out = apply_sim3(g, SIM3)
    R = torch.tensor(SIM3.rotation)
    expected = SIM3.scale**2 * R @ _cov(g) @ R.T
    torch.testing.assert_close(_cov(out), expected, atol=1e-12, rtol=1e-10)
    # Sanity: the covariance does change, so this check could fail.
    assert (_cov(out) - _cov(g)).abs().max() > 1e-3


def test_view_dependent_colour_follows_the_rotation():
    g = _gaussians(degree=3)
    out = apply_sim3(g, SIM3)
    cam = torch.tensor([3.0, -2.0, 1.0], dtype=torch.float64)
    d = g.means - cam  # camera -> mean
    d_new = out.means - SIM3.apply(cam)  # same camera moved with the scene: direction R d (times s)

    def colour(gs: Gaussians, dirs: torch.Tensor) -> torch.Tensor:
        return torch.einsum("nk,nkc->nc", sh_basis(dirs, gs.sh_degree), gs.sh)

    torch.testing.assert_close(colour(out, d_new), colour(g, d), atol=1e-10, rtol=0)
    no_rot = apply_sim3(g, SIM3, rotate_sh=False)
    assert no_rot.sh is g.sh
    assert (colour(no_rot, d_new) - colour(g, d)).abs().max() > 0.05


def test_inverse_round_trips():
    g = _gaussians()
    back = apply_sim3(apply_sim3(g, SIM3), SIM3.inverse())
    torch.testing.assert_close(back.means, g.means, atol=1e-12, rtol=0)
    torch.testing.assert_close(back.log_scales, g.log_scales, atol=1e-12, rtol=0)
    torch.testing.assert_close(back.sh, g.sh, atol=1e-12, rtol=0)
    # Quaternions come back normalised and up to sign (q and -q are the same rotation).
    q0 = g.quats / g.quats.norm(dim=-1, keepdim=True)
    sign = torch.sign((back.quats * q0).sum(-1, keepdim=True))
    torch.testing.assert_close(back.quats * sign, q0, atol=1e-12, rtol=0)


def test_composition_matches_composed_sim3():
    g = _gaussians(seed=1)
    other = Sim3(0.7, axis_angle_to_matrix(np.array([0.0, 1.0, 0.0]), 2.0), [1.0, 0.0, -1.0])
    a = apply_sim3(apply_sim3(g, SIM3), other)
    b = apply_sim3(g, other @ SIM3)
    for name in ("means", "log_scales", "sh"):
        torch.testing.assert_close(getattr(a, name), getattr(b, name), atol=1e-12, rtol=0)
    torch.testing.assert_close(_cov(a), _cov(b), atol=1e-12, rtol=1e-10)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dtype_preserved_and_gradients_flow(dtype):
    g = _gaussians(16, dtype=dtype).map(lambda t: t.clone().requires_grad_(True))
    out = apply_sim3(g, SIM3)
    for name, t in out.tensors().items():
        assert t.dtype == dtype and t.device == g.device, name
    loss = sum(t.pow(2).sum() for t in out.tensors().values())
    loss.backward()
    for name, t in g.tensors().items():
        assert t.grad is not None and torch.isfinite(t.grad).all() and t.grad.abs().sum() > 0, name


def test_degree_zero_and_empty():
    g = _gaussians(5, degree=0)
    out = apply_sim3(g, SIM3)
    assert out.sh is g.sh
    empty = apply_sim3(_gaussians(0), SIM3)
    assert len(empty) == 0 and empty.sh.shape == (0, 16, 3)


@pytest.mark.parametrize("scale", [1.3, (0.7, 1.0, 1.3)], ids=["one-scale", "per-pose-scales"])
def test_apply_rigid_batch_is_apply_sim3_per_pose(scale) -> None:
    from mirage2matter.gaussians.transform import apply_rigid_batch

    g = _gaussians(degree=2, dtype=torch.float32)
    rng = np.random.default_rng(3)
    Rs = np.stack([axis_angle_to_matrix(rng.normal(size=3), a) for a in (0.0, 0.7, 2.9)])
    ts = rng.normal(size=(3, 3))
    out = apply_rigid_batch(g, np.asarray(scale) if isinstance(scale, tuple) else scale, Rs, ts)
    scales = np.broadcast_to(np.asarray(scale, np.float64), (3,))
    for b in range(3):
        want = apply_sim3(g, Sim3(float(scales[b]), Rs[b], ts[b]))
        for k in ("means", "quats", "log_scales", "sh"):
            torch.testing.assert_close(out[k][b], getattr(want, k), atol=2e-5, rtol=1e-5)
