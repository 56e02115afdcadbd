"""``m2m world <edit>`` (insert, move, duplicate, delete, import-placement, match-lighting) and ``m2m task``
(scripted task success rates in the twin): tools over a workspace's world/world.yaml."""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, fields
from pathlib import Path

from ..atomic import atomic_write
from ..configs import add_flags, from_flags, ranged
from ..stages.transaction import Transaction, workspace_lock
from ..workspace import Workspace
from .args import CliError, check_output, positive_float, show, xyz

_EDITS = (
    ("insert", "add an object from a Gaussian PLY + a mesh"),
    ("move", "move an object (--to x,y,z or --by dx,dy,dz; --yaw about z)"),
    ("duplicate", "copy an object under a new name (--as NAME --to x,y,z)"),
    ("delete", "remove an object"),
    ("import-placement", "take an object's placement from a PLY moved in SuperSplat"),
    ("match-lighting", "shift an object's colours toward the scene's illumination"),
    ("check", "recompose world.ply from world.yaml (after editing it by hand) and check every part"),
)


@dataclass
class PlaceConfig:
    """m2m world insert / move / duplicate settings.

    yaw   turn about z (deg)
    """

    yaw: float = 0.0


@dataclass
class LightingConfig:
    """m2m world match-lighting settings.

    strength  0..1 of the full correction
    radius    scene neighbourhood (m)
    """

    strength: float = ranged(1.0, gt=0)
    radius: float = ranged(0.3, gt=0)


def task_config() -> type:
    """m2m task's Config (a function: its episodes default is the generate stage's, whose Config imports the
    generation libraries)."""
    from ..stages import generate

    @dataclass
    class TaskConfig:
        """m2m task settings.

        episodes  per task
        seed      first reset seed
        """

        episodes: int = ranged(generate.Config.episodes, ge=1, metadata={"metavar": "N"})
        seed: int = ranged(0, ge=0)

    return TaskConfig


# the edits whose flags come from a Config
_OP_CONFIGS = {"insert": (PlaceConfig,), "move": (PlaceConfig,), "duplicate": (PlaceConfig,),
               "match-lighting": (LightingConfig,)}  # fmt: skip


def _given(args: argparse.Namespace, *configs: type) -> argparse.Namespace:
    """``args`` with the Configs' fields filled in: those given on the command line, the others at their default."""
    values = {f.name: getattr(from_flags(c, args), f.name) for c in configs for f in fields(c)}
    return argparse.Namespace(**{**vars(args), **values})


def register(sub: argparse._SubParsersAction, full: bool = True) -> None:
    wo = sub.add_parser("world", help="edit world.yaml: insert, move, duplicate, delete, import-placement, ...")
    wo_sub = wo.add_subparsers(dest="op", metavar="OP", required=True)
    for op, text in _EDITS:
        w = wo_sub.add_parser(op, help=text)
        w.add_argument("-w", "--workspace", required=True, metavar="DIR")
        if op == "check":
            w.add_argument(
                "--max-mm",
                type=positive_float,
                help="largest median Gaussian-to-mesh distance per part (mm; default: compose's max_mm)",
            )
            w.set_defaults(func=check_world)
            continue
        w.add_argument("--name", required=True)
        if op in ("insert", "move", "duplicate"):
            w.add_argument("--to", metavar="X,Y,Z", help="new origin in the base frame (m)")
            add_flags(w, PlaceConfig)
            w.add_argument("--scale", type=positive_float, help="placement scale (without it: kept, or 1)")
        if op == "move":
            w.add_argument("--by", metavar="DX,DY,DZ", help="shift by (m)")
        if op == "insert":
            w.add_argument("--gaussians", required=True, metavar="PLY")
            w.add_argument("--mesh", required=True, metavar="OBJ")
            w.add_argument("--collision", metavar="DIR", help="convex parts (*.obj); computed when absent")
            w.add_argument("--mass", type=positive_float, help="kg (without it: density 500 kg/m^3)")
        if op == "duplicate":
            w.add_argument("--as", dest="as_name", required=True, metavar="NEW")
        if op == "import-placement":
            w.add_argument("--ply", required=True, help="the object's (or world.ply's) Gaussians, moved")
            w.add_argument("--allow-scale", action="store_true", help="accept a changed object size (> x1.5)")
        if op == "match-lighting":
            add_flags(w, LightingConfig)
        w.set_defaults(func=edit_world)

    ta = sub.add_parser("task", help="run scripted tasks on randomised starts in the Genesis twin -> summary.json")
    ta.add_argument("-w", "--workspace", required=True, metavar="DIR", help="workspace with world/world.yaml")
    ta.add_argument("task", nargs="+", help='e.g. "grasp banana" "press button" "push croissant --direction 0,1"')
    if full:  # the Config's flags (this imports the generation libraries)
        add_flags(ta, task_config())
    ta.add_argument("--out", metavar="JSON", help="the summary (without it: <workspace>/world/task_summary.json)")
    ta.set_defaults(func=run_tasks)


def _world(workspace: str):
    from ..world import load_world

    ws = Workspace(workspace)
    return ws, load_world(ws.require(ws.world_yaml, "compose"))


