"""``m2m demo``: ``m2m run`` on the bundled sample, as it would run on a capture of yours.

The sample's ``m2m.yaml`` gives the stages their inputs (video, board, calibration, hand-eye images, head
photo) and the demo's budget; any stage field can be changed with ``--<stage>.<field>``. Those settings are
written to ``<workspace>/m2m.yaml`` and the workspace is run as ``m2m run`` runs one (each stage's record in
``pipeline.json``: an interrupted run resumes); the sample's ``ground_truth.json`` adds how close each stage came.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from pathlib import Path

from ..configs import add_flags, from_flags
from ..sample.inspect import BUNDLED_SAMPLE
from ..stages.transaction import workspace_lock
from ..workspace import Workspace, WorkspaceError
from .args import Formatter, add_settings
from .run import StagesConfig, run_workspace


@dataclass
class DemoConfig:
    """m2m demo settings (besides the stages': the sample's m2m.yaml, changed by --<stage>.<field>).

    workspace  the workspace folder
    sample     a capture in the bundled sample's layout, with its m2m.yaml (default: the bundled one)
    """

    workspace: Path = field(default=Path("workspaces/demo"), metadata={"flags": ("-w", "--workspace"),
                                                                       "metavar": "DIR"})  # fmt: skip
    sample: Path = field(default=BUNDLED_SAMPLE, metadata={"metavar": "DIR"})


def register(sub: argparse._SubParsersAction, full: bool = True) -> None:
    d = sub.add_parser(
        "demo",
        help="the whole pipeline on the bundled sample: video -> reconstruction -> world -> demonstrations",
        description=(
            "Run every stage on the bundled sample capture (as it would run on yours): keyframes, SfM, metric "
            "alignment, hand-eye, scene 3DGS and its head-camera check, objects, the world and its Genesis twin, "
            "and a few LeRobot demonstrations per task, validated. The sample's m2m.yaml sets the inputs and "
            "budget; --<stage>.<field> changes any setting. Each stage is recorded in pipeline.json; a rerun (e.g. "
            "after an interruption) skips the finished ones."
        ),
        formatter_class=Formatter,
        add_help=False,
    )
    add_flags(d, DemoConfig)
    add_flags(d, StagesConfig)
    base = None
    if full:  # the defaults --help shows: the bundled sample's settings
        from ..stages.pipeline import PipelineConfig

        bundled = BUNDLED_SAMPLE / "m2m.yaml"
        base = PipelineConfig.load(bundled) if bundled.is_file() else None
    add_settings(d, full, base)  # every stage's settings as --<stage>.<field> (when full: imports their libraries)
    d.set_defaults(func=run)


def _sample_config(sample: Path):
    from ..stages.pipeline import PipelineConfig

    path = sample / "m2m.yaml"
    if not path.is_file():
        raise WorkspaceError(f"{path} not found: the demo needs a sample with its m2m.yaml (`m2m sample make DIR`)")
    return PipelineConfig.load(path)


def run(args: argparse.Namespace) -> int:
    from ..stages.pipeline import PipelineConfig

    demo, stages = from_flags(DemoConfig, args), from_flags(StagesConfig, args)
    sample = demo.sample
    cfg = from_flags(PipelineConfig, args, _sample_config(sample))
    ws = Workspace(demo.workspace)
    gt_path = sample / "ground_truth.json"
    gt = json.loads(gt_path.read_text()) if gt_path.is_file() else None
    if ws.root.exists() and not ws.root.is_dir():
        raise WorkspaceError(f"workspace {ws.root} exists and is not a folder; choose another with -w")
    with workspace_lock(ws, "m2m demo"):  # the settings written and run under one lock
        cfg.save(ws.config_file)
        run_workspace(ws, stages.until, stages.start, ground_truth=gt, command="m2m demo", summary_file=ws.demo_summary)
    return 0
