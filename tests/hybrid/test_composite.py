"""Hybrid compositing on synthetic arrays and small Gaussian scenes (no simulator)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.transform import apply_sim3
from mirage2matter.geometry.camera import look_at_pose
from mirage2matter.geometry.sim3 import Sim3, invert_rigid
from mirage2matter.render import ColorJitter, MovablePart, SplatRenderOptions, SplatWorld, to_uint8
from mirage2matter.render.composite import composite

H, W = 48, 64
K = np.array([[60.0, 0, W / 2], [0, 60.0, H / 2], [0, 0, 1]])


def _layers():
    rng = np.random.default_rng(0)
    splat = rng.uniform(0, 1, (H, W, 3)).astype(np.float32)
    robot = np.zeros((H, W, 3), np.float32)
    robot[..., 0] = 1.0
    mask = np.zeros((H, W), bool)
    mask[10:40, 20:50] = True
    robot_depth = np.where(mask, 0.5, np.inf).astype(np.float32)
    splat_depth = np.full((H, W), 1.0, np.float32)
    splat_alpha = np.ones((H, W), np.float32)
    return splat, robot, mask, robot_depth, splat_depth, splat_alpha


def test_baseline_pastes_the_mask() -> None:
    splat, robot, mask, *_ = _layers()
    out, shown = composite(splat, robot, mask)
    np.testing.assert_array_equal(out[mask], robot[mask])
    np.testing.assert_array_equal(out[~mask], splat[~mask])
    np.testing.assert_array_equal(shown, mask)


def test_object_in_front_of_the_gripper_hides_it() -> None:
    splat, robot, mask, rd, sd, sa = _layers()
    sd[15:25, 25:35] = 0.3  # an object 20 cm nearer than the gripper
    sa[30:35, 40:45] = 0.1  # and a faint splat region: no surface there, the robot shows
    sd[30:35, 40:45] = 0.2
    out, shown = composite(splat, robot, mask, rd, sd, sa)
    front = np.zeros_like(mask)
    front[15:25, 25:35] = True
    np.testing.assert_array_equal(out[front], splat[front])  # hidden by the object
    np.testing.assert_array_equal(shown, mask & ~front)
    assert (out[30:35, 40:45] == robot[30:35, 40:45]).all()
    # Touching (within the margin) favours the robot.
    sd[:] = 0.497
    _, shown = composite(splat, robot, mask, rd, sd, sa)
    np.testing.assert_array_equal(shown, mask)
    # uint8 layers in, uint8 out.
    out8, _ = composite(to_uint8(splat), to_uint8(robot), mask, rd, sd, sa)
    assert out8.dtype == np.uint8 and (out8[mask] == [255, 0, 0]).all()
    with pytest.raises(ValueError, match="sizes differ"):
        composite(splat[:-1], robot, mask)


def _blob(center, color, n=400, radius=0.03, seed=0, sh_degree=1) -> Gaussians:
    g = torch.Generator().manual_seed(seed)
    means = torch.tensor(center, dtype=torch.float32) + radius * torch.randn(n, 3, generator=g)
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1)
    scales = torch.full((n, 3), radius / 3)
    rgb = torch.tensor(color, dtype=torch.float32).expand(n, 3)
    out = Gaussians.from_activated(means, quats, scales, torch.full((n,), 0.9), rgb=rgb, sh_degree=sh_degree)
    # A little view-dependent colour so that the SH rotation matters.
    out.sh[:, 1:] = 0.2 * torch.randn(out.sh[:, 1:].shape, generator=g)
    return out


def _camera(eye, target=(0.5, 0.0, 0.05)) -> np.ndarray:
    return invert_rigid(look_at_pose(np.array(eye, float), np.array(target, float)))  # viewmat


def test_part_moved_to_its_physics_pose_matches_the_transformed_gaussians() -> None:
    local = _blob((0.0, 0.0, 0.03), (0.9, 0.8, 0.1), seed=1)
    scene = _blob((0.5, 0.2, 0.0), (0.2, 0.3, 0.8), n=800, radius=0.08, seed=2)
    world = SplatWorld(scene, [MovablePart("banana", local, scale=1.2)], SplatRenderOptions(backend="cpu"))
    c, s = np.cos(0.7), np.sin(0.7)
    T = np.array([[c, -s, 0, 0.45], [s, c, 0, -0.05], [0, 0, 1, 0.0], [0, 0, 0, 1.0]])
    world.set_poses({"banana": T, "unknown": np.eye(4)})
    view = _camera((0.0, -0.4, 0.5))
    rgb, alpha, depth = world.render(view, K, W, H)
    expect = Gaussians.concat([scene, apply_sim3(local, Sim3(1.2, T[:3, :3], T[:3, 3]))])
    ref = SplatWorld(expect, [], SplatRenderOptions(backend="cpu")).render(view, K, W, H)
    np.testing.assert_allclose(rgb, ref[0], atol=1e-5)
    np.testing.assert_allclose(alpha, ref[1], atol=1e-5)
    assert alpha.max() > 0.5  # the blobs are in view
    # Moving it again (and back) gives the same pixels: the rows are overwritten, not accumulated.
    world.set_poses({"banana": np.eye(4)})
    world.set_poses({"banana": T})
    np.testing.assert_allclose(world.render(view, K, W, H)[0], rgb, atol=1e-5)


def test_object_gaussians_in_front_of_a_robot_hide_it() -> None:
    # The object sits between the camera and a robot layer (a flat "gripper" 0.6 m away).
    view = _camera((0.0, 0.0, 0.3), target=(1.0, 0.0, 0.3))
    obj = _blob((0.0, 0.0, 0.0), (0.1, 0.9, 0.1), n=600, radius=0.02)
    world = SplatWorld(None, [MovablePart("croissant", obj)], SplatRenderOptions(backend="cpu"))
    world.set_poses({"croissant": np.array([[1, 0, 0, 0.3], [0, 1, 0, 0], [0, 0, 1, 0.3], [0, 0, 0, 1.0]])})
    rgb, alpha, depth = world.render(view, K, W, H, background=(0.5, 0.5, 0.5))
    robot = np.zeros_like(rgb)
    robot[..., 2] = 1.0
    mask = np.ones((H, W), bool)
    out, shown = composite(rgb, robot, mask, np.full((H, W), 0.6, np.float32), depth, alpha)
    covered = alpha >= 0.5
    assert covered.sum() > 20
    assert not shown[covered].any() and shown[~covered].all()
    assert np.abs(out[covered] - rgb[covered]).max() == 0
    # The paper's baseline would paste the robot over the object.
    base, _ = composite(rgb, robot, mask)
    assert (base[covered] == robot[covered]).all()


def test_color_jitter() -> None:
    rng = np.random.default_rng(3)
    im = rng.uniform(0, 1, (8, 8, 3)).astype(np.float32)
    assert ColorJitter().apply(im) is im
    j = ColorJitter.sample(rng)
    out = j.apply(im)
    assert out.min() >= 0 and out.max() <= 1 and not np.allclose(out, im)
    assert ColorJitter.sample(np.random.default_rng(5)) == ColorJitter.sample(np.random.default_rng(5))
    j2 = ColorJitter(brightness=0.1)
    np.testing.assert_allclose(j2.apply(np.full((2, 2, 3), 0.5, np.float32)), 0.6, atol=1e-6)


def test_static_camera_cache_matches_the_full_render() -> None:
    scene = _blob((0.5, 0.0, -0.05), (0.3, 0.3, 0.3), n=1500, radius=0.12, seed=4)
    a, b = _blob((0, 0, 0.02), (0.9, 0.1, 0.1), seed=5), _blob((0, 0, 0.02), (0.1, 0.1, 0.9), seed=6)
    world = SplatWorld(scene, [MovablePart("a", a), MovablePart("b", b)], SplatRenderOptions(backend="cpu"))
    rest = {"a": np.eye(4), "b": np.eye(4)}
    rest["a"][:3, 3] = (0.45, -0.08, 0.0)
    rest["b"][:3, 3] = (0.55, 0.08, 0.0)
    view = _camera((0.0, 0.0, 0.5))
    world.reset_cache()
    world.set_poses(rest)
    got = world.render_static_camera("head", view, K, W, H)
    full = world.render(view, K, W, H)
    for x, y in zip(got, full, strict=True):
        np.testing.assert_array_equal(x, y)  # nothing moved: the cached background is the frame
    lifted = dict(rest, a=rest["a"].copy())
    lifted["a"][:3, 3] += (0.0, -0.05, 0.12)  # "a" picked up and carried
    world.set_poses(lifted)
    got = world.render_static_camera("head", view, K, W, H)
    full = world.render(view, K, W, H)
    mse = np.mean((got[0] - full[0]) ** 2)
    assert 10 * np.log10(1.0 / mse) > 30
    # No ghost where "a" used to be: its old footprint looks like the full render there too.
    old = SplatWorld(None, [MovablePart("a", a)], SplatRenderOptions(backend="cpu"))
    old.set_poses(rest)
    footprint = old.render(view, K, W, H)[1] > 0.5
    assert footprint.sum() > 10
    assert np.abs(got[0][footprint] - full[0][footprint]).mean() < 0.02
    assert world._moving == {"a"}


def test_view_culling_changes_no_pixel() -> None:
    # A wide scene seen close up: most Gaussians are outside the view and get dropped before rendering.
    g = torch.Generator().manual_seed(7)
    n = 4000
    means = torch.rand(n, 3, generator=g) * torch.tensor([2.0, 2.0, 0.05]) - torch.tensor([0.5, 1.0, 0.0])
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1)
    scales = torch.rand(n, 3, generator=g) * 0.03 + 0.002
    scene = Gaussians.from_activated(means, quats, scales, torch.full((n,), 0.8), rgb=torch.rand(n, 3, generator=g))
    view = _camera((0.4, 0.0, 0.25), target=(0.45, 0.0, 0.0))
    culled = SplatWorld(scene, [], SplatRenderOptions(backend="cpu", cull=True))
    plain = SplatWorld(scene, [], SplatRenderOptions(backend="cpu", cull=False))
    keep = SplatWorld._in_view(culled.gaussians, view, K, W, H)
    assert 0.02 < float(keep.float().mean()) < 0.5
    for a, b in zip(culled.render(view, K, W, H), plain.render(view, K, W, H), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6)


def test_moving_camera_reuses_a_frame_only_while_nothing_moved() -> None:
    scene = _blob((0.5, 0.0, -0.05), (0.3, 0.3, 0.3), n=800, radius=0.12, seed=8)
    a = _blob((0, 0, 0.02), (0.9, 0.1, 0.1), seed=9)
    world = SplatWorld(scene, [MovablePart("a", a)], SplatRenderOptions(backend="cpu"))
    pose = np.eye(4)
    pose[:3, 3] = (0.5, 0.0, 0.15)  # above the scene blob
    world.set_poses({"a": pose})
    view = _camera((0.0, 0.0, 0.5))
    first = world.render_camera("wrist", view, K, W, H)
    assert world.render_camera("wrist", view + 1e-7, K, W, H) is first  # an arm at rest: the same frame
    jittered = pose.copy()
    jittered[0, 3] += 1e-6  # a resting object's physics jitter is no move either
    world.set_poses({"a": jittered})
    assert world.render_camera("wrist", view, K, W, H) is first
    moved = world.render_camera("wrist", _camera((0.0, 0.02, 0.5)), K, W, H)  # the camera moved
    assert moved is not first and np.abs(moved[0] - first[0]).max() > 0.05
    lifted = pose.copy()
    lifted[1, 3] += 0.1
    world.set_poses({"a": lifted})  # a part moved: the frame is redrawn and equals a plain render
    again = world.render_camera("wrist", _camera((0.0, 0.02, 0.5)), K, W, H)
    for x, y in zip(again, world.render(_camera((0.0, 0.02, 0.5)), K, W, H), strict=True):
        np.testing.assert_array_equal(x, y)
    assert np.abs(again[0] - moved[0]).max() > 0.05
