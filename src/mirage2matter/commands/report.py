"""``m2m report``: write ``<workspace>/report.html`` again for an existing workspace (``m2m run`` and ``m2m demo``
write it after every run): after stages run one by one, a policy trained or evaluated, or a page deleted."""

from __future__ import annotations

import argparse

from ..stages.report import write_report
from ..workspace import Workspace, WorkspaceError
from .args import show


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report",
        help="write <workspace>/report.html: every stage's line and pictures, the datasets, warnings, what next",
        description=(
            "Write the workspace's run report (report.html) from its stage records (pipeline.json) and its last run "
            "summary: every stage's line, figures and pictures, the datasets' previews, warnings and what to do "
            "next. It links the workspace's files relatively: open it from disk, no server; the folder can be moved."
        ),
    )
    p.add_argument("-w", "--workspace", required=True, metavar="DIR", help="the workspace folder")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    ws = Workspace(args.workspace)
    if not ws.root.is_dir():
        raise WorkspaceError(f"workspace {ws.root} not found (or not a folder); give the folder of `m2m run -w`")
    if not any(p.is_file() for p in (ws.record_file, ws.config_file, ws.run_summary, ws.demo_summary)):
        raise WorkspaceError(f"{ws.root} is not a workspace (no pipeline.json, m2m.yaml or run summary); `m2m init -w "
                             f"{ws.root} ...` writes one")  # fmt: skip
    path = write_report(ws)
    print(f"{show(path)} (open it in a browser)")
    return 0
