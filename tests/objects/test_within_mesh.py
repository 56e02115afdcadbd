"""objects.within_mesh: an object's Gaussians held inside its mesh (the footprint a camera sees is the mesh's)."""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from mirage2matter.gaussians.model import Gaussians
from mirage2matter.geometry.camera import Camera
from mirage2matter.geometry.rotation import quat_to_matrix, random_quat
from mirage2matter.objects.inside import points_inside
from mirage2matter.objects.matting import render_alpha
from mirage2matter.objects.within_mesh import REACH, keep_within_mesh


def _box_and_shell(seed: int = 0):
    """A 6 x 3 x 2 cm box, Gaussians throughout it and a trained object's shell: soft Gaussians up to 3 mm outside."""
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.box(extents=(0.06, 0.03, 0.02))
    inner = rng.uniform(-1, 1, (1500, 3)) * [0.027, 0.012, 0.007]  # >= 3 mm inside
    surface, face = trimesh.sample.sample_surface(mesh, 3000, seed=seed)
    shell = surface + mesh.face_normals[face] * rng.uniform(-0.001, 0.003, (3000, 1))
    means = np.r_[inner, shell]
    n = len(means)
    g = Gaussians.from_activated(
        torch.tensor(means, dtype=torch.float32), torch.tensor(random_quat(n, seed=seed), dtype=torch.float32),
        torch.full((n, 3), 0.0015), torch.full((n,), 0.9), rgb=torch.full((n, 3), 0.8),
    )  # fmt: skip
    return mesh, g, len(inner)


def _top_camera(size: int = 200) -> Camera:
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = [[1, 0, 0], [0, -1, 0], [0, 0, -1]]  # looking down -z
    T_world_cam[:3, 3] = [0, 0, 0.5]
    K = np.array([[2000.0, 0, size / 2], [0, 2000.0, size / 2], [0, 0, 1]])  # 0.25 mm a pixel on the box's top
    return Camera(K, T_world_cam, size, size)


def test_the_footprint_from_above_is_the_mesh():
    mesh, g, _ = _box_and_shell()
    cam = _top_camera()
    box_px = (0.06 * 4000) * (0.03 * 4000)  # the box's top, 240 x 120 px at 2000 px / 0.5 m
    before = (render_alpha(g, cam)[1] > 0.5).sum() / box_px
    held, figures = keep_within_mesh(g, mesh)
    after = (render_alpha(held, cam)[1] > 0.5).sum() / box_px
    assert before > 1.15, before  # the shell widens the box as a trained object's did (1.30x on the sample)
    assert 0.8 < after < 1.04, after  # not wider; the few soft Gaussians along the edges fade ~1 mm in (0.87)
    assert figures["dropped"] > 0 and figures["moved_inside"] > 0 and figures["squashed"] > 0


def test_every_axis_ends_inside_and_the_deep_ones_are_untouched():
    mesh, g, n_inner = _box_and_shell(1)
    held, figures = keep_within_mesh(g, mesh, tol=0.0005, drop=0.002)
    centres = g.means.numpy().astype(np.float64)
    outside = np.abs(centres) - [0.03, 0.015, 0.01]
    gone = (outside > 0.002).any(1) & (np.linalg.norm(np.maximum(outside, 0), axis=1) > 0.002)
    assert figures["dropped"] == int(gone.sum()) and len(held) == len(g) - gone.sum()
    mu = held.means.numpy().astype(np.float64)
    assert points_inside(mesh.vertices, mesh.faces, mu).all()
    R = quat_to_matrix(held.quats.numpy().astype(np.float64))
    s = np.exp(held.log_scales.numpy().astype(np.float64))
    for axis in range(3):
        for sign in (1, -1):  # each axis's end at REACH sigma (to the bisection's 1/64) lies inside
            ends = mu + sign * 0.98 * REACH * s[:, axis, None] * R[:, :, axis]
            assert points_inside(mesh.vertices, mesh.faces, ends).all()
    # the Gaussians well inside (>= 3 mm from every face, 2 sigma = 3 mm) keep every number
    deep = (np.abs(centres[:n_inner]) < [0.027 - 0.003, 0.012 - 0.003, 0.007 - 0.003]).all(1)
    assert deep.sum() > 100
    for name in ("means", "quats", "log_scales", "logit_opacities", "sh"):
        want = getattr(g, name)[:n_inner][deep]
        torch.testing.assert_close(getattr(held, name)[:n_inner][deep], want, rtol=0, atol=0)


def test_nothing_outside_changes_nothing():
    mesh = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    g = Gaussians.from_activated(torch.zeros(1, 3), torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), 0.001),
                                 torch.full((1,), 0.5), rgb=torch.ones(1, 3))  # fmt: skip
    held, figures = keep_within_mesh(g, mesh)
    assert figures["squashed"] == figures["dropped"] == figures["moved_inside"] == 0
    torch.testing.assert_close(held.log_scales, g.log_scales, rtol=0, atol=0)
