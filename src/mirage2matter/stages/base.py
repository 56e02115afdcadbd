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
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ..atomic import atomic_write
from ..configs import check_ranges, fingerprinted, ranged, to_dict
from ..errors import M2MError
from ..fingerprint import fingerprint
from ..robots import DEFAULT_ROBOT
from ..workspace import Workspace, WorkspaceError
from .transaction import OutputLock, Transaction, holds_lock, workspace_lock

__all__ = ["SHARED", "Input", "PipelineSettings", "Stage", "StageRecord", "jsonable", "run_stage", "stage_fingerprint",
           "used_with"]  # fmt: skip

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
    """One pipeline stage: its names here, its code in ``stages/<name>.py`` (imported on first use, so
    ``m2m --help`` loads no stage's libraries).

    name      the key in pipeline.json and m2m.yaml ("capture", "sfm", "align", ...) and the module under
              ``stages/`` that defines ``Config``, ``inputs(ws, cfg) -> [Input]`` (the files read: their content
              enters the fingerprint), ``writes(ws, cfg) -> [Path]`` (the artifacts it replaces, swapped in
              together), ``outputs(ws, cfg) -> [Path]`` (what a finished stage leaves), ``run(ws, cfg, log) ->
              summary`` (JSON-ready, with a one-line "line") and optionally ``compare(ws, cfg, ground_truth) ->
              summary fields`` (how close the stage came to a sample's ground truth, with a "line" suffix)
    command   its ``m2m`` subcommand ("capture", "align-scene", "train-scene", ...)
    help      one line for ``m2m --help``; also the doc of its section in m2m.yaml
    pipeline  part of a pipeline run (``m2m demo``, ``m2m run``); False: run on its own only (the policy stages,
              the user's experiment after the twin is built)
    """

    name: str
    command: str
    help: str
    pipeline: bool = True

    @property
    def code(self) -> Any:
        return importlib.import_module(f"{__package__}.{self.name}")

    @property
    def config(self) -> type:
        return self.code.Config

    def inputs(self, ws: Workspace, cfg: Any) -> list[Input]:
        return self.code.inputs(ws, cfg)

    def outputs(self, ws: Workspace, cfg: Any) -> list[Path]:
        return self.code.outputs(ws, cfg)

    def writes(self, ws: Workspace, cfg: Any) -> list[Path]:
        return self.code.writes(ws, cfg)

    def run(self, ws: Workspace, cfg: Any, log: Log) -> dict[str, Any]:
        return self.code.run(ws, cfg, log)

    def record_key(self, ws: Workspace, cfg: Any) -> str:
        """Its key in pipeline.json: the stage's name, or (a stage run once per output, e.g. one policy per
        name) the module's ``record_key(ws, cfg)``."""
        fn = getattr(self.code, "record_key", None)
        return self.name if fn is None else fn(ws, cfg)

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
    settings = fingerprinted(cfg)
    for f in fields(cfg):  # a setting of no use without another: out while that one is not set
        if f.metadata.get("used_with") and getattr(cfg, f.metadata["used_with"]) is None:
            settings.pop(f.name, None)
    return fingerprint(stage.name, settings, *[i.path for i in inputs])


START_WAIT_S = 60.0  # how long a policy stage's start waits for the workspace lock before it is refused

SHARED = {"shared": True}
"""Field metadata of a stage's setting that is the whole pipeline's (a field of the same name in
:class:`PipelineSettings`, e.g. the robot): ``m2m.yaml`` holds it once, at the top, and
:class:`~.pipeline.PipelineConfig` gives every stage that has it the same value; a stage command's flag for it
changes it for every stage."""


def used_with(name: str) -> dict[str, str]:
    """Field metadata of a stage's setting that only its field ``name`` uses (e.g. the head photo's joint state, of no
    use without a head photo): while ``name`` is None it stays out of the stage's fingerprint, so setting it for
    another stage (a SHARED one) does not rerun this one."""
    return {"used_with": name}


