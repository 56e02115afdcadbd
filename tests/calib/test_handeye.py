"""Hand-eye calibration against exact synthetic data and the rendered sample's ground truth."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from PIL import Image

from fixtures import SAMPLE
from mirage2matter.calib.board import BoardSpec
from mirage2matter.calib.handeye import (
    METHODS,
    HandEyeError,
    calibrate_from_files,
    calibrate_handeye,
    detect_board_pose,
)
from mirage2matter.cli import main
from mirage2matter.robots.kinematics import RobotKinematics


def _pose(rng: np.random.Generator, angle_deg: float, shift: float) -> np.ndarray:
    axis = rng.normal(size=3)
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(axis / np.linalg.norm(axis) * np.radians(angle_deg))[0]
    T[:3, 3] = rng.normal(size=3) * shift
    return T


def _errors(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    dR = T[:3, :3].T @ T_true[:3, :3]
    return float(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))), float(
        1000 * np.linalg.norm(T[:3, 3] - T_true[:3, 3])
    )


@pytest.mark.parametrize("mount", ["head", "wrist"])
@pytest.mark.parametrize("method", METHODS)
def test_exact_synthetic_data_is_recovered(mount, method):
    rng = np.random.default_rng(1)
    # camera mount, board mount: a head camera within a metre or so of the base, a wrist camera on the hand
    X, Y = _pose(rng, 120, 0.5 if mount == "head" else 0.08), _pose(rng, 60, 0.1)
    T_links = [_pose(rng, 40, 0.3) @ np.diag([1.0, 1, 1, 1]) for _ in range(12)]
    for T in T_links:
        T[:3, 3] += [0.5, 0.0, 0.4]
    inv = np.linalg.inv
    if mount == "head":  # camera fixed in the base, board on the link
        T_cam = [inv(X) @ Tl @ Y for Tl in T_links]
    else:  # camera on the link, board fixed in the base
        T_cam = [inv(X) @ inv(Tl) @ Y for Tl in T_links]
    result = calibrate_handeye(T_links, T_cam, mount, method)
    deg, mm = _errors(result.T, X)
    assert deg < 1e-4 and mm < 1e-3
    assert max(result.residual_mm) < 1e-3


def test_degenerate_motions_and_bad_input_are_refused():
    rng = np.random.default_rng(2)
    T_links = []
    for k in range(8):  # all rotations about the same (z) axis
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(np.array([0, 0, np.radians(10 * k)]))[0]
        T[:3, 3] = rng.normal(size=3) * 0.1
        T_links.append(T)
    with pytest.raises(HandEyeError, match="single axis"):
        calibrate_handeye(T_links, T_links, "head")
    with pytest.raises(HandEyeError, match="pair up"):
        calibrate_handeye(T_links, T_links[:-1], "head")
    with pytest.raises(HandEyeError, match="at least 3"):
        calibrate_handeye(T_links[:2], T_links[:2], "head")
    with pytest.raises(HandEyeError, match="unknown hand-eye method"):
        calibrate_handeye(T_links, T_links, "head", method="magic")


@pytest.fixture(scope="module")
def sample():
    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    board = BoardSpec.load(SAMPLE / "handeye" / "board.json")
    return gt, board, np.asarray(gt["head_camera"]["K"]), np.asarray(gt["head_camera"]["T_base_headcam"])


def test_sample_head_camera_within_tolerance(sample):
    gt, board, K, T_true = sample
    result, out = calibrate_from_files(SAMPLE / "handeye" / "images", SAMPLE / "handeye" / "joints.json", board, K)
    deg, mm = _errors(result.T, T_true)
    assert deg <= 0.1 and mm <= 1.0, (deg, mm)
    assert not out["skipped"] and len(out["per_view"]) >= 15
    # the board mount it finds is the one the sample used
    deg_b, mm_b = _errors(result.T_board, np.asarray(gt["handeye"]["T_hand_board"]))
    assert deg_b <= 0.1 and mm_b <= 1.0


def test_a_joints_file_of_another_robot_is_named_not_calibrated(sample):
    """The pipeline's robot has a default (the Panda): a joints file that names another arm is refused before any
    image is read, naming both, while the same robot named two ways (registered name, model file) is accepted."""
    _, board, K, _ = sample
    images, joints = SAMPLE / "handeye" / "images", SAMPLE / "handeye" / "joints.json"
    with pytest.raises(HandEyeError, match=r"names the robot .*panda.xml.* but the calibration was given 'ur5e'"):
        calibrate_from_files(images, joints, board, K, robot="ur5e")
    result, _ = calibrate_from_files(images, joints, board, K, robot="panda")  # the file's model, by its name
    assert result.T.shape == (4, 4)


def test_sample_with_noisy_robot_poses(sample):
    gt, board, K, T_true = sample
    joints = json.loads((SAMPLE / "handeye" / "joints.json").read_text())
    views, gt_link = joints["views"], joints["link"]
    kin = RobotKinematics(gt["handeye"].get("robot"))  # default: the default robot's model
    obs = [detect_board_pose(np.asarray(Image.open(SAMPLE / "handeye" / v["image"]).convert("RGB")), board, K)
           for v in views]  # fmt: skip
    rng = np.random.default_rng(0)
    T_links = []
    for v in views:  # 0.05 deg / 0.3 mm of end-effector pose noise
        T = kin.link_pose(v["joints"], gt_link)
        axis = rng.normal(size=3)
        T[:3, :3] = cv2.Rodrigues(axis / np.linalg.norm(axis) * np.radians(0.05))[0] @ T[:3, :3]
        shift = rng.normal(size=3)
        T[:3, 3] += 0.0003 * shift / np.linalg.norm(shift)
        T_links.append(T)
    result = calibrate_handeye(T_links, [o.T_cam_board for o in obs], "head", "tsai", observations=obs, K=K)
    deg, mm = _errors(result.T, T_true)
    assert deg <= 0.15 and mm <= 1.5, (deg, mm)


def test_cli_writes_handeye_json_and_names_the_problem(tmp_path, capsys):
    args = ["calibrate-handeye", "--images", str(SAMPLE / "handeye" / "images")]
    args += ["--joints", str(SAMPLE / "handeye" / "joints.json"), "--intrinsics", str(SAMPLE / "ground_truth.json")]
    assert main([*args, "--board", str(SAMPLE / "handeye" / "board.json"), "-w", str(tmp_path)]) == 0
    out = json.loads((tmp_path / "calib" / "handeye.json").read_text())
    assert out["mount"] == "head" and np.asarray(out["T_base_headcam"]).shape == (4, 4)
    # the table board's spec is not the held board: clear error, nothing written
    assert main([*args, "--board", str(SAMPLE / "board.json"), "-w", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "found in only 0 of 18 images" in err and "0000.png" in err
    assert not (tmp_path / "x" / "calib" / "handeye.json").exists()


def test_the_stage_says_where_the_world_will_mount_a_wrist_camera():
    """In the world's own words: poses of a link or of a frame the robot's spec names mount on the link; of a frame
    nobody names: the world keeps the default mount, said where the calibration is made."""
    from mirage2matter.stages.handeye import Config, _mount_note

    wrist = Config(mount="wrist", robot="panda")

    def calibration(link: str) -> dict:
        return {"mount": "wrist", "link": link, f"T_{link}_wristcam": np.eye(4).tolist(), "K": np.eye(3).tolist(),
                "width": 640, "height": 480}  # fmt: skip

    assert _mount_note(wrist, calibration("hand")) == "; in the world: the wrist camera as calibrated (on hand)"
    assert _mount_note(wrist, calibration("EE")) == ("; in the world: the wrist camera as calibrated (on EE: hand "
                                                     "+103.4 mm along z)")  # fmt: skip
    assert ("default mount (calibrate-handeye's link 'tool9' is neither a link of panda's model nor a frame its spec "
            "names") in _mount_note(wrist, calibration("tool9"))  # fmt: skip
    assert _mount_note(Config(mount="head", robot="panda"), calibration("tool9")) == ""


def test_head_poses_in_the_model_s_base_on_a_robot_with_another_base_frame_are_questioned():
    """A UR's controller logs poses in its own base (ur_base, the model's turned 180 deg): a head camera calibrated
    from end-effector poses with no base_frame says so; joint angles, a base_frame given, a wrist camera or a robot
    whose spec names no such frame (the Panda) say nothing."""
    from mirage2matter.stages.handeye import Config, _base_frame_note

    ur, ee = Config(mount="head", robot="ur5e"), {"poses": "ee"}
    assert "if the controller logged them in base_link or ur_base, set the poses file's base_frame" in \
        _base_frame_note(ur, ee)  # fmt: skip
    assert _base_frame_note(ur, {"poses": "joints"}) == _base_frame_note(ur, {**ee, "base_frame": "ur_base"}) == ""
    assert _base_frame_note(Config(mount="wrist", robot="ur5e"), ee) == ""
    assert _base_frame_note(Config(mount="head", robot="panda"), ee) == ""
