"""The world built from the objects stage's real output (slow: ~5 minutes on 2 cores).

Workspace: the sample's keyframes and ground-truth cameras (``ground_truth_workspace``), a short
objects stage for the banana and the button (one rigid reconstruction), a synthetic scene splat holding the
objects, and the sample's head camera. Then the world stage -> a world whose Gaussians and meshes agree, whose
button is cut into base and cap, and whose Genesis twin grasps the reconstructed banana and presses the button.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fixtures import SAMPLE
from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.ply import write_ply
from mirage2matter.gaussians.transform import apply_sim3
from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.stages import get_stage, run_stage
from mirage2matter.workspace import Workspace
from mirage2matter.world import load_world
from mirage2matter.world.compose import consistency
from mirage2matter.world.sample import _scene_stand_in, surface_gaussians


@pytest.fixture(scope="module")
def staged_ws(tmp_path_factory) -> Path:
    from fixtures.ground_truth_workspace import ground_truth_workspace
    from mirage2matter.objects.matting import MattingConfig
    from mirage2matter.objects.reconstruct import ObjectsConfig
    from mirage2matter.objects.splat import SplatConfig
    from mirage2matter.world.sample_assets import build_assets

    if not (SAMPLE / "ground_truth.json").is_file():
        pytest.skip(f"bundled sample missing at {SAMPLE}")
    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    ws = tmp_path_factory.mktemp("staged_ws")
    ground_truth_workspace(ws, SAMPLE, n_keyframes=24)
    run_stage(
        get_stage("objects"),
        Workspace(ws),
        ObjectsConfig(
            names=["banana=0.42,0.16", "button=0.62,0.30"],
            matting=MattingConfig(iterations=600, init_gaussians=8000, max_gaussians=20000),
            splat=SplatConfig(iterations=400, sh_degree=1, max_gaussians=20000),
            voxel=0.0025,
            figure_views=0,
        ),
        log=lambda s: None,
    )
    scene = [_scene_stand_in(0, 8000.0, gt)]
    for k, a in enumerate(x for x in build_assets(0) if x.name in ("banana", "croissant", "button_base", "button_cap")):
        scene.append(apply_sim3(surface_gaussians(a.mesh, 3000, 50 + k), Sim3.from_matrix(np.asarray(a.T_base_obj))))
    (ws / "scene").mkdir()
    write_ply(ws / "scene" / "gaussians.ply", Gaussians.concat(scene))
    head = gt["head_camera"]
    handeye = {k: head[k] for k in ("T_base_headcam", "K", "width", "height")}
    (ws / "calib" / "handeye.json").write_text(json.dumps({"mount": "head", **handeye}))
    run_stage(get_stage("world"), Workspace(ws), get_stage("world").config(), log=lambda s: None)
    return ws


@pytest.mark.slow
def test_world_from_the_objects_stage(staged_ws):
    cfg = load_world(staged_ws / "world")
    assert [o.name for o in cfg.objects] == ["banana"] and [a.name for a in cfg.articulated] == ["button"]
    cons = consistency(cfg)
    print("consistency mm", {k: round(1000 * v, 2) for k, v in cons.items()})
    assert max(cons.values()) <= 0.003, cons
    info = json.loads((staged_ws / "world" / "reconstruction.json").read_text())["objects"]
    print("button", info["button"])
    # the cap is the red top: its cut lies near the true step (40 mm), found from the shape
    assert info["button"]["cap_cut_from"] == "step"
    assert 0.036 <= info["button"]["cap_cut_height_m"] <= 0.048
    # the scene lost both objects, and the table under them is filled
    assert all(info[n]["scene_removed"] > 1000 and info[n]["scene_filled"] > 200 for n in ("banana", "button"))


@pytest.mark.slow
def test_twin_of_the_reconstructed_world(staged_ws):
    from mirage2matter.sim.tasks import parse_task, run_task
    from mirage2matter.sim.twin import Twin, TwinOptions

    cfg = load_world(staged_ws / "world")
    outcomes = {}
    with Twin.build(cfg, TwinOptions(render=False)) as twin:
        for task in ("grasp banana", "press button"):
            for seed in range(3):
                twin.reset(seed=seed)
                r = run_task(twin, parse_task(task, cfg))
                outcomes[(task, seed)] = (r.success, r.reason)
    print(outcomes)
    assert all(ok for ok, _ in outcomes.values()), outcomes
