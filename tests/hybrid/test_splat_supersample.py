"""SplatRenderOptions.supersample: the splat layer drawn at s x the frame size and box-averaged down. A Gaussian far
smaller than a pixel keeps (close to) its own footprint instead of swelling to the rasterizer's minimum one, nothing
moves by a sub-pixel, and the batched path draws the same frames."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from test_composite import H, K, W, _blob, _camera

from mirage2matter.gaussians.model import Gaussians
from mirage2matter.render import MovablePart, SplatRenderOptions, SplatWorld, SplatWorldBatch
from mirage2matter.render.splat_world import box_down


def _dot(sigma: float, xy=(0.0, 0.0), depth: float = 4.0) -> Gaussians:
    """One grey Gaussian of world sigma ``sigma`` at (x, y, depth) in front of an identity-pose camera, opacity 0.5."""
    one = lambda *v: torch.tensor([v], dtype=torch.float32)
    return Gaussians(one(xy[0], xy[1], depth), one(1.0, 0.0, 0.0, 0.0), torch.full((1, 3), math.log(sigma)),
                     one(0.0).reshape(1), torch.zeros(1, 1, 3))  # fmt: skip


def _render(g: Gaussians, s: int, f: float = 100.0, size: int = 32):
    world = SplatWorld(g, [], SplatRenderOptions(backend="cpu", supersample=s))
    Kc = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]])
    return world.render(np.eye(4), Kc, size, size)


def test_a_sub_pixel_gaussian_keeps_its_own_footprint_as_s_grows():
    """Classic splatting adds 0.3 px^2 to every projected covariance: a Gaussian of screen variance v covers
    opacity * 2 pi (v + 0.3) px^2 of alpha. Drawn at s x and averaged down, the 0.3 is a high-res pixel's:
    opacity * 2 pi (v + 0.3 / s^2) output px^2, which tends to the Gaussian's own area."""
    sigma = 0.004  # at focal 100 and depth 4: 0.1 px
    var = (100.0 * sigma / 4.0) ** 2
    ink = {}
    for s in (1, 2, 4, 8):
        _, alpha, _ = _render(_dot(sigma), s)
        ink[s] = float(alpha.astype(np.float64).sum())
        # a few % of the mass lies in tails below alpha 1/255, which are not drawn
        assert ink[s] == pytest.approx(0.5 * 2 * math.pi * (var + 0.3 / s**2), rel=0.05), s
    assert ink[8] < ink[4] < ink[2] < ink[1] / 3
    assert ink[8] < 3 * 0.5 * 2 * math.pi * var  # within a few x of the true area (classic: 31 x)


@pytest.mark.parametrize("xy", [(0.0, 0.0), (0.013, -0.021)])
def test_supersampling_moves_nothing(xy):
    """The s x view's intrinsics keep pixel centres where they were: a dot's alpha centroid stays put to a
    hundredth of a pixel (an off-by-half-pixel principal point would move it by (s - 1) / 2s px). The dot spans a
    few pixels (sigma 0.75 px): a sub-pixel one's box-averaged centroid snaps towards its block's centre."""
    def centroid(s):
        _, a, _ = _render(_dot(0.03, xy), s)
        yy, xx = np.mgrid[: a.shape[0], : a.shape[1]]
        return np.array([(a * xx).sum(), (a * yy).sum()]) / a.sum()

    where = [16 + 100 * xy[0] / 4 - 0.5, 16 + 100 * xy[1] / 4 - 0.5]  # pixel i's centre is at i + 0.5
    for s in (1, 2, 3, 4):
        np.testing.assert_allclose(centroid(s), where, atol=0.01)


def test_a_well_resolved_world_looks_the_same_and_depth_stays_expected_depth():
    scene = _blob((0.5, 0.0, -0.05), (0.3, 0.5, 0.3), n=1500, radius=0.12, seed=4)
    part = _blob((0, 0, 0.02), (0.9, 0.1, 0.1), seed=5)
    T = np.eye(4)
    T[:3, 3] = (0.45, 0.0, 0.15)
    frames = {}
    for s in (1, 3):
        w = SplatWorld(scene, [MovablePart("a", part)], SplatRenderOptions(backend="cpu", supersample=s))
        w.set_poses({"a": T})
        frames[s] = w.render(_camera((0.0, 0.0, 0.5)), K, W, H, background=(0.1, 0.2, 0.3))
        assert frames[s][0].shape == (H, W, 3) and frames[s][1].shape == frames[s][2].shape == (H, W)
    (r1, a1, d1), (r3, a3, d3) = frames[1], frames[3]
    mse = float(((r1 - r3) ** 2).mean())
    assert 10 * math.log10(1 / mse) > 30  # blobs of ~4 px sigma: the same picture, anti-aliased
    covered = (a1 > 0.9) & (a3 > 0.9)
    assert covered.sum() > 0.3 * H * W
    assert np.median(np.abs(d1[covered] - d3[covered])) < 0.005  # metres


def test_box_down_weights_depth_by_alpha():
    rgb = np.zeros((2, 2, 3), np.float32)
    alpha = np.array([[1.0, 0.0], [0.5, 0.5]], np.float32)
    depth = np.array([[1.0, 0.0], [2.0, 4.0]], np.float32)  # 0 where nothing was drawn, as the renderers write
    r, a, d = box_down(rgb, alpha, depth, 2)
    assert r.shape == (1, 1, 3) and a[0, 0] == pytest.approx(0.5)
    assert d[0, 0] == pytest.approx((1.0 + 1.0 + 2.0) / 2.0)  # (1*1 + .5*2 + .5*4) / (1 + .5 + .5)
    _, a, d = box_down(rgb, np.zeros((2, 2), np.float32), depth, 2)
    assert a[0, 0] == 0 and d[0, 0] == 0


def test_the_batched_cpu_path_supersamples_alike():
    scene = _blob((0.5, 0.0, -0.05), (0.3, 0.3, 0.3), n=600, radius=0.12, seed=4)
    opts = SplatRenderOptions(backend="cpu", supersample=2)
    batch = SplatWorldBatch(SplatWorld(scene, [], opts), 2)
    views = np.stack([np.stack([_camera((0.0, 0.0, 0.5))])] * 2)
    rgb, alpha, depth = batch.render(views, np.broadcast_to(K, (2, 1, 3, 3)), W, H)
    alone = SplatWorld(scene, [], opts).render(views[0, 0], K, W, H)
    assert rgb.shape == (2, 1, H, W, 3)
    np.testing.assert_allclose(rgb[1, 0], alone[0], atol=1e-6)
    np.testing.assert_allclose(depth[0, 0], alone[2], atol=1e-6)


@pytest.mark.parametrize("bad", [0, 9, 1.5])
def test_bad_supersample_is_refused(bad):
    with pytest.raises(ValueError, match="supersample must be an integer from 1 to 8"):
        SplatRenderOptions(supersample=bad)
