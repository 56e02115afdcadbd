"""Every stage in order over one workspace: ``m2m run`` (a workspace's ``m2m.yaml``) and ``m2m demo`` (the
bundled sample's, plus its ground truth).

:class:`PipelineConfig` composes the stages' Configs; it is what a workspace's ``m2m.yaml`` holds, written with
every field and its doc as a comment (``m2m init``, :meth:`PipelineConfig.save`) and read strictly: an unknown key,
a wrong type or a key given twice is a :class:`~..configs.ConfigError` naming the file and the line
(:class:`SettingsFile`). :func:`plan_run` says which stages run and why the others are skipped (an optional input
not given: no hand-eye images, no tasks), after checking that every file the settings name exists. ``run_pipeline``
runs the stages through :func:`~.base.run_stage`, so a killed run resumes: finished stages whose config and input
content are unchanged are skipped, and the stage that was killed resumes from its staging.
"""

from __future__ import annotations

import dataclasses
import functools
import re
import time
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..atomic import atomic_write
from ..configs import ConfigError, from_dict, to_dict, to_yaml
from ..errors import M2MError
from ..inputs import read_yaml_lines
from ..robots import get_robot
from ..robots.surface import check_capture_joints
from ..workspace import Workspace
from . import PIPELINE, STAGES
from .base import Log, PipelineSettings, run_stage
from .report import RunNotes, write_report
from .transaction import workspace_lock

__all__ = ["PipelineConfig", "PipelineError", "SettingsFile", "input_paths", "plan_run", "run_pipeline"]

_HEADER = """\
# Mirage2Matter workspace settings (m2m.yaml): every input and setting of the pipeline, the whole pipeline's own
# (the robot, the head photo's joint state), then one section per stage.
#   m2m run -w WORKSPACE      runs the stages in order from this file (--until / --from STAGE: part of them)
#   m2m <stage> --help        explains a stage's fields; `m2m <stage> -w WORKSPACE --field VALUE` runs one stage
# Every field is written, at its stage's default unless set. Paths: relative to this file's folder, or absolute.
# An unknown key, a value of the wrong type or a missing file is an error naming its line here.
# A stage command that changes a setting writes this file again (these comments regenerated, others dropped).
"""


class PipelineError(M2MError):
    """A stage of a pipeline run failed; the message names the stage, its command, and how to go on."""

    result: dict[str, Any] | None = None  # the stopped run's summary (where and why), for run_summary.json


