"""``m2m view -w WS``: the twin in a browser (viser), or ``--export view.html``: one file that opens without a
server. It reads whatever the workspace holds (and says what is missing); the one thing it writes to the workspace
is an object moved in the page, through ``m2m world move``'s path (the workspace lock, a transaction, the world's
validation)."""

from __future__ import annotations

import argparse
import contextlib
import errno
import json
import socket
import time
from dataclasses import dataclass
from pathlib import Path

from ..configs import add_flags, from_flags, ranged
from ..robots import DEFAULT_ROBOT, get_robot
from ..robots.surface import check_capture_joints
from ..viewer.config import ViewerConfig
from ..viewer.inputs import Board, ViewerInputs
from ..workspace import Workspace
from .args import CliError, check_output, show
from .world import edit_world

__all__ = ["ViewConfig", "register", "view", "workspace_inputs"]


@dataclass
class ViewConfig:
    """m2m view settings (the viewer's own defaults, :class:`~..viewer.ViewerConfig`).

    port           the page's port
    host           address to serve on; 127.0.0.1: this machine only
    max_gaussians  most Gaussians per layer sent to the browser
    """

    port: int = ranged(ViewerConfig.port, ge=1, le=65535)
    host: str = ViewerConfig.host
    max_gaussians: int = ranged(ViewerConfig.max_gaussians, ge=1000, metadata={"metavar": "N"})


def register(sub: argparse._SubParsersAction) -> None:
    text = "look at the twin in a browser: world, robot, cameras, episodes (viser)"
    p = sub.add_parser("view", help=text, description=text[0].upper() + text[1:] + "; drag an object to move it.")
    p.add_argument("-w", "--workspace", required=True, metavar="DIR", help="the workspace folder")
    add_flags(p, ViewConfig)
    p.add_argument("--joints", metavar="J1,J2,...", help="the robot's arm joint state, rad (without it: home)")
    p.add_argument("--episode", metavar="NAME[:N]", help="a dataset or evaluation's episode N to play (N: 0 unless "
                   "given)")  # fmt: skip
    p.add_argument("--export", metavar="HTML", help="write the scene as one HTML file (opens without a server)")
    p.set_defaults(func=view)