@dataclass
class PipelineSettings:
    """The settings of the whole pipeline (at the top of ``m2m.yaml``), read by the stages whose Config has a
    field of the same name marked :data:`SHARED` (the robot: align-scene, calibrate-handeye and compose; what
    was filmed, the board and the robot's joint states: sfm and align-scene; the head photo's joint state:
    train-scene and head-view).

    robot   the robot at the base: a registered name (panda, ur5e) or a robot spec file ("none": a scene-only
            workspace)
    board   the calibration target beside the robot in the capture: its spec JSON (from `m2m board`: ChArUco,
            ArUco marker, AprilTag, ArUco grid)
    board_pose  a JSON with T_base_board (4x4, or under "board") when the target is not centred on the base with
            its x along base x
    capture_joints  the robot's joint state while the capture was filmed: its arm joints in radians (and fingers,
            in the model's units), as the robot logged them; default: the robot's home
    capture_moves  the robot moved while filming: {N: joints} says that from the video's frame N on (an image
            folder's image N, in name order) it stood at these joints; capture_joints holds before the first move
    head_photo_joints  the robot's arm joints (radians) in the head camera's photo, where train-scene masks it
            out and head-view draws it. Default: the capture joints
    head_keyframe  a fixed camera's image put in the capture's image folder (e.g. right.jpg): always a keyframe,
            and the world's head camera (its pose and intrinsics from align-scene's cameras: no head calibration
            needed). Default: calibrate-handeye's head camera
    """

    robot: str = DEFAULT_ROBOT
    board: Path | None = None
    board_pose: Path | None = None
    # wide: degrees given for radians are the robot's check to name (check_capture_joints), not a bare range
    capture_joints: list[float] | None = ranged(None, ge=-1000, le=1000)
    capture_moves: dict[int, list[float]] | None = ranged(None, ge=-1000, le=1000,
                                                          metadata={"metavar": "FRAME=RAD,..."})
    head_photo_joints: list[float] | None = ranged(None, ge=-1000, le=1000, metadata={"metavar": "RAD"})
    head_keyframe: str | None = field(default=None, metadata={"metavar": "IMAGE"})


ADDED_LATER = {"fingerprint": "when_set"}
"""Field metadata of a setting added to a stage after workspaces were made: at its default it stays out of the
stage's fingerprint, so a finished stage of an existing workspace is not rerun for a setting it never used."""


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


def finished_record(stage: Stage, ws: Workspace, cfg: Any, key: str | None = None) -> dict | None:
    """The record of an identical finished run (its fingerprint ``key``, its outputs in place): what
    :func:`run_stage` skips; None when there is none."""
    key = key or stage_fingerprint(stage, ws, cfg)
    return StageRecord(ws).get(stage.record_key(ws, cfg), key, stage.outputs(ws, cfg))


