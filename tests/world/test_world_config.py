"""world.yaml: round trip, and bad input caught with clear messages before anything is simulated."""

import shutil

import numpy as np
import pytest
import yaml

from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.world import WorldConfigError, load_world, save_world
from mirage2matter.world.config import world_yaml_path


def _edit_yaml(ws, tmp_path, fn):
    """A second world.yaml in the same workspace with fn applied to its dict; returns its path."""
    cfg = load_world(ws / "world")
    out = ws / f"edited_{tmp_path.name}" / "world.yaml"  # a world folder of the same workspace
    save_world(cfg, out)
    data = yaml.safe_load(out.read_text())
    fn(data)
    out.write_text(yaml.safe_dump(data))
    return out


def test_round_trip(sample_ws, tmp_path):
    cfg = load_world(sample_ws / "world")
    assert [o.name for o in cfg.objects] == ["banana", "croissant"]
    assert [a.name for a in cfg.articulated] == ["button"]
    out = save_world(cfg, sample_ws / "copy" / "world.yaml")  # another folder of the workspace: paths re-relativised
    again = load_world(out)
    assert again.to_dict()["objects"][0]["placement"] == cfg.to_dict()["objects"][0]["placement"]
    assert again.objects[0].part.mesh == cfg.objects[0].part.mesh  # relative paths re-resolved to the same files
    assert np.allclose(again.cameras["head"].T_mount_cam, cfg.cameras["head"].T_mount_cam)
    assert again.articulated[0].travel == pytest.approx(0.008)


def test_unknown_robot_file(sample_ws, tmp_path):
    path = _edit_yaml(sample_ws, tmp_path, lambda d: d["robot"].update(file="xml/no_such_robot.xml"))
    with pytest.raises(WorldConfigError, match=r"robot\.file.*no_such_robot"):
        load_world(path)


def test_object_without_mesh(sample_ws, tmp_path):
    path = _edit_yaml(sample_ws, tmp_path, lambda d: d["objects"][0].update(mesh=None))
    with pytest.raises(WorldConfigError, match=r"banana.*no mesh"):
        load_world(path)


def test_missing_mesh_file(sample_ws, tmp_path):
    path = _edit_yaml(sample_ws, tmp_path, lambda d: d["objects"][1].update(mesh="../missing/croissant.obj"))
    with pytest.raises(WorldConfigError, match=r"croissant.*not found"):
        load_world(path)
    path = _edit_yaml(sample_ws, tmp_path, lambda d: d["objects"][1].update(mesh="/etc/croissant.obj"))
    with pytest.raises(WorldConfigError, match=r"croissant.*outside the workspace"):
        load_world(path)


def test_overlapping_objects(sample_ws, tmp_path):
    cfg = load_world(sample_ws / "world")
    banana = cfg.object("banana").placement

    def put_croissant_on_banana(d):
        d["objects"][1]["placement"] = Sim3(1.0, np.eye(3), banana.translation + [0.01, 0.0, 0.0]).to_json()

    path = _edit_yaml(sample_ws, tmp_path, put_croissant_on_banana)
    with pytest.raises(WorldConfigError, match=r"'banana' and 'croissant' overlap"):
        load_world(path)


def test_object_below_table(sample_ws, tmp_path):
    def sink(d):
        d["objects"][0]["placement"]["translation"][2] = -0.02

    with pytest.raises(WorldConfigError, match="below the table"):
        load_world(_edit_yaml(sample_ws, tmp_path, sink))


def test_unknown_field_and_duplicate_name(sample_ws, tmp_path):
    with pytest.raises(WorldConfigError, match="unknown field"):
        load_world(_edit_yaml(sample_ws, tmp_path, lambda d: d["objects"][0].update(colour="yellow")))
    with pytest.raises(WorldConfigError, match="used twice"):
        load_world(_edit_yaml(sample_ws, tmp_path, lambda d: d["objects"][1].update(name="banana")))


def test_camera_on_unknown_link(sample_ws, tmp_path):
    with pytest.raises(WorldConfigError, match="cameras.wrist.mount"):
        load_world(_edit_yaml(sample_ws, tmp_path, lambda d: d["cameras"]["wrist"].update(mount="gripper_cam")))


def test_missing_world(tmp_path):
    with pytest.raises(WorldConfigError, match="not found"):
        load_world(tmp_path)
    assert world_yaml_path(tmp_path) == tmp_path / "world.yaml"  # a world folder: no guessing of workspaces


def test_collision_folder_without_parts(sample_ws, tmp_path):
    empty = sample_ws / f"edited_{tmp_path.name}" / "empty_collision"
    empty.mkdir(parents=True)
    path = _edit_yaml(sample_ws, tmp_path, lambda d: d["objects"][0].update(collision=str(empty)))
    with pytest.raises(WorldConfigError, match="convex"):
        load_world(path)
    shutil.rmtree(empty)