def _port_free(host: str, port: int) -> None:
    """Refuse a port another program listens on (viser would quietly take the next one)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # a closed server's TIME_WAIT is no conflict
        try:
            s.bind((host, port))
        except OSError as e:
            why = "is in use (another viewer?)" if e.errno == errno.EADDRINUSE else f"cannot be used ({e.strerror})"
            raise CliError(f"--port {port} on {host} {why}; choose another with --port") from None


def workspace_inputs(ws: Workspace):
    """What ``ws`` holds for the viewer (:class:`~mirage2matter.viewer.ViewerInputs`), with what is missing."""
    from ..geometry.camera import Camera
    from ..world import load_world

    world = load_world(ws.world_yaml) if ws.world_yaml.is_file() else None
    missing = []
    robot_gaussians = None
    if world is not None:
        robot_gaussians, spec = world.robot.gaussians, world.robot.spec
    else:
        missing.append(f"the world ({show(ws.world_yaml)}; `m2m compose`): objects and cameras are not shown")
        robot_json = ws.robot_gaussians_dir / "robot.json"
        name = DEFAULT_ROBOT
        if robot_json.is_file():
            robot_gaussians, name = ws.robot_gaussians_dir, json.loads(robot_json.read_text()).get("robot", name)
        spec = get_robot(name)
    scene_ply = None
    if world is None:
        scene_ply = ws.scene_ply if ws.scene_ply.is_file() else None
        if scene_ply is None:
            missing.append(f"the scene's Gaussians ({show(ws.scene_ply)}; `m2m train-scene`)")
    keyframes = []
    if ws.cameras_base_file.is_file():
        keyframes = [Camera.from_json(c, source=str(ws.cameras_base_file))
                     for c in json.loads(ws.cameras_base_file.read_text())]  # fmt: skip
    else:
        missing.append(f"the keyframe cameras ({show(ws.cameras_base_file)}; `m2m align-scene`)")
    on_table = ws.board_on_table()
    board = None if on_table is None else Board(on_table[1], on_table[0])
    folders = lambda d, marker: {p.name: p for p in sorted(d.iterdir()) if (p / marker).is_file()} if d.is_dir() else {}
    return ViewerInputs(
        robot=spec, world=world, scene_ply=scene_ply, robot_gaussians=robot_gaussians, keyframes=keyframes,
        image_dir=ws.capture_dir, board=board, datasets=folders(ws.datasets_dir, Path("meta", "info.json")),
        evals=folders(ws.evals_dir, "episodes.jsonl"), missing=missing,
    )  # fmt: skip


def _mover(ws: Workspace):
    """A released drag -> ``m2m world move --to x,y,z --yaw deg``, the same function, lock and transaction."""
    from ..world import load_world
    from ..world.edit import placement_of

    def move(name: str, xyz, yaw_deg: float):
        to = ",".join(repr(float(v)) for v in xyz)
        edit_world(argparse.Namespace(workspace=str(ws.root), op="move", name=name, to=to, yaw=float(yaw_deg),
                                      scale=None, by=None))  # fmt: skip
        return placement_of(load_world(ws.world_yaml), name)

    return move


def _episode(text: str, inputs) -> tuple[str, str, int]:
    name, _, n = text.partition(":")
    try:
        index = int(n) if n else 0
    except ValueError:
        raise CliError(f"--episode {text}: expected NAME or NAME:N (N an episode number)") from None
    if name in inputs.datasets:
        return "dataset", name, index
    if name in inputs.evals:
        return "eval", name, index
    have = [*inputs.datasets, *inputs.evals]
    raise CliError(f"--episode {text}: no dataset or evaluation named {name!r}; the workspace has: "
                   f"{', '.join(have) or 'none (m2m generate / m2m eval-policy write them)'}")  # fmt: skip


def view(args: argparse.Namespace) -> int:
    from ..viewer.app import TwinViewer

    cfg_view = from_flags(ViewConfig, args)
    ws = Workspace(args.workspace)
    if not ws.root.is_dir():
        raise CliError(f"workspace {args.workspace} not found")
    export = Path(args.export) if args.export else None
    if export is not None:
        check_output(export, "--export", (".html",))
    else:
        _port_free(cfg_view.host, cfg_view.port)
    joints = None
    if args.joints:
        try:
            joints = tuple(float(v) for v in args.joints.split(","))
        except ValueError:
            raise CliError(f"--joints {args.joints}: expected numbers J1,J2,... (rad)") from None
    inputs = workspace_inputs(ws)
    if joints is not None:
        joints = tuple(check_capture_joints(inputs.robot, joints, "--joints").tolist())
    episode = _episode(args.episode, inputs) if args.episode else None
    for line in inputs.missing:
        print(f"view: not there yet: {line}")
    cfg = ViewerConfig(host=cfg_view.host, port=0 if export else cfg_view.port,
                       max_gaussians=cfg_view.max_gaussians, joints=joints)  # fmt: skip
    editable = export is None and inputs.world is not None
    viewer = TwinViewer(inputs, cfg, on_move=_mover(ws) if editable else None, log=print)
    try:
        if episode is not None:
            ep = viewer.load_episode(*episode)
            print(f"view: {ep.title}: {ep.length} frames, {ep.note}")
        if export is not None:
            size = viewer.export_html(export)
            print(f"view: loaded in {viewer.load_s:.1f} s -> {show(export)} ({size / 1e6:.1f} MB, opens without a "
                  "server)")  # fmt: skip
            return 0
        print(f"view: loaded in {viewer.load_s:.1f} s; open {viewer.url} (Ctrl-C stops)", flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            while True:
                time.sleep(1.0)
        return 0
    finally:
        viewer.close()
