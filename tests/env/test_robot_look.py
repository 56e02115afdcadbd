"""The robot drawn from its own Gaussians in the hybrid frames: posed by forward kinematics in the same splat pass as
the world, no Genesis camera in the loop; ``robot_look mesh`` keeps the Genesis robot composited over the splats."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
import yaml

SIZE = 96


@pytest.fixture(scope="module")
def green_robot_ws(sample_world_ws, tmp_path_factory):
    """The sample world with robot Gaussians painted green (as train-scene writes them: scene/robot/)."""
    from mirage2matter.gaussians.ply import write_ply
    from mirage2matter.gaussians.robot import mesh_gaussians
    from mirage2matter.gaussians.sh import rgb_to_sh_dc
    from mirage2matter.robots import get_robot
    from mirage2matter.robots.surface import robot_surface

    ws = tmp_path_factory.mktemp("robot_look") / "ws"
    shutil.copytree(sample_world_ws(), ws)
    spec = get_robot("panda")
    out = ws / "scene" / "robot"
    out.mkdir(parents=True)
    links = {}
    for name, g in mesh_gaussians(robot_surface(spec, spec.home), spacing=0.006).items():
        g.sh[:, 0] = rgb_to_sh_dc(torch.tensor([0.0, 1.0, 0.0]))
        write_ply(out / f"{name}.ply", g)
        links[name] = f"{name}.ply"
    (out / "robot.json").write_text(json.dumps({"robot": "panda", "links": links}))
    world = ws / "world" / "world.yaml"
    data = yaml.safe_load(world.read_text())
    data["robot"]["gaussians"] = "../scene/robot"
    world.write_text(yaml.safe_dump(data, sort_keys=False))
    return ws


def _green(frame: np.ndarray) -> np.ndarray:
    f = frame.astype(int)
    return (f[..., 1] > 150) & (f[..., 1] > f[..., 0] + 80) & (f[..., 1] > f[..., 2] + 80)


def test_the_gaussian_robot_is_where_the_mesh_robot_is_without_a_genesis_camera(green_robot_ws):
    from mirage2matter.env.config import hybrid_options
    from mirage2matter.env.twin_env import TwinEnv

    env = TwinEnv(green_robot_ws / "world", "grasp banana", size=SIZE, hybrid=hybrid_options(robot_look="gaussians"))
    try:
        obs, _ = env.reset(seed=0)
        assert env.twin.cameras == {}  # nothing for Genesis to draw: no camera in the per-frame loop
        head, wrist = obs["observation.images.head"], obs["observation.images.wrist"]
        assert env.renderer.timings["robot_render"] == 0.0
    finally:
        env.close()
    env = TwinEnv(green_robot_ws / "world", "grasp banana", size=SIZE, hybrid=hybrid_options(robot_look="mesh"))
    try:
        obs, _ = env.reset(seed=0)
        mask = env.twin.render_robot("head", SIZE, SIZE)["robot_mask"]
        assert not _green(obs["observation.images.head"]).any()  # the mesh look has no green paint
    finally:
        env.close()
    green = _green(head)
    iou = (green & mask).sum() / max((green | mask).sum(), 1)
    assert mask.sum() > 50 and iou > 0.7, (iou, mask.sum(), green.sum())
    assert _green(wrist).mean() > 0.01  # the hand's fingers in the wrist camera


def test_a_world_without_robot_gaussians_refuses_the_gaussian_look(sample_world_ws):
    from mirage2matter.env.config import hybrid_options
    from mirage2matter.world import load_world

    world = load_world(sample_world_ws() / "world")
    assert not hybrid_options(robot_look="auto").robot_gaussians(world)
    with pytest.raises(ValueError, match="no robot Gaussians"):
        hybrid_options(robot_look="gaussians").robot_gaussians(world)
