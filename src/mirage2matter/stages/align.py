"""Stage ``align``: the SfM scene in the robot-base frame, metric, from the ChArUco board at the base
(paper eqs. ``icp`` and ``pose_update``) -> ``calib/`` (sim3_sfm_to_base.json, cameras_base.json,
points_base.npy, colors_base.npy, overlay.png)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..atomic import atomic_write
from ..calib.align import AlignError, align_scene, board_in_base, draw_base_overlay
from ..calib.board import load_target
from ..capture import load_keyframes
from ..configs import ranged
from ..robots import DEFAULT_ROBOT, get_robot, is_spec_file
from ..robots.capture_poses import CapturePoses, capture_poses
from ..robots.kinematics import RobotKinematics
from ..robots.surface import robot_surface
from ..workspace import Workspace
from .base import ADDED_LATER, SHARED, Input, Log


@dataclass
class Config:
    """align settings.

    board        the calibration target's spec JSON (from `m2m board`: ChArUco, ArUco marker, AprilTag, ArUco grid).
                 The pipeline's (m2m.yaml's top-level board; sfm reads it too, below)
    board_pose   a JSON with T_base_board (4x4, or under "board") when the target is not centred on the base
                 with its x along base x. The pipeline's
    icp          also fit the SfM points around the target onto the robot-base surface (scaled ICP), where the SfM
                 saw that surface near the base. Off by default: on the sample it made every target's alignment
                 worse (ChArUco, 48 keyframes: 1.20 -> 1.51 mm, 0.035 -> 0.060 deg; 16: 0.94 -> 2.40 mm), and on
                 a real capture 2.5 -> 13.4 mm
    robot        the robot (a name from `mirage2matter.robots` or a robot spec file) whose base footprint bounds
                 the ICP region and is drawn in the overlay; "none" for a 10 cm circle. The pipeline's robot (m2m.yaml's
                 top-level robot): giving it here changes it for every stage
    unaligned    no target: keep the SfM frame (not metric, not the robot's) for scene-only use
    capture_joints  the robot's joint state while the capture was filmed: its arm joints in radians (and fingers, in
                 the model's units), as the robot logged them; default: the robot's home. Where the keyframes show
                 the robot, its links at this state are found in them: their SfM points are kept out of the scene
                 and the objects, the scene is not trained on their pixels, and their surface is a second target
                 that checks (and may refine) the board's alignment. The pipeline's
    capture_moves  the robot moved while filming: {N: joints} says that from the video's frame N on (an image
                 folder's image N, in name order) it stood at these joints (as capture_joints: arm joints in
                 radians); capture_joints holds before the first move. Each keyframe is then taken out of the scene,
                 and fitted to the robot's look, at its own joint state: a second pose shows what the first hid;
                 sfm keeps the moved robot out of its features. The pipeline's
    robot_fit    "auto": refine the alignment with the robot's surface (board corners held) when that lowers the
                 robot's residual by a quarter or more and keeps the corners within 1.5x (+0.5 mm) of the board's
                 fit; "off": the board alone, the robot's residual reported
    """

    board: Path | None = field(default=None, metadata=SHARED)
    board_pose: Path | None = field(default=None, metadata=SHARED)
    icp: bool = False
    robot: str = field(default=DEFAULT_ROBOT, metadata=SHARED)
    unaligned: bool = False
    # wide: degrees given for radians are the robot's check to name (check_capture_joints), not a bare range
    capture_joints: list[float] | None = ranged(None, ge=-1000, le=1000, metadata={**SHARED, **ADDED_LATER})
    capture_moves: dict[int, list[float]] | None = ranged(None, ge=-1000, le=1000, metadata={
        **SHARED, **ADDED_LATER, "metavar": "FRAME=RAD,..."})
    robot_fit: Literal["auto", "off"] = field(default="auto", metadata=ADDED_LATER)

    def validate(self) -> None:
        if self.board is None and not self.unaligned:
            raise AlignError("align-scene: no calibration target; give its spec JSON (--board, from `m2m board`), "
                             "or --unaligned to keep the SfM frame for a scene-only capture")  # fmt: skip
        if self.robot.lower() != "none" and (self.capture_joints is not None or self.capture_moves):
            capture_poses(get_robot(self.robot), self.capture_joints, self.capture_moves)


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    out = [Input(ws.sfm_file, made_by="sfm"), Input(ws.sfm_model, made_by="sfm")]
    out += [Input(Path(p), field=f"align {n}") for p, n in ((cfg.board, "board"), (cfg.board_pose, "board_pose")) if p]
    if is_spec_file(cfg.robot):  # a user's robot spec: its content counts
        out.append(Input(Path(cfg.robot), field="align robot"))
    return out


def _footprint(robot: str) -> np.ndarray | None:
    if robot.lower() == "none":
        return None

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
    T_base_board = board_in_base(board, cfg.board_pose)
    images = [np.asarray(Image.open(posed.image_dir / c.name).convert("RGB")) for c in posed.cameras]
    footprint = _footprint(cfg.robot)
    result = align_scene(posed.cameras, images, posed.points, board, T_base_board, icp=cfg.icp,
                         footprint_xy=footprint)  # fmt: skip
    robot = _robot_in_capture(cfg, result, posed, board, T_base_board, log, ws.sfm_model)
    if robot.get("correction") is not None:  # the robot's surface refined the board's alignment
        from ..geometry.sim3 import Sim3

        result = dataclasses.replace(result, sim3_sfm_to_base=Sim3.from_json(robot["correction"]) @
                                     result.sim3_sfm_to_base, method=result.method + "+robot")  # fmt: skip
    sim = result.sim3_sfm_to_base
    cameras_base = _save(ws, result, T_base_board, board, posed, robot)
    overlay = draw_base_overlay(images, cameras_base, result.triangulation.frames_with_board, footprint,
                                _robot_outline(ws))  # fmt: skip
    with atomic_write(ws.overlay_png, "wb") as f:
        Image.fromarray(overlay).save(f, format="PNG")
    icp = "" if result.icp_rmse_mm is None else f", ICP {result.icp_rmse_mm:.1f} mm"
    return {
        "method": result.method, "note": result.note, "scale": sim.scale, "corner_rms_mm": result.corner_rms_mm,
        "icp_rmse_mm": result.icp_rmse_mm, "robot": {k: v for k, v in robot.items() if k != "on_robot"},
        "line": f"SfM -> robot base ({board.describe()}): scale {sim.scale:.5f}, corners {result.corner_rms_mm:.2f} "
        f"mm RMS from {len(result.triangulation.ids)} corners in {len(result.triangulation.frames_with_board)} "
        f"keyframes{icp}; {result.note}; {robot['line']}",
    }  # fmt: skip


def _robot_outline(ws: Workspace):
    """``camera -> bool [H,W]``: the robot's silhouette at the joint state that keyframe saw (calib/robot.json, just
    written), for the overlay; None where the keyframes do not show the robot."""
    from ..calib.robot_view import robot_silhouette, seen_robot

    seen = seen_robot(ws.robot_capture_file)
    return None if seen is None else lambda cam: robot_silhouette(cam, seen.links_for(cam.name))


# The robot's surface disagrees with the board's alignment past these (after the robot's own fit): a wrong
# capture_joints or a board that moved. SfM points on a textured link scatter ~2-4 mm at the sample's distances.
DISAGREE_RMS_MM = 8.0
DISAGREE_MOVE_MM, DISAGREE_MOVE_DEG = 10.0, 1.0


def _framing(cameras: list, pose_links: list, keyframe_pose: dict[str, int], sim, sfm_model: Path) -> dict[str, Any]:
    """robot.json's fields for a robot SfM put too few points on: smooth paint gives SfM few features (and sfm keeps
    a moved robot out of them), so it counts as seen where keyframes frame it and what they observed there does not
    lie behind it (calib.robot_view.robot_framing, on the SfM model's observations moved to the base)."""
    from ..calib.robot_view import robot_framing
    from ..sfm.colmap import load_observations

    observations = {n: (xy, sim.apply(xyz)) for n, (xy, xyz) in load_observations(sfm_model).items()}
    framing = robot_framing(cameras, lambda c: pose_links[keyframe_pose[c.name]], observations)
    line = f"framed by {framing.keyframes} keyframes"
    if framing.keyframes:
        line += (f", {framing.through} of the {framing.inside} SfM observations inside it lie behind it" if
                 framing.inside else ", no SfM observation inside it")  # fmt: skip
    if framing.keyframes and framing.inside and not framing.seen:
        line += ": the cameras saw the table through where it would stand"
    return {"seen": framing.seen, "seen_by": "framing", "keyframes_framing": framing.keyframes,
            "observations_inside": framing.inside, "observations_behind": framing.through, "framing_line": line}


def _robot_in_capture(cfg: Config, result, posed, board, T_base_board: np.ndarray, log: Log,
                      sfm_model: Path) -> dict[str, Any]:  # fmt: skip
    """Where the keyframes show the robot at ``cfg.capture_joints``: which SfM points are its own, how well its
    surface agrees with the board's alignment, and (``robot_fit`` auto) the correction when it is better by the
    measure above. Returns robot.json's record (``on_robot`` [N] bool over the SfM points, not saved as such).
    ``sfm_model``: the SfM model, whose observations say whether keyframes saw through where the robot stands."""
    if cfg.robot.lower() == "none":
        return {"seen": False, "line": "robot: none given (align.robot none)", "on_robot": None}
    from ..calib.align import apply_to_cameras
    from ..calib.robot_view import POSE_MIN_ON_FRACTION, fit_to_robot, robot_points, robot_silhouettes, visual_hull

    spec = get_robot(cfg.robot)
    poses = capture_poses(spec, cfg.capture_joints, cfg.capture_moves)
    given = "given" if cfg.capture_joints is not None else "the robot's home: capture_joints not given"
    if len(poses) > 1:
        given += f", {len(poses) - 1} move(s) while filming"
    pose_links = [robot_surface(spec, q) for q in poses.joints]
    links = [link for each in pose_links for link in each]  # every pose's surface: a point on any is the robot's
    sim = result.sim3_sfm_to_base
    cameras = apply_to_cameras(sim, posed.cameras)
    keyframe_pose = _keyframe_poses(posed.image_dir, cameras, poses)
    points = sim.apply(posed.points)
    found = robot_points(points, links, cameras)
    if len(poses) > 1:
        # sfm kept the moved robot out of its features: its points are the first pose's, and so is the check of the
        # joint state
        found.on_fraction = robot_points(points, pose_links[0], cameras).on_fraction
    record: dict[str, Any] = {"robot": spec.name, **poses.to_json(), "capture_joints_source": given,
                              "keyframe_pose": keyframe_pose, "seen": found.seen,
                              "points_on_surface": found.on_surface, "on_fraction": found.on_fraction,
                              "seen_fraction": found.seen_fraction, "per_link": found.per_link}  # fmt: skip
    if not found.seen:
        record.update(_framing(cameras, pose_links, keyframe_pose, sim, sfm_model))
        found.seen = record["seen"]
    if not found.seen:
        record["line"] = (f"robot: not in the keyframes ({found.on_surface} SfM points on its surface at "
                          f"{given.split(':')[0]}; {record['framing_line']}); nothing removed")  # fmt: skip
        return {**record, "on_robot": None}
    # the visual hull too (only now: the silhouettes cost ~0.3 s a keyframe): points every view of a pose sees inside
    # the robot at that pose are the robot's even off its model surface
    on = found.on_robot.copy()
    for p, each in enumerate(pose_links):
        small = [c.scaled(0.25) for c in cameras if keyframe_pose[c.name] == p]
        on |= visual_hull(points, small, robot_silhouettes(small, each, dilate_px=1))
    tri = result.triangulation
    corners_base = board.points_board(tri.ids) @ T_base_board[:3, :3].T + T_base_board[:3, 3]
    near = on & (found.distance <= 0.03)
    fit = fit_to_robot(points[near], links, anchors=(sim.apply(tri.points), corners_base)) if near.sum() >= 30 \
        else None  # fmt: skip
    record.update(points_removed=int(on.sum()), points_total=len(points))
    seen_by = f"{record['framing_line']}; " if "seen_by" in record else ""
    line = (f"robot: in the keyframes ({seen_by}{found.on_surface} SfM points on its surface, "
            f"{100 * found.seen_fraction:.0f} % of it reconstructed; capture joints {given.split(':')[0]}), "
            f"{int(on.sum())} of {len(points)} SfM points are its own and kept out of the scene")  # fmt: skip
    if fit is None:  # too few points on the robot to check the joint state or the alignment by its surface
        line += (f"; too few SfM points on it ({int(near.sum())}) to check capture_joints or the alignment against "
                 "its surface")  # fmt: skip
    else:
        record["fit"] = fit.to_json()
        better = (fit.rms_after_mm <= 0.75 * fit.rms_before_mm
                  and fit.corner_rms_mm <= 1.5 * result.corner_rms_mm + 0.5)  # fmt: skip
        use = cfg.robot_fit == "auto" and better
        record["used"] = "board+robot" if use else "board"
        record["correction"] = fit.correction.to_json() if use else None
        line += (f"; its surface {fit.rms_before_mm:.1f} mm RMS from the board's alignment, {fit.rms_after_mm:.1f} "
                 f"after its own fit ({fit.rotation_deg:.2f} deg / {fit.translation_mm:.1f} mm, corners "
                 f"{fit.corner_rms_mm:.2f} mm): {'used' if use else 'the board alone kept'}")  # fmt: skip
        residual = fit.rms_after_mm if use else fit.rms_before_mm
        beside = found.on_fraction < POSE_MIN_ON_FRACTION
        if beside or residual > DISAGREE_RMS_MM or fit.translation_mm > DISAGREE_MOVE_MM \
                or fit.rotation_deg > DISAGREE_MOVE_DEG:  # fmt: skip
            record["warning"] = (
                f"the robot's surface disagrees with the board's alignment ({residual:.1f} mm RMS, the fit moves it "
                f"{fit.translation_mm:.1f} mm / {fit.rotation_deg:.2f} deg; of the SfM points around the robot "
                f"{100 * found.on_fraction:.0f} % lie on it): check capture_joints (the joint state while "
                f"filming, {given.split(':')[0]}) and that the board did not move while filming"
            )
            log(f"align-scene: WARNING: {record['warning']}")
            line += f"; WARNING: {record['warning']}"
    record["line"] = line
    return {**record, "on_robot": on}


def _keyframe_poses(capture_dir: Path, cameras: list, poses: CapturePoses) -> dict[str, int]:
    """{keyframe: the pose the robot held when the video frame it came from was taken} (capture/keyframes.json)."""
    if len(poses) == 1:
        return {c.name: 0 for c in cameras}
    frame_of = {k["file"]: int(k["frame_index"]) for k in load_keyframes(capture_dir)["keyframes"]}
    missing = [c.name for c in cameras if c.name not in frame_of]
    if missing:
        raise AlignError(f"align capture_moves: the keyframes {', '.join(missing[:4])} are not in "
                         f"{capture_dir}/keyframes.json, so their frame (the robot's pose then) is unknown; run the "
                         "capture stage again")  # fmt: skip
    return {c.name: poses.index_at(frame_of[c.name]) for c in cameras}


def _save(ws: Workspace, result, T_base_board: np.ndarray, board, posed, robot: dict | None = None) -> list:
    """The alignment, the cameras and points in the base frame (each file atomically); the robot's SfM points apart
    from the rest."""
    from ..calib.align import apply_to_cameras

    ws.calib_dir.mkdir(parents=True, exist_ok=True)
    sim = result.sim3_sfm_to_base
    with atomic_write(ws.alignment_file, "w", encoding="utf-8") as f:
        json.dump({**result.to_json(), "T_base_board": np.asarray(T_base_board).tolist(),
                   "board": board.to_json() if board is not None else None}, f, indent=1)  # fmt: skip
    cameras_base = apply_to_cameras(sim, posed.cameras)
    with atomic_write(ws.cameras_base_file, "w", encoding="utf-8") as f:
        json.dump([c.to_json() for c in cameras_base], f, indent=1)
    points, colors = sim.apply(posed.points), posed.colors
    on = (robot or {}).get("on_robot")
    on = np.zeros(len(points), bool) if on is None else on
    with atomic_write(ws.points_base_file, "wb") as f:
        np.save(f, points[~on].astype(np.float32))
    with atomic_write(ws.colors_base_file, "wb") as f:
        np.save(f, colors[~on].astype(np.uint8))
    with atomic_write(ws.robot_points_file, "wb") as f:
        np.save(f, points[on].astype(np.float32))
    with atomic_write(ws.robot_capture_file, "w", encoding="utf-8") as f:
        json.dump({k: v for k, v in (robot or {"seen": False}).items() if k != "on_robot"}, f, indent=1)
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
    return [ws.alignment_file, ws.cameras_base_file, ws.points_base_file, ws.colors_base_file, ws.overlay_png,
            ws.robot_capture_file, ws.robot_points_file]
