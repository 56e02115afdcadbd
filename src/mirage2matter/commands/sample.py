"""``m2m sample make``: render a sample capture with ground truth (what ships in samples/tabletop)."""

from __future__ import annotations

import argparse

from .args import info, int_at_least


def register(sub: argparse._SubParsersAction) -> None:
    sample = sub.add_parser("sample", help="the bundled sample capture with ground truth")
    sample_sub = sample.add_subparsers(dest="what", metavar="WHAT", required=True)
    sm = sample_sub.add_parser(
        "make",
        help="render a sample capture (video + hand-eye images + ground truth) with Genesis",
        description=(
            "Render a hand-held video orbiting a table with a ChArUco board, two objects and a button, the fixed "
            "head camera's hand-eye images of a board held by the robot, and ground_truth.json, into a NEW "
            "directory (written under a temporary name and renamed when complete). Deterministic for a seed."
        ),
    )
    sm.add_argument("dir", help="output directory (must not exist, or be empty)")
    sm.add_argument("--seed", type=int_at_least(0), default=0, help="scene and trajectory seed (default 0)")
    sm.add_argument("--short", action="store_true", help="a quick version: 4 s of video at 5 fps, 6 hand-eye views")
    sm.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..sample.make import SampleConfig, make_sample

    config = SampleConfig.short(args.seed) if args.short else SampleConfig(seed=args.seed)
    make_sample(args.dir, config, log=info)
    print(f"wrote the sample to {args.dir} (ground_truth.json, scene.mp4, handeye/, gt/, contact_sheet.jpg)")
    return 0