class _Pipeline(PipelineSettings):
    """The methods of :class:`PipelineConfig`; its fields: the pipeline's own settings, then one per stage."""

    def __post_init__(self) -> None:
        # the pipeline's settings are the stages' (SHARED fields): every section holds the pipeline's value
        for name, value in _shared(self).items():
            for section in _sharing(name):
                setattr(self, section, dataclasses.replace(getattr(self, section), **{name: value}))

    @staticmethod
    def upgrade(data: dict[str, Any]) -> dict[str, Any]:
        """An m2m.yaml of before a setting was the pipeline's: ``robot`` under align, handeye and world (as ``m2m
        init`` fanned it out) moved to the top when they name one robot (handeye's may be that robot's model file),
        ``head_view.photo_joints`` to the top as ``head_photo_joints`` (:data:`_RENAMED`); a ConfigError saying how
        to fix the file when they differ."""
        for (section, old), name in _RENAMED.items():
            d = data.get(section)
            if not isinstance(d, dict) or old not in d:
                continue
            data = {**data, section: {k: v for k, v in d.items() if k != old}}
            if d[old] is None:  # every field was written: at its default, it says nothing
                continue
            if data.get(name) is not None and data[name] != d[old]:
                raise ConfigError(f"{section}.{old}: {d[old]}, {name}: {data[name]}: one {name} for the whole "
                                  f"pipeline now, set once at the top of the file; remove {old} from {section}",
                                  name)  # fmt: skip
            data[name] = d[old]
        for name in (f.name for f in dataclasses.fields(PipelineSettings)):
            sections = {s: data[s] for s in _sharing(name) if isinstance(data.get(s), dict)}
            # values of the setting's kind only (a text, a list): another stays where it is, for its section to
            # refuse by name
            kind = _kind(name)
            given = {s: d[name] for s, d in sections.items() if isinstance(d.get(name), kind)}
            if not given:
                continue
            top = [data[name]] if isinstance(data.get(name), kind) else []
            values = {_hashable(v): v for v in [*given.values(), *top]}
            if name == "robot":
                values = {n: n for n in _robots(set(values))}
            if len(values) > 1:
                top = [f"{name}: {data[name]}"] if name in data else []
                where = ", ".join([f"{s}.{name}: {v}" for s, v in given.items()] + top)
                raise ConfigError(f"{where}: one {name} for the whole pipeline now, set once at the top of the file; "
                                  f"write `{name}: ...` there and remove {name} from the sections", name)  # fmt: skip
            data = {k: {n: x for n, x in v.items() if n != name} if k in given else v for k, v in data.items()}
            data.setdefault(name, next(iter(values.values())))
        return data

    @classmethod
    def load(cls, path: str | Path) -> PipelineConfig:
        """Read an ``m2m.yaml`` (paths relative to its folder); ConfigError names the file, the line and the field."""
        return cls.read(path)[0]

    @classmethod
    def read(cls, path: str | Path) -> tuple[PipelineConfig, SettingsFile]:
        """The settings of an ``m2m.yaml`` and where each key is in it (for messages about a value)."""
        path = Path(path)
        data, lines = read_yaml_lines(path, "pipeline settings (m2m.yaml)")
        where = SettingsFile(path, lines)
        try:
            return from_dict(cls, data, base_dir=path.parent.resolve()), where
        except ConfigError as e:
            what = "fix or remove the key" if "unknown setting" in str(e) else "fix the value"
            what = "" if "set once at the top" in str(e) else f"; {what}"
            raise ConfigError(f"{where.at(e.field)}: {e}{what}", e.field) from None

    def save(self, path: str | Path) -> Path:
        """Write every setting (defaults filled in, each field's doc as a comment) atomically; paths relative to
        the file's folder when below it, else absolute."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        notes = {s.name: f"---- {s.name} (`m2m {s.command}`)" + ("" if s.pipeline else ": not part of `m2m run`")
                 for s in STAGES}  # fmt: skip
        text = to_yaml(self, base_dir=path.parent.resolve(), header=_HEADER, notes=notes)
        with atomic_write(path, "w", encoding="utf-8") as f:
            f.write(text)
        return path

    def stage_config(self, name: str) -> Any:
        return getattr(self, name)

    def with_stage(self, name: str, cfg: Any) -> PipelineConfig:
        """These settings with the stage ``name``'s section replaced by ``cfg``; the pipeline's settings it holds
        (the robot a stage command was given) become every stage's."""
        shared = {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg) if f.metadata.get("shared")}
        return dataclasses.replace(self, **{name: cfg, **shared})


def _robots(names: set[str]) -> set[str]:
    """``names`` without a model file that is another name's robot model (old m2m.yaml's handeye.robot)."""
    models = set()
    for n in names:
        try:
            models.add(str(get_robot(n).model))  # what `m2m init --robot NAME` wrote as handeye.robot
        except (M2MError, OSError):
            pass
    return {n for n in names if n not in models} or names


# settings a section held that are the pipeline's now, under another name: {(section, old key): the pipeline's}
_RENAMED = {("head_view", "photo_joints"): "head_photo_joints"}


def _kind(name: str) -> type:
    """The type of the pipeline's setting ``name`` (str, list): what a section's value must be to move to the top."""
    tp = typing.get_type_hints(PipelineSettings)[name]
    tp = next((a for a in typing.get_args(tp) if a is not type(None)), tp)  # X | None -> X
    return str if tp is Path else typing.get_origin(tp) or tp  # a path: a text in the file


