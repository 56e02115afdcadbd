"""Stage ``sfm``: camera poses and sparse points of the keyframes (COLMAP) -> ``sfm/``; or poses imported
from a transforms.json or a COLMAP model (their images copied into ``capture/``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np

from ..calib.align import board_in_base
from ..calib.board import load_target
from ..capture import load_keyframes
from ..configs import ranged
from ..geometry.camera import load_intrinsics
from ..robots import DEFAULT_ROBOT, get_robot, is_spec_file
from ..robots.capture_poses import capture_poses
from ..sfm import SfMConfig, SfMError, compare_poses, run_sfm
from ..workspace import Workspace
from .base import ADDED_LATER, SHARED, Input, Log, used_with


@dataclass
class Config:
    """sfm settings.

    matching         image pairs to match: auto (exhaustive below 40 images), sequential, exhaustive
    downscale        extract features at 1/downscale of the keyframes' resolution
    intrinsics       known camera intrinsics held fixed (our JSON with K, width, height, distortion, OpenCV's
                     calibration YAML/XML, ROS camera_info, COLMAP cameras.txt or RealSense JSON; or such an
                     object under "camera"; radial-tangential or equidistant fisheye lens; `m2m intrinsics FILE`
                     shows how it reads): more accurate poses than self-calibration
    from_transforms  import poses from an instant-ngp / nerfstudio transforms.json instead (copies its images
                     into capture/, triangulates points with the given poses; keeps its world frame)
    from_colmap      import a COLMAP sparse model instead (needs images)
    images           with from_colmap: the folder the model's image names are relative to
    capture_moves    the robot moved while filming (the pipeline's): {N: joints}, from video frame N on it stood at
                     these joints (radians; `--capture-moves 360=q1,q2,...`). Its features would match across the
                     move (a rigid body moving against the room) and pull the cameras off, so SfM runs twice:
                     once as it is, to place the keyframes' cameras by the board, then with the moved robot's
                     silhouette (its joint state then, through that camera) masked out of every keyframe filmed
                     after a move. The first pose keeps its features: align-scene checks
                     capture_joints with them
    robot            the pipeline's robot, drawn into the masks (with capture_moves only)
    board            the pipeline's calibration target, which places the first run's cameras (with capture_moves)
    board_pose       the pipeline's T_base_board file (with capture_moves)
    capture_joints   the pipeline's joint state before the first move (with capture_moves)
    """

    # where the cameras' intrinsics come from, one at a time (an import brings its own): given one on the command
    # line, a stage command drops the others m2m.yaml holds (for that run, and saves that)
    EXCLUSIVE: ClassVar = (("intrinsics", "from_transforms", "from_colmap"),)

    matching: Literal["auto", "sequential", "exhaustive"] = SfMConfig.matching
    downscale: float = ranged(1.0, ge=1, le=16)
    intrinsics: Path | None = None
    from_transforms: Path | None = None
    from_colmap: Path | None = None
    images: Path | None = None
    # the pipeline's: what was filmed (sfm masks the moved robot's features)
    robot: str = field(default=DEFAULT_ROBOT, metadata={**SHARED, **used_with("capture_moves")})
    board: Path | None = field(default=None, metadata={**SHARED, **used_with("capture_moves")})
    board_pose: Path | None = field(default=None, metadata={**SHARED, **used_with("capture_moves")})
    capture_joints: list[float] | None = ranged(None, ge=-1000, le=1000, metadata={
        **SHARED, **used_with("capture_moves")})
    capture_moves: dict[int, list[float]] | None = ranged(None, ge=-1000, le=1000, metadata={
        **SHARED, **ADDED_LATER, "metavar": "FRAME=RAD,..."})

    def validate(self) -> None:
        if not self.downscale > 0:
            raise SfMError(f"sfm: downscale must be positive, got {self.downscale}")
        given = [n for n in self.EXCLUSIVE[0] if getattr(self, n) is not None]
        if len(given) > 1:
            raise SfMError(f"sfm: {' and '.join(given)} are both given; give one: an import (from_transforms, "
                           "from_colmap) brings its cameras' own intrinsics, intrinsics is for SfM on keyframes")
        if self.from_colmap is not None and self.images is None:
            raise SfMError("sfm: from_colmap needs images (the folder the model's image names are relative to)")
        if self.capture_moves and self.robot.lower() != "none":  # the moved robot's masks need its poses
            capture_poses(get_robot(self.robot), self.capture_joints, self.capture_moves, what="sfm")


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    given = [(cfg.intrinsics, "intrinsics"), (cfg.from_transforms, "from_transforms"), (cfg.from_colmap, "from_colmap"),
             (cfg.images, "images")]  # fmt: skip
    out = [Input(Path(p), field=f"sfm {name}") for p, name in given if p is not None]
    if cfg.from_transforms is None and cfg.from_colmap is None:
        out.append(Input(ws.keyframes_file, made_by="capture"))
        if cfg.capture_moves:  # the moved robot's masks: the board places it, the robot's model draws it
            out += [Input(Path(p), field=n) for p, n in ((cfg.board, "board"), (cfg.board_pose, "board_pose")) if p]
            if is_spec_file(cfg.robot):
                out.append(Input(Path(cfg.robot), field="robot"))
    return out


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    from ..sfm.importers import import_colmap_model, import_transforms
    from ..sfm.known_poses import with_fixed_intrinsics

    config = SfMConfig(matching=cfg.matching, downscale=1.0 / cfg.downscale)
    if cfg.intrinsics is not None:
        config = with_fixed_intrinsics(config, load_intrinsics(cfg.intrinsics))
    if cfg.from_transforms is not None:
        result = import_transforms(cfg.from_transforms, ws.capture_dir, ws.sfm_dir, config)
        how = f"imported {result.total} posed images from {cfg.from_transforms}; triangulated with those poses"
    elif cfg.from_colmap is not None:
        result = import_colmap_model(cfg.from_colmap, cfg.images, ws.capture_dir, ws.sfm_dir)
        how = f"imported the COLMAP model {cfg.from_colmap}"
    elif cfg.capture_moves:
        result, how = _sfm_without_moved_robot(ws, cfg, config, log)
    else:
        result = run_sfm(ws.capture_dir, ws.sfm_dir, config)
        how = f"registered {result.registered}/{result.total} keyframes"
    from ..capture.coverage import scene_coverage

    coverage = scene_coverage(result.cameras, result.points)  # what to film more, while the user still can
    return {
        "registered": result.registered, "total": result.total, "points": len(result.points),
        "reprojection_px": result.mean_reprojection_error, "seconds": result.seconds, "coverage": coverage.to_json(),
        "line": f"{how}, {len(result.points):,} points, reprojection {result.mean_reprojection_error:.2f} px (mean); "
        f"{coverage.line}",
    }  # fmt: skip


def _sfm_without_moved_robot(ws: Workspace, cfg: Config, config: SfMConfig, log: Log) -> tuple[Any, str]:
    """SfM with the robot masked out of the keyframes filmed after a move (sfm/robot_mask.py); the masks are kept in
    sfm/masks/, what was done in sfm/robot_masks.json."""
    from ..sfm.robot_mask import run_sfm_without_moved_robot

    masks, kept = None, ""
    if cfg.robot.lower() == "none":
        kept = "no robot (the pipeline's robot is none) to draw"
    elif cfg.board is None:
        kept = "no board (the pipeline's board) to place the cameras by"
    if kept:
        result = run_sfm(ws.capture_dir, ws.sfm_dir, config)
    else:
        spec, board = get_robot(cfg.robot), load_target(cfg.board)
        poses = capture_poses(spec, cfg.capture_joints, cfg.capture_moves, what="sfm")
        result, masks, kept = run_sfm_without_moved_robot(
            ws.capture_dir, ws.sfm_dir, config, load_keyframes(ws.capture_dir)["keyframes"], spec, poses, board,
            board_in_base(board, cfg.board_pose), log)  # fmt: skip
    if masks is not None:
        return result, f"registered {result.registered}/{result.total} keyframes; {masks.line}"
    return result, (f"registered {result.registered}/{result.total} keyframes (the moved robot's features kept: "
                    f"{kept})")  # fmt: skip


def compare(ws: Workspace, cfg: Config, gt: dict) -> dict[str, Any]:
    posed = ws.posed_capture(frame="sfm")
    keyframes = load_keyframes(ws.capture_dir)["keyframes"]
    reference = {k["file"]: np.asarray(gt["frames"][k["frame_index"]]["T_base_cam"]) for k in keyframes}
    err = compare_poses({c.name: c.T_world_cam for c in posed.cameras}, reference)
    return {
        "rotation_deg": err["rotation_deg_median"], "centre_frac": err["center_frac_median"],
        "line": f"; vs ground truth {err['rotation_deg_median']:.3f} deg / {100 * err['center_frac_median']:.3f}% "
        "(median, after a Sim3 fit)",
    }  # fmt: skip


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.sfm_file]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.sfm_dir] + ([ws.capture_dir] if cfg.from_transforms is not None or cfg.from_colmap is not None else [])
