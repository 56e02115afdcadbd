"""What a stage is, and the one skip/resume rule every stage follows.

A stage is a :class:`Stage` and one module in ``stages/``: a typed Config (the only place its defaults
live), the files it reads (:class:`Input`, so a missing one names the command that writes it), what it
writes (``outputs``) and ``run(ws, cfg, log) -> summary`` (a JSON-ready dict with a one-line ``"line"``).

:func:`run_stage` is the only way a stage runs, from ``m2m <stage>``, ``m2m demo`` or ``m2m run``: the
stage's fingerprint is a hash of its config and of the content of its inputs; when ``pipeline.json``
holds that fingerprint for the stage and its outputs exist, the stage is skipped (its recorded summary
returned). Otherwise it runs and its record is written. Work inside a stage that resumes after a kill
(scene checkpoints, finished objects, staged episodes) keys on the same fingerprint.
"""

from __future__ import annotations

import importlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..atomic import atomic_write
from ..configs import to_dict
from ..errors import M2MError
from ..fingerprint import fingerprint
from ..workspace import Workspace, WorkspaceError

__all__ = ["Input", "Stage", "StageRecord", "jsonable", "run_stage", "stage_fingerprint"]

Log = Callable[[str], None]


@dataclass(frozen=True)
class Input:
    """One file (or folder) a stage reads.

    path      where it is
    made_by   the stage command that writes it (an earlier stage's artifact), or None for a user's file
    field     the config field that names it (a user's file)
    """

    path: Path
    made_by: str | None = None
    field: str | None = None

    def check(self, ws: Workspace) -> None:
        if self.path.exists():
            return
        if self.made_by is not None:
            raise WorkspaceError(f"{self.path} not found; run `m2m {self.made_by} -w {ws.root}` first")
        raise M2MError(f"{self.field or 'input'}: {self.path} not found; check the path")


@dataclass(frozen=True)
class Stage:
    """One pipeline stage: its names here, its code in ``stages/<module>.py`` (imported on first use, so
    ``m2m --help`` loads no stage's libraries).

    name      the key in pipeline.json and m2m.yaml ("capture", "sfm", "align", ...)
    command   its ``m2m`` subcommand ("capture", "align-scene", "train-scene", ...)
    help      one line for ``m2m --help``
    module    the module under ``stages/`` that defines ``Config``, ``inputs(ws, cfg) -> [Input]`` (the files
              read: their content enters the fingerprint), ``outputs(ws, cfg) -> [Path]`` (what a finished
              stage leaves), ``run(ws, cfg, log) -> summary`` (JSON-ready, with a one-line "line") and
              optionally ``compare(ws, cfg, ground_truth) -> summary fields`` (how close the stage came to a
              sample's ground truth, with a "line" suffix)
    """

    name: str
    command: str
    help: str
    module: str

    @property
    def code(self) -> Any:
        return importlib.import_module(f"{__package__}.{self.module}")

    @property
    def config(self) -> type:
        return self.code.Config

    def inputs(self, ws: Workspace, cfg: Any) -> list[Input]:
        return self.code.inputs(ws, cfg)

    def outputs(self, ws: Workspace, cfg: Any) -> list[Path]:
        return self.code.outputs(ws, cfg)

    def run(self, ws: Workspace, cfg: Any, log: Log) -> dict[str, Any]:
        return self.code.run(ws, cfg, log)

    def compare(self, ws: Workspace, cfg: Any, ground_truth: dict) -> dict[str, Any] | None:
        fn = getattr(self.code, "compare", None)
        return None if fn is None else fn(ws, cfg, ground_truth)


def jsonable(x: Any) -> Any:
    return json.loads(json.dumps(x, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def stage_fingerprint(stage: Stage, ws: Workspace, cfg: Any) -> str:
    """The stage's skip/resume key: its config and the content of its inputs."""
    inputs = stage.inputs(ws, cfg)
    for i in inputs:
        i.check(ws)
    return fingerprint(stage.name, to_dict(cfg), *[i.path for i in inputs])


class StageRecord:
    """``pipeline.json``: per finished stage its fingerprint, config, summary and seconds."""

    def __init__(self, ws: Workspace) -> None:
        self.path = ws.record_file
        self.data: dict[str, Any] = {}
        if self.path.is_file():
            try:
                self.data = json.loads(self.path.read_text(encoding="utf-8"))
            except ValueError:
                self.data = {}  # unreadable: every stage reruns (their artifacts are rewritten atomically)

    def get(self, stage: str, key: str, outputs: list[Path]) -> dict | None:
        rec = self.data.get(stage)
        if rec and rec.get("fingerprint") == key and all(p.exists() for p in outputs):
            return rec
        return None

    def put(self, stage: str, rec: dict[str, Any]) -> None:
        self.data[stage] = rec
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(self.path, "w", encoding="utf-8") as f:
            json.dump(self.data, f, indent=1, default=str)


def run_stage(
    stage: Stage, ws: Workspace, cfg: Any, log: Log = print, force: bool = False, ground_truth: dict | None = None
) -> tuple[dict[str, Any], bool]:
    """Run ``stage`` on ``ws`` with ``cfg`` unless an identical run finished; returns (summary, skipped).

    With ``ground_truth`` (a sample's ground_truth.json) the stage's ``compare`` adds how close it came."""
    validate = getattr(cfg, "validate", None)
    if validate is not None:
        validate()
    if ws.root.exists() and not ws.root.is_dir():
        raise WorkspaceError(f"workspace {ws.root} exists and is not a folder; choose another with -w")
    key = stage_fingerprint(stage, ws, cfg)
    record = StageRecord(ws)
    done = None if force else record.get(stage.name, key, stage.outputs(ws, cfg))
    if done is not None:
        return done["summary"], True
    ws.root.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    summary = stage.run(ws, cfg, log)
    extra = None if ground_truth is None else stage.compare(ws, cfg, ground_truth)
    if extra is not None:
        summary = {**summary, **extra, "line": summary["line"] + extra["line"]}
    seconds = time.perf_counter() - t0
    summary = jsonable(summary)
    record = StageRecord(ws)  # re-read: a long stage may have run beside another command
    record.put(stage.name, {"fingerprint": key, "config": to_dict(cfg), "summary": summary,
                            "seconds": round(seconds, 1)})  # fmt: skip
    return summary, False

