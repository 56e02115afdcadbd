"""Stage ``handeye``: the camera's mount in the robot's kinematic chain from images of a calibration board and
the robot's poses (joint angles or end-effector poses): Tsai-Lenz on lens-corrected corners, refined with each
view's robot pose error modelled, judged by its leave-one-out corner error -> ``calib/handeye.json``."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..atomic import atomic_write
from ..calib.board import load_target
from ..calib.handeye import HandEyeError, calibrate_from_files
from ..geometry.camera import load_intrinsics
from ..robots import DEFAULT_ROBOT
from ..robots.kinematics import RobotKinematics
from ..workspace import Workspace
from .base import SHARED, Input, Log


@dataclass
class Config:
    """calibrate-handeye settings.

    images      folder of the camera's images of the board
    joints      JSON of the robot's pose per image: {"robot", "link", "units", "views": [{"image", "joints": [rad]}
                or {"image", "T_base_link": 4x4} or {"image", "position", "quaternion_xyzw" | "quaternion_wxyz" |
                "rpy"}]}; units (default m, rad): {"position": "m"|"mm", "rotation": "rad"|"deg", "joints": ...}
    board       the calibration target's spec JSON (from `m2m board`: ChArUco, ArUco marker, AprilTag, grid)
    intrinsics  the camera's intrinsics with its lens distortion: our JSON (K, width, height, distortion, or such an
                object under "head_camera"), OpenCV calibration YAML/XML, ROS camera_info, COLMAP cameras.txt or
                RealSense intrinsics JSON
    mount       head: eye-to-hand, the camera fixed in the base (T_base_headcam); wrist: eye-in-hand
    method      OpenCV's closed-form hand-eye solver
    robot       the robot: a registered name (panda, ur5e), a robot spec file or a bare model file (MJCF/URDF)
                (default: the joints file's, else the default robot). In a workspace: the pipeline's robot (m2m.yaml's
                top-level robot); giving it here changes it for every stage
    link        the link holding the board (head) or the camera (wrist), or a frame the robot's spec names (the
                Panda's: libfranka's "EE", franka_ros's panda_hand ...; the UR5e's: UR's tool0, flange) (default: the
                joints file's, else the robot's end-effector link)
    refine      auto: pose_error or none, whichever has the lower leave-one-out corner error; pose_error: refine on
                the corner pixels with each view's robot pose error modelled (~1 mm / 0.1 deg); exact: refine taking
                the robot poses as exact (wrong on real arms, kept to compare); none: the closed form
    poses       which robot poses to use: joints (forward kinematics), ee (end-effector poses), auto (joints when
                every view has them)
    """

    images: Path | None = None
    joints: Path | None = None
    board: Path | None = None
    intrinsics: Path | None = None
    mount: Literal["head", "wrist"] = "head"
    method: Literal["tsai", "park", "horaud", "andreff", "daniilidis"] = "tsai"
    robot: str | None = field(default=None, metadata=SHARED)
    link: str | None = None
    refine: Literal["auto", "pose_error", "exact", "none"] = "auto"
    poses: Literal["auto", "joints", "ee"] = "auto"

    @staticmethod
    def upgrade(data: dict[str, Any]) -> dict[str, Any]:
        """A workspace's settings from before ``refine`` had variants: true (the default then) -> the default now,
        false -> none."""
        if isinstance(data.get("refine"), bool):
            data["refine"] = "auto" if data["refine"] else "none"
        return data

    def validate(self) -> None:
        missing = [n for n in ("images", "joints", "board", "intrinsics") if getattr(self, n) is None]
        if missing:
            raise HandEyeError(f"calibrate-handeye: give {', '.join('--' + n for n in missing)}")


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    names = ("images", "joints", "board", "intrinsics")
    return [Input(Path(getattr(cfg, n)), field=f"handeye {n}") for n in names if getattr(cfg, n) is not None]


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    cam = load_intrinsics(cfg.intrinsics, keys=("head_camera",))
    result, out = calibrate_from_files(
        cfg.images, cfg.joints, load_target(cfg.board), cam, mount=cfg.mount, method=cfg.method,
        robot=cfg.robot, link=cfg.link, refine=cfg.refine, poses=cfg.poses,
    )  # fmt: skip
    out.update(width=cam.width, height=cam.height, distortion=cam.distortion_json())
    ws.calib_dir.mkdir(parents=True, exist_ok=True)
    with atomic_write(ws.handeye_file, "w", encoding="utf-8") as f:
        json.dump(out, f, indent=1)
    refined = {"pose_error": " + refinement modelling robot pose error", "exact": " + refinement (exact robot poses)",
               "none": ""}[result.refine]  # fmt: skip
    how = f"{cfg.mount}, {cfg.method}{refined}, from {out['poses']}"
    outliers = f"; views that stand out: {', '.join(out['outlier_views'])}" if out["outlier_views"] else ""
    outliers += _mount_note(cfg, out) + _base_frame_note(cfg, out)
    return {
        "views": len(out["per_view"]), "skipped": len(out["skipped"]), "refine": result.refine,
        "loo_px_median": out["loo_px_median"], "loo_px_p90": out["loo_px_p90"], "outlier_views": out["outlier_views"],
        "residual_deg": out["residual_deg_median"], "residual_mm": out["residual_mm_median"],
        "line": f"camera mount ({how}) from {len(out['per_view'])} views ({len(out['skipped'])} skipped); "
        f"leave-one-out corner error {out['loo_px_median']:.2f} px median, {out['loo_px_p90']:.2f} px p90; loop "
        f"residual {out['residual_deg_median']:.3f} deg / {out['residual_mm_median']:.2f} mm{outliers}",
    }  # fmt: skip


def _base_frame_note(cfg: Config, handeye: dict[str, Any]) -> str:
    """A head camera from end-effector poses read in the model's base frame, on a robot whose spec names other frames
    fixed to its base (the UR5e's ur_base, its controller's): poses logged in one of those turn the camera, silently
    (a wrist camera's mount does not depend on it)."""
    if cfg.mount != "head" or handeye.get("poses") != "ee" or handeye.get("base_frame"):
        return ""
    kin = RobotKinematics(cfg.robot or DEFAULT_ROBOT)
    others = [n for n in kin.frames if (T := kin.fixed_pose(n)) is not None and not np.allclose(T, np.eye(4))]
    return (f"; the poses were read in the model's base frame: if the controller logged them in {' or '.join(others)}, "
            "set the poses file's base_frame" if others else "")  # fmt: skip


def _mount_note(cfg: Config, handeye: dict[str, Any]) -> str:
    """What the world will do with the wrist camera calibrated so (``handeye``: the calibration's handeye.json), in
    the world's own words: a calibration it cannot mount is said here, where it is made, not only when the world is
    composed."""
    from ..world.cameras import calibrated_wrist_camera

    if cfg.mount != "wrist":
        return ""
    return f"; in the world: {calibrated_wrist_camera(handeye, cfg.robot or DEFAULT_ROBOT)[1]}"


def compare(ws: Workspace, cfg: Config, gt: dict) -> dict[str, Any]:
    from ..geometry.rotation import rotation_angle

    he = json.loads(ws.handeye_file.read_text())
    if "T_base_headcam" not in he:
        return {"line": ""}
    X, T = np.asarray(he["T_base_headcam"]), np.asarray(gt["head_camera"]["T_base_headcam"])
    r = float(np.degrees(rotation_angle(X[:3, :3].T @ T[:3, :3])))
    t = float(1000 * np.linalg.norm(X[:3, 3] - T[:3, 3]))
    return {"rotation_deg": r, "translation_mm": t, "line": f"; vs ground truth {r:.3f} deg / {t:.2f} mm"}


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.handeye_file]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.handeye_file]
