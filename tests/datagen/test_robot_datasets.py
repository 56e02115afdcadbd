"""Datasets generated with the second robot (the UR5e with the Franka hand) in the sample world: hybrid frames with
that robot composited, valid for the independent reader, its joints' names in state and action and its
robot_type (slow: builds the rendering twin and renders every frame, ~2-3 minutes)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mirage2matter.datagen import GenerateConfig, RunConfig, generate
from mirage2matter.env.config import EpisodeSpec
from mirage2matter.export.validate import validate
from mirage2matter.robots import get_robot
from mirage2matter.sim.tasks import parse_task
from mirage2matter.world import load_world


@pytest.mark.slow
@pytest.mark.parametrize("text", ["grasp banana", "press button"])
def test_ur5e_datasets_validate_with_its_names(sample_world_ws, tmp_path, text):
    ws = sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0, robot="ur5e")
    world = load_world(ws / "world")
    spec = get_robot("ur5e")
    out = tmp_path / "ds"
    cfg = GenerateConfig(RunConfig(episodes=2, preview=0), EpisodeSpec((96, 96)))
    summary = generate(world, parse_task(text, world), out, cfg, log=lambda _m: None, progress=False)
    assert summary["episodes"] == 2
    assert validate(out) == []
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["robot_type"] == spec.robot_type == "ur5e"
    assert info["features"]["observation.state"]["names"] == list(spec.state_names)
    assert info["features"]["action"]["names"] == [*spec.arm_joints, "gripper"]
    import pyarrow.parquet as pq

    table = pq.read_table(next((out / "data").rglob("*.parquet")))
    state = np.stack(table.column("observation.state").to_numpy(zero_copy_only=False))
    assert state.shape[1] == 8 and np.abs(state[0, :6] - spec.home).max() < 0.05  # the UR5e's joints at home
