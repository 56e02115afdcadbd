"""``m2m sample make``: render a sample capture with ground truth (what ships in samples/tabletop)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from ..configs import add_flags, from_flags, ranged
from ..robots import DEFAULT_ROBOT, get_robot, is_spec_file
from ..sample.handeye_capture import HandEyeCaptureConfig
from .args import info


@dataclass
class SampleMakeConfig:
    """m2m sample make settings.

    seed    scene and trajectory seed
    marker  the target on the table: the ChArUco board (default), an 18 cm ArUco marker or AprilTag, or an ArUco grid
    lens    the video camera: the renderer's pinhole (default; the head camera's), or a phone's main camera with barrel
            distortion and an off-centre principal point (k1 -0.16; ground_truth.json holds it under "camera"; the
            sample's m2m.yaml leaves it out, so SfM calibrates it)
    layout  where the objects stand: the bundled sample's places (default; jittered by 1.5 cm for seeds other than 0),
            or drawn anywhere in the workspace for the seed
    robot   the robot holding the board in the hand-eye images: a registered robot (panda, ur5e) or a robot spec file
    """

    seed: int = ranged(0, ge=0)
    marker: Literal["charuco", "aruco", "apriltag", "aruco_grid"] = "charuco"
    lens: Literal["pinhole", "phone"] = "pinhole"
    layout: Literal["nominal", "random"] = "nominal"
    robot: str = field(default=DEFAULT_ROBOT, metadata={"metavar": "ROBOT"})


@dataclass
class SampleHandEyeConfig:
    """m2m sample handeye settings (``sample.handeye_capture.HandEyeCaptureConfig``'s).

    mount   wrist: camera on the hand, board on the table; head: camera fixed, board in the gripper
    views   images to make
    seed    poses, noise and robot error seed
    """

    mount: Literal["wrist", "head"] = "wrist"
    views: int = ranged(HandEyeCaptureConfig.views, ge=3)
    seed: int = ranged(0, ge=0)


def register(sub: argparse._SubParsersAction) -> None:
    sample = sub.add_parser("sample", help="the bundled sample capture with ground truth")
    sample_sub = sample.add_subparsers(dest="what", metavar="WHAT", required=True)
    sm = sample_sub.add_parser(
        "make",
        help="render a sample capture (video + hand-eye images + ground truth) with Genesis",
        description=(
            "Render a hand-held video orbiting a table with the robot standing at its base (at a logged joint state, "
            "in a look of its own), a ChArUco board beside it, two objects and a button, the fixed head camera's "
            "hand-eye images of a board held by the robot, and ground_truth.json, into a NEW directory (written under "
            "a temporary name and renamed when complete). Deterministic for a seed."
        ),
    )
    sm.add_argument("dir", help="output directory (must not exist, or be empty)")
    add_flags(sm, SampleMakeConfig)
    sm.add_argument("--short", action="store_true", help="a quick version: 4 s of video at 5 fps, 6 hand-eye views")
    sm.add_argument(
        "--empty-table",
        action="store_true",
        help="film the table without the robot (it appears only in the hand-eye images; the board lies "
        "where its base would stand). By default the robot stands in the video at a logged joint state "
        "(ground_truth.json robot.capture_joints, capture_joints in the sample's m2m.yaml), as on "
        "every real capture",
    )
    sm.add_argument(
        "--one-pose",
        action="store_true",
        help="the robot stands still while filmed. By default it moves once: from the video's middle frame on "
        "it stands at a second pose that shows the orbit what the first hid (its upper arm, wrist and hand "
        "from above, the room behind it), as if the user paused the recording, moved the arm and resumed "
        "(ground_truth.json robot.capture_moves, capture_moves in the sample's m2m.yaml); the head "
        "photo and the hand-eye images show the first pose",
    )
    sm.set_defaults(func=run)
    he = sample_sub.add_parser(
        "handeye",
        help="make a hand-eye capture as a real arm and camera make it (lens distortion, noise, robot pose error)",
        description=(
            "Ray-trace a camera's images of a ChArUco board while the default robot moves, with what makes real "
            "data hard: a lens with distortion, sensor noise, blur and exposure changes, and joint angles off by "
            "encoder offsets and noise (about 1 mm / 0.1 deg at the hand). Writes images/, joints.json (the "
            "reported joints and hand poses), intrinsics.json, board.json and ground_truth.json into a NEW folder."
        ),
    )
    he.add_argument("dir", help="output directory (must not exist, or be empty)")
    add_flags(he, SampleHandEyeConfig)
    he.set_defaults(func=run_handeye)


def run(args: argparse.Namespace) -> int:
    from ..sample.make import (
        SampleConfig,
        SampleError,
        make_sample,
        with_layout,
        with_lens,
        with_marker,
        with_robot_in_view,
    )

    short, empty_table, one_pose = args.short, args.empty_table, args.one_pose
    out_dir, args = args.dir, from_flags(SampleMakeConfig, args)
    if empty_table and one_pose:
        raise SampleError("--one-pose is the pose of the robot in the video; --empty-table films none: give one of "
                          "them")  # fmt: skip
    config = SampleConfig.short(args.seed) if short else SampleConfig(seed=args.seed)
    config = with_layout(with_lens(with_marker(config, args.marker), args.lens), args.layout)
    if args.robot != config.robot:
        robot = str(Path(args.robot).resolve()) if is_spec_file(args.robot) else args.robot
        get_robot(robot)  # an unknown robot or a bad spec file fails before anything renders
        config = replace(config, robot=robot)
    if not empty_table:  # after the robot is chosen: its second pose is its own
        config = with_robot_in_view(config, second_pose=not one_pose)
    make_sample(out_dir, config, log=info)
    print(f"wrote the sample to {out_dir} (ground_truth.json, scene.mp4, handeye/, gt/, contact_sheet.jpg)")
    return 0


def run_handeye(args: argparse.Namespace) -> int:
    from ..sample.handeye_capture import HandEyeCaptureConfig, make_handeye_capture

    given = from_flags(SampleHandEyeConfig, args)
    cfg = HandEyeCaptureConfig(mount=given.mount, views=given.views, seed=given.seed)
    gt = make_handeye_capture(args.dir, cfg, log=info)
    print(
        f"wrote a {cfg.mount} hand-eye capture of {cfg.views} views to {args.dir}; reported hand poses off by "
        f"{np.median(gt['hand_pose_error_mm']):.2f} mm / {np.median(gt['hand_pose_error_deg']):.3f} deg (median)"
    )
    return 0
