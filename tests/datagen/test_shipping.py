"""A world as content (datagen/shipping.py): what the simulator's source ships to a worker on another machine, and
that the world unpacked there names only files there, with the same bytes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mirage2matter.datagen.shipping import ShippedFactory, pack, relocate, unpack
from mirage2matter.datagen.sim_source import SimSourceConfig, SimSourceFactory
from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.sim.tasks import parse_task
from mirage2matter.world.config import ObjectConfig, PartConfig, WorldConfig


def _world(ws: Path) -> WorldConfig:
    files = {"world/world.yaml": b"w", "scene/scene.ply": b"s" * 100, "scene/checkpoint.pt": b"never read",
             "objects/box/gaussians.ply": b"g", "objects/box/mesh.obj": b"mtllib mesh.mtl",
             "objects/box/mesh.mtl": b"map_Kd tex.png", "objects/box/tex.png": b"png",
             "objects/box/collision/part_0.obj": b"c"}  # fmt: skip
    for rel, data in files.items():
        (ws / rel).parent.mkdir(parents=True, exist_ok=True)
        (ws / rel).write_bytes(data)
    box = ws / "objects" / "box"
    part = PartConfig(box / "gaussians.ply", box / "mesh.obj", box / "collision")
    return WorldConfig(root=ws / "world", scene_gaussians=ws / "scene" / "scene.ply",
                       objects=[ObjectConfig("box", part, Sim3.identity())])  # fmt: skip


def test_a_sim_source_ships_its_worlds_files_and_names_them_where_unpacked(tmp_path: Path) -> None:
    ws = (tmp_path / "ws").resolve()
    world = _world(ws)
    factory = SimSourceFactory(SimSourceConfig(world=world, task=parse_task("grasp box")))
    shipped = factory.portable()
    assert isinstance(shipped, ShippedFactory)
    names = {rel for rel, _ in shipped.shipment.files}
    assert names == {"world/world.yaml", "scene/scene.ply", "objects/box/gaussians.ply", "objects/box/mesh.obj",
                     "objects/box/mesh.mtl", "objects/box/tex.png", "objects/box/collision/part_0.obj"}  # fmt: skip
    dest = unpack(shipped.shipment, tmp_path / "node")
    assert unpack(shipped.shipment, tmp_path / "node") == dest  # once per content
    local = relocate(factory, ws, dest)
    w = local.cfg.world
    assert w.root == dest / "world" and w.scene_gaussians == dest / "scene" / "scene.ply"
    assert w.objects[0].part.collision == dest / "objects" / "box" / "collision"
    assert (w.objects[0].part.mesh.parent / "tex.png").read_bytes() == b"png"
    assert world.scene_gaussians == ws / "scene" / "scene.ply"  # the driver's world is untouched
    assert np.array_equal(w.objects[0].placement.matrix, world.objects[0].placement.matrix)
    # the same content, the same digest; another byte, another
    assert pack([ws / "scene"], ws).digest == pack([ws / "scene"], ws).digest
    (ws / "scene" / "scene.ply").write_bytes(b"t" * 100)
    assert pack([ws / "scene"], ws).digest != shipped.shipment.digest
