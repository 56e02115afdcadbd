"""The first-surface depth (`gaussians/surface_depth.py`): its per-level opacities are exactly the alpha of the
Gaussians in front of each level, and it finds an opaque surface behind a faint haze where the renderers'
alpha-weighted mean depth does not."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from render_helpers import intrinsics, look_at

from fixtures.gaussians import random_gaussians
from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.render import render
from mirage2matter.gaussians.surface_depth import opacity_in_front, surface_depth

W, H = 40, 30


@pytest.mark.parametrize("backend", ["reference", "cpu"])
def test_opacity_in_front_is_the_alpha_of_the_gaussians_in_front(backend):
    g = random_gaussians(300, sh_degree=2, seed=3, extent=0.5)
    V, K = look_at((0.2, -2.5, 0.8), (0, 0, 0)), intrinsics(W, H, 50.0)
    z = g.means.double().numpy() @ V[2, :3] + V[2, 3]
    levels = np.quantile(z, [0.1, 0.35, 0.5, 0.8])  # four levels: a render of three and one of one
    A, alpha = opacity_in_front(g, V, K, W, H, levels, backend=backend)
    assert A.shape == (4, H, W)
    vm, KK = torch.as_tensor(V, dtype=torch.float32), torch.as_tensor(K, dtype=torch.float32)
    for a, level in zip(A, levels, strict=True):
        subset = g.select(torch.from_numpy(z < level))
        want = render(subset, vm, KK, W, H, torch.zeros(3), backend="reference").alpha.numpy()
        np.testing.assert_allclose(a, want, atol=2e-5)
    full = render(g, vm, KK, W, H, torch.zeros(3), backend="reference").alpha.numpy()
    np.testing.assert_allclose(alpha, full, atol=2e-5)
    assert (np.diff(A, axis=0) >= -1e-6).all() and A[1].max() > 0.1  # it accumulates, and something is in front


def test_opacity_in_front_needs_a_level():
    g = random_gaussians(10, sh_degree=0, seed=1, extent=0.5)
    V, K = look_at((0.2, -2.5, 0.8), (0, 0, 0)), intrinsics(W, H, 50.0)
    with pytest.raises(ValueError, match="at least one depth"):
        opacity_in_front(g, V, K, W, H, np.zeros(0))


def _layer(z: float, opacity: float, spacing: float = 0.02, half: float = 0.3) -> Gaussians:
    """A square grid of round Gaussians at camera depth ``z`` (the camera looks along +z from the origin)."""
    xs = np.arange(-half, half + 1e-9, spacing)
    xy = np.stack(np.meshgrid(xs, xs), -1).reshape(-1, 2)
    n = len(xy)
    t = lambda a: torch.as_tensor(np.asarray(a, np.float32))
    return Gaussians.from_activated(
        t(np.c_[xy, np.full(n, z)]), t(np.tile([1.0, 0, 0, 0], (n, 1))), t(np.full((n, 3), spacing)),
        t(np.full(n, opacity)), sh=t(np.zeros((n, 1, 3))),
    )  # fmt: skip


def test_an_opaque_wall_behind_a_faint_haze_is_found_where_the_mean_depth_is_not():
    wall, haze = _layer(1.0, 0.99), _layer(0.9, 0.04, spacing=0.01)
    g = Gaussians(*(torch.cat([a, b]) for a, b in zip(wall.tensors().values(), haze.tensors().values(), strict=True)))
    V, K = np.eye(4), intrinsics(W, H, 20.0)
    centre = (slice(10, 20), slice(15, 25))
    haze_alpha = render(haze, torch.eye(4), torch.as_tensor(K, dtype=torch.float32), W, H).alpha.numpy()[centre]
    assert 0.1 < haze_alpha.min() < 0.5 < 0.9  # the haze is faint, but not nothing
    mean = render(g, torch.eye(4), torch.as_tensor(K, dtype=torch.float32), W, H).depth.numpy()[centre]
    assert (1.0 - mean).min() > 0.01  # the mean depth lies centimetres in front of the wall

    depth, alpha = surface_depth(g, V, K, W, H, q=0.6, step=0.002)
    assert alpha[centre].min() > 0.99
    np.testing.assert_allclose(depth[centre], 1.0, atol=0.002)  # within a level of the wall
    shallow, _ = surface_depth(g, V, K, W, H, q=haze_alpha.min() / 2, step=0.002)
    np.testing.assert_allclose(shallow[centre], 0.9, atol=0.002)  # a q below the haze's opacity stops in it

    nothing, _ = surface_depth(haze, V, K, W, H, q=0.6)
    assert np.isnan(nothing).all()  # the haze alone never reaches 0.6
    with pytest.raises(ValueError, match="q must lie in"):
        surface_depth(g, V, K, W, H, q=1.0)
