"""world.ply composition, visual-physical consistency, edits, SuperSplat placement import, lighting match."""

import numpy as np
import pytest
import torch
import trimesh

from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.ply import read_ply, write_ply
from mirage2matter.gaussians.transform import apply_sim3
from mirage2matter.geometry.rotation import random_rotation
from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.world import WorldConfigError, edit, load_world, save_world
from mirage2matter.world.compose import WorldGaussians, compose, consistency, part_names, write_world_ply
from mirage2matter.world.config import ObjectConfig, PartConfig, WorldConfig
from mirage2matter.world.sample import surface_gaussians


def test_compose_has_scene_and_every_part(sample_ws):
    cfg = load_world(sample_ws / "world")
    world = WorldGaussians.load(cfg)
    g = compose(cfg)
    ranges = world.ranges()
    assert list(ranges) == ["scene", *part_names(cfg)] == ["scene", "banana", "croissant", "button", "button/cap"]
    assert len(g) == max(b for _, b in ranges.values())
    # The cap sits on the base: its Gaussians are above the base's top (4 cm), around the placement's xy.
    a, b = ranges["button/cap"]
    cap = g.means[a:b].numpy()
    assert cap[:, 2].min() > 0.039
    assert np.allclose(cap[:, :2].mean(0), cfg.articulated[0].placement.translation[:2], atol=0.003)


def test_gaussians_lie_on_the_placed_meshes(sample_ws):
    for name, d in consistency(load_world(sample_ws / "world")).items():
        assert d <= 0.003, f"{name}: median Gaussian-to-mesh distance {1000 * d:.2f} mm"


def test_moving_an_object_in_world_yaml_moves_gaussians_and_mesh(sample_ws, tmp_path):
    cfg = load_world(sample_ws / "world")
    before = WorldGaussians.load(cfg)
    a, b = before.ranges()["croissant"]
    old = before.at().means[a:b].numpy()
    # Edit the YAML text itself: the croissant 5 cm along +y and turned 30 degrees.
    new_placement = edit.placement_from_pose(
        cfg.object("croissant").placement.translation + [0.0, 0.05, 0.0], 30.0, 1.0, cfg.object("croissant").placement
    )
    path = tmp_path / "world.yaml"
    save_world(edit.move(cfg, "croissant", new_placement), path)
    moved = load_world(path)
    new = WorldGaussians.load(moved).at().means[a:b].numpy()
    # Gaussians: exactly the new placement applied to the object-frame Gaussians.
    rel = Sim3.from_matrix(new_placement.matrix @ np.linalg.inv(cfg.object("croissant").placement.matrix))
    assert np.abs(rel.apply(old) - new).max() < 1e-5
    assert np.linalg.norm(new.mean(0) - old.mean(0)) > 0.04
    # Mesh: the consistency check places the mesh with the same (new) placement -> still on the Gaussians.
    assert consistency(moved)["croissant"] <= 0.003
    mesh = trimesh.load(str(moved.object("croissant").part.mesh), force="mesh")
    mesh.apply_transform(new_placement.matrix)
    assert np.allclose(mesh.bounds.mean(0)[:2], new[:, :2].min(0) / 2 + new[:, :2].max(0) / 2, atol=0.004)


def _known_sim3(seed=0) -> Sim3:
    rng = np.random.default_rng(seed)
    return Sim3(1.3, random_rotation(seed=rng), rng.uniform(-0.5, 0.5, 3))


def test_supersplat_round_trip_object_ply(sample_ws, tmp_path):
    cfg = load_world(sample_ws / "world")
    truth = _known_sim3(1)
    local = read_ply(cfg.object("banana").part.gaussians)
    write_ply(tmp_path / "banana_moved.ply", apply_sim3(local, truth))  # what SuperSplat exports (float32)
    new_cfg, sim = edit.import_placement(cfg, "banana", tmp_path / "banana_moved.ply")
    assert np.abs(sim.matrix - truth.matrix).max() < 1e-5
    assert np.abs(new_cfg.object("banana").placement.matrix - truth.matrix).max() < 1e-5


def test_supersplat_round_trip_whole_world_ply(sample_ws, tmp_path):
    cfg = load_world(sample_ws / "world")
    ply = write_world_ply(cfg, out_dir=cfg.root)
    world = read_ply(ply)
    a, b = WorldGaussians.load(cfg).ranges()["croissant"]
    # The person drags the croissant 12 cm and turns it 40 degrees about z in the viewer.
    old = cfg.object("croissant").placement
    truth = edit.placement_from_pose(old.translation + [-0.12, 0.03, 0.0], 40.0, old.scale, old)
    delta = truth @ old.inverse()
    moved = apply_sim3(world.select(slice(a, b)), delta)
    edited = Gaussians.concat([world.select(slice(0, a)), moved, world.select(slice(b, len(world)))])
    write_ply(tmp_path / "edited_world.ply", edited)
    _, sim = edit.import_placement(cfg, "croissant", tmp_path / "edited_world.ply")
    assert np.abs(sim.matrix - truth.matrix).max() < 1e-5


