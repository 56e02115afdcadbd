"""``m2m run``: every stage of a workspace's ``m2m.yaml`` (``m2m init`` writes one), in order.

The settings are checked before anything runs (an unknown key, a wrong type or a missing file names its line);
stages whose optional inputs are not given are skipped with the reason (:func:`~..stages.pipeline.plan_run`).
Each stage shows its progress, its record goes to ``pipeline.json`` (a killed run resumes at the stage it was
in), and the run ends with one line per stage, also written to ``run_summary.json``, and ``report.html`` (the
run's page, a failed run's too). ``m2m demo`` is this on the bundled sample's settings, with the sample's ground
truth compared where a stage can.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from .. import __version__, configure_threads
from ..atomic import atomic_write
from ..configs import add_flags, from_flags
from ..stages import PIPELINE
from ..stages.transaction import workspace_lock
from ..workspace import Workspace, WorkspaceError
from .args import Formatter, info, show

__all__ = ["StagesConfig", "print_summary", "register", "run_workspace"]

PipelineStage = Literal[tuple(s.name for s in PIPELINE)]  # type: ignore[valid-type]


@dataclass
class StagesConfig:
    """The stages a run goes through (``m2m run``, ``m2m demo``).

    until   last stage to run (default: all)
    start   first stage to run (default: the first); the earlier stages' outputs must be in the workspace
    """

    until: PipelineStage | None = field(default=None, metadata={"metavar": "STAGE"})
    start: PipelineStage | None = field(default=None, metadata={"metavar": "STAGE", "flags": ("--from",)})


def register(sub: argparse._SubParsersAction) -> None:
    names = [s.name for s in PIPELINE]
    p = sub.add_parser(
        "run",
        help="every stage of the workspace's m2m.yaml (from `m2m init`): video -> world -> demonstrations",
        description=(
            "Run every stage of the workspace's m2m.yaml in order (" + ", ".join(names) + "), from the settings "
            "in that file (`m2m init` writes one; edit it to change any setting). Stages whose optional inputs are "
            "not given (hand-eye images, a head-camera photo, tasks) are skipped with the reason. Each finished "
            "stage is recorded in pipeline.json: a rerun skips it while its settings and input files are unchanged, "
            "so a run that was killed resumes at the stage it was in."
        ),
        epilog="every setting: <workspace>/m2m.yaml, each explained; as flags:\n  m2m init --help-all",
        formatter_class=Formatter,
        add_help=False,
    )
    p.add_argument("-w", "--workspace", required=True, metavar="DIR", help="the workspace folder (with its m2m.yaml)")
    add_flags(p, StagesConfig)
    p.add_argument("-h", "--help", action="help", help="show this help")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = from_flags(StagesConfig, args)
    run_workspace(Workspace(args.workspace), until=cfg.until, start=cfg.start)
    return 0


def run_workspace(
    ws: Workspace,
    until: str | None = None,
    start: str | None = None,
    ground_truth: dict | None = None,
    command: str = "m2m run",
    summary_file: Path | None = None,
) -> dict[str, Any]:
    """The stages of ``ws``'s m2m.yaml from ``start`` through ``until``; prints the progress (stderr) and the
    summary (stdout), writes it to ``summary_file`` (default ``run_summary.json``) and returns it."""
    from ..stages.pipeline import PipelineConfig, PipelineError, run_pipeline

    if ws.root.exists() and not ws.root.is_dir():
        raise WorkspaceError(f"workspace {ws.root} exists and is not a folder; choose another with -w")
    if not ws.config_file.is_file():
        raise WorkspaceError(f"{ws.config_file} not found: write the workspace's settings first, `m2m init -w "
                             f"{ws.root} --video VIDEO --board BOARD.json ...` (see `m2m init --help`)")  # fmt: skip
    configure_threads()
    summary_file = ws.run_summary if summary_file is None else summary_file
    t0 = time.perf_counter()
    with workspace_lock(ws, command):
        cfg, where = PipelineConfig.read(ws.config_file)
        try:
            result = run_pipeline(ws, cfg, info, until, start, ground_truth, where, command)
        except PipelineError as e:  # a stopped run's summary says where and why (`m2m report` reads it)
            if e.result is not None:
                _write_summary(summary_file, e.result)
            raise
        _write_summary(summary_file, result)
    print_summary(result, ws, time.perf_counter() - t0, command, summary_file)
    return result


def _write_summary(path: Path, result: dict[str, Any]) -> None:
    result["mirage2matter_version"] = __version__
    with atomic_write(path, "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1, default=str)


def print_summary(result: dict[str, Any], ws: Workspace, elapsed: float, command: str, summary_file: Path) -> None:
    lines = [f"{command} finished in {elapsed / 60:.1f} min; workspace {show(ws.root)}/"]
    for stage, summary in result["stages"].items():
        lines.append(f"  {stage:<10} {summary['line']}")
        lines += [f"             {d}" for d in summary.get("details", [])]
    lines.append(f"  summary    {show(summary_file)}; settings in {show(ws.config_file)}; stage records in "
                 f"{show(ws.record_file)}")  # fmt: skip
    if ws.report_html.is_file():
        lines.append(f"  report     {show(ws.report_html)} (open it in a browser: the stages' pictures, the datasets)")
    print("\n".join(lines), flush=True)
