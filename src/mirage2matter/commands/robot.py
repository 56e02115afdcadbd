"""``m2m robot [ROBOT]``: the robots the package knows, or one robot as the pipeline reads it (a registered name or
your own robot spec file: its joints, the limits and reach read from its model, and where each number came from)."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from ..robots import ROBOTS, get_robot


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "robot", help="list the robots, or show one robot (a name or a spec file) as the pipeline reads it",
        description="Without ROBOT: the registered robots. With ROBOT (a registered name, or the path of your own "
        "robot spec YAML/JSON, format in mirage2matter/robots/specfile.py): its model, arm and finger joints with the "
        "limits, speeds, gains and force limits read from the model (or, where the model has none, the spec's or the "
        "documented defaults: the provenance says which), the tool centre, the shoulder and reach, the camera mounts "
        "and the dataset names. A bad spec file is an error naming the file, the field and what to do.",
    )  # fmt: skip
    p.add_argument("robot", nargs="?", help="a registered robot or a robot spec file")
    p.add_argument("--json", action="store_true", help="print the spec as JSON")
    p.set_defaults(func=run)


def _jsonable(spec) -> dict:
    out = {}
    for f in dataclasses.fields(spec):
        v = getattr(spec, f.name)
        if f.name in ("cameras", "frames"):
            v = {n: dataclasses.asdict(m) for n, m in v}
        elif f.name == "provenance":
            v = dict(v)
        elif isinstance(v, Path):
            v = str(v)
        out[f.name] = v
    return {**out, "state_names": list(spec.state_names), "action_names": list(spec.action_names)}


def run(args: argparse.Namespace) -> int:
    if args.robot is None:
        rows = {name: get_robot(name) for name in ROBOTS}
        if args.json:
            print(json.dumps({n: _jsonable(s) for n, s in rows.items()}, indent=1))
            return 0
        for name, s in rows.items():
            print(f"{name:8s} {s.n_arm}-joint arm + {len(s.gripper_joints)} fingers, reach {s.reach:.2f} m, "
                  f"robot_type {s.robot_type}  ({ROBOTS[name]})")  # fmt: skip
        print("Your own robot: a spec file (mirage2matter/robots/specfile.py), e.g. `m2m robot my_arm.yaml`; name it "
              "wherever a robot is asked for (`m2m compose --robot my_arm.yaml`).")  # fmt: skip
        return 0
    s = get_robot(args.robot)
    if args.json:
        print(json.dumps(_jsonable(s), indent=1))
        return 0
    prov = dict(s.provenance)
    print(f"robot {s.name} (LeRobot robot_type {s.robot_type}) from {s.source or 'code'}")
    print(f"  model        {s.model}")
    print(f"  arm          {s.n_arm} joints; velocity limits from the {prov.get('velocity_limit')}, accelerations from "
          f"the {prov.get('acceleration_limit')}, gains from the {prov.get('kp')}, force limits from the "
          f"{prov.get('force_limit')}")  # fmt: skip
    head = ("joint", "limits", "home", "speed", "accel", "kp", "kv", "force")
    print("    {:16s} {:>20s} {:>8s} {:>7s} {:>7s} {:>7s} {:>6s} {:>6s}".format(*head))
    for i, j in enumerate(s.arm_joints):
        lo, hi = s.joint_limits[i]
        print(f"    {j:16s} {f'[{lo:.3f}, {hi:.3f}]':>20s} {s.home[i]:8.3f} {s.velocity_limit[i]:7.3f} "
              f"{s.acceleration_limit[i]:7.2f} {s.kp[i]:7.0f} {s.kv[i]:6.0f} {s.force_limit[i]:6.0f}")  # fmt: skip
    print(f"  gripper      {', '.join(s.gripper_joints)}: open {s.gripper_open:g}, closed {s.gripper_closed:g}; "
          f"fingers {', '.join(s.finger_links)}; grasps up to {100 * s.max_grasp_width:.1f} cm, "
          f"{s.grasp_force:g} N")  # fmt: skip
    print(f"  end effector {s.ee_link}; tool centre {list(s.tcp_position)}, approach {list(s.tcp_approach)}, closing "
          f"{list(s.tcp_closing)}; fingertips {1000 * s.tip_depth:.1f} mm beyond it")  # fmt: skip
    print(f"  reach        {s.reach:.3f} m from the shoulder at {[round(v, 4) for v in s.shoulder]} (from the model)")
    for name, m in s.cameras:
        print(f"  camera       {name}: on {m.link}, eye {list(m.eye)}, looking at {list(m.target)}, "
              f"{m.width}x{m.height}, {m.fov_deg:g} deg")  # fmt: skip
    if s.frames:  # the names a controller logs poses in (hand-eye), on the model's links
        print("  frames       " + "; ".join(f"{n}: {f.describe()}" for n, f in s.frames))
    print(f"  datasets     observation.state {list(s.state_names)}; action {list(s.action_names)}")
    return 0
