"""Datagen frames on the GPU: the Gaussian world (SplatWorld) rendered by gsplat agrees with the numba CPU
frames of test_composite.py, including a part culled to nothing (which must never reach gsplat with N = 0:
gsplat 1.5.3 kills the process with SIGFPE). Skipped without a CUDA GPU and gsplat."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from test_composite import H, K, W, _blob, _camera

from fixtures.cuda import CUDA_MARKS
from mirage2matter.render import MovablePart, SplatRenderOptions, SplatWorld

pytestmark = CUDA_MARKS


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / max(np.mean((a - b) ** 2), 1e-30)))


def _worlds(**kw):
    scene = _blob((0.5, 0.0, -0.05), (0.3, 0.3, 0.3), n=1500, radius=0.12, seed=4)
    a, b = _blob((0, 0, 0.02), (0.9, 0.1, 0.1), seed=5), _blob((0, 0, 0.02), (0.1, 0.1, 0.9), seed=6)
    parts = [MovablePart("a", a), MovablePart("b", b, scale=1.2)]
    return tuple(SplatWorld(scene, parts, SplatRenderOptions(backend=be, **kw)) for be in ("cpu", "cuda"))


def test_frames_match_the_cpu_frames_as_parts_move():
    cpu, gpu = _worlds()
    poses = {"a": np.eye(4), "b": np.eye(4)}
    poses["a"][:3, 3] = (0.45, -0.08, 0.0)
    poses["b"][:3, 3] = (0.55, 0.08, 0.0)
    head, wrist = _camera((0.0, 0.0, 0.5)), _camera((0.4, 0.1, 0.3), target=(0.5, 0.0, 0.0))
    for lift in (0.0, 0.05, 0.12):
        poses["a"][2, 3] = lift
        for world in (cpu, gpu):
            world.set_poses(poses)
        for view in (head, wrist):
            c, g = cpu.render(view, K, W, H), gpu.render(view, K, W, H)
            assert _psnr(g[0], c[0]) >= 35.0 and _psnr(g[1], c[1]) >= 35.0
            sure = (c[1] > 0.5) & (g[1] > 0.5)
            assert sure.mean() > 0.05
            assert np.abs(g[2][sure] - c[2][sure]).mean() <= 1e-2 * c[2][sure].mean()
        c, g = cpu.render_static_camera("head", head, K, W, H), gpu.render_static_camera("head", head, K, W, H)
        assert _psnr(g[0], c[0]) >= 35.0


def test_a_part_out_of_view_renders_without_reaching_gsplat_empty():
    """The moving part carried out of the head camera's view: culled to nothing, rendered as nothing."""
    cpu, gpu = _worlds(cull=True)
    poses = {"a": np.eye(4), "b": np.eye(4)}
    poses["b"][:3, 3] = (0.55, 0.08, 0.0)
    head = _camera((0.0, 0.0, 0.5))
    for world in (cpu, gpu):
        world.render_static_camera("head", head, K, W, H)  # first frame: everything at rest
    poses["a"][:3, 3] = (0.5, 0.0, 3.0)  # far above the camera: out of its view
    for world in (cpu, gpu):
        world.set_poses(poses)
    c, g = cpu.render_static_camera("head", head, K, W, H), gpu.render_static_camera("head", head, K, W, H)
    assert _psnr(g[0], c[0]) >= 35.0
    empty = SplatWorld(None, [MovablePart("a", _blob((0, 0, 0), (1, 0, 0)))], SplatRenderOptions(backend="cuda"))
    empty.set_poses({"a": poses["a"]})
    rgb, alpha, depth = empty.render(head, K, W, H, background=(0.2, 0.4, 0.6))
    assert not alpha.any() and not depth.any() and np.allclose(rgb, (0.2, 0.4, 0.6))


def test_a_batch_of_worlds_in_one_gsplat_call_matches_the_cpu_worlds():
    """SplatWorldBatch on the GPU (one gsplat call for B copies x C cameras) against each copy's CPU frames."""
    from test_splat_batch import _poses
    from test_splat_batch import _world as _batch_world

    from mirage2matter.render import SplatWorldBatch

    batch = SplatWorldBatch(_batch_world(backend="cuda"), 3)
    assert batch.worlds[0].device.type == "cuda"
    batch.set_poses([_poses(k) for k in range(3)])
    views = np.stack([np.stack([_camera((0.0, 0.0, 0.5)), _camera((0.4, 0.1, 0.3), target=(0.5, 0.0, 0.0))])] * 3)
    rgb, alpha, depth = batch.render(views, np.broadcast_to(K, (3, 2, 3, 3)), W, H, background=(0.1, 0.2, 0.3))
    for k in range(3):
        alone = _batch_world(backend="cpu")
        alone.set_poses(_poses(k))
        for c in range(2):
            r, a, _ = alone.render(views[k, c], K, W, H, background=(0.1, 0.2, 0.3))
            assert _psnr(rgb[k, c], r) >= 35.0 and _psnr(alpha[k, c], a) >= 35.0
    assert np.abs(rgb[0, 0] - rgb[1, 0]).mean() > 1e-3


def test_a_splat_server_on_the_gpu_draws_each_slot_as_the_cpu_does(tmp_path):
    """generate --splat-server's renderer on the GPU: two of three slots asking together, drawn in one gsplat call,
    each slot's frames (one with its own object scale and table look) as its CPU world's."""
    import threading

    from test_splat_batch import _poses
    from test_splat_server import KS, OPTIONS, TABLE_Z, VIEWS, _alone, write_parts

    from mirage2matter.render.splat_server import RemoteSplatLayer, SplatServer
    from mirage2matter.render.table_texture import TableTexture

    parts = write_parts(tmp_path)
    texture = TableTexture.sample(np.random.default_rng(1), 0.3)
    server = SplatServer(parts, replace(OPTIONS, backend="cuda"), slots=3, cameras=2, size=(W, H),
                         background=(0.1, 0.2, 0.3), table_z=TABLE_Z, gather_ms=20_000)  # fmt: skip
    frames = {}
    with server as handle:
        layers = [RemoteSplatLayer(handle) for _ in range(2)]  # 2 of 3 slots: the batch drawn is a subset
        layers[0].start_episode()
        layers[1].start_episode(object_scale=0.6, table_texture=texture)

        def ask(i: int) -> None:
            frames[i] = layers[i].render(_poses(i + 1), VIEWS, KS)

        threads = [threading.Thread(target=ask, args=(i,)) for i in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert server.stats["largest_batch"] == 2
    for i, want in ((0, _alone(parts, _poses(1))), (1, _alone(parts, _poses(2), 0.6, texture))):
        for c in range(2):
            assert _psnr(frames[i][0][c], want[0][c]) >= 35.0 and _psnr(frames[i][1][c], want[1][c]) >= 35.0
