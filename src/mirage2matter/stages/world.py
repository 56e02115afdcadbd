"""Stage ``world`` (``m2m compose``): the world of the reconstruction -> ``world/`` (world.yaml with the
robot, the calibrated cameras, the scene without the objects, the placed objects and press buttons; one
Gaussian ``world.ply``), checked: every part's Gaussians must lie on its mesh. With ``sample`` the world is
the sample's ground truth instead (a stand-in to try the twin without reconstructing)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..configs import ranged
from ..robots import DEFAULT_ROBOT, is_spec_file
from ..workspace import Workspace
from ..world.cameras import calibrated_wrist_camera
from ..world.config import CameraConfig, RandomizeConfig, RobotConfig, WorldConfigError
from ..world.reconstruction import ReconstructionOptions
from .base import SHARED, Input, Log

if TYPE_CHECKING:
    from ..geometry.camera import Camera


@dataclass
class Config:
    """compose settings.

    robot             the robot at the base origin (a name from `mirage2matter.robots`: panda, ur5e; or the path of a
                      robot spec file, see `mirage2matter.robots.specfile`). The pipeline's robot (m2m.yaml's
                      top-level robot): giving it here changes it for every stage
    buttons           reconstructed objects that are press buttons (names with "button" always are)
    crop_margin       scene Gaussians this close (m) to an object's mesh are removed
    means_margin      scene Gaussians this close (m) to an object's own opaque Gaussians are removed too
    fill_spacing      m between the flat Gaussians filling the table under each object (0: no fill)
    snap_to_table     rest each object's lowest collision vertex on the table
    button_travel     press button travel (m)
    button_stiffness  the button's spring (N/m)
    randomize         where the twin may put objects at each reset
    max_mm            largest accepted median distance (mm) from a part's opaque Gaussians to its mesh
    sample            build the world from this sample's ground truth instead of the reconstruction
    head_keyframe     the head camera is the fixed camera that took this keyframe of the capture (e.g. right.jpg):
                      its pose and intrinsics from align-scene's cameras, no head calibration needed (default:
                      calibrate-handeye's head camera). The pipeline's (capture keeps that image as a keyframe)
    """

    robot: str = field(default=DEFAULT_ROBOT, metadata=SHARED)
    buttons: tuple[str, ...] = ()
    crop_margin: float = ranged(ReconstructionOptions.crop_margin, ge=0, le=0.1)
    means_margin: float = ranged(ReconstructionOptions.means_margin, ge=0, le=0.1)
    fill_spacing: float = ranged(ReconstructionOptions.fill_spacing, ge=0, le=0.1)
    snap_to_table: bool = ReconstructionOptions.snap_to_table
    button_travel: float = ranged(ReconstructionOptions.button_travel, gt=0, le=0.1)
    button_stiffness: float = ranged(ReconstructionOptions.button_stiffness, gt=0, le=1e6)
    randomize: RandomizeConfig = field(default_factory=RandomizeConfig)
    max_mm: float = ranged(3.0, gt=0, le=1000)
    sample: Path | None = None
    head_keyframe: str | None = field(default=None, metadata={**SHARED, "metavar": "IMAGE"})

    def options(self) -> ReconstructionOptions:
        """The library's options from these settings, each named (a renamed field fails here, not silently)."""
        return ReconstructionOptions(
            robot=RobotConfig(name=self.robot), buttons=self.buttons, crop_margin=self.crop_margin,
            means_margin=self.means_margin, fill_spacing=self.fill_spacing, snap_to_table=self.snap_to_table,
            button_travel=self.button_travel, button_stiffness=self.button_stiffness, randomize=self.randomize,
        )  # fmt: skip


def _object_dirs(ws: Workspace) -> dict[str, Path]:
    names = list(json.loads(ws.objects_summary.read_text())) if ws.objects_summary.is_file() else []
    if not names:
        raise WorldConfigError(f"{ws.objects_dir}: no reconstructed objects; run `m2m objects -w {ws.root}` first")
    for name in names:
        for f in ("align.json", "mesh.obj", "gaussians.ply"):
            if not (ws.object_dir(name) / f).is_file():
                raise WorldConfigError(f"{ws.object_dir(name) / f} not found: object {name!r} is incomplete; run "
                                       f"`m2m objects -w {ws.root}` again")  # fmt: skip
    return {n: ws.object_dir(n) for n in names}


# The base frame's z = 0 is the surface the robot stands on. A board within this height of it lies on a table level
# with the base (the difference is the board's own thickness: 0.5 mm on the samples); further off, the table is where
# the board is (the public real capture's arm stands on a frame, its table 3.8 cm lower).
TABLE_LEVEL_M = 0.005


def _table_z(ws: Workspace) -> float:
    """The table's height in the base frame (m): the board's, which lies on it, unless level with the base."""
    plane = ws.board_plane()
    z = 0.0 if plane is None else float(plane[0][2])
    return z if abs(z) > TABLE_LEVEL_M else 0.0


def _keyframe_camera(ws: Workspace, keyframe: str) -> CameraConfig:
    """The camera that took ``keyframe``, fixed in the base frame (align-scene's cameras)."""
    from ..capture.keyframes import names_image

    cameras = ws.cameras_base()
    matches = [c for c in cameras if names_image(c.name, keyframe)]
    if len(matches) != 1:
        shown = ", ".join(c.name for c in cameras[:8]) + (", ..." if len(cameras) > 8 else "")
        raise WorldConfigError(f"head_keyframe {keyframe!r}: not one of the capture's keyframes ({shown}); "
                               "give the file name of the keyframe the head camera took")  # fmt: skip
    return _fixed_camera(matches[0])


