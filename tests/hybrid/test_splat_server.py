"""SplatServer: one process drawing several workers' splat layers, batched. Its frames are each slot's world posed
alike and rendered alone (with the slot's own object scale and table look), slots that ask together are drawn in
one batch, and a server that fails or dies is a clear error at its clients, never a hang."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from test_composite import H, K, W, _blob, _camera
from test_splat_batch import _poses

from mirage2matter.gaussians.ply import write_ply
from mirage2matter.render import SplatRenderOptions, SplatWorld
from mirage2matter.render.splat_server import RemoteSplatLayer, SplatServer, SplatServerError
from mirage2matter.render.table_texture import TableGaussians, TableTexture

OPTIONS = SplatRenderOptions(backend="cpu", sh_degree=1)
TABLE_Z = -0.05


def write_parts(d) -> dict:
    """A wooden table top (coloured Gaussians on the plane z = TABLE_Z) and two movable parts, as PLY files in d."""
    table = _blob((0.5, 0.0, TABLE_Z), (0.6, 0.4, 0.2), n=1500, radius=0.12, seed=4)
    table.means[:, 2] = TABLE_Z
    files = {"scene": table, "a": _blob((0, 0, 0.02), (0.9, 0.1, 0.1), seed=5),
             "b": _blob((0, 0, 0.02), (0.1, 0.1, 0.9), seed=6)}  # fmt: skip
    for name, g in files.items():
        write_ply(d / f"{name}.ply", g)
    return {"scene": str(d / "scene.ply"), "parts": [["a", str(d / "a.ply"), 1.0], ["b", str(d / "b.ply"), 1.2]]}


@pytest.fixture(scope="module")
def parts(tmp_path_factory) -> dict:
    return write_parts(tmp_path_factory.mktemp("splat_server"))


VIEWS = np.stack([_camera((0.0, 0.0, 0.5)), _camera((0.4, 0.1, 0.3), target=(0.5, 0.0, 0.0))])
KS = np.stack([K, K])


def _alone(parts, poses, scale=1.0, texture=None):
    """(rgb, alpha, depth) [C, ...] of a world of its own posed alike: the reference."""
    import torch

    world = SplatWorld.from_files(parts, OPTIONS)
    for p in world.parts:
        p.scale *= scale
    if texture is not None:
        table = TableGaussians.find(world.gaussians, world.static_rows, TABLE_Z)
        with torch.no_grad():
            world.gaussians.sh[table.rows, 0] = table.sh_dc(texture)
    world.set_poses(poses)
    out = [world.render(v, k, W, H, (0.1, 0.2, 0.3)) for v, k in zip(VIEWS, KS, strict=True)]
    return tuple(np.stack([o[i] for o in out]) for i in range(3))


def test_slots_draw_their_own_episodes_batched(parts):
    texture = TableTexture.sample(np.random.default_rng(1), 0.3)
    server = SplatServer(parts, OPTIONS, slots=2, cameras=2, size=(W, H), background=(0.1, 0.2, 0.3),
                         table_z=TABLE_Z, gather_ms=20_000)  # fmt: skip
    with server as handle:
        layers = [RemoteSplatLayer(handle), RemoteSplatLayer(handle)]
        assert sorted(x.slot for x in layers) == [0, 1]
        layers[0].start_episode()
        layers[1].start_episode(object_scale=0.6, table_texture=texture)
        frames: dict = {}

        def ask(i: int, k: int) -> None:
            frames[i] = layers[i].render(_poses(k), VIEWS, KS)

        # both ask at once: the server waits for the second (gather_ms) and draws them in one batch
        threads = [threading.Thread(target=ask, args=(i, i + 1)) for i in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for got, want in ((frames[0], _alone(parts, _poses(1))), (frames[1], _alone(parts, _poses(2), 0.6, texture))):
            for g, r in zip(got, want, strict=True):
                np.testing.assert_allclose(g, r, atol=1e-6)
        assert np.abs(frames[1][0] - _alone(parts, _poses(2))[0]).mean() > 1e-3  # the slot's look really applied

        with pytest.raises(ValueError, match=r"2 camera\(s\)"):
            layers[0].render(_poses(1), VIEWS[:1], KS[:1])
        with pytest.raises(SplatServerError, match="slots is taken"):
            RemoteSplatLayer(handle, slot_wait_s=0.5)
        freed = layers[0].slot
        layers[0].close()  # detached: the server no longer waits for its frames

        # slot 1's next episode is back to the world as built (the table exactly)
        layers[1].start_episode()
        ask(1, 2)
        for g, r in zip(frames[1], _alone(parts, _poses(2)), strict=True):
            np.testing.assert_allclose(g, r, atol=1e-6)
        assert RemoteSplatLayer(handle).slot == freed  # a freed slot is taken again
    stats = server.close()
    assert stats["largest_batch"] == 2 and stats["frames"] == 3 and stats["gaussians"] == 1500 + 400 + 400


def test_a_server_that_cannot_start_or_dies_is_a_clear_error(parts, tmp_path):
    broken = {"scene": str(tmp_path / "missing.ply"), "parts": []}
    with pytest.raises(SplatServerError, match="failed to start.*missing.ply"):
        SplatServer(broken, OPTIONS, slots=1, cameras=2, size=(W, H)).start()
    server = SplatServer(parts, OPTIONS, slots=1, cameras=2, size=(W, H))
    handle = server.start()
    layer = RemoteSplatLayer(handle)
    server.proc.kill()
    server.proc.join()
    with pytest.raises(SplatServerError, match="died"):
        layer.render(_poses(0), VIEWS, KS)
    server.close()
    with pytest.raises(ValueError, match="at least one slot"):
        SplatServer(parts, OPTIONS, slots=0, cameras=2, size=(W, H))
