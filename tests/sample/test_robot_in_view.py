"""A capture with the robot in it (`m2m sample make --robot-in-view`): the robot stands at its base at a logged joint
state with a look of its own, the board beside it. align-scene finds the robot's SfM points and keeps them out of
the scene, its surface agrees with the board's alignment at the true joint state and disagrees at a wrong one, and
no scene Gaussian learns the robot (slow: ~6 minutes on 2 cores)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from mirage2matter.cli import main


def _m2m(*args: str) -> None:
    assert main(list(args)) == 0, args


@pytest.fixture(scope="module")
def robot_sample(tmp_path_factory):
    from mirage2matter.sample.make import SampleConfig, make_sample, with_robot_in_view

    sample = tmp_path_factory.mktemp("robot_sample") / "sample"
    gt = make_sample(sample, with_robot_in_view(SampleConfig.short()), log=lambda _m: None)
    return sample, gt


@pytest.mark.slow
def test_the_ground_truth_world_draws_the_robot_in_the_videos_look(robot_sample):
    """The ground-truth world at a video frame's pose and the capture joints renders that frame, robot included (to
    what H.264 leaves of it); with the robot taken out its pixels are the room's."""
    import av

    from mirage2matter.env.ground_truth import GroundTruthRenderer

    sample, gt = robot_sample
    with av.open(str(sample / "scene.mp4")) as c:
        video = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    K = np.asarray(gt["camera"]["K"])
    with GroundTruthRenderer(sample, {"v": (K, gt["camera"]["width"], gt["camera"]["height"])}) as r:
        for i in (0, len(video) // 2):
            T = {"v": np.asarray(gt["frames"][i]["T_base_cam"])}
            img = r.render(T, robot_q=gt["robot"]["capture_joints"])["v"]
            robot = r.mask(r.segmentation(T)["v"], "robot")
            assert robot.mean() > 0.02
            err = (img.astype(float) - video[i].astype(float)) ** 2
            assert 10 * np.log10(255.0**2 / err[robot].mean()) > 30.0
            r.set_state(robot_visible=False)
            hidden = r.render(T)["v"]
            r.set_state(robot_visible=True)
            assert np.abs(hidden.astype(float) - img.astype(float))[robot].mean() > 20.0


@pytest.mark.slow
def test_the_robot_in_the_capture_is_found_aligned_to_and_kept_out_of_the_scene(tmp_path, robot_sample):
    from mirage2matter.calib.robot_view import visual_hull  # noqa: F401 (imports the calib layer once)
    from mirage2matter.gaussians.ply import read_ply
    from mirage2matter.inputs import read_yaml
    from mirage2matter.robots import get_robot
    from mirage2matter.robots.surface import robot_surface, sample_surface
    from mirage2matter.stages.align import compare
    from mirage2matter.stages.pipeline import PipelineConfig
    from mirage2matter.workspace import Workspace

    sample, gt = robot_sample
    spec = get_robot("panda")
    q = np.asarray(gt["robot"]["capture_joints"])
    settings = read_yaml(sample / "m2m.yaml")
    np.testing.assert_allclose(settings["capture_joints"], q[: spec.n_arm], atol=1e-6)
    assert not np.allclose(q[: spec.n_arm], spec.home)  # the default (home) is not the truth
    T_board = np.asarray(gt["board"]["T_base_board"])
    assert np.hypot(*T_board[:2, 3]) > 0.2  # the board lies beside the base, not under it

    ws = tmp_path / "ws"
    _m2m("capture", str(sample / "scene.mp4"), "-w", str(ws))
    _m2m("sfm", "-w", str(ws), "--intrinsics", str(sample / "ground_truth.json"))
    joints = [str(v) for v in q[: spec.n_arm]]
    wrong = tmp_path / "ws_home"
    shutil.copytree(ws, wrong)
    _m2m("align-scene", "-w", str(ws), "--board", str(sample / "board.json"), "--board-pose",
         str(sample / "ground_truth.json"), "--capture-joints", *joints)  # fmt: skip
    robot = json.loads((ws / "calib" / "robot.json").read_text())
    assert robot["seen"] and robot["points_removed"] >= 30 and "warning" not in robot, robot
    assert robot["fit"]["rms_before_mm"] < 5.0 and robot["on_fraction"] > 0.9
    w = Workspace(ws)
    cfg = PipelineConfig.load(w.config_file).align
    err = compare(w, cfg, gt)
    assert err["rotation_deg"] < 0.3 and err["translation_mm"] < 3.0, err
    # the robot's points left the scene's points for a file of their own
    robot_pts = np.load(w.robot_points_file)
    scene_pts = w.posed_capture().points
    links = robot_surface(spec, q)
    surface, _ = sample_surface(links, 0.003)
    from scipy.spatial import cKDTree

    d_scene = cKDTree(surface).query(scene_pts[scene_pts[:, 2] > 0.03])[0]
    assert len(robot_pts) == robot["points_removed"] and (d_scene < 0.008).sum() <= 2

    # the robot's home instead of the logged joints: the disagreement is named
    _m2m("align-scene", "-w", str(wrong), "--board", str(sample / "board.json"), "--board-pose",
         str(sample / "ground_truth.json"))  # fmt: skip
    home = json.loads((wrong / "calib" / "robot.json").read_text())
    assert "capture_joints" in home.get("warning", "") and home["capture_joints_source"].startswith("the robot's home")

    # no Gaussian of the scene learns the robot
    _m2m("train-scene", "-w", str(ws), "--iterations", "300")
    metrics = json.loads((ws / "scene" / "metrics.json").read_text())
    assert metrics["robot"]["masked_fraction"] > 0.02
    g = read_ply(ws / "scene" / "gaussians.ply")
    means = g.means.detach().numpy()
    opaque = g.opacities.detach().numpy() > 0.3
    d = cKDTree(surface).query(means)[0]
    on_robot = (d < 0.01) & (means[:, 2] > 0.03) & opaque
    assert on_robot.sum() <= 0.002 * len(g), (on_robot.sum(), len(g))

    # the robot as the capture saw it: per-link Gaussians on its meshes, in its paint, not the model's white
    robot_dir = ws / "scene" / "robot"
    look = json.loads((robot_dir / "robot.json").read_text())
    assert set(look["links"]) >= {spec.ee_link, *spec.finger_links}
    assert all((robot_dir / f).is_file() for f in look["links"].values())
    assert look["psnr_captured"] > look["psnr_mesh_look"] + 3.0, look
    assert look["seen_fraction"]["link0"] > 0.5
