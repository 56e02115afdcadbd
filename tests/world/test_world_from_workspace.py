"""The world from a workspace's own reconstruction (the world stage, `m2m compose`).

The workspace is hand-made in the objects stage's format (objects/<name>/{mesh.obj, collision/, gaussians.ply,
align.json}) from the sample's meshes: the button as ONE remeshed solid (what a reconstruction gives: no
separate cap), the banana's placement floating 3 mm over the table; a scene splat that contains the objects
(table + board + each object's surface); calib/handeye.json with the sample's head camera.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh

from fixtures import SAMPLE
from mirage2matter.cli import main
from mirage2matter.gaussians.model import Gaussians
from mirage2matter.gaussians.ply import read_ply, write_ply
from mirage2matter.gaussians.transform import apply_sim3
from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.stages import get_stage, run_stage
from mirage2matter.workspace import Workspace, WorkspaceError
from mirage2matter.world import load_world
from mirage2matter.world.compose import WorldGaussians, consistency, write_world_ply
from mirage2matter.world.sample import _scene_stand_in, surface_gaussians

MARGIN = 0.01
WORLD = get_stage("world")


def from_workspace(ws: Path) -> dict:
    """The world stage as `m2m compose` runs it."""
    return run_stage(WORLD, Workspace(ws), WORLD.config(), log=lambda s: None)[0]


def _remeshed(mesh: trimesh.Trimesh, pitch: float = 0.002) -> trimesh.Trimesh:
    """A voxel remesh (marching cubes), bottom centre at the origin: a reconstruction-like single solid."""
    grid = mesh.voxelized(pitch).fill()
    out = grid.marching_cubes
    out.apply_transform(grid.transform)
    lo, hi = out.bounds
    out.apply_translation([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    return out


def _write_object(ws: Path, name: str, mesh: trimesh.Trimesh, placement: Sim3, seed: int) -> None:
    folder = ws / "objects" / name
    (folder / "collision").mkdir(parents=True)
    mesh.export(folder / "mesh.obj")
    write_ply(folder / "gaussians.ply", surface_gaussians(mesh, 3000, seed))
    for i, part in enumerate([mesh.convex_hull]):
        part.export(folder / "collision" / f"part_{i:02d}.obj")
    align = {"name": name, "sim3_obj_to_base": placement.to_json(), "mesh": {"density": 600.0}}
    (folder / "align.json").write_text(json.dumps(align))


@pytest.fixture(scope="module")
def recon_ws(tmp_path_factory) -> tuple[Path, dict[str, trimesh.Trimesh]]:
    """(workspace, {name: the object's mesh in the base frame where it really stands})."""
    from mirage2matter.world.sample_assets import build_assets

    gt_path = SAMPLE / "ground_truth.json"
    if not gt_path.is_file():
        pytest.skip(f"bundled sample missing at {SAMPLE}")
    gt = json.loads(gt_path.read_text())
    assets = {a.name: a for a in build_assets(0)}
    cap = assets["button_cap"].mesh.copy()
    cap.apply_translation([0.0, 0.0, 0.04])
    meshes = {
        "banana": assets["banana"].mesh,
        "croissant": assets["croissant"].mesh,
        "button": _remeshed(trimesh.util.concatenate([assets["button_base"].mesh, cap])),
    }
    poses = {n: np.asarray(assets[n if n != "button" else "button_base"].T_base_obj, float) for n in meshes}
    ws = tmp_path_factory.mktemp("recon_ws")
    truth = {}
    scene = [_scene_stand_in(0, 8000.0, gt)]
    for k, (name, mesh) in enumerate(meshes.items()):
        placement = Sim3.from_matrix(poses[name])
        scene.append(apply_sim3(surface_gaussians(mesh, 3000, 100 + k), placement))  # the splat holds the objects
        m = mesh.copy()
        m.apply_transform(placement.matrix)
        truth[name] = m
        if name == "banana":  # a reconstruction whose bottom stops 3 mm over the table
            placement = Sim3(1.0, placement.rotation, placement.translation + [0.0, 0.0, 0.003])
        _write_object(ws, name, mesh, placement, k)
    (ws / "objects" / "summary.json").write_text(json.dumps({n: {} for n in meshes}))
    (ws / "scene").mkdir()
    write_ply(ws / "scene" / "gaussians.ply", Gaussians.concat(scene))
    head = gt["head_camera"]
    (ws / "calib").mkdir()
    handeye = {"mount": "head", "T_base_headcam": head["T_base_headcam"], "K": head["K"], "width": head["width"]}
    (ws / "calib" / "handeye.json").write_text(json.dumps({**handeye, "height": head["height"]}))
    from_workspace(ws)
    return ws, truth


def test_world_from_reconstruction(recon_ws):
    ws, truth = recon_ws
    cfg = load_world(ws / "world")  # validates: files, names, no overlaps, nothing under the table
    assert [o.name for o in cfg.objects] == ["banana", "croissant"]
    assert [a.name for a in cfg.articulated] == ["button"] and cfg.articulated[0].kind == "press_button"
    head = json.loads((SAMPLE / "ground_truth.json").read_text())["head_camera"]
    assert np.allclose(cfg.cameras["head"].T_mount_cam, head["T_base_headcam"]) and cfg.cameras["head"].mount == "base"
    assert cfg.cameras["wrist"].mount == "hand"
    # the floating banana rests on the table, and its Gaussians came down with it
    banana = cfg.object("banana")
    assert banana.placement.translation[2] == pytest.approx(0.0, abs=1e-6)
    assert banana.density == 600.0 and banana.mass is None

    # Gaussians and meshes agree for every part, the button's base and cap included
    cons = consistency(cfg)
    assert set(cons) == {"banana", "croissant", "button", "button/cap"}
    assert max(cons.values()) <= 0.003, cons


def test_button_split_into_base_and_cap(recon_ws):
    ws, _ = recon_ws
    a = load_world(ws / "world").articulated_asset("button")
    # the cap (4 x 4 x 1.5 cm) sits on the 8 x 8 x 4 cm base: the cut is found at the step, not at a third
    z_cut = a.T_base_cap[2, 3]
    assert abs(z_cut - 0.041) <= 0.0025, z_cut  # the remesh shifted surfaces by up to a voxel (2 mm)
    assert np.abs(a.T_base_cap[:2, 3]).max() < 0.003
    cap = trimesh.load(a.cap.mesh, force="mesh")
    base = trimesh.load(a.base.mesh, force="mesh")
    assert cap.is_volume and base.is_volume
    assert 0.03 < cap.extents[0] < 0.05 and base.extents[0] > 0.075
    assert base.bounds[1, 2] == pytest.approx(z_cut, abs=1e-6) and cap.bounds[0, 2] == pytest.approx(0.0, abs=1e-6)
    for p in sorted(a.cap.collision.glob("*.obj")):
        part = trimesh.load(p, force="mesh")
        assert part.is_convex and part.bounds[0, 2] >= -1e-6
    for p in sorted(a.base.collision.glob("*.obj")):
        part = trimesh.load(p, force="mesh")
        assert part.is_convex and part.bounds[1, 2] <= z_cut + 1e-6
    assert (a.axis, a.travel) == ((0.0, 0.0, -1.0), 0.008)
    cap_g = read_ply(a.cap.gaussians)
    assert 100 < len(cap_g) < len(read_ply(a.base.gaussians))


def _surface_distance(mesh: trimesh.Trimesh, X: np.ndarray) -> np.ndarray:
    """Distance (m, ~1 mm accurate) from points [N,3] to a mesh surface, via dense surface samples."""
    from scipy.spatial import cKDTree

    pts, _ = trimesh.sample.sample_surface(mesh, 60000, seed=0)
    return cKDTree(pts).query(X)[0]


def test_scene_loses_the_objects_and_keeps_the_table(recon_ws):
    ws, truth = recon_ws
    cfg = load_world(ws / "world")
    g0, g1 = read_ply(ws / "scene" / "gaussians.ply"), read_ply(cfg.scene_gaussians)
    before, after = (g.means.numpy().astype(np.float64) for g in (g0, g1))
    near = lambda mesh, X: int(((_surface_distance(mesh, X) < 0.005) & (X[:, 2] > 0.003)).sum())
    for name, mesh in truth.items():
        assert near(mesh, before) > 1000, name  # the splat had the object
        assert near(mesh, after) == 0, name  # and now has none of it
    # 4 cm away from every object nothing changed
    far = lambda X: X[np.min([_surface_distance(m, X) for m in truth.values()], axis=0) > 0.04]
    assert np.array_equal(np.sort(far(after), axis=0), np.sort(far(before), axis=0))

    # every table Gaussian removed is replaced by a fill Gaussian within the fill spacing, coloured like the table
    from scipy.spatial import cKDTree

    table0, table1 = np.abs(before[:, 2]) < 0.002, np.abs(after[:, 2]) < 0.002
    gone = cKDTree(after).query(before)[0] > 1e-7
    removed = before[gone & table0]
    assert len(removed) > 50
    d, idx = cKDTree(after[table1]).query(removed)
    assert d.max() < 0.003
    rgb = lambda g: (g.sh[:, 0].numpy() * 0.28209479177387814 + 0.5).clip(0, 1)
    fills = np.unique(idx)
    kept_near = table1 & (cKDTree(before).query(after)[0] < 1e-7)
    ring = kept_near & (np.min([_surface_distance(m, after) for m in truth.values()], axis=0) < 0.03)
    assert np.abs(rgb(g1)[table1][fills].mean(0) - rgb(g1)[ring].mean(0)).max() < 0.1
    info = json.loads((ws / "world" / "reconstruction.json").read_text())["objects"]
    assert all(info[n]["scene_removed"] > 1000 and info[n]["scene_filled"] > 0 for n in truth)


def test_grasped_object_leaves_nothing_behind(recon_ws):
    ws, truth = recon_ws
    cfg = load_world(ws / "world")
    world = WorldGaussians.load(cfg)
    lifted = cfg.object("banana").placement.matrix.copy()
    lifted[2, 3] += 0.2
    X = world.at({"banana": lifted}).means.numpy().astype(np.float64)
    X = X[X[:, 2] > 0.003]
    assert (_surface_distance(truth["banana"], X) < 0.005).sum() == 0
    ply = write_world_ply(cfg)
    assert len(read_ply(ply)) == len(world.at())


def test_missing_inputs_name_the_stage(recon_ws, tmp_path):
    ws, _ = recon_ws
    bad = tmp_path / "ws"
    for sub in ("calib", "scene", "objects"):
        shutil.copytree(ws / sub, bad / sub)
    (bad / "calib" / "handeye.json").unlink()
    with pytest.raises(WorkspaceError, match="run `m2m calibrate-handeye"):
        from_workspace(bad)
    shutil.copy(ws / "calib" / "handeye.json", bad / "calib" / "handeye.json")
    (bad / "scene" / "gaussians.ply").unlink()
    with pytest.raises(WorkspaceError, match="run `m2m train-scene"):
        from_workspace(bad)
    shutil.copy(ws / "scene" / "gaussians.ply", bad / "scene" / "gaussians.ply")
    shutil.rmtree(bad / "objects")
    with pytest.raises(WorkspaceError, match="run `m2m objects"):
        from_workspace(bad)
    assert not (bad / "world" / "world.yaml").exists()


def test_head_camera_from_a_keyframe_and_the_wrist_camera_as_calibrated(recon_ws, tmp_path):
    # a capture whose fixed camera took one of its keyframes (a side camera in the SfM), and a wrist calibration
    from dataclasses import replace

    from mirage2matter.world.config import WorldConfigError

    ws, _ = recon_ws
    new = tmp_path / "ws"
    for sub in ("calib", "scene", "objects"):
        shutil.copytree(ws / sub, new / sub)
    head = json.loads((SAMPLE / "ground_truth.json").read_text())["head_camera"]
    K_side = [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]
    side = {"name": "side.jpg", "width": 640, "height": 480, "K": K_side, "T_world_cam": head["T_base_headcam"]}
    other = {**side, "name": "frame_000001.jpg", "T_world_cam": np.eye(4).tolist()}
    (new / "calib" / "cameras_base.json").write_text(json.dumps([other, side]))
    T_hand_cam = np.eye(4)
    T_hand_cam[:3, 3] = [0.05, 0.0, 0.04]
    K_wrist = [[600.0, 0, 424], [0, 600.0, 240], [0, 0, 1]]
    lens = {"k1": -0.05, "k2": 0.01, "p1": 0.0, "p2": 0.0, "k3": 0.0}
    wrist = {"mount": "wrist", "link": "hand", "T_hand_wristcam": T_hand_cam.tolist(), "K": K_wrist, "width": 848,
             "height": 480, "distortion": lens}
    (new / "calib" / "handeye.json").write_text(json.dumps(wrist))
    with pytest.raises(WorldConfigError, match="head_keyframe"):
        from_workspace(new)  # the only calibration is the wrist camera's
    bad = replace(WORLD.config(), head_keyframe="nowhere.jpg")
    with pytest.raises(WorldConfigError, match="'nowhere.jpg': not one of the capture's keyframes"):
        run_stage(WORLD, Workspace(new), bad, log=lambda s: None)
    assert not (new / "world").exists()  # nothing half-written
    record = run_stage(WORLD, Workspace(new), replace(bad, head_keyframe="side.jpg"), log=lambda s: None)[0]
    cfg = load_world(new / "world")
    assert cfg.cameras["head"].mount == "base" and np.allclose(cfg.cameras["head"].T_mount_cam, head["T_base_headcam"])
    assert np.allclose(cfg.cameras["head"].K, K_side) and cfg.cameras["head"].width == 640
    w = cfg.cameras["wrist"]
    assert w.mount == "hand" and np.allclose(w.T_mount_cam, T_hand_cam) and np.allclose(w.K, K_wrist)
    assert w.distortion == lens and cfg.cameras["head"].distortion == {}  # the world draws the wrist lens
    assert "keyframe side.jpg" in record["line"] and "wrist camera as calibrated (on hand)" in record["line"]
    assert "; wrist drawn through the calibrated lens" in record["line"]
    # a joints calibration records the model file it ran forward kinematics on: the same robot as "panda"
    from mirage2matter.robots.kinematics import robot_model_file

    (new / "calib" / "handeye.json").write_text(json.dumps({**wrist, "robot": robot_model_file("panda")}))
    record = run_stage(WORLD, Workspace(new), replace(bad, head_keyframe="side"), log=lambda s: None, force=True)[0]
    assert np.allclose(load_world(new / "world").cameras["wrist"].T_mount_cam, T_hand_cam), record["line"]
    # poses of libfranka's end-effector frame "EE", which the Panda's spec names (the hand + 103.4 mm along z): the
    # camera is mounted on the hand, the frame's offset composed in
    ee = {**wrist, "link": "EE", "T_EE_wristcam": wrist.pop("T_hand_wristcam")}
    (new / "calib" / "handeye.json").write_text(json.dumps(ee))
    record = run_stage(WORLD, Workspace(new), replace(bad, head_keyframe="side"), log=lambda s: None, force=True)[0]
    w = load_world(new / "world").cameras["wrist"]
    T_hand_ee = np.eye(4)
    T_hand_ee[2, 3] = 0.1034
    assert w.mount == "hand" and np.allclose(w.T_mount_cam, T_hand_ee @ T_hand_cam)
    assert "wrist camera as calibrated (on EE: hand +103.4 mm along z)" in record["line"]
    # poses of a frame neither the model nor its spec has: the robot's own mount, said so
    tool9 = {**wrist, "link": "tool9", "T_tool9_wristcam": T_hand_cam.tolist()}
    (new / "calib" / "handeye.json").write_text(json.dumps(tool9))
    record = run_stage(WORLD, Workspace(new), replace(bad, head_keyframe="side"), log=lambda s: None, force=True)[0]
    assert load_world(new / "world").cameras["wrist"].mount == "hand"
    assert not np.allclose(load_world(new / "world").cameras["wrist"].T_mount_cam, T_hand_cam)
    assert "link 'tool9' is neither a link of panda's model nor a frame its spec names" in record["line"]
    # a calibration of another robot's model: the default mount, said so
    (new / "calib" / "handeye.json").write_text(json.dumps({**ee, "robot": robot_model_file("ur5e")}))
    record = run_stage(WORLD, Workspace(new), replace(bad, head_keyframe="side"), log=lambda s: None, force=True)[0]
    assert "wrist camera at the robot's default mount (calibrate-handeye's is on" in record["line"]


def test_the_table_is_where_the_board_lies(recon_ws, tmp_path):
    # a robot standing on a frame above its table (the public real capture's: 3.8 cm): the board, which lies on the
    # table, gives its height; a board level with the base (its own thickness off) leaves the table at z = 0
    ws, _ = recon_ws
    new = tmp_path / "ws"
    for sub in ("calib", "scene", "objects"):
        shutil.copytree(ws / sub, new / sub)
    board = json.loads((SAMPLE / "board.json").read_text())
    for z, table_z in ((0.0005, 0.0), (-0.038, -0.038)):
        T = np.eye(4)
        T[:3, 3] = [0.3, -0.3, z]
        (new / "calib" / "sim3_sfm_to_base.json").write_text(json.dumps({"T_base_board": T.tolist(), "board": board}))
        record = run_stage(WORLD, Workspace(new), WORLD.config(), log=lambda s: None, force=True)[0]
        cfg = load_world(new / "world")
        assert cfg.table_z == pytest.approx(table_z, abs=2e-4)
        # the banana rests on that table (its reconstruction stood on z = 0)
        assert cfg.object("banana").placement.translation[2] == pytest.approx(table_z, abs=1e-6)
    assert "the table 38.0 mm below the robot's base" in record["line"]


def test_compose_cli_builds_the_world_from_the_workspace(recon_ws, tmp_path, capsys):
    ws, _ = recon_ws
    cli_ws = tmp_path / "ws"
    for sub in ("calib", "scene", "objects"):
        shutil.copytree(ws / sub, cli_ws / sub)
    assert main(["compose", "-w", str(cli_ws)]) == 0
    assert (cli_ws / "world" / "world.yaml").is_file() and (cli_ws / "world" / "world.ply").is_file()
    assert "button/cap: median Gaussian-to-mesh distance" in capsys.readouterr().out
    # edits survive a rerun (the reconstruction is unchanged: up to date); --force makes it again from it
    assert main(["world", "move", "-w", str(cli_ws), "--name", "banana", "--by", "0,-0.02,0"]) == 0
    y = load_world(cli_ws / "world").object("banana").placement.translation[1]
    assert main(["compose", "-w", str(cli_ws)]) == 0
    assert "up to date" in capsys.readouterr().out
    assert load_world(cli_ws / "world").object("banana").placement.translation[1] == pytest.approx(y)
    assert main(["compose", "-w", str(cli_ws), "--force"]) == 0
    assert load_world(cli_ws / "world").object("banana").placement.translation[1] == pytest.approx(y + 0.02)
    capsys.readouterr()
    assert main(["compose", "-w", str(tmp_path / "nowhere")]) == 2
    assert "not found" in capsys.readouterr().err


@pytest.mark.slow
def test_reconstructed_world_twin_grasps_and_presses(recon_ws):
    """The Genesis twin of the reconstructed world: the banana is lifted, the split button presses."""
    from mirage2matter.sim.tasks import parse_task, run_task
    from mirage2matter.sim.twin import Twin, TwinOptions

    ws, _ = recon_ws
    cfg = load_world(ws / "world")
    with Twin.build(cfg, TwinOptions(render=False)) as twin:
        results = {}
        for task in ("grasp banana", "press button"):
            twin.reset(seed=1)
            r = run_task(twin, parse_task(task, cfg))
            results[task] = (r.success, r.reason)
        print(results)
        assert all(ok for ok, _ in results.values()), results
