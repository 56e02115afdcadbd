"""SplatWorldBatch: B copies of one Gaussian world posed on their own and rendered together give, copy by copy,
the frames of a SplatWorld posed alike (the CPU path; tests/hybrid/test_splat_world_cuda.py holds the GPU's)."""

from __future__ import annotations

import numpy as np
import pytest
from test_composite import H, K, W, _blob, _camera

from mirage2matter.render import MovablePart, SplatRenderOptions, SplatWorld, SplatWorldBatch


def _world(**kw) -> SplatWorld:
    scene = _blob((0.5, 0.0, -0.05), (0.3, 0.3, 0.3), n=1500, radius=0.12, seed=4)
    a, b = _blob((0, 0, 0.02), (0.9, 0.1, 0.1), seed=5), _blob((0, 0, 0.02), (0.1, 0.1, 0.9), seed=6)
    return SplatWorld(scene, [MovablePart("a", a), MovablePart("b", b, scale=1.2)], SplatRenderOptions(**kw))


def _poses(k: int) -> dict[str, np.ndarray]:
    """Copy k's poses: part a moved 6 cm sideways per copy, b turned."""
    a, b = np.eye(4), np.eye(4)
    a[:3, 3] = (0.45, -0.08 + 0.06 * k, 0.15)  # above the scene blob
    c, s = np.cos(0.7 * k), np.sin(0.7 * k)
    b[:2, :2] = [[c, -s], [s, c]]
    b[:3, 3] = (0.55, 0.08, 0.15)
    return {"a": a, "b": b}


def test_each_copy_renders_as_its_own_world() -> None:
    batch = SplatWorldBatch(_world(backend="cpu"), 3)
    batch.set_poses([_poses(0), _poses(0), _poses(0)])
    batch.set_poses([None, _poses(1), _poses(2)])  # copy 0 kept, the others moved again
    cams = [_camera((0.0, 0.0, 0.5)), _camera((0.4, 0.1, 0.3), target=(0.5, 0.0, 0.0))]
    views = np.stack([np.stack(cams)] * 3)
    views[2, 1] = _camera((0.3, -0.1, 0.35), target=(0.5, 0.0, 0.0))  # copies need not share their cameras
    rgb, alpha, depth = batch.render(views, np.broadcast_to(K, (3, 2, 3, 3)), W, H, background=(0.1, 0.2, 0.3))
    assert rgb.shape == (3, 2, H, W, 3) and alpha.shape == depth.shape == (3, 2, H, W)
    for k in range(3):
        alone = _world(backend="cpu")
        alone.set_poses(_poses(k))
        for c in range(2):
            r, a, d = alone.render(views[k, c], K, W, H, background=(0.1, 0.2, 0.3))
            np.testing.assert_allclose(rgb[k, c], r, atol=1e-6)
            np.testing.assert_allclose(alpha[k, c], a, atol=1e-6)
            np.testing.assert_allclose(depth[k, c], d, atol=1e-6)
    # the copies really differ (part a is elsewhere in each): not one world rendered three times
    assert np.abs(rgb[0, 0] - rgb[1, 0]).mean() > 1e-3


def test_posing_one_copy_leaves_the_others() -> None:
    batch = SplatWorldBatch(_world(backend="cpu"), 2)
    batch.set_poses([_poses(0), _poses(0)])
    view = np.stack([np.stack([_camera((0.0, 0.0, 0.5))])] * 2)
    Ks = np.broadcast_to(K, (2, 1, 3, 3))
    before = batch.render(view, Ks, W, H)[0]
    batch.set_poses([None, _poses(2)])
    after = batch.render(view, Ks, W, H)[0]
    np.testing.assert_array_equal(after[0], before[0])
    assert np.abs(after[1] - before[1]).mean() > 1e-3


def test_a_subset_of_copies_and_a_copy_at_its_own_scale() -> None:
    """``copies=`` draws only the copies named (a splat server's episodes that asked for a frame), in their order;
    ``set_scale`` draws one copy's parts at its own scale (an episode's object scale), the others as built."""
    batch = SplatWorldBatch(_world(backend="cpu"), 3)
    batch.set_scale(2, 0.6)
    batch.set_poses([_poses(0), _poses(1), _poses(1)])
    view = _camera((0.0, 0.0, 0.5))
    views, Ks = np.tile(view, (2, 1, 1, 1)), np.tile(K, (2, 1, 1, 1))
    rgb, alpha, depth = batch.render(views, Ks, W, H, copies=[2, 0])
    assert rgb.shape == (2, 1, H, W, 3)
    plain = _world(backend="cpu")
    plain.set_poses(_poses(0))
    np.testing.assert_allclose(rgb[1, 0], plain.render(view, K, W, H)[0], atol=1e-6)
    small = _world(backend="cpu")
    for part in small.parts:
        part.scale *= 0.6
    small.set_poses(_poses(1))
    np.testing.assert_allclose(rgb[0, 0], small.render(view, K, W, H)[0], atol=1e-6)
    full = _world(backend="cpu")
    full.set_poses(_poses(1))
    assert np.abs(rgb[0, 0] - full.render(view, K, W, H)[0]).mean() > 1e-3  # the scale really applied
    with pytest.raises(ValueError, match="distinct indices below 3"):
        batch.render(views, Ks, W, H, copies=[0, 0])
    with pytest.raises(ValueError, match="must be positive"):
        batch.set_scale(0, 0.0)


def test_bad_camera_stacks_are_named() -> None:
    batch = SplatWorldBatch(_world(backend="cpu"), 2)
    with pytest.raises(ValueError, match=r"viewmats \[2,C,4,4\]"):
        batch.render(np.eye(4)[None, None].repeat(3, 0), np.broadcast_to(K, (3, 1, 3, 3)), W, H)
    with pytest.raises(ValueError, match="one pose dict per copy"):
        batch.set_poses([_poses(0)])
    with pytest.raises(ValueError, match="at least one copy"):
        SplatWorldBatch(_world(backend="cpu"), 0)