def test_supersplat_import_refuses_changed_gaussians(sample_ws, tmp_path):
    cfg = load_world(sample_ws / "world")
    local = read_ply(cfg.object("banana").part.gaussians)
    bent = local.map(lambda t: t.clone())
    bent.means[:, 2] += 0.3 * bent.means[:, 0] ** 2  # not a similarity
    write_ply(tmp_path / "bent.ply", bent)
    with pytest.raises(WorldConfigError, match="changed other than moved"):
        edit.import_placement(cfg, "banana", tmp_path / "bent.ply")
    write_ply(tmp_path / "fewer.ply", local.select(slice(0, 100)))
    with pytest.raises(WorldConfigError, match="Gaussians"):
        edit.import_placement(cfg, "banana", tmp_path / "fewer.ply")


def test_insert_duplicate_delete(sample_ws, tmp_path):
    cfg = load_world(sample_ws / "world")
    croissant = cfg.object("croissant")
    free_spot = edit.placement_from_pose((0.3, -0.35, 0.0), 0.0)
    new = edit.insert(
        cfg, "pastry", croissant.part.gaussians, croissant.part.mesh, free_spot,
        collision=croissant.part.collision, objects_dir=tmp_path / "objects", mass=0.05,
    )  # fmt: skip
    assert new.names == ["banana", "croissant", "pastry", "button"]
    assert (tmp_path / "objects" / "pastry" / "gaussians.ply").is_file()
    assert consistency(new)["pastry"] <= 0.003
    assert len(compose(new)) == len(compose(cfg)) + len(read_ply(croissant.part.gaussians))
    # Inserting on top of the banana fails and leaves no folder behind.
    on_banana = edit.placement_from_pose(cfg.object("banana").placement.translation, 0.0)
    with pytest.raises(WorldConfigError, match="overlap"):
        edit.insert(cfg, "bad", croissant.part.gaussians, croissant.part.mesh, on_banana,
                    collision=croissant.part.collision, objects_dir=tmp_path / "objects")  # fmt: skip
    assert not (tmp_path / "objects" / "bad").exists()
    with pytest.raises(WorldConfigError, match="taken"):
        edit.duplicate(new, "banana", "pastry", free_spot)
    dup = edit.duplicate(cfg, "banana", "banana2", edit.placement_from_pose((0.3, 0.35, 0.0), 90.0))
    assert dup.object("banana2").part.gaussians == dup.object("banana").part.gaussians
    gone = edit.delete(dup, "banana")
    assert "banana" not in gone.names and "banana2" in gone.names
    with pytest.raises(WorldConfigError, match="no object named"):
        edit.delete(gone, "banana")


def _flat_world(tmp_path, scene_rgb, asset_rgb) -> WorldConfig:
    """A table patch (scene) and a box (asset) whose Gaussians have the given colours [N,3]."""
    table = trimesh.creation.box((0.8, 0.8, 0.01))
    table.apply_translation((0.5, 0.0, -0.005))
    scene = surface_gaussians(table, len(scene_rgb), seed=1)
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    box.apply_translation((0.0, 0.0, 0.025))
    asset = surface_gaussians(box, len(asset_rgb), seed=2)
    for g, rgb in ((scene, scene_rgb), (asset, asset_rgb)):
        g.sh[:, 0] = (torch.as_tensor(rgb, dtype=torch.float32) - 0.5) / 0.28209479177387814
    (tmp_path / "box").mkdir()
    write_ply(tmp_path / "scene.ply", scene)
    write_ply(tmp_path / "box" / "gaussians.ply", asset)
    box.export(tmp_path / "box" / "mesh.obj")
    part = PartConfig(tmp_path / "box" / "gaussians.ply", tmp_path / "box" / "mesh.obj")
    obj = ObjectConfig("box", part, edit.placement_from_pose((0.5, 0.0, 0.0)))
    return WorldConfig(root=tmp_path, scene_gaussians=tmp_path / "scene.ply", objects=[obj])


def test_match_lighting_recovers_the_scene_illuminant(tmp_path):
    # Albedos averaging grey; the scene lit warm, the asset captured under a cold light.
    rng = np.random.default_rng(0)
    albedo_scene = rng.uniform(0.2, 0.8, (6000, 3))
    albedo_asset = rng.uniform(0.2, 0.8, (3000, 3))
    warm, cold = np.array([1.0, 0.85, 0.6]), np.array([0.55, 0.7, 1.0])
    cfg = _flat_world(tmp_path, albedo_scene * warm, albedo_asset * cold)
    new, gain = edit.match_lighting(cfg, "box", radius=0.4)
    assert np.allclose(gain, warm / cold, rtol=0.05)
    lit = read_ply(new.object("box").part.gaussians)
    rgb = (lit.sh[:, 0] * 0.28209479177387814 + 0.5).numpy()
    err_before = np.abs(albedo_asset * cold - albedo_asset * warm).mean()
    err_after = np.abs(rgb - albedo_asset * warm).mean()
    assert err_after < 0.02 < err_before
    assert new.object("box").part.gaussians.name == "gaussians_lit.ply"
    assert cfg.object("box").part.gaussians.name == "gaussians.ply"  # the input config is untouched