def _hashable(value: Any) -> Any:
    if isinstance(value, dict):  # capture_moves {frame: joints}
        return tuple(sorted((str(k), _hashable(v)) for k, v in value.items()))
    return tuple(_hashable(v) for v in value) if isinstance(value, list) else value


def _shared(cfg: PipelineSettings) -> dict[str, Any]:
    return {f.name: getattr(cfg, f.name) for f in dataclasses.fields(PipelineSettings)}


@functools.cache
def _sharing(name: str) -> tuple[str, ...]:
    """The stages whose Config holds the pipeline's setting ``name`` (a SHARED field)."""
    return tuple(s.name for s in STAGES
                 if any(f.name == name and f.metadata.get("shared") for f in dataclasses.fields(s.config)))  # fmt: skip


# Every stage's settings, one section per stage of the registry (stages/__init__.py), after the pipeline's own.
PipelineConfig = dataclasses.make_dataclass(
    "PipelineConfig",
    [(s.name, s.config, field(default_factory=s.config)) for s in STAGES],
    bases=(_Pipeline,),
    namespace={
        "__module__": __name__,
        "__doc__": "Every stage's settings (``m2m.yaml``): the pipeline's own (the robot, the head photo's joint "
        "state), then one section per stage.\n\n"
        + "\n".join(
            f"{s.name:<13} {s.help}" + ("" if s.pipeline else f" (run on its own: ``m2m {s.command}``)") for s in STAGES
        ),  # fmt: skip
    },
)


_KEY = re.compile(r"\[(\d+)\]|([^.\[\]]+)")


@dataclass(frozen=True)
class SettingsFile:
    """An ``m2m.yaml`` as messages name it: its path and the line of each key and list item.

    path    the file
    lines   {key path (``("scene", "minutes")``, ``("objects", "names", 2)``): 1-based line}
            (``inputs.read_yaml_lines``)
    """

    path: Path
    lines: dict[tuple[str | int, ...], int] = field(default_factory=dict)

    def line(self, name: str | None) -> int | None:
        """The line of the dotted field ``name`` (``objects.names[2]``), else of the nearest enclosing key the
        file has; None when it has none (the field is at its default)."""
        keys = tuple(int(i) if i else k for i, k in _KEY.findall(name or ""))
        for n in range(len(keys), 0, -1):
            if keys[:n] in self.lines:
                return self.lines[keys[:n]]
        # the pipeline's setting that the file names in a section (moved to the top when read), or by its old name
        at = [(s, keys[0]) for s in _sharing(keys[0])] if keys and isinstance(keys[0], str) else []
        at += [key for key, new in _RENAMED.items() if keys[:1] == (new,)]
        return next((self.lines[key] for key in at if key in self.lines), None)

    def at(self, name: str | None) -> str:
        """``<file>, line N``: where a message about the field ``name`` points."""
        n = self.line(name)
        return f"{self.path}, line {n}" if n else str(self.path)


def _chosen(until: str | None, start: str | None) -> tuple:
    names = [s.name for s in PIPELINE]
    for flag, name in (("--until", until), ("--from", start)):
        if name is not None and name not in names:
            raise ConfigError(f"{flag} {name}: not a pipeline stage; stages: {', '.join(names)}")
    lo = names.index(start) if start else 0
    hi = names.index(until) + 1 if until else len(names)
    if lo >= hi:
        raise ConfigError(f"--from {start} comes after --until {until}")
    return PIPELINE[lo:hi]


