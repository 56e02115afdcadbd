"""Stage ``align``: the SfM scene in the robot-base frame, metric, from the ChArUco board at the base
(paper eqs. ``icp`` and ``pose_update``) -> ``calib/`` (sim3_sfm_to_base.json, cameras_base.json,
points_base.npy, colors_base.npy, overlay.png)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write
from ..calib.align import AlignError, align_scene, default_T_base_board, draw_base_overlay
from ..calib.board import load_target
from ..robots import DEFAULT_ROBOT, is_spec_file
from ..workspace import Workspace
from .base import Input, Log


@dataclass
class Config:
    """align settings.

    board        the calibration target's spec JSON (from `m2m board`: ChArUco, ArUco marker, AprilTag, ArUco grid)
    board_pose   a JSON with T_base_board (4x4, or under "board") when the target is not centred on the base
                 with its x along base x
    icp          also fit the SfM points around the target onto the robot-base surface (scaled ICP), where the SfM
                 saw that surface near the base. Off by default: on the sample it made every target's alignment
                 worse (ChArUco, 48 keyframes: 1.20 -> 1.51 mm, 0.035 -> 0.060 deg; 16: 0.94 -> 2.40 mm), and on
                 a real capture 2.5 -> 13.4 mm
    robot        the robot (a name from `mirage2matter.robots` or a robot spec file) whose base footprint bounds
                 the ICP region and is drawn in the overlay; "none" for a 10 cm circle
    unaligned    no target: keep the SfM frame (not metric, not the robot's) for scene-only use
    """

    board: Path | None = None
    board_pose: Path | None = None
    icp: bool = False
    robot: str = DEFAULT_ROBOT
    unaligned: bool = False

    def validate(self) -> None:
        if self.board is None and not self.unaligned:
            raise AlignError("align-scene: no calibration target; give its spec JSON (--board, from `m2m board`), "
                             "or --unaligned to keep the SfM frame for a scene-only capture")  # fmt: skip


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    out = [Input(ws.sfm_file, made_by="sfm"), Input(ws.sfm_model, made_by="sfm")]
    out += [Input(Path(p), field=f"align {n}") for p, n in ((cfg.board, "board"), (cfg.board_pose, "board_pose")) if p]
    if is_spec_file(cfg.robot):  # a user's robot spec: its content counts
        out.append(Input(Path(cfg.robot), field="align robot"))
    return out


def _board_pose(path: Path) -> np.ndarray:
    data = json.loads(path.read_text(encoding="utf-8"))
    T = data.get("T_base_board") if isinstance(data, dict) else None
    if T is None and isinstance(data, dict) and isinstance(data.get("board"), dict):
        T = data["board"].get("T_base_board")
    T = np.asarray(T, dtype=np.float64) if T is not None else None
    if T is None or T.shape != (4, 4) or not np.isfinite(T).all():
        raise AlignError(f"{path}: need T_base_board (4x4 numbers), at the top level or under 'board'")
    return T


def _footprint(robot: str) -> np.ndarray | None:
    if robot.lower() == "none":
        return None
    from ..calib.kinematics import RobotKinematics

    return RobotKinematics(robot).base_footprint()


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    from PIL import Image

    posed = ws.posed_capture(frame="sfm")  # a rerun aligns from the SfM frame again
    if cfg.unaligned:
        from ..calib.align import unaligned_result

        result = unaligned_result(posed.cameras)
        _save(ws, result, np.eye(4), None, posed)
        import cv2  # the overlay says so, rather than an earlier alignment's overlay staying

        first = np.asarray(Image.open(posed.image_dir / posed.cameras[0].name).convert("RGB")).copy()
        cv2.putText(first, "UNALIGNED: SfM frame", (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 0, 0), 2)
        with atomic_write(ws.overlay_png, "wb") as f:
            Image.fromarray(first).save(f, format="PNG")
        return {"method": "unaligned", "scale": 1.0, "line": "UNALIGNED: the scene stays in the SfM frame (not "
                "metric, not the robot's base); fine for viewing the scene, not for a robot twin"}  # fmt: skip
    board = load_target(cfg.board)
    T_base_board = _board_pose(cfg.board_pose) if cfg.board_pose is not None else default_T_base_board(board)
    images = [np.asarray(Image.open(posed.image_dir / c.name).convert("RGB")) for c in posed.cameras]
    footprint = _footprint(cfg.robot)
    result = align_scene(posed.cameras, images, posed.points, board, T_base_board, icp=cfg.icp,
                         footprint_xy=footprint)  # fmt: skip
    sim = result.sim3_sfm_to_base
    cameras_base = _save(ws, result, T_base_board, board, posed)
    overlay = draw_base_overlay(images, cameras_base, result.triangulation.frames_with_board, footprint)
    with atomic_write(ws.overlay_png, "wb") as f:
        Image.fromarray(overlay).save(f, format="PNG")
    icp = "" if result.icp_rmse_mm is None else f", ICP {result.icp_rmse_mm:.1f} mm"
    return {
        "method": result.method, "note": result.note, "scale": sim.scale, "corner_rms_mm": result.corner_rms_mm,
        "icp_rmse_mm": result.icp_rmse_mm,
        "line": f"SfM -> robot base ({board.describe()}): scale {sim.scale:.5f}, corners {result.corner_rms_mm:.2f} "
        f"mm RMS from {len(result.triangulation.ids)} corners in {len(result.triangulation.frames_with_board)} "
        f"keyframes{icp}; {result.note}",
    }  # fmt: skip


def _save(ws: Workspace, result, T_base_board: np.ndarray, board, posed) -> list:
    """The alignment, the cameras and points in the base frame (each file atomically)."""
    from ..calib.align import apply_to_cameras

    ws.calib_dir.mkdir(parents=True, exist_ok=True)
    sim = result.sim3_sfm_to_base
    with atomic_write(ws.alignment_file, "w", encoding="utf-8") as f:
        json.dump({**result.to_json(), "T_base_board": np.asarray(T_base_board).tolist(),
                   "board": board.to_json() if board is not None else None}, f, indent=1)  # fmt: skip
    cameras_base = apply_to_cameras(sim, posed.cameras)
    with atomic_write(ws.cameras_base_file, "w", encoding="utf-8") as f:
        json.dump([c.to_json() for c in cameras_base], f, indent=1)
    with atomic_write(ws.points_base_file, "wb") as f:
        np.save(f, sim.apply(posed.points).astype(np.float32))
    with atomic_write(ws.colors_base_file, "wb") as f:
        np.save(f, posed.colors.astype(np.uint8))
    return cameras_base


def compare(ws: Workspace, cfg: Config, gt: dict) -> dict[str, Any]:
    from ..capture import load_keyframes
    from ..geometry.rotation import rotation_angle

    index = {k["file"]: k["frame_index"] for k in load_keyframes(ws.capture_dir)["keyframes"]}
    rot, trans = [], []
    for c in ws.posed_capture(frame="base").cameras:
        T = np.asarray(gt["frames"][index[c.name]]["T_base_cam"])
        rot.append(float(np.degrees(rotation_angle(c.T_world_cam[:3, :3].T @ T[:3, :3]))))
        trans.append(float(1000 * np.linalg.norm(c.T_world_cam[:3, 3] - T[:3, 3])))
    r, t = float(np.median(rot)), float(np.median(trans))
    line = f"; cameras vs ground truth {r:.3f} deg / {t:.2f} mm (median)"
    return {"rotation_deg": r, "translation_mm": t, "line": line}


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.alignment_file, ws.cameras_base_file, ws.points_base_file]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.alignment_file, ws.cameras_base_file, ws.points_base_file, ws.colors_base_file, ws.overlay_png]
