"""``m2m init``: a workspace's ``m2m.yaml`` from your inputs, for ``m2m run``.

The file holds every stage's section with every field, at its default unless given, each under its doc as
a comment (:meth:`~..stages.pipeline.PipelineConfig.save`). The common inputs have short flags (``--video``,
``--board``, ``--handeye-images``, ``--task`` ...); any field can be given as ``--<stage>.<field>`` (``--help``
lists the short ones, ``--help STAGE`` a stage's fields, ``--help-all`` every flag). Every input
is checked before the file is written: a missing file, a board spec or a calibration that cannot be read, an
unknown robot, a hand-eye calibration without the head camera's intrinsics are errors naming the flag.

Paths are written relative to the workspace when they lie inside it and absolute otherwise: a path with
``..`` would break when the workspace folder is moved or copied on its own, an absolute one keeps pointing
at your capture, and inputs you keep inside the workspace travel with it.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

from ..configs import ConfigError, add_flags, from_flags, range_errors
from ..errors import M2MError
from ..inputs import check_image_file, check_name
from ..robots import get_robot
from ..stages.base import PipelineSettings
from ..stages.transaction import workspace_lock
from ..workspace import Workspace, WorkspaceError
from .args import CliError, Formatter, add_settings, int_at_least, show

__all__ = ["register"]

# the short flags, and the m2m.yaml field each sets (a field's own --<stage>.<field> flag overrides it)
SHORT = {
    "video": "capture.source", "images": "capture.source", "intrinsics": "sfm.intrinsics", "board": "board",
    "board_pose": "board_pose", "handeye_images": "handeye.images", "handeye_poses": "handeye.joints",
    "handeye_board": "handeye.board", "handeye_intrinsics": "handeye.intrinsics", "head_photo": "head_view.photo",
    "objects": "objects.names", "task": "generate.task", "episodes": "generate.episodes",
    "capture_joints": "capture_joints", "head_keyframe": "head_keyframe",
}  # fmt: skip

# the pipeline's settings with init's own flags
OWN_FLAGS = ("board", "board_pose", "capture_joints", "capture_moves", "head_keyframe")

EXAMPLE = """example:
  m2m init -w ws --video table.mp4 --board board.json --intrinsics phone.json \\
      --handeye-images he/images --handeye-poses he/joints.json \\
      --handeye-board he/board.json --handeye-intrinsics head_cam.yaml \\
      --head-photo head.png --objects banana croissant button \\
      --task "grasp banana" "press button" --episodes 50
  m2m run -w ws
