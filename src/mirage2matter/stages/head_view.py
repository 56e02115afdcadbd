"""Stage ``head_view``: the scene rendered through the calibrated head camera, compared with a photo the
head camera took (PSNR, board corners) -> ``calib/head_view.png`` + ``head_view.json``. A wrong scale,
alignment or hand-eye shows up as pixels of offset. The robot's own Gaussians (scene/robot/, when the capture
showed it) are drawn with the scene at the photo's joint state (the pipeline's ``head_photo_joints``, which
train-scene's head photo shares): the photo shows the robot too."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..configs import ranged
from ..fingerprint import fingerprint
from ..inputs import read_image_rgb
from ..robots import RobotSpec, get_robot
from ..robots.kinematics import RobotKinematics
from ..robots.surface import check_capture_joints
from ..workspace import Workspace, WorkspaceError
from .base import ADDED_LATER, SHARED, Input, Log


@dataclass
class Config:
    """head-view settings.

    photo         an image the head camera took of the same scene (without one: the render alone)
    backend       renderer: auto (cuda when available), cpu, cuda
    head_photo_joints  the robot's joint state when the photo was taken (the arm's joint angles in radians, or
                  every joint's with the fingers); its Gaussians (scene/robot/) are drawn there. Default: the
                  capture joints. The pipeline's (m2m.yaml's top-level head_photo_joints, train-scene's head photo
                  too): giving it here changes it for every stage
    """

    photo: Path | None = None
    backend: Literal["auto", "cpu", "cuda"] = "auto"
    # wide: degrees given for radians are the robot's check to name (check_capture_joints), not a bare range
    head_photo_joints: list[float] | None = ranged(None, ge=-1000, le=1000, metadata={**SHARED, **ADDED_LATER,
                                                                                     "metavar": "RAD"})  # fmt: skip


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    out = [Input(ws.scene_ply, made_by="train-scene"), Input(ws.handeye_file, made_by="calibrate-handeye"),
           Input(ws.alignment_file, made_by="align-scene")]  # fmt: skip
    robot = ws.robot_gaussians_dir / "robot.json"  # the robot's Gaussians, when train-scene fitted them
    out += [Input(robot, made_by="train-scene")] if robot.is_file() else []
    return out + ([Input(Path(cfg.photo), field="head-view photo")] if cfg.photo is not None else [])


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    from ..calib.board import target_from_json
    from ..gaussians.ply import read_ply
    from ..render.head_view import check_head_view, save_head_view

    board = ws.board_on_table()
    if board is None:
        raise WorkspaceError(f"{ws.alignment_file}: no calibration target recorded; the head-view check draws it "
                             "(run `m2m align-scene` with a board)")  # fmt: skip
    photo = read_image_rgb(cfg.photo, "head photo") if cfg.photo is not None else None
    cam = head_camera(ws, "the head-view check", photo, cfg.photo)
    if photo is not None and cam.has_distortion:
        # the render is an ideal pinhole with the same K: take the lens out of the photo before comparing
        from ..gaussians.dataset import undistort_image

        ideal, _ = undistort_image(photo.astype(np.float32) / 255.0, cam)
        photo = np.clip(np.round(ideal * 255.0), 0, 255).astype(np.uint8)
    cam = dataclasses.replace(cam, distortion={}, distortion_model="")
    robot, T_base_link, robot_words = robot_at_photo(ws, cfg)
    check = check_head_view(read_ply(ws.scene_ply), cam, photo, target_from_json(board[0]), board[1],
                            backend=cfg.backend, robot=robot, T_base_link=T_base_link)  # fmt: skip
    save_head_view(ws.head_view_png, check, photo)
    known, seen = check.corners_vs_known_px, check.corners_vs_photo_px
    trained_on = cfg.photo is not None and _scene_trained_on(ws, Path(cfg.photo))
    parts = []
    if check.psnr is not None:
        trained = " (a training view: train-scene --head-photo)" if trained_on else ""
        robot_px = "" if check.psnr_robot is None else (
            f" (the robot's pixels {check.psnr_robot:.2f} dB, {100 * check.robot_mask.mean():.0f} % of the photo; "
            f"elsewhere {check.psnr_elsewhere:.2f} dB)")  # fmt: skip
        parts.append(f"PSNR {check.psnr:.2f} dB vs the photo{trained}{robot_px}")
    if known.get("n"):
        parts.append(f"board corners {known['median']:.2f} px (median, {known['n']}) from the board's known pose")
    if seen.get("n"):
        parts.append(f"{seen['median']:.2f} px from the photo's")
    if check.photo_vs_known_px.get("n"):  # the calibration alone: the photo's corners vs the board's known pose
        pk = check.photo_vs_known_px
        parts.append(f"the photo's corners {pk['median']:.2f} px (median, {pk['n']}) from the known pose")
    line = "; ".join(parts) or "rendered (the board is not seen in the render)"
    return {**check.to_json(), "photo_trained_on": trained_on, "robot": robot_words, "line": f"{line}; {robot_words}"}


def robot_at_photo(ws: Workspace, cfg: Config) -> tuple[dict | None, dict | None, str]:
    """(the robot's Gaussians {link: Gaussians, link frame}, their poses {link: T_base_link [4,4]} at the photo's
    joint state, the words for the stage line); (None, None, words) when the workspace has no robot Gaussians (the
    capture did not show the robot): the scene is drawn alone. A ``head_photo_joints`` that does not fit the robot
    (length, limits, degrees) is refused, naming the setting."""
    from ..gaussians.ply import read_ply

    info_file = ws.robot_gaussians_dir / "robot.json"
    if not info_file.is_file():
        unused = "; head_photo_joints unused" if cfg.head_photo_joints is not None else ""
        return None, None, ("the robot not drawn: the workspace has no robot Gaussians (scene/robot/: train-scene "
                            f"fits them when the keyframes show the robot){unused}")  # fmt: skip
    try:
        info = json.loads(info_file.read_text(encoding="utf-8"))
        name, links, capture = info["robot"], dict(info["links"]), info["capture_joints"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise WorkspaceError(f"{info_file}: unreadable ({e}); run `m2m train-scene -w {ws.root}` again") from None
    q, where = photo_joint_state(get_robot(name), cfg.head_photo_joints, capture, info_file)
    T_base_link = RobotKinematics(name).link_poses(q)
    unknown = sorted(set(links) - set(T_base_link))
    if unknown:
        raise WorkspaceError(f"{info_file}: link(s) {', '.join(unknown)} are not {name}'s; run `m2m train-scene -w "
                             f"{ws.root}` again")  # fmt: skip
    robot = {link: read_ply(ws.robot_gaussians_dir / f) for link, f in links.items()}
    return robot, T_base_link, f"the robot drawn from its Gaussians (scene/robot/) at {where}"


def photo_joint_state(spec: RobotSpec, head_photo_joints: list[float] | None, capture_joints: list[float],
                      capture_file: Path) -> tuple[np.ndarray, str]:  # fmt: skip
    """(the robot's joint state [n_dofs] when the head photo was taken, the words saying which): the pipeline's
    ``head_photo_joints`` when given, else the capture joints (``capture_joints``, as ``capture_file`` records
    them). One that does not fit the robot (length, limits, degrees) is refused naming the setting."""
    if head_photo_joints is not None:
        return check_capture_joints(spec, head_photo_joints, "head_photo_joints"), "head_photo_joints"
    q = check_capture_joints(spec, capture_joints, f"{capture_file} capture_joints")
    return q, "the capture joints (head_photo_joints: the photo's, if it was taken at another)"


def head_camera(ws: Workspace, who: str, photo: np.ndarray | None = None, photo_path: Path | None = None):
    """The calibrated head camera (``geometry.camera.Camera``: K, T_base_headcam, image size, lens) from
    calibrate-handeye's result (``world.cameras.calibrated_head_camera``). ``photo`` [H,W,3], one the camera took
    (``photo_path``), gives the size when the calibration has none and must match it otherwise; ``who`` names the
    user in the errors."""
    from ..world.cameras import calibrated_head_camera

    size = None if photo is None else (photo.shape[1], photo.shape[0])
    cam, why = calibrated_head_camera(json.loads(ws.handeye_file.read_text()), size)
    if cam is None:
        photo_advice = "; or give a head-camera photo (--photo)" if why.endswith("image size") else ""
        raise WorkspaceError(f"{ws.handeye_file}: {why}; {who} needs a head camera (`m2m calibrate-handeye --mount "
                             f"head`){photo_advice}")  # fmt: skip
    if photo is not None and photo.shape[:2] != (cam.height, cam.width):
        raise WorkspaceError(f"{photo_path} is {photo.shape[1]}x{photo.shape[0]} but the head camera is "
                             f"{cam.width}x{cam.height}; give a photo the head camera took")  # fmt: skip
    return cam


def _scene_trained_on(ws: Workspace, photo: Path) -> bool:
    """Whether the scene was trained on this photo (``train-scene --head-photo``, the same file contents): the
    check then measures a fit, not a new view."""
    try:
        metrics = json.loads(ws.scene_metrics.read_text())
        key = metrics.get("head_photo_fingerprint")
        if key is None and metrics["config"].get("head_photo"):  # a scene trained before the key was recorded
            key = fingerprint(Path(metrics["config"]["head_photo"]))
        return key is not None and fingerprint(photo) == key
    except (OSError, ValueError, KeyError, AttributeError, TypeError):
        return False


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.head_view_file]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.head_view_png, ws.head_view_file]
