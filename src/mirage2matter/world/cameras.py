"""The world's robot cameras from a hand-eye calibration (calibrate-handeye's handeye.json): the calibrated head
camera, where a calibrated wrist camera is mounted, or why the robot's default mount is kept. One owner for the world,
which mounts them, for the stages that draw the head camera's view (head-view, train-scene --head-photo) and for the
calibration's line, which says beforehand what the world will do."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..robots import get_robot
from ..robots.kinematics import KinematicsError, RobotKinematics, robot_model_file
from .config import CameraConfig

if TYPE_CHECKING:
    from ..geometry.camera import Camera


def calibrated_head_camera(handeye: dict[str, Any], size: tuple[int, int] | None = None) -> tuple[Camera | None, str]:
    """(the head camera calibrate-handeye calibrated (``handeye``: its handeye.json) as a ``geometry.camera.Camera``
    (K, T_base_headcam, image size, lens), or None; what is missing when None). ``size`` (width, height) serves where
    the calibration records no image size (older files; a photo the camera took gives it)."""
    from ..geometry.camera import Camera

    if handeye.get("mount") != "head":
        return None, f"its mount is {handeye.get('mount', 'wrist')!r}, not a head camera"
    missing = [k for k in ("T_base_headcam", "K") if k not in handeye]
    if "width" not in handeye and size is None:
        missing.append("image size")
    if missing:
        return None, f"it records no {', '.join(missing)}"
    width, height = (handeye["width"], handeye["height"]) if "width" in handeye else size
    T, K = np.asarray(handeye["T_base_headcam"], np.float64), np.asarray(handeye["K"], np.float64)
    if T.shape != (4, 4) or K.shape != (3, 3):
        return None, "its T_base_headcam must be 4x4 and its K 3x3"
    return Camera(K, T, int(width), int(height), "head", handeye.get("distortion") or {}), ""


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
    return CameraConfig(parent, T, K, int(handeye["width"]), int(handeye["height"]), handeye.get("distortion") or {}), \
        f"the wrist camera as calibrated (on {on})"  # fmt: skip