def run_stage(
    stage: Stage, ws: Workspace, cfg: Any, log: Log = print, force: bool = False, ground_truth: dict | None = None
) -> tuple[dict[str, Any], bool]:
    """Run ``stage`` on ``ws`` with ``cfg`` unless an identical run finished; returns (summary, skipped).

    Holds the workspace lock; the stage writes into its transaction's staging and its outputs are swapped in
    together only when it succeeded (see ``stages.transaction``). A policy stage (not part of a pipeline) holds
    it only to start and to commit, and its own output's lock in between, so several run side by side. With
    ``ground_truth`` (a sample's ground_truth.json) the stage's ``compare`` adds how close it came."""
    check_ranges(cfg, stage.name)  # a Config built in code, not read: its numbers as a read one's
    validate = getattr(cfg, "validate", None)
    if validate is not None:
        validate()
    if ws.root.exists() and not ws.root.is_dir():
        raise WorkspaceError(f"workspace {ws.root} exists and is not a folder; choose another with -w")
    stage_fingerprint(stage, ws, cfg)  # missing inputs are errors before anything is written
    alongside = not stage.pipeline and not holds_lock(ws)
    # a policy stage's start, like its commit, waits out another's bookkeeping (seconds): seeds started together
    # (sim2real's) otherwise find each other's start or commit holding the lock and fail
    with workspace_lock(ws, alongside=alongside, wait_s=START_WAIT_S if alongside else 0.0):
        key = stage_fingerprint(stage, ws, cfg)  # under the lock: what the stage will read
        record_key = stage.record_key(ws, cfg)
        done = None if force else finished_record(stage, ws, cfg, key)
        if done is not None:
            return done["summary"], True
        txn = Transaction(ws, record_key.replace("/", "-"), [_inside(ws, p, stage) for p in stage.writes(ws, cfg)])
        if not alongside:  # the whole run under the lock
            t0 = time.perf_counter()
            # a failed stage leaves the workspace as it was; a killed (or interrupted) one, its staging to resume
            with txn.staging_of(key) as staged:
                summary = _run_staged(stage, staged, cfg, txn, ws, log, ground_truth)
            StageRecord(ws).put(record_key, _record(key, cfg, summary, t0))
            return summary, False
        running = OutputLock(ws, txn.name).acquire()
        try:
            txn.resumed = txn.begin(key)
        except BaseException:
            running.release()
            raise
    t0 = time.perf_counter()
    try:
        summary = _run_staged(stage, txn.staged_ws, cfg, txn, ws, log, ground_truth)
    except KeyboardInterrupt:  # like a kill: the staging stays for the next run to resume
        running.release(unlink=False)
        raise
    except BaseException:
        txn.abort()
        running.release(unlink=False)
        raise
    try:  # the commit waits out another run's bookkeeping (seconds), not hours of work
        with workspace_lock(ws, alongside=True, wait_s=600.0):
            txn.commit()
            StageRecord(ws).put(record_key, _record(key, cfg, summary, t0))
            running.release()
    finally:
        running.release(unlink=False)
    return summary, False


def _run_staged(stage: Stage, staged: Workspace, cfg: Any, txn: Any, ws: Workspace, log: Log,
                ground_truth: dict | None) -> dict[str, Any]:  # fmt: skip
    """The stage on its staged workspace; the summary with staged paths named where they land."""
    if txn.resumed:
        log(f"{stage.name}: resuming the interrupted run")
    summary = stage.run(staged, cfg, log)
    # an output the stage found up to date and left in place (not rewritten into the staging) counts
    missing = [str(_relative(p, txn.staging, ws.root)) for p in stage.outputs(staged, cfg)
               if not p.exists() and not (ws.root / _relative(p, txn.staging, ws.root)).exists()]  # fmt: skip
    if missing:
        raise WorkspaceError(f"{stage.command} finished without writing {', '.join(missing)}")
    extra = None if ground_truth is None else stage.compare(staged, cfg, ground_truth)
    if extra is not None:
        summary = {**summary, **extra, "line": summary["line"] + extra["line"]}
    return jsonable(_unstaged(summary, txn.staging, ws.root))


def _record(key: str, cfg: Any, summary: dict[str, Any], t0: float) -> dict[str, Any]:
    seconds = round(time.perf_counter() - t0, 1)
    return {"fingerprint": key, "config": to_dict(cfg), "summary": summary, "seconds": seconds}


def _relative(p: Path, staging: Path, root: Path) -> Path:
    """``p`` (in the staging or the workspace) relative to the workspace root."""
    for base in (staging, root):
        try:
            return p.relative_to(base)
        except ValueError:
            pass
    return p


def _inside(ws: Workspace, path: Path, stage: Stage) -> Path:
    """``path`` relative to the workspace root; outputs are written only inside the workspace."""
    root, p = Path(os.path.abspath(ws.root)), Path(os.path.abspath(path))
    if p == root or root not in p.parents:
        raise WorkspaceError(f"{stage.command}: {path} is outside the workspace {ws.root}; outputs are written only "
                             "inside it (choose a path below the workspace)")  # fmt: skip
    return p.relative_to(root)


def _unstaged(x: Any, staging: Path, root: Path) -> Any:
    """``x`` with the staging folder in paths and texts replaced by the workspace root (where they land)."""
    if isinstance(x, dict):
        return {k: _unstaged(v, staging, root) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_unstaged(v, staging, root) for v in x]
    if isinstance(x, Path | str) and str(staging) in str(x):
        return type(x)(str(x).replace(str(staging), str(root)))
    return x