def input_paths(cfg: Any, prefix: str) -> list[tuple[str, Path]]:
    """(dotted field, path) of every input path in a stage's Config (nested Configs, lists and mappings walked;
    fields with ``metadata={"output": True}`` are written, not read, and left out)."""
    out: list[tuple[str, Path]] = []

    def walk(value: Any, name: str) -> None:
        if isinstance(value, Path):
            out.append((name, value))
        elif isinstance(value, list | tuple):
            for i, v in enumerate(value):
                walk(v, f"{name}[{i}]")
        elif isinstance(value, dict):
            for k, v in value.items():
                walk(v, f"{name}.{k}")
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            for f in dataclasses.fields(value):
                if not f.metadata.get("output"):
                    walk(getattr(value, f.name), f"{name}.{f.name}")

    walk(cfg, prefix)
    return out


def _check_files(cfg: PipelineConfig, where: SettingsFile, names: list[str]) -> None:
    missing = [(n, p) for name in names for n, p in input_paths(getattr(cfg, name), name) if not p.exists()]
    if len(missing) == 1:
        (name, path), folder = missing[0], where.path.parent
        raise ConfigError(f"{where.at(name)}: {name}: {path} not found; fix the path (a relative one is relative to "
                          f"{folder}/)", name)  # fmt: skip
    if missing:
        lines = [f"  {f'line {where.line(n)}' if where.line(n) else '(not in the file)'}: {n}: {p}" for n, p in missing]
        raise ConfigError(f"{where.path}: {len(missing)} files not found:\n" + "\n".join(lines) + "\nfix the paths (a "
                          f"relative one is relative to {where.path.parent}/)", missing[0][0])  # fmt: skip


def plan_run(
    ws: Workspace,
    cfg: PipelineConfig,
    where: SettingsFile | None = None,
    until: str | None = None,
    start: str | None = None,
) -> dict[str, str | None]:
    """{stage: None when it runs, else why it is skipped} for the pipeline stages from ``start`` through
    ``until`` (default: all), in order. Checked first, before anything runs (ConfigError naming the line of
    ``where``, the workspace's m2m.yaml): every file the settings of those stages name exists, the inputs a
    stage cannot do without are given, and each running stage's Config accepts its values.

    Optional inputs make stages optional: no hand-eye images -> no hand-eye calibration (an earlier
    ``calib/handeye.json`` is kept), and without a head camera's calibration no head-view check and no world (unless
    ``head_keyframe`` names the keyframe a fixed camera took);
    no head-camera photo -> no head-view check; no tasks -> no demonstrations. Without object names the objects
    stage takes every object it finds."""
    where = where or SettingsFile(ws.config_file)
    names = [s.name for s in _chosen(until, start)]
    _check_files(cfg, where, names)
    _check_required(cfg, where, names)
    he_given = cfg.handeye.images is not None or cfg.handeye.joints is not None
    head = cfg.handeye.mount == "head" if he_given else ws.handeye_file.is_file()
    no_head = ("the hand-eye calibration is of a wrist camera (handeye.mount: wrist), not a head camera" if he_given
               else "no head-camera calibration (the hand-eye calibration is skipped)")  # fmt: skip
    imported = next((f"sfm.{k}" for k in ("from_transforms", "from_colmap") if getattr(cfg.sfm, k)), None)
    kept = "; calib/handeye.json of an earlier calibration is kept" if ws.handeye_file.is_file() else ""
    plan: dict[str, str | None] = {}
    for name in names:
        reason = None
        if name == "capture" and cfg.capture.source is None:
            reason = f"{imported} imports posed images"
        elif name == "handeye" and not he_given:
            reason = f"no hand-eye images (handeye.images and handeye.joints are not set){kept}"
        elif name == "head_view" and not head:
            reason = no_head
        elif name == "head_view" and cfg.head_view.photo is None:  # the render alone checks nothing (measured: on
            # the sample after a short training the board was not even found in it)
            reason = (f"no head-camera photo to compare the scene with (head_view.photo is not set); `m2m head-view -w "
                      f"{ws.root}` renders the head camera's view alone")  # fmt: skip
        elif name == "world" and not head and cfg.world.sample is None and cfg.head_keyframe is None:
            reason = (f"{no_head}; the world's head camera needs one: give handeye.images, .joints, .board and "
                      ".intrinsics (`m2m init --handeye-images DIR --handeye-poses FILE ...`), or head_keyframe "
                      "(the keyframe of the capture a fixed camera took)")  # fmt: skip
        elif name == "generate" and plan.get("world"):
            reason = "no world (skipped above)"
        elif name == "generate" and not cfg.generate.task:
            reason = 'no tasks (generate.task is empty); add some, e.g. "grasp banana", and run again'
        plan[name] = reason
    for name in names:
        validate = getattr(cfg.stage_config(name), "validate", None)
        if plan[name] is None and validate is not None:
            try:
                validate()
            except M2MError as e:
                raise ConfigError(f"{where.at(name)}: section {name}: {e}", name) from None
    return plan