def edit_world(args: argparse.Namespace) -> int:
    """One edit as a transaction: the new world.yaml, world.ply (+ world.json) and any new assets are written
    into staging and swapped in together, under the workspace lock."""
    from ..world import load_world, save_world
    from ..world.compose import write_world_ply

    args = _given(args, *_OP_CONFIGS.get(args.op, ()))
    ws = Workspace(args.workspace)
    ws.require(ws.world_yaml, "compose")
    with workspace_lock(ws, f"m2m world {args.op}"):
        cfg = load_world(ws.world_yaml)
        asset = ws.world_asset_dir(args.name)
        writes = [ws.world_yaml, ws.world_ply, ws.world_manifest, asset]
        txn = Transaction(ws, "world-edit", [p.relative_to(ws.root) for p in writes])
        with txn.staging_of(f"{args.op}-{time.time_ns()}", resumable=False) as staged:  # an edit is never resumed
            staged.world_dir.mkdir(parents=True, exist_ok=True)
            new = _edit(args, cfg, staged.world_asset_dir(args.name).resolve())
            write_world_ply(new, out_dir=staged.world_dir)
            save_world(new.relocated(staged.world_dir, ws.world_dir), staged.world_yaml, home=ws.world_dir)
    print(f"{args.op} {args.name}: saved {show(ws.world_yaml)}, recomposed {show(ws.world_ply)}")
    return 0


def _edit(args: argparse.Namespace, cfg, asset_dir: Path):
    """The edited world; new files go into ``asset_dir``."""
    from ..world import edit

    op = args.op
    if op == "delete":
        return edit.delete(cfg, args.name)
    if op == "import-placement":
        new, sim = edit.import_placement(cfg, args.name, args.ply, allow_scale=args.allow_scale)
        print(f"{args.name}: placement from {args.ply}: {sim}")
        return new
    if op == "match-lighting":
        new, gain = edit.match_lighting(cfg, args.name, asset_dir / "gaussians_lit.ply", strength=args.strength,
                                        radius=args.radius)  # fmt: skip
        print(f"{args.name}: colour gain r,g,b = {', '.join(f'{g:.3f}' for g in gain)}")
        return new
    base = None if op == "insert" else edit.placement_of(cfg, args.name)
    if op == "move" and args.by:
        placement = edit.placement_from_pose(base.translation + xyz(args.by, "--by"), args.yaw, base.scale, base)
    else:
        if not args.to:
            raise CliError(f"`m2m world {op}` needs --to x,y,z")
        scale = args.scale if args.scale else (base.scale if base is not None else 1.0)
        placement = edit.placement_from_pose(xyz(args.to, "--to"), args.yaw, scale, base)
    if op == "insert":
        return edit.insert(cfg, args.name, args.gaussians, args.mesh, placement, collision=args.collision,
                           mass=args.mass, objects_dir=asset_dir.parent)  # fmt: skip
    if op == "move":
        return edit.move(cfg, args.name, placement)
    return edit.duplicate(cfg, args.name, args.as_name, placement)


def check_world(args: argparse.Namespace) -> int:
    """world.ply + world.json recomposed from world.yaml and checked; swapped in together only when they pass."""
    from ..stages import world as compose
    from ..world import load_world
    from ..world.compose import consistency, write_world_ply

    max_mm = compose.Config.max_mm if args.max_mm is None else args.max_mm
    ws = Workspace(args.workspace)
    ws.require(ws.world_yaml, "compose")
    with workspace_lock(ws, "m2m world check"):
        cfg = load_world(ws.world_yaml)
        txn = Transaction(ws, "world-check", [p.relative_to(ws.root) for p in (ws.world_ply, ws.world_manifest)])
        with txn.staging_of(f"check-{time.time_ns()}", resumable=False) as staged:
            staged.world_dir.mkdir(parents=True, exist_ok=True)
            write_world_ply(cfg, out_dir=staged.world_dir)
            cons = consistency(cfg)
            worst = max(cons.values(), default=0.0)
            if worst > max_mm / 1000:
                raise CliError(f"an object's Gaussians and mesh disagree by {1000 * worst:.1f} mm (> {max_mm} mm)")
    print(f"world: {len(cfg.objects)} objects, {len(cfg.articulated)} articulated -> {show(ws.world_ply)} "
          "(+ world.json)")  # fmt: skip
    for name, d in cons.items():
        print(f"  {name}: median Gaussian-to-mesh distance {1000 * d:.2f} mm")
    return 0


def run_tasks(args: argparse.Namespace) -> int:
    from ..sim.tasks import parse_task

    args = _given(args, task_config())
    ws, cfg = _world(args.workspace)
    tasks = [parse_task(t, cfg) for t in args.task]  # unknown tasks / objects fail before Genesis starts
    out = Path(args.out) if args.out else ws.task_summary
    check_output(out, "--out", (".json",))
    with workspace_lock(ws, "m2m task"):  # one writer: the world it runs is the one on disk throughout
        return _run_tasks(ws, cfg, tasks, out, args)


def _run_tasks(ws: Workspace, cfg, tasks, out: Path, args: argparse.Namespace) -> int:
    from ..sim.tasks import evaluate
    from ..sim.twin import Twin, TwinOptions

    t0 = time.perf_counter()
    twin = Twin.build(cfg, TwinOptions(render=False))
    build_s = time.perf_counter() - t0
    results = []
    for task in tasks:
        r = evaluate(twin, task, args.episodes, seed=args.seed, progress=True)
        results.append(r)
        print(
            f"{task.instruction!r}: {r['successes']}/{r['episodes']} = {100 * r['success_rate']:.0f}% "
            f"(mean {r['mean_sim_s']:.1f} s simulated, {r['mean_wall_s']:.2f} s wall per episode)"
        )
    summary = {"world": str(ws.world_yaml), "build_s": build_s, "seed": args.seed, "tasks": results}
    with atomic_write(out, "w", encoding="utf-8") as f:
        json.dump(summary, f, indent=1)
    print(f"-> {show(out)}")
    return 0
