"""Stage ``objects``: per object found on the table, masks -> object 3DGS -> watertight mesh + convex
collision parts -> alignment, in one object frame -> ``objects/<name>/`` (see ``objects.reconstruct``) and
``objects/summary.json``. An object whose ``align.json`` was written from the same config and points is
kept, so a killed run resumes at the object it was on."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write
from ..objects import ObjectsError
from ..objects.pool import object_workers, process_objects
from ..objects.reconstruct import ObjectsConfig, find_targets, pinhole_keyframes, target_fingerprint
from ..workspace import Workspace
from .base import Input, Log

Config = ObjectsConfig


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    out = [Input(ws.cameras_base_file, made_by="align-scene"), Input(ws.points_base_file, made_by="align-scene"),
           Input(ws.keyframes_file, made_by="capture")]  # fmt: skip
    out += [Input(ws.robot_capture_file)] if ws.robot_capture_file.is_file() else []  # where the robot hides objects
    files = [(cfg.masks, "objects masks"), (cfg.sam2_checkpoint, "objects sam2_checkpoint")]
    files += [(p, f"objects mesh {name}") for name, p in cfg.mesh.items()]
    return out + [Input(Path(p), field=what) for p, what in files if p is not None]


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    from ..calib.board import target_plane

    posed = ws.posed_capture(frame="base")
    cameras, images = pinhole_keyframes(posed.cameras, posed.image_dir)  # a camera's lens taken out up front
    lens = posed.cameras if any(c.has_distortion for c in posed.cameras) else None
    board = ws.target_on_table()
    plane = None if board is None else target_plane(*board)
    _, targets = find_targets(cfg, cameras, _off_the_board(posed.points, board), board=plane)
    robot_in_front(ws, cameras, targets)
    unknown = set(cfg.mesh) - {t.name for t in targets}
    if unknown:
        names = [t.name for t in targets]
        raise ObjectsError(f"mesh for {', '.join(sorted(unknown))}: no such object (objects: {names})")
    out: dict[str, Any] = {}
    todo = []
    for target in targets:
        folder = ws.object_dir(target.name)
        done = folder / "align.json"
        if done.is_file():
            previous = json.loads(done.read_text())
            if previous.get("fingerprint") == target_fingerprint(cfg, target):
                log(f"{target.name}: up to date, skipped")
                out[target.name] = previous
                continue
        todo.append((target, folder))
    made = process_objects(todo, cfg, cameras, images, log, lens, workers=object_workers(cfg.workers, len(todo)))
    out = {t.name: out.get(t.name) or made[t.name] for t in targets}
    keep = ("sim3_obj_to_base", "mesh", "gaussians")
    with atomic_write(ws.objects_summary, "w", encoding="utf-8") as f:
        json.dump({k: {kk: v[kk] for kk in keep if kk in v} for k, v in out.items()}, f, indent=1, default=str)
    lines = [_object_line(name, s) for name, s in out.items()]
    return {"objects": out, "details": lines, "line": f"{len(out)} objects: {', '.join(sorted(out))}"}


def _off_the_board(points_base: np.ndarray, board) -> np.ndarray:
    """The SfM points [N,3] without those on the calibration target (``board``: Workspace.target_on_table; None: no
    target): the board is no object. With the board beside the robot's base (on the bundled sample), 12 points over
    its pattern were the "object" nearest the base, named for the first object the user listed."""
    from ..calib.board import on_target

    return points_base if board is None else points_base[~on_target(points_base, *board)]


# A keyframe in which the robot stands in front of this share of the object's points or more is left out of its
# masks: what is left of the object there teaches little. In the others only the robot's pixels are (Target.unknown).
# On the bundled sample's 40 keyframes (volume vs truth banana / croissant / button): 5 %, keyframes left out whole,
# 1.149 / 0.964 / 1.107; 50 % with the robot's pixels unknown 1.146 / 0.929 / 1.082; 90 % 1.125 / 0.966 / 1.118 (the
# same inputs give the same meshes; a few keyframes more or less move a volume by a few %).
HIDDEN_FRACTION = 0.5
ROBOT_MARGIN_PX = 3  # the robot's drawn silhouette grown by this: its mesh and pose are a few pixels off the photo's


def robot_in_front(ws: Workspace, cameras: list, targets: list) -> None:
    """Where align-scene found the robot in the keyframes, each object's ``hidden`` (the keyframes in which the robot,
    at the joint state it held then, stands in front of HIDDEN_FRACTION of its points or more) and ``unknown`` (in
    the other keyframes that show the robot, its pixels: they would paint the robot onto the object, or onto the
    table behind it). (Before, 5 % of its points behind the robot left a keyframe out: on the bundled sample the
    button lost 13 of 40 keyframes, one sector of the orbit, and its mesh came out 7-13 mm too wide, 10 mm too tall.)"""
    from ..calib.robot_view import grow_mask, seen_robot, views_behind_robot

    robot = seen_robot(ws.robot_capture_file)
    if robot is None:
        return
    depths = robot.depths(cameras)  # each keyframe against the robot as it stood then
    pixels = [grow_mask(on, ROBOT_MARGIN_PX) if on.any() else None for on in (np.isfinite(d) for d in depths)]
    for t in targets:
        if t.cluster is None:
            continue
        behind = views_behind_robot(t.cluster.points, cameras, depths, min_fraction=HIDDEN_FRACTION)
        t.hidden = tuple(i for i, h in enumerate(behind) if h)
        t.unknown = tuple(None if i in t.hidden else p for i, p in enumerate(pixels))
        if all(u is None for u in t.unknown):
            t.unknown = ()


def _object_line(name: str, s: dict[str, Any]) -> str:
    """One object's figures; a figure an object lacks (no held-out view, no opaque Gaussian) reads n/a."""

    def num(v: Any, scale: float, fmt: str) -> str:
        return "n/a" if not isinstance(v, int | float) else format(scale * v, fmt)

    held, mesh = s.get("gaussians", {}).get("heldout") or {}, s.get("mesh", {})
    return (
        f"{name}: mesh {num(mesh.get('volume'), 1e6, '.1f')} cm3, {num(mesh.get('mass'), 1000, '.0f')} g, watertight "
        f"{mesh.get('watertight')}, {s.get('collision', {}).get('parts')} convex parts; 3DGS masked PSNR "
        f"{num(held.get('psnr_masked'), 1, '.2f')} dB, alpha outside {num(held.get('alpha_outside'), 1, '.3f')}; "
        f"Gaussians to mesh {num(s.get('alignment', {}).get('median_distance_to_mesh_m'), 1000, '.2f')} mm (median); "
        f"{num(s.get('seconds', {}).get('total'), 1, '.0f')} s{_within_words(s)}{_hidden_words(s)}"
    )


def _within_words(s: dict[str, Any]) -> str:
    within = s.get("gaussians", {}).get("within_mesh")
    if not within:
        return ""
    return (f"; held inside the mesh (short retraining): masked PSNR then {within['heldout']['psnr_masked']:.2f} dB, "
            f"alpha outside {within['heldout']['alpha_outside']:.3f}")  # fmt: skip


def _hidden_words(s: dict[str, Any]) -> str:
    hidden = s.get("masks", {}).get("hidden_by_robot") or []
    partly = s.get("masks", {}).get("robot_pixels_left_out") or 0
    words = f"; {len(hidden)} keyframe(s) with the robot in front of most of it left out" if hidden else ""
    return words + (f"; the robot's pixels left out of its masks in {partly} more" if partly else "")


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.objects_summary]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.objects_dir]
