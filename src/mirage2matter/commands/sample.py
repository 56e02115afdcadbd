"""``m2m sample make``: render a sample capture with ground truth (what ships in samples/tabletop)."""

from __future__ import annotations

import argparse

from ..robots import DEFAULT_ROBOT, ROBOTS
from .args import info, int_at_least


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
    sm.add_argument("--seed", type=int_at_least(0), default=0, help="scene and trajectory seed (default 0)")
    sm.add_argument("--short", action="store_true", help="a quick version: 4 s of video at 5 fps, 6 hand-eye views")
    sm.add_argument("--marker", choices=("charuco", "aruco", "apriltag", "aruco_grid"), default="charuco",
                    help="the target on the table: the ChArUco board (default), an 18 cm ArUco marker or AprilTag, or "
                    "an ArUco grid")
    sm.add_argument("--lens", choices=("pinhole", "phone"), default="pinhole",
                    help="the video camera: the renderer's pinhole (default; the head camera's), or a phone's main "
                    "camera with barrel distortion and an off-centre principal point (k1 -0.16; ground_truth.json "
                    "holds it under \"camera\"; the sample's m2m.yaml leaves it out, so SfM calibrates it)")
    sm.add_argument("--layout", choices=("nominal", "random"), default="nominal",
                    help="where the objects stand: the bundled sample's places (default; jittered by 1.5 cm for "
                    "seeds other than 0), or drawn anywhere in the workspace for the seed")
    sm.add_argument("--robot", default=DEFAULT_ROBOT, metavar="ROBOT",
                    help="the robot holding the board in the hand-eye images: a registered robot "
                    f"({', '.join(ROBOTS)}) or a robot spec file (default {DEFAULT_ROBOT})")
    sm.add_argument("--empty-table", action="store_true",
                    help="film the table without the robot (it appears only in the hand-eye images; the board lies "
                    "where its base would stand). By default the robot stands in the video at a logged joint state "
                    "(ground_truth.json robot.capture_joints, align.capture_joints in the sample's m2m.yaml), as on "
                    "every real capture")
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
    he.add_argument("--mount", choices=("wrist", "head"), default="wrist",
                    help="wrist: camera on the hand, board on the table; head: camera fixed, board in the gripper")
    he.add_argument("--views", type=int_at_least(3), default=12, help="images to make (default 12)")
    he.add_argument("--seed", type=int_at_least(0), default=0, help="poses, noise and robot error seed (default 0)")
    he.set_defaults(func=run_handeye)


def run(args: argparse.Namespace) -> int:
    from ..sample.make import SampleConfig, make_sample, with_layout, with_lens, with_marker, with_robot_in_view

    config = SampleConfig.short(args.seed) if args.short else SampleConfig(seed=args.seed)
    config = with_layout(with_lens(with_marker(config, args.marker), args.lens), args.layout)
    if not args.empty_table:
        config = with_robot_in_view(config)
    if args.robot != config.robot:
        from dataclasses import replace
        from pathlib import Path

        from ..robots import get_robot, is_spec_file

        robot = str(Path(args.robot).resolve()) if is_spec_file(args.robot) else args.robot
        get_robot(robot)  # an unknown robot or a bad spec file fails before anything renders
        config = replace(config, robot=robot)
    make_sample(args.dir, config, log=info)
    print(f"wrote the sample to {args.dir} (ground_truth.json, scene.mp4, handeye/, gt/, contact_sheet.jpg)")
    return 0


def run_handeye(args: argparse.Namespace) -> int:
    import numpy as np

    from ..sample.handeye_capture import HandEyeCaptureConfig, make_handeye_capture

    cfg = HandEyeCaptureConfig(mount=args.mount, views=args.views, seed=args.seed)
    gt = make_handeye_capture(args.dir, cfg, log=info)
    print(f"wrote a {args.mount} hand-eye capture of {args.views} views to {args.dir}; reported hand poses off by "
          f"{np.median(gt['hand_pose_error_mm']):.2f} mm / {np.median(gt['hand_pose_error_deg']):.3f} deg (median)")
    return 0
