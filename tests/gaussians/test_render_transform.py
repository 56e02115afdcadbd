"""Rendering a Sim3-transformed scene equals rendering the original from the equivalent camera.

For x' = s R x + t and a camera V' = [R_c | t_c] looking at the transformed scene, the camera-frame
point is R_c x' + t_c = s (R_c R x + (R_c t + t_c) / s), so the camera V = [R_c R | (R_c t + t_c) / s]
sees the original scene with every camera-frame coordinate divided by s. Perspective projection is
scale invariant (pixels, including the EWA footprints, are identical) and depth scales by s. The
view-dependent colour only matches when the SH bands are rotated with the scene (DESIGN.md section 2).
"""

import functools
import math

import numpy as np
import pytest
import torch
from render_helpers import intrinsics as _intrinsics
from render_helpers import look_at, psnr

from fixtures.gaussians import random_gaussians
from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.render import render
from mirage2matter.gaussians.transform import apply_sim3
from mirage2matter.geometry.rotation import axis_angle_to_matrix
from mirage2matter.geometry.sim3 import Sim3

MIN_PSNR = 45.0
W, H = 80, 60


def intrinsics(width: int, height: int, fov_deg: float = 60.0) -> np.ndarray:
    return _intrinsics(width, height, fov_deg, offset=(0.7, -1.3), aspect=1.05)


@functools.cache
def strong_sh_scene() -> Gaussians:
    """800 Gaussians, SH degree 3 with higher bands of magnitude ~0.3: strongly view dependent."""
    g = random_gaussians(800, 3, seed=5)
    rng = torch.Generator().manual_seed(5)
    sh = torch.cat([g.sh[:, :1], 0.3 * torch.randn(g.sh[:, 1:].shape, generator=rng)], 1)
    return Gaussians(g.means, g.quats, g.log_scales, g.logit_opacities, sh)


def random_sim3(seed: int) -> Sim3:
    """Rotation of 40..70 degrees about a skewed axis, scale 1.7 or 0.6, translation ~1."""
    rng = np.random.default_rng(seed)
    axis = np.ones(3)
    while np.abs(axis).max() > 0.9:  # skewed, well away from a coordinate axis
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
    R = axis_angle_to_matrix(axis, math.radians(rng.uniform(40.0, 70.0)))
    t = rng.normal(size=3)
    t *= rng.uniform(0.8, 1.2) / np.linalg.norm(t)
    return Sim3((1.7, 0.6)[seed % 2], R, t)


def cameras(sim3: Sim3, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(V', V): a camera looking at the transformed scene and its equivalent for the original one."""
    rng = np.random.default_rng(100 + seed)
    centre = sim3.apply(np.zeros(3))
    offset = np.array([0.0, 0.0, 1.0])
    while abs(offset[2]) > 0.7:  # not looking straight down (the look-at's up is +z)
        offset = rng.normal(size=3)
        offset /= np.linalg.norm(offset)
    offset *= 3.3
    V_prime = look_at(centre + sim3.scale * offset, centre)
    R_c, t_c = V_prime[:3, :3], V_prime[:3, 3]
    s, R, t = sim3.scale, sim3.rotation, sim3.translation
    V = np.eye(4)
    V[:3, :3] = R_c @ R
    V[:3, 3] = (R_c @ t + t_c) / s
    return V_prime, V


def compare(moved, original, scale: float) -> tuple[float, float, float]:
    """(rgb PSNR, alpha PSNR, max relative depth error where alpha > 0.5) of moved vs original."""
    mask = original.alpha > 0.5
    assert mask.float().mean() > 0.1, "the scene barely covers the image; the comparison would be weak"
    expected = scale * original.depth[mask].double()
    depth_err = ((moved.depth[mask].double() - expected).abs().max() / expected.max()).item()
    return psnr(moved.rgb, original.rgb), psnr(moved.alpha, original.alpha), depth_err


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_transformed_scene_renders_like_original_from_equivalent_camera(seed):
    g = strong_sh_scene()
    sim3 = random_sim3(seed)
    V_prime, V = cameras(sim3, seed)
    K = intrinsics(W, H)
    original = render(g, V, K, W, H, backend="cpu")
    moved = render(apply_sim3(g, sim3), V_prime, K, W, H, backend="cpu")
    p_rgb, p_alpha, depth_err = compare(moved, original, sim3.scale)
    assert p_rgb >= MIN_PSNR and p_alpha >= MIN_PSNR, (p_rgb, p_alpha)
    assert depth_err <= 1e-4, depth_err

    # The test can fail: without rotating the SH, geometry (alpha, depth) still agrees but colour does not.
    unrotated = render(apply_sim3(g, sim3, rotate_sh=False), V_prime, K, W, H, backend="cpu")
    p_rgb_bad, p_alpha_bad, depth_err_bad = compare(unrotated, original, sim3.scale)
    assert p_rgb_bad < MIN_PSNR, p_rgb_bad
    assert p_alpha_bad >= MIN_PSNR and depth_err_bad <= 1e-4


def test_transform_equivalence_with_the_reference_renderer():
    g = strong_sh_scene().to(torch.float64)
    sim3 = random_sim3(7)
    V_prime, V = cameras(sim3, 7)
    K = intrinsics(W, H)
    original = render(g, V, K, W, H, backend="reference")
    moved = render(apply_sim3(g, sim3), V_prime, K, W, H, backend="reference")
    p_rgb, p_alpha, depth_err = compare(moved, original, sim3.scale)
    assert p_rgb >= MIN_PSNR and p_alpha >= MIN_PSNR and depth_err <= 1e-6, (p_rgb, p_alpha, depth_err)
    unrotated = render(apply_sim3(g, sim3, rotate_sh=False), V_prime, K, W, H, backend="reference")
    assert compare(unrotated, original, sim3.scale)[0] < MIN_PSNR


def test_camera_formula_is_not_trivially_satisfied():
    """Sanity for the setup: the original camera V (not V') sees a different image of the moved scene."""
    g = strong_sh_scene()
    sim3 = random_sim3(0)
    V_prime, V = cameras(sim3, 0)
    K = intrinsics(W, H)
    moved_wrong_camera = render(apply_sim3(g, sim3), V, K, W, H, backend="cpu")
    original = render(g, V, K, W, H, backend="cpu")
    assert psnr(moved_wrong_camera.alpha, original.alpha) < 30
