"""The robot's link surfaces at a joint state, and the checks on a capture joint state."""

from __future__ import annotations

import numpy as np
import pytest

from mirage2matter.robots import get_robot
from mirage2matter.robots.kinematics import RobotKinematics
from mirage2matter.robots.surface import CaptureJointsError, check_capture_joints, robot_surface, sample_surface


@pytest.mark.parametrize("name", ["panda", "ur5e"])
def test_link_poses_are_the_kinematics_poses(name):
    """Each link's pose is forward kinematics' (the calibration's FK, computed apart), and its base-frame vertices are
    its link-frame vertices moved by that pose."""
    spec = get_robot(name)
    q = spec.home_q()
    q[0] += 0.4
    q[1] -= 0.2
    links = robot_surface(spec, q)
    names = [link.link for link in links]
    assert spec.ee_link in names and all(f in names for f in spec.finger_links)
    fk = RobotKinematics(name)
    for link in links:
        np.testing.assert_allclose(link.T_base_link, fk.link_pose(q, link.link), atol=1e-9)
        T = link.T_base_link
        np.testing.assert_allclose(link.vertices, link.vertices_link @ T[:3, :3].T + T[:3, 3])
    # turning only the first joint (about the base's vertical axis) turns the hand's surface with it
    turned = spec.home_q()
    turned[0] += 0.4
    hand = next(link for link in robot_surface(spec, turned) if link.link == spec.ee_link)
    hand0 = next(link for link in robot_surface(spec, spec.home_q()) if link.link == spec.ee_link)
    c, s = np.cos(0.4), np.sin(0.4)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(hand.vertices, hand0.vertices @ Rz.T, atol=1e-6)


def test_surface_samples_lie_on_the_links_and_cover_them():
    spec = get_robot("panda")
    links = robot_surface(spec, spec.home)
    pts, owner = sample_surface(links, 0.01, seed=3)
    area = sum(link.area for link in links)
    assert abs(len(pts) - area / 0.01**2) < len(links) + 1  # one point per square centimetre, per link rounded up
    for i, link in enumerate(links):
        mine = pts[owner == i]
        lo, hi = link.vertices.min(0) - 1e-9, link.vertices.max(0) + 1e-9
        assert np.all((mine >= lo) & (mine <= hi))
    again, _ = sample_surface(links, 0.01, seed=3)
    np.testing.assert_array_equal(pts, again)


def test_capture_joints_default_to_home_with_the_fingers_open():
    spec = get_robot("panda")
    np.testing.assert_array_equal(check_capture_joints(spec, None), spec.home_q(spec.gripper_open))
    q = check_capture_joints(spec, list(spec.home))
    assert q.shape == (spec.n_dofs,) and np.all(q[spec.n_arm :] == spec.gripper_open)


@pytest.mark.parametrize(
    ("values", "words"),
    [
        ([0.0, 0.1], ["2 values given", "7 arm joints"]),
        ([0.0, -45.0, 0.0, -135.0, 0.0, 90.0, 45.0], ["degrees", "radians"]),
        ([0.0, -0.78, 0.0, -2.36, 0.0, 1.57, 3.5], ["joint7", "outside its limits"]),
        ([0.0, float("nan"), 0.0, -2.36, 0.0, 1.57, 0.78], ["joint2", "finite"]),
    ],
)
def test_a_capture_joint_state_that_does_not_fit_the_robot_is_named(values, words):
    with pytest.raises(CaptureJointsError) as e:
        check_capture_joints(get_robot("panda"), values, "align capture_joints")
    assert "align capture_joints" in str(e.value)
    for w in words:
        assert w in str(e.value)


@pytest.mark.parametrize(
    ("joints", "words"),
    [(["0", "1"], "2 values given"), (["0", "-45", "0", "-135", "0", "90", "45"], "reads as degrees")],
)
def test_align_scene_refuses_a_bad_capture_joint_state_before_anything_is_written(tmp_path, capsys, joints, words):
    from fixtures import SAMPLE
    from mirage2matter.cli import main

    ws = tmp_path / "ws"
    ws.mkdir()
    assert main(["align-scene", "-w", str(ws), "--board", str(SAMPLE / "board.json"), "--capture-joints", *joints]) == 2
    err = capsys.readouterr().err
    assert "align capture_joints" in err and words in err and "Traceback" not in err
    assert not any(ws.iterdir())