def _check_head_keyframe(cfg: PipelineConfig, where: SettingsFile, names: list[str]) -> None:
    """``head_keyframe`` names an image of the capture's image folder (before the capture's stages run for minutes
    and the world cannot find it)."""
    name, source = cfg.head_keyframe, cfg.capture.source
    if name is None or source is None or not ({"capture", "world"} & set(names)) or not Path(source).exists():
        return  # an imported capture's own names; a missing source is named by the file check
    if not Path(source).is_dir():
        raise ConfigError(f"{where.at('head_keyframe')}: head_keyframe {name!r}: the capture is a video ({source}), "
                          "whose frames are the moving camera's; put the fixed camera's image in a folder with the "
                          "capture's images (capture.source: that folder), or remove head_keyframe",
                          "head_keyframe")  # fmt: skip
    from ..capture.keyframes import image_files, names_image

    if not any(names_image(p.name, name) for p in image_files(Path(source))):
        raise ConfigError(f"{where.at('head_keyframe')}: head_keyframe {name!r}: no such image in {source}; put the "
                          "fixed camera's image there, or give its name as it is there", "head_keyframe")  # fmt: skip


def _check_required(cfg: PipelineConfig, where: SettingsFile, names: list[str]) -> None:
    """The inputs a stage cannot do without, and a robot that loads; ConfigError naming the line."""
    at = where.at
    if cfg.robot.lower() != "none":
        try:
            spec = get_robot(cfg.robot)
        except M2MError as e:
            raise ConfigError(f"{at('robot')}: robot: {e}", "robot") from None
        if cfg.head_photo_joints is not None:  # before a scene trains for minutes on it
            try:
                check_capture_joints(spec, cfg.head_photo_joints, "head_photo_joints")
            except M2MError as e:
                raise ConfigError(f"{at('head_photo_joints')}: {e}", "head_photo_joints") from None
    elif "world" in names:
        raise ConfigError(f"{at('robot')}: robot: none, but the world needs one; name the robot at the base (`m2m "
                          "init --robot NAME`), or run --until an earlier stage", "robot")  # fmt: skip
    imports = cfg.sfm.from_transforms is not None or cfg.sfm.from_colmap is not None
    _check_head_keyframe(cfg, where, names)
    if "capture" in names and cfg.capture.source is None and not imports:
        raise ConfigError(f"{at('capture.source')}: capture.source: no video or image folder; give the capture (`m2m "
                          "init --video FILE` or `--images DIR`), or import posed images with sfm.from_transforms or "
                          "sfm.from_colmap", "capture.source")  # fmt: skip
    if "align" in names and cfg.board is None and not cfg.align.unaligned:
        raise ConfigError(f"{at('board')}: board: no calibration target; give the spec JSON of the board "
                          "at the robot base (from `m2m board`; `m2m init --board FILE`), or set align.unaligned: true "
                          "for a scene-only workspace (no robot twin)", "board")  # fmt: skip
    he = cfg.handeye
    lacking = [n for n in ("images", "joints", "board", "intrinsics") if getattr(he, n) is None]
    if "handeye" in names and (he.images is not None or he.joints is not None) and lacking:
        what = {
            "images": "the folder of the head camera's images of the board",
            "joints": "the robot's pose per image",
            "board": "the spec JSON of the board the robot holds",
            "intrinsics": "the head camera's calibration",
        }
        raise ConfigError(f"{at('handeye')}: the hand-eye calibration lacks "
                          + "; ".join(f"handeye.{n} ({what[n]})" for n in lacking)
                          + "; give them, or remove handeye.images and handeye.joints to run without a head camera "
                          "(no world then)", f"handeye.{lacking[0]}")  # fmt: skip