"""


def register(sub: argparse._SubParsersAction, full: bool = True) -> None:
    p = sub.add_parser(
        "init",
        help="write a workspace's m2m.yaml (every setting, explained) from your capture, board, robot and tasks",
        description=(
            "Write <workspace>/m2m.yaml for `m2m run`: every setting, explained, at its default unless given. The "
            "inputs are checked first. Without hand-eye images the run skips the hand-eye calibration, the head "
            "view and the world; without a head photo, the head view; without tasks, the demonstrations."
        ),
        epilog=EXAMPLE,
        formatter_class=Formatter,
        add_help=False,
    )
    g = p.add_argument_group("your inputs (paths relative to the current folder)")
    g.add_argument("-w", "--workspace", required=True, metavar="DIR", help="the workspace folder (created)")
    source = g.add_mutually_exclusive_group()
    source.add_argument("--video", type=Path, metavar="FILE", help="the capture: a video orbiting the table "
                        "(mp4/mov/mkv)")  # fmt: skip
    source.add_argument("--images", type=Path, metavar="DIR", help="the capture as a folder of images instead")
    # the pipeline's settings, read by init itself (absent unless given: not the Config's flags' None)
    g.add_argument("--board", type=Path, default=argparse.SUPPRESS, metavar="FILE",
                   help="spec JSON of the calibration target at the robot base (from `m2m board`)")
    g.add_argument("--board-pose", type=Path, default=argparse.SUPPRESS, metavar="FILE",
                   help="T_base_board (JSON): a target not centred on the base")
    g.add_argument("--intrinsics", type=Path, metavar="FILE", help="the capture camera's calibration (`m2m "
                   "intrinsics FILE` reads it); without it SfM estimates one")  # fmt: skip
    g.add_argument("--handeye-images", type=Path, metavar="DIR", help="the head camera's images of a board the robot "
                   "holds (without them or --head-keyframe: no world)")  # fmt: skip
    g.add_argument("--handeye-poses", type=Path, metavar="FILE", help="the robot's joints per hand-eye image (JSON)")
    g.add_argument("--handeye-board", type=Path, metavar="FILE", help="the held board's spec (without it: --board)")
    g.add_argument("--handeye-intrinsics", type=Path, metavar="FILE", help="the head camera's calibration")
    g.add_argument("--head-keyframe", metavar="IMAGE", help="or: the image in --images a fixed head camera took")
    g.add_argument("--head-photo", type=Path, metavar="FILE", help="a photo the head camera took of the table, "
                   "for the head-view check")  # fmt: skip
    g.add_argument("--objects", nargs="+", metavar="NAME", help="the objects on the table, nearest the base first "
                   "(without them: every object found, named object_0, object_1, ...)")  # fmt: skip
    g.add_argument("--task", nargs="+", action="extend", metavar="TEXT", help='task instructions, e.g. "grasp banana" '
                   '"press button" (without them: no demonstrations)')  # fmt: skip
    g.add_argument("--episodes", type=int_at_least(1), metavar="N", help="successful episodes per task")
    # the whole pipeline's settings (the robot, ...), written once at the top of m2m.yaml; the board and the capture's
    # joint states have their own flags above and below
    add_flags(g, PipelineSettings, skip=OWN_FLAGS)
    g.add_argument("--capture-joints", nargs="+", type=float, default=argparse.SUPPRESS, metavar="RAD",
                   help="the robot's joint angles while you filmed (radians, as it logged them; default: its home "
                   "pose)")  # fmt: skip
    g.add_argument("--capture-move", nargs="+", type=float, action="append", dest="capture_moves",
                   default=argparse.SUPPRESS, metavar="FRAME RAD", help="you moved the robot while filming: from "
                   "this frame on it stood here (repeatable)")  # fmt: skip

    p.add_argument("--force", action="store_true", help="replace the workspace's m2m.yaml if it has one")
    add_settings(p, full)  # every field as --<stage>.<field> (when full: imports every stage's libraries)
    p.set_defaults(func=run)


def _flag(field: str) -> str:
    """The flags that set the m2m.yaml field ``field`` (``handeye.board`` -> ``--handeye-board / --handeye.board``;
    a section: ``--scene.*``; the pipeline's ``board`` -> ``--board``)."""
    field = field.split("[")[0]
    if "." not in field and field in {f.name for f in dataclasses.fields(PipelineSettings)}:
        return f"--{field.replace('_', '-')}"  # the pipeline's own setting
    section, _, rest = field.partition(".")
    short = [f"--{k.replace('_', '-')}" for k, v in SHORT.items() if v == field]
    return " / ".join([*short, f"--{section.replace('_', '-')}.{rest.replace('_', '-') or '*'}"])


def _settings(args: argparse.Namespace) -> Any:
    """The PipelineConfig of the flags: the short ones, then every --<stage>.<field> given on top."""
    from ..stages.pipeline import PipelineConfig

    cfg = PipelineConfig()
    given: dict[str, Any] = {}
    for name, field in SHORT.items():
        value = getattr(args, name, None)
        if value is not None:
            given[field] = value.resolve() if isinstance(value, Path) else value
    if getattr(args, "capture_joints", None) is not None:
        given["capture_joints"] = list(args.capture_joints)
    if getattr(args, "capture_moves", None):
        moves = {}
        for move in args.capture_moves:
            if len(move) < 2 or move[0] != int(move[0]):
                raise CliError(f"--capture-move {' '.join(f'{v:g}' for v in move)}: give the video frame (a whole "
                                     "number) and then the joint angles in radians")  # fmt: skip
            moves[int(move[0])] = list(move[1:])
        given["capture_moves"] = moves
    if args.handeye_images is not None and args.handeye_board is None and getattr(args, "board", None) is not None:
        given["handeye.board"] = args.board.resolve()  # one board for both, unless a second is named
    sections: dict[str, dict[str, Any]] = {}
    for field, value in given.items():
        section, _, key = field.rpartition(".")  # no section: the pipeline's own setting
        sections.setdefault(section, {})[key] = tuple(value) if key == "task" else value
    cfg = dataclasses.replace(cfg, **sections.pop("", {}))  # the pipeline's: every stage that reads it gets it
    for section, changes in sections.items():
        cfg = dataclasses.replace(cfg, **{section: dataclasses.replace(getattr(cfg, section), **changes)})
    # init's own flags for the pipeline's board and joint states are read above (paths resolved, moves parsed)
    rest = argparse.Namespace(**{k: v for k, v in vars(args).items() if k not in OWN_FLAGS})
    return from_flags(PipelineConfig, rest, cfg, check=False)  # its numbers' ranges: among the problems listed


def _problems(cfg: Any, args: argparse.Namespace) -> list[tuple[str, str]]:
    """Every problem init can find before anything runs, as (field, message naming the flag): all of them, so that one
    run of init lists what to fix (the files, the settings' ranges, the boards, calibrations, poses, robot, tasks,
    object names and images), not the first only."""
    from ..stages.pipeline import input_paths

    out = [(e.field or "", f"{_flag(e.field or '')}: {str(e).partition(': ')[2]}") for e in range_errors(cfg)]
    given = {SHORT[k]: (f"--{k.replace('_', '-')}", v) for k, v in vars(args).items()
             if k in SHORT and isinstance(v, Path)}  # fmt: skip
    missing = {f: given.get(f, (_flag(f), p)) for s in dataclasses.fields(cfg)
               for f, p in input_paths(getattr(cfg, s.name), s.name) if not p.exists()}  # fmt: skip
    out += [(f, f"{flag} {show(p)}: not found") for f, (flag, p) in missing.items()]
    if args.video is not None and args.video.is_dir():
        out.append(("capture.source", f"--video {args.video} is a folder; give the video file, or the folder as "
                                      "--images"))  # fmt: skip
    if args.images is not None and args.images.is_file():
        out.append(("capture.source", f"--images {args.images} is a file; give the folder of images, or a video as "
                                      "--video"))  # fmt: skip
    if cfg.capture.source is None and cfg.sfm.from_transforms is None and cfg.sfm.from_colmap is None:
        out.append(("capture.source", "no capture: give --video FILE or --images DIR (or --sfm.from-transforms FILE "
                                      "to import poses)"))  # fmt: skip
    if cfg.board is None and not cfg.align.unaligned:
        out.append(("board", "no calibration target: give --board FILE (its spec JSON, from `m2m board`), or "
                                   "--align.unaligned for a scene-only workspace (no robot twin)"))  # fmt: skip
    he = cfg.handeye
    lacking = [n for n in ("images", "joints", "board", "intrinsics") if getattr(he, n) is None]
    if (he.images is not None or he.joints is not None) and lacking:
        out.append((f"handeye.{lacking[0]}", "the hand-eye calibration also needs " +
                    ", ".join(_flag(f"handeye.{n}") for n in lacking)))  # fmt: skip
    for field, check in _reads(cfg):
        try:
            check()
        except M2MError as e:
            out.append((field, f"{_flag(field)}: {e}"))
    return [(f, m) for f, m in out if f not in missing or m.endswith(": not found")]


def _robot_known(robot: str) -> bool:
    """Whether ``robot`` reads (when it does not, the robot's own check says why, once)."""
    try:
        get_robot(robot)
    except M2MError:
        return False
    return True


def _reads(cfg: Any) -> list[tuple[str, Any]]:
    """(field, a check that reads what it names as its stage will) for every input init can read."""
    from ..calib.board import load_target
    from ..calib.handeye import check_poses_file, check_poses_link
    from ..geometry.camera import load_intrinsics
    from ..sim.tasks import parse_task

    def exists(path: Path | None) -> bool:
        return path is not None and path.exists()

    def images(folder: Path, what: str):
        files = [p for p in sorted(folder.iterdir()) if p.suffix.lower() in (".jpg", ".jpeg", ".png")]
        return lambda: [check_image_file(p, what) for p in files]

    checks: list[tuple[str, Any]] = []
    for field, read in (("board", load_target), ("handeye.board", load_target),
                        ("sfm.intrinsics", load_intrinsics), ("handeye.joints", check_poses_file),
                        ("handeye.intrinsics", lambda p: load_intrinsics(p, keys=("head_camera",))),
                        ("head_view.photo", lambda p: check_image_file(p, "head photo"))):  # fmt: skip
        section, _, name = field.rpartition(".")
        path = getattr(getattr(cfg, section) if section else cfg, name)
        if exists(path):
            checks.append((field, lambda read=read, path=path: read(path)))
    for field, folder in (("capture.source", cfg.capture.source), ("handeye.images", cfg.handeye.images)):
        if exists(folder) and folder.is_dir():
            checks.append((field, images(folder, "image")))
    if cfg.robot.lower() != "none":
        checks.append(("robot", lambda: get_robot(cfg.robot)))
        if exists(cfg.handeye.joints):
            checks.append(("handeye.link", lambda: _robot_known(cfg.robot) and check_poses_link(
                cfg.handeye.joints, cfg.robot, cfg.handeye.link, cfg.handeye.poses)))  # fmt: skip
    checks += [(f"generate.task[{i}]", lambda t=t: parse_task(t)) for i, t in enumerate(cfg.generate.task)]
    checks += [(f"objects.names[{i}]", lambda n=n: check_name(n.partition("=")[0], f"object name {n!r}"))
               for i, n in enumerate(cfg.objects.names)]  # fmt: skip
    return checks


def run(args: argparse.Namespace) -> int:
    from ..stages.pipeline import SettingsFile, plan_run

    ws = Workspace(args.workspace)
    if ws.root.exists() and not ws.root.is_dir():
        raise WorkspaceError(f"workspace {ws.root} exists and is not a folder; choose another with -w")
    if ws.config_file.exists() and not args.force:
        raise CliError(f"{ws.config_file} exists; edit it, or `m2m init --force ...` replaces it")
    cfg = _settings(args)
    problems = _problems(cfg, args)
    try:  # the checks `m2m run` makes, before anything is written
        plan = plan_run(ws, cfg, SettingsFile(Path("m2m init")))
    except ConfigError as e:
        said = [f.split("[")[0] for f, _ in problems]
        if not any(f.startswith(e.field or "") or (e.field or "").startswith(f) for f in said):  # not said already
            problems.append((e.field or "", f"{str(e).removeprefix('m2m init: ')} (flag {_flag(e.field or '')})"))
    if len(problems) == 1:
        raise CliError(problems[0][1])
    if problems:
        raise CliError(f"{len(problems)} problems, nothing written:\n" + "\n".join(f"  - {m}" for _, m in problems))
    with workspace_lock(ws, "m2m init"):
        if ws.config_file.exists() and not args.force:  # written meanwhile
            raise CliError(f"{ws.config_file} exists; edit it, or `m2m init --force ...` replaces it")
        cfg.save(ws.config_file)
    runs = [name for name, why in plan.items() if why is None]
    lines = [f"m2m init: wrote {show(ws.config_file)} (every setting, each explained; edit it to change any)",
             f"  m2m run will run  {', '.join(runs)}"]  # fmt: skip
    lines += [f"  and skip {name:<9} {why}" for name, why in plan.items() if why is not None]
    if not cfg.align.unaligned and cfg.robot.lower() != "none":
        joints = cfg.capture_joints
        lines.append(f"  the robot ({cfg.robot}) while filming: " + (
            f"{list(joints)} rad" if joints else "its home pose (give --capture-joints if it stood elsewhere)"))
        for frame, q in sorted((cfg.capture_moves or {}).items()):
            lines.append(f"  moved at frame {frame} to {list(q)} rad")
    lines.append(f"next: m2m run -w {show(ws.root)}")
    print("\n".join(lines))
    return 0
