"""The single ``m2m`` command.

One subcommand per pipeline stage, generated from the stage's Config (``m2m capture``, ``m2m sfm``,
``m2m align-scene``, ``m2m calibrate-handeye``, ``m2m train-scene``, ``m2m head-view``, ``m2m objects``,
``m2m compose``, ``m2m generate``): each field is a flag whose default and doc come from the Config, on top of
the workspace's ``m2m.yaml`` when it has the stage's section. The tools that are not stages live in
``commands/`` (init and run: a workspace's m2m.yaml and every stage of it; demo, render, bench, board, intrinsics,
validate, sample, world edits, task, view).

Expected failures (:class:`~mirage2matter.errors.M2MError`: bad files, bad fields, missing inputs) and file
system errors print ``m2m: error: <message>`` to stderr and exit with status 2, without a traceback;
``m2m --debug ...`` (or ``M2M_DEBUG=1``) shows the traceback instead. Heavy imports (torch, numba, Genesis)
happen inside the commands so that ``m2m --help`` answers at once.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from collections.abc import Sequence
from typing import Any

from . import __version__, configure_threads
from .commands import bench, board, demo, init, intrinsics, render, report, robot, run, sample, validate, view, world
from .commands.args import info, show
from .configs import add_flags, from_flags
from .errors import M2MError
from .stages import STAGES, Stage
from .stages.base import run_stage
from .stages.transaction import workspace_lock
from .workspace import Workspace

EXIT_ERROR = 2  # bad input, like argparse's own usage errors
EXIT_INTERRUPTED = 130


def _stage_parser(sub: argparse._SubParsersAction, stage: Stage, full: bool) -> None:
    p = sub.add_parser(stage.command, help=stage.help, description=stage.help)
    p.add_argument("-w", "--workspace", required=True, metavar="DIR", help="the workspace folder")
    p.add_argument("--force", action="store_true", help="run even if a run with the same settings and inputs finished")
    if full:  # the Config's flags (this imports the stage's libraries)
        add_flags(p, stage.config)
    p.set_defaults(func=lambda args: run_stage_command(stage, args))


def run_stage_command(stage: Stage, args: argparse.Namespace) -> int:
    """The stage with the workspace's settings (m2m.yaml) changed by the flags given; the settings it ran
    with are saved back into m2m.yaml."""
    from .stages.pipeline import PipelineConfig

    ws = Workspace(args.workspace)
    load = lambda: PipelineConfig.load(ws.config_file) if ws.config_file.is_file() else PipelineConfig()
    cfg = _command_line_wins(from_flags(stage.config, args, load().stage_config(stage.name)), args)
    configure_threads()
    summary, skipped = run_stage(stage, ws, cfg, log=info, force=args.force)
    # read-modify-write of m2m.yaml (another stage's section may have changed), beside running policy stages
    with workspace_lock(ws, alongside=True, wait_s=60.0):
        load().with_stage(stage.name, cfg).save(ws.config_file)
    for line in summary.get("details", []):
        print(line)
    note = " (up to date: same settings and inputs as the last run; --force to rerun)" if skipped else ""
    print(f"{stage.name}: {summary['line']}{note} -> {show(ws.root)}/")
    return 0


def _command_line_wins(cfg: Any, args: argparse.Namespace) -> Any:
    """``cfg`` without the settings of m2m.yaml that exclude one given on the command line (a Config's
    ``EXCLUSIVE`` groups, e.g. sfm's intrinsics and from_transforms): the flag wins, and the line says so."""
    for group in getattr(cfg, "EXCLUSIVE", ()):
        flags = [n for n in group if getattr(args, n, None) is not None]
        dropped = [n for n in group if n not in flags and getattr(cfg, n) is not None]
        if flags and dropped:
            info(f"--{flags[0].replace('_', '-')} given: {', '.join(dropped)} of m2m.yaml dropped")
            cfg = dataclasses.replace(cfg, **{n: None for n in dropped})
    return cfg


def build_parser(only: str | None = "*") -> argparse.ArgumentParser:
    """The ``m2m`` parser; the commands whose flags come from Configs get them only when ``only`` names them
    ("*": every command; None: none, enough for ``m2m --help``)."""
    parser = argparse.ArgumentParser(
        prog="m2m",
        description="Mirage2Matter: multi-view video of a robot workspace -> photorealistic, physically grounded "
        "simulator and robot demonstrations.",
        epilog=(
            "examples:\n"
            '  m2m init -w ws --video table.mp4 --board board.json --task "grasp banana"   your capture\'s settings\n'
            "  m2m run -w ws                              every stage, from ws/m2m.yaml\n"
            "  m2m demo                                   the whole pipeline on the bundled sample\n"
            "  m2m capture my_table.mp4 -w ws && m2m sfm -w ws\n"
            "  m2m train-scene -w ws --minutes 10\n"
            "  m2m render scene.ply --camera cam.json --out view.png\n"
            "  m2m bench render --gaussians 100000 --size 224"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"m2m (mirage2matter) {__version__}")
    parser.add_argument("--debug", action="store_true", help="show Python tracebacks for errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    init.register(sub, full=only in ("*", "init"))
    run.register(sub)
    demo.register(sub, full=only in ("*", "demo"))
    for stage in STAGES:
        _stage_parser(sub, stage, full=only in ("*", stage.command))
    bench.register(sub, full=only in ("*", "bench"))
    for module in (render, board, intrinsics, validate, sample):
        module.register(sub)
    world.register(sub, full=only in ("*", "task"))  # m2m task's flags import the generation libraries
    for module in (robot, report, view):
        module.register(sub)
    return parser


def _command(argv: Sequence[str]) -> str | None:
    """The subcommand named in ``argv`` (the first word that is not an option), None without one."""
    return next((a for a in argv if not a.startswith("-")), None)


def _describe(e: BaseException) -> str:
    if isinstance(e, OSError) and e.filename and e.strerror:
        return f"{e.filename}: {e.strerror}"
    return str(e) or type(e).__name__


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``m2m`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(only=_command(argv))
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, --version and usage errors; return rather than exit for in-process callers
        return e.code if isinstance(e.code, int) else (0 if e.code is None else EXIT_ERROR)
    debug = args.debug or os.environ.get("M2M_DEBUG", "") not in ("", "0")
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("m2m: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (M2MError, OSError) as e:  # every expected failure; OSError: missing or unwritable files
        if debug:
            raise
        print(f"m2m: error: {_describe(e)}", file=sys.stderr)
        return EXIT_ERROR