def run_pipeline(
    ws: Workspace,
    cfg: PipelineConfig,
    log: Log = print,
    until: str | None = None,
    start: str | None = None,
    ground_truth: dict | None = None,
    where: SettingsFile | None = None,
    command: str = "m2m run",
) -> dict[str, Any]:
    """Run (or resume) the stages from ``start`` through ``until`` (names; default: all) as :func:`plan_run`
    plans them; returns {"stages": {name: summary (a skipped stage's: {"skipped": why, "line"})}, "seconds": ...}.
    ``ground_truth``: a sample's, compared with where it can. A stage that fails raises :class:`PipelineError`
    naming it and ``command``, the command to run again once the cause is fixed (its ``result``: the stopped run's
    summary). ``report.html`` is written after the run, a failed or interrupted one too (``stages/report.py``)."""
    plan = plan_run(ws, cfg, where, until, start)
    chosen = [s for s in PIPELINE if s.name in plan]
    notes = RunNotes(command, [s.name for s in chosen], log)  # what report.html says of this run
    with workspace_lock(ws):  # one writer for the whole run
        t_start = time.perf_counter()
        try:
            result = _run(ws, cfg, chosen, plan, notes, ground_truth, where or SettingsFile(ws.config_file), command)
        except BaseException as e:  # the report says where and why; the error goes on as before
            stopped = notes.stopped(ws, e, time.perf_counter() - t_start)
            if isinstance(e, PipelineError):
                e.result = stopped
            raise
        write_report(ws, result, quiet=log)
        return result


def _run(ws: Workspace, cfg: PipelineConfig, chosen, plan: dict[str, str | None], notes: RunNotes,
         ground_truth: dict | None, where: SettingsFile, command: str) -> dict[str, Any]:  # fmt: skip
    t_start = time.perf_counter()
    log, summaries = notes.log, notes.summaries
    for i, stage in enumerate(chosen, 1):
        notes.stage = stage.name
        tag = f"[{i}/{len(chosen)}] {stage.name}"
        if plan[stage.name] is not None:
            log(f"{tag}: skipped - {plan[stage.name]}")
            summaries[stage.name] = {"skipped": plan[stage.name], "line": f"skipped: {plan[stage.name]}"}
            continue
        log(f"{tag} ...")
        t0 = time.perf_counter()
        try:
            summary, skipped = run_stage(stage, ws, cfg.stage_config(stage.name), log, ground_truth=ground_truth)
        except M2MError as e:
            log(f"{tag}: failed")
            raise PipelineError(
                f"{stage.name} (stage {i} of {len(chosen)}, `m2m {stage.command}`): {e}\nFix that (the settings are in "
                f"{where.path}) and run `{command} -w {ws.root}` again: the finished stages are kept"
            ) from e
        summaries[stage.name] = summary
        if skipped:
            notes.done_earlier.append(stage.name)
            log(f"{tag}: done earlier - {summary['line']}")
        else:
            dt = time.perf_counter() - t0
            log(f"{tag}: {summary['line']}  [{dt:.0f} s, total {time.perf_counter() - t_start:.0f} s]")
    return {"workspace": str(ws.root.resolve()), "stages": summaries, "seconds": time.perf_counter() - t_start,
            "config": to_dict(cfg), **notes.fields()}  # fmt: skip