def _head_camera(ws: Workspace, handeye: dict[str, Any], keyframe: str | None = None) -> CameraConfig:
    from ..world.cameras import calibrated_head_camera

    if keyframe is not None:
        return _keyframe_camera(ws, keyframe)
    cam, why = calibrated_head_camera(handeye)
    if cam is None:
        raise WorldConfigError(
            f"{ws.handeye_file}: {why} (a head-camera calibration records T_base_headcam, K and the image size); "
            f"rerun `m2m calibrate-handeye --mount head ... -w {ws.root}`, or give head_keyframe (m2m.yaml, at the "
            "top): the keyframe of the capture a fixed camera took"
        )
    return _fixed_camera(cam)


def _fixed_camera(cam: Camera) -> CameraConfig:
    """A camera fixed in the base frame (``cam.T_world_cam`` is T_base_cam), its lens kept: the world draws it."""
    return CameraConfig("base", cam.T_world_cam, cam.K, cam.width, cam.height, cam.distortion_json())


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    robot = [Input(Path(cfg.robot), field="compose robot")] if is_spec_file(cfg.robot) else []  # its content counts
    if cfg.sample is not None:
        optional = [Input(p) for p in (ws.handeye_file, ws.scene_ply) if p.is_file()]
        truth = [Input(Path(cfg.sample) / n, field="compose sample") for n in ("ground_truth.json", "gt")]
        return truth + optional + robot
    look = [Input(ws.robot_gaussians_dir / "robot.json")] if (ws.robot_gaussians_dir / "robot.json").is_file() else []
    if cfg.head_keyframe is not None:  # a wrist calibration, when there is one, still counts
        cameras = [Input(ws.cameras_base_file, made_by="align-scene")] + \
            ([Input(ws.handeye_file)] if ws.handeye_file.is_file() else [])  # fmt: skip
    else:
        cameras = [Input(ws.handeye_file, made_by="calibrate-handeye")]
    return [*cameras, Input(ws.scene_ply, made_by="train-scene"), Input(ws.objects_summary, made_by="objects"),
            *robot, *look]  # fmt: skip


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    from ..world import sample_world, save_world, world_from_reconstruction
    from ..world.compose import consistency, write_world_ply

    he = json.loads(ws.handeye_file.read_text()) if ws.handeye_file.is_file() else {}
    if cfg.sample is not None:  # the sample's ground truth, over the workspace's scene and head camera if it has them
        T = np.asarray(he["T_base_headcam"], np.float64) if "T_base_headcam" in he else None
        scene = ws.scene_ply if ws.scene_ply.is_file() else None
        world = sample_world(cfg.sample, ws.world_dir, scene_ply=scene, T_base_headcam=T, overwrite=True,
                             robot=cfg.robot)  # fmt: skip
        note = ""
    else:
        wrist, wrist_note = calibrated_wrist_camera(he, cfg.robot)
        head = "the head camera: keyframe " + cfg.head_keyframe if cfg.head_keyframe else "the head camera calibrated"
        note = f"; {head}, {wrist_note}"
        table_z = _table_z(ws)
        if table_z:
            side = "below" if table_z < 0 else "above"
            note += f"; the table {1000 * abs(table_z):.1f} mm {side} the robot's base (where the board lies)"
        world = world_from_reconstruction(ws.world_dir, _head_camera(ws, he, cfg.head_keyframe), ws.scene_ply,
                                          _object_dirs(ws), replace(cfg.options(), table_z=table_z), log,
                                          wrist=wrist)  # fmt: skip
    lensed = [c for c, cam in world.cameras.items() if cam.distortion]
    note += f"; {' and '.join(lensed)} drawn through the calibrated lens" if lensed else ""
    robot_note = _robot_gaussians(ws, world, cfg) + note
    save_world(world.relocated(ws.world_dir, ws.committed.world_dir), ws.world_yaml, home=ws.committed.world_dir)
    write_world_ply(world)
    cons = {k: 1000 * v for k, v in consistency(world).items()}
    worst = max(cons.values(), default=0.0)
    details = [f"{name}: median Gaussian-to-mesh distance {d:.2f} mm" for name, d in cons.items()]
    if worst > cfg.max_mm:
        raise WorldConfigError(f"an object's Gaussians and mesh disagree by {worst:.1f} mm (> max_mm {cfg.max_mm}); "
                               "check objects/<name>/figure.png")  # fmt: skip
    return {"consistency_mm": cons, "details": details,
            "line": f"{len(world.objects)} objects, {len(world.articulated)} articulated; Gaussians vs meshes "
                    f"<= {worst:.2f} mm (median per part); {robot_note}"}  # fmt: skip


def _robot_gaussians(ws: Workspace, world, cfg: Config) -> str:
    """The robot as the capture saw it (train-scene's scene/robot/) into the world, when it is this world's robot;
    the words for the stage's line."""
    info = ws.committed.robot_gaussians_dir / "robot.json"
    if not info.is_file():
        return "the robot in its model's look (the capture did not show it)"
    robot = json.loads(info.read_text(encoding="utf-8")).get("robot")
    if robot != world.robot.spec.name:
        return f"the robot in its model's look (the capture's robot Gaussians are of {robot}, the world's robot is " \
               f"{world.robot.spec.name})"  # fmt: skip
    world.robot.gaussians = info.parent
    return "the robot as the capture saw it (scene/robot/)"


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.world_yaml]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.world_dir]
