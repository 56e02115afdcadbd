"""The world's robot cameras from a hand-eye calibration (calibrate-handeye's handeye.json): where a calibrated wrist
camera is mounted, or why the robot's default mount is kept. One owner for the world, which mounts it, and for the
calibration's line, which says beforehand what the world will do."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..robots import get_robot
from ..robots.kinematics import KinematicsError, RobotKinematics, robot_model_file
from .config import CameraConfig


def calibrated_wrist_camera(handeye: dict[str, Any], robot: str) -> tuple[CameraConfig | None, str]:
    """(the wrist camera calibrate-handeye calibrated (``handeye``: its handeye.json), or None: the robot's default
    mount; the words saying which). Poses of a frame the robot's spec names (libfranka's "EE", UR's "tool0") mount
    the camera on that frame's link."""
    if handeye.get("mount") != "wrist":
        return None, "the wrist camera at the robot's default mount"
    spec, link = get_robot(robot), str(handeye.get("link"))
    # handeye.json records the robot's model file (older ones: none for end-effector poses)
    if handeye.get("robot") is not None and robot_model_file(handeye["robot"]) != robot_model_file(robot):
        return None, f"the wrist camera at the robot's default mount (calibrate-handeye's is on {handeye['robot']})"
    try:
        parent, T_link_frame = RobotKinematics(robot).frame(link)
    except KinematicsError:
        return None, (f"the wrist camera at the robot's default mount (calibrate-handeye's link {link!r} is neither a "
                      f"link of {spec.name}'s model nor a frame its spec names: calibrate from joint angles, or add "
                      "the frame to the robot's spec (frames:)")  # fmt: skip
    T = T_link_frame @ np.asarray(handeye[f"T_{link}_wristcam"], np.float64)
    K = np.asarray(handeye["K"], np.float64)
    on = link if parent == link else f"{link}: {spec.frame(link).describe()}"
    return CameraConfig(parent, T, K, int(handeye["width"]), int(handeye["height"])), \
        f"the wrist camera as calibrated (on {on})"  # fmt: skip
