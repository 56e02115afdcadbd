"""``m2m validate``: check a LeRobot dataset with an independent reader."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..export import validate
from .args import CliError, info


def register(sub: argparse._SubParsersAction) -> None:
    v = sub.add_parser("validate", help="check a LeRobot v3.0 / v2.1 dataset with an independent reader")
    v.add_argument("dataset", help="dataset folder")
    v.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    problems = validate(args.dataset)
    if problems:
        raise CliError(f"{args.dataset}: {len(problems)} problem(s) found:\n" + "\n".join(f"  - {p}" for p in problems))
    meta = json.loads((Path(args.dataset) / "meta" / "info.json").read_text(encoding="utf-8"))
    info(f"{args.dataset}: valid LeRobot {meta['codebase_version']} dataset, {meta['total_episodes']} episodes, "
         f"{meta['total_frames']} frames")  # fmt: skip
    return 0
