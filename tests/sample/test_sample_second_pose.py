"""`m2m sample make` (`--one-pose` keeps the robot still): the robot moves once, half-way through the video, to a pose
that shows the orbit what the first hid. The second pose of each robot is within its limits and clear of the table,
the objects, the board and itself; the sample records the move (ground truth, m2m.yaml, config) and the video shows
each pose in its own frames (~1 minute on 2 cores)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mirage2matter.cli import main
from mirage2matter.robots import get_robot
from mirage2matter.world.sample_robot_look import capture_joints_for, second_pose_for

CLEARANCE = 0.03  # metres between the moved robot and the table top, the objects' and the board's boxes


@pytest.mark.parametrize("robot", ["panda", "ur5e"])
def test_the_second_pose_is_clear_of_the_sample_and_brings_the_hand_down_into_view(robot):
    import mujoco

    from mirage2matter.robots.model import load_model, resolve_model
    from mirage2matter.robots.surface import check_capture_joints, robot_surface
    from mirage2matter.sample.make import SampleConfig, with_robot_in_view
    from mirage2matter.sample.render import RenderConfig
    from mirage2matter.sample.trajectory import orbit_poses
    from mirage2matter.world.sample_assets import build_assets

    spec = get_robot(robot)
    q2 = check_capture_joints(spec, second_pose_for(spec), "second pose")  # within the joint limits
    q1 = check_capture_joints(spec, capture_joints_for(spec))
    assert np.abs(q2 - q1).max() > 0.3
    config = with_robot_in_view(SampleConfig())
    assets = build_assets(seed=0, board=config.board, layout=config.layout, board_at=config.board_at)
    links = robot_surface(spec, q2)
    for link in links[1:]:  # the base stands on the table
        v = link.vertices
        over_table = (v[:, 0] > -0.35) & (v[:, 0] < 1.05) & (np.abs(v[:, 1]) < 0.5)
        assert v[over_table, 2].min(initial=1.0) > CLEARANCE, link.link
        for a in assets:
            if a.category in ("board", "object", "button"):
                av = a.mesh.vertices @ a.T_base_obj[:3, :3].T + a.T_base_obj[:3, 3]
                inside = np.all((v > av.min(0) - CLEARANCE) & (v < av.max(0) + CLEARANCE), axis=1)
                assert not inside.any(), (link.link, a.name)
    model = load_model(resolve_model(spec.model), meshes=True)
    data = mujoco.MjData(model)
    data.qpos[: q2.size] = q2
    mujoco.mj_forward(model, data)
    assert not any(c.dist < 0 for c in data.contact[: data.ncon])  # no part of the robot in another

    # the hand comes down from above the orbit's view into the view of its second half
    hand = {x.link: x.T_base_link[:3, 3] for x in links}[spec.ee_link]
    assert hand[2] < {x.link: x.T_base_link[:3, 3] for x in robot_surface(spec, q1)}[spec.ee_link][2] - 0.15
    render = RenderConfig(width=config.width, height=config.height, fov_deg=config.fov_deg)
    _, poses = orbit_poses(config.orbit, seed=0)
    second_half = poses[len(poses) // 2 :]
    p = np.einsum("nij,j->ni", np.linalg.inv(second_half), np.append(hand, 1.0))[:, :3]
    uv = p @ render.K.T
    uv = uv[:, :2] / uv[:, 2:]
    in_view = (p[:, 2] > 0) & np.all((uv > 0) & (uv < (config.width, config.height)), axis=1)
    assert in_view.mean() > 0.5


@pytest.fixture(scope="module")
def moved_sample(tmp_path_factory):
    sample = tmp_path_factory.mktemp("second_pose") / "sample"
    assert main(["sample", "make", str(sample), "--short"]) == 0
    return sample, json.loads((sample / "ground_truth.json").read_text())


def test_the_sample_records_the_move_where_the_pipeline_reads_it(moved_sample):
    from fixtures import SAMPLE
    from mirage2matter.inputs import read_yaml
    from mirage2matter.stages.pipeline import PipelineConfig

    sample, gt = moved_sample
    spec = get_robot("panda")
    n_frames = gt["video"]["n_frames"]
    mid = str(n_frames // 2)
    q2 = second_pose_for(spec)
    assert list(gt["robot"]["capture_moves"]) == [mid]
    moved = np.asarray(gt["robot"]["capture_moves"][mid])
    assert moved.shape == (spec.n_dofs,) and np.allclose(moved[: spec.n_arm], q2)
    assert np.allclose(gt["robot"]["capture_joints"][: spec.n_arm], capture_joints_for(spec))
    assert gt["config"]["capture_moves"] == {mid: q2.tolist()}
    settings = read_yaml(sample / "m2m.yaml")
    assert settings["capture_moves"] == {int(mid): np.round(q2, 6).tolist()}
    assert "--one-pose" in (sample / "m2m.yaml").read_text()
    pipeline = PipelineConfig.load(sample / "m2m.yaml")
    assert {int(n): list(q) for n, q in pipeline.capture_moves.items()} == {int(mid): np.round(q2, 6).tolist()}
    # the head photo shows the robot at its first pose: the bundled sample's, byte for byte
    assert (sample / "head_view.png").read_bytes() == (SAMPLE / "head_view.png").read_bytes()


def test_the_frames_before_and_after_the_move_show_the_robot_at_their_own_pose(moved_sample):
    """The ground-truth world draws each frame's robot pixels (the union of its silhouettes at both poses) at that
    frame's pose to what H.264 leaves of them, and at the other pose far worse."""
    from mirage2matter.env.ground_truth import GroundTruthRenderer
    from mirage2matter.video import read_video_frames

    sample, gt = moved_sample
    mid = int(next(iter(gt["robot"]["capture_moves"])))
    q = {"before": gt["robot"]["capture_joints"], "after": gt["robot"]["capture_moves"][str(mid)]}
    video = {i: image for i, _, image in read_video_frames(sample / "scene.mp4") if i in (mid - 1, mid)}
    K = np.asarray(gt["camera"]["K"])
    with GroundTruthRenderer(sample, {"v": (K, gt["camera"]["width"], gt["camera"]["height"])}) as r:
        for i, own, other in ((mid - 1, "before", "after"), (mid, "after", "before")):
            T = {"v": np.asarray(gt["frames"][i]["T_base_cam"])}
            robot = np.zeros(video[i].shape[:2], bool)
            drawn = {}
            for pose in (own, other):
                drawn[pose] = r.render(T, robot_q=q[pose])["v"].astype(float)
                robot |= r.mask(r.segmentation(T)["v"], "robot")
            assert robot.mean() > 0.03
            err = {pose: np.abs(drawn[pose] - video[i].astype(float))[robot].mean() for pose in drawn}
            assert err[own] < 4.0 and err[other] > 5 * err[own], (i, err)


def test_the_second_pose_needs_the_robot_in_the_video(tmp_path, capsys):
    assert main(["sample", "make", str(tmp_path / "s"), "--short", "--one-pose", "--empty-table"]) != 0
    assert "--one-pose" in capsys.readouterr().err and not (tmp_path / "s").exists()
