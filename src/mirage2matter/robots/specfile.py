"""A robot spec file (YAML or JSON) -> a :class:`RobotSpec`, with the limits and reach read from its model.

The file names the model and what only a person knows about it (which joints are the arm and which the
fingers, the finger values of an open and a closed gripper, where the tool centre is, where cameras sit);
everything the model holds is read from it: joint ranges, velocity limits (URDF), force limits and PD gains
(MJCF position actuators, URDF effort), the finger links, the shoulder and the reach (forward kinematics),
the closing axis at home. The robots shipped with the package are such files (``robots/specs/*.yaml``)::

    name: ur5e                          # what world.yaml and the commands call it (letters, digits, _ -)
    units: m                            # of the lengths below (tcp, eye, target, tip_depth, grasp widths): m or mm
    robot_type: ur5e                    # LeRobot's robot_type of its datasets (default: name)
    model: xml/universal_robots_ur5e/ur5e.xml   # MJCF/URDF: relative to this file, absolute, or in Genesis' assets
    # ... or an arm without a gripper fitted with one (its root body fixed at a site or link of the arm):
    # model: {arm: ARM.xml|.urdf, gripper: xml/franka_emika_panda/hand.xml, mount: attachment_site,
    #         prefix: gripper_, pos: [0, 0, 0], quat: [1, 0, 0, 0]}
    arm:
      joints: [shoulder_pan, ...]       # the arm's joints, base to tip: the model's first dofs
      home: [...]                       # rest pose (rad)
    gripper:
      joints: [gripper_finger_joint1, gripper_finger_joint2]   # the fingers: the dofs right after the arm's
      open: 0.04                        # finger value open / closed (default: the joint's upper / lower limit)
      closed: 0.0
      state_names: [finger_left, finger_right]   # their names in observation.state (default: the joint names)
      max_grasp_width: 0.072            # widest slab the open fingers take (default: 90 % of the opening of
                                        # sliding fingers)
      pad_half_width: 0.012             # half the finger pads' width (default 0.01 m)
      min_grasp_height: 0.012           # lowest tool centre over the table (default: tip_depth + 3 mm)
      force: 20                         # squeeze (N per finger, default 20)
      coupling: 3000                    # spring (N/m) tying the fingers together while squeezing (default 0)
    end_effector:
      link: gripper_hand                # the link the gripper hangs off (IK target)
      tcp: [0, 0, 0.1034]               # tool centre between the finger pads, in that link's frame (m)
      approach: [0, 0, 1]               # towards the fingertips (default z)
      closing: [0, 1, 0]                # the fingers close along it (default y)
      tip_depth: 0.0089                 # the fingertip ends beyond the tool centre (m)
    control:                            # PD gains and force limits, per joint name or a list over all joints;
      kp: {gripper_finger_joint1: 1000} # default: the model's position actuators and force ranges (URDF effort)
    limits:                             # used where the model has none (MJCF never has velocity limits)
      velocity: [3.14, ...]             # rad/s per arm joint (default DEFAULT_VELOCITY)
      acceleration: [...]               # rad/s^2 (default ACCELERATION_PER_VELOCITY x the velocity limit)
    cameras:
      wrist: {link: gripper_hand, eye: [0.07, 0, 0], target: [0, 0, 0.14], up: [1, 0, 0], fov_deg: 70,
              width: 640, height: 480}  # look-at in the link's frame (m)
    frames:                             # names the model does not have, fixed to its links: robot poses logged
      EE: {link: gripper_hand, xyz: [0, 0, 0.1034], rpy: [0, 0, 0]}   # in them (hand-eye) resolve to the link;
                                        # e.g. the controller's TCP as set on its pendant
      tool0: gripper_hand               # another name for a link (or for a frame above)

Every problem is a :class:`RobotSpecError` naming the file, the field and what to do: a model without the
named joints or links, joints out of the model's order, a model with no gripper, a home outside the limits.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..inputs import InputError, read_json, read_yaml
from .model import ModelError, ModelInfo, compose_model, genesis_assets_dir, load_model, model_info, resolve_model
from .spec import CameraMount, NamedFrame, RobotSpec, RobotSpecError

__all__ = [
    "ACCELERATION_PER_VELOCITY",
    "DEFAULT_KP_PER_FORCE",
    "DEFAULT_VELOCITY",
    "load_robot_spec",
    "spec_from_dict",
]

# Where the model and the spec give no velocity limit (MJCF has none): a cautious speed for an unknown arm
# (industrial arms' wrists reach 3-6 rad/s, their shoulders 2-3; prismatic joints 0.2 m/s, a gripper's speed).
DEFAULT_VELOCITY = {"hinge": 1.0, "slide": 0.2}  # rad/s, m/s
# Where the spec gives no acceleration limit (no model format has one): reach full speed in 0.25 s. The Panda's
# datasheet ratios are 3.4-7.7 / s.
ACCELERATION_PER_VELOCITY = 4.0
# Where the model has no position actuator and the spec no gains: the full force at 2 cm / 0.02 rad off target,
# damped at a tenth (the Panda's actuators' ratio: kp 4500, kv 450).
DEFAULT_KP_PER_FORCE = 50.0
DEFAULT_KV_PER_KP = 0.1
DEFAULTS = {"pad_half_width": 0.01, "grasp_force": 20.0, "coupling": 0.0, "tip_clearance": 0.003}

_NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*$")
MAX_OFFSET_M = 0.5  # a tool centre or a camera mount this far from its link is in other units (103.4: mm)
TOP_KEYS = {"name", "robot_type", "units", "model", "arm", "gripper", "end_effector", "control", "limits",
            "cameras", "frames"}
NO_GRIPPER_HELP = (
    "a robot here needs a gripper: name its finger joints (gripper.joints), or fit one to an arm without: "
    "model: {arm: ARM_FILE, gripper: xml/franka_emika_panda/hand.xml, mount: SITE_OR_LINK_AT_THE_FLANGE}"
)


class _Reader:
    """Typed access to one spec file's fields; every error names the file and the field."""

    def __init__(self, source: str) -> None:
        self.source = source

    def error(self, field: str, message: str) -> RobotSpecError:
        return RobotSpecError(f"{self.source}: {field}: {message}")

    def mapping(self, value: Any, field: str, allowed: set[str] | None = None) -> dict:
        if value is None:
            return {}
        if not isinstance(value, dict):
            raise self.error(field, f"expected a mapping (key: value), got {type(value).__name__}")
        if allowed is not None:
            unknown = sorted(str(k) for k in set(value) - allowed)
            if unknown:
                raise self.error(field, f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")
        return value

    def string(self, value: Any, field: str) -> str:
        if not isinstance(value, str) or not value:
            raise self.error(field, f"expected a non-empty string, got {value!r}")
        return value

    def names(self, value: Any, field: str, allow_empty: bool = False) -> tuple[str, ...]:
        if value is None:
            value = []
        if not isinstance(value, list | tuple) or not all(isinstance(v, str) and v for v in value):
            raise self.error(field, f"expected a list of names, got {value!r}")
        if not value and not allow_empty:
            raise self.error(field, "the list is empty")
        if len(set(value)) != len(value):
            raise self.error(field, f"a name appears twice in {list(value)}")
        return tuple(value)

    def number(self, value: Any, field: str, lo: float = -math.inf, hi: float = math.inf) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.error(field, f"expected a number, got {value!r}")
        if not lo <= value <= hi:
            raise self.error(field, f"{value!r} is outside [{lo:g}, {hi:g}]")
        return float(value)

    scale = 1.0  # the spec's lengths to metres (``units: mm``: 0.001)

    def offset(self, value: Any, field: str, link: str, limit: float) -> tuple[float, ...]:
        """A point in ``link``'s frame in metres, given in the spec's units; more than ``limit`` m from the link is an
        error naming the field (millimetres written as metres)."""
        v = tuple(x * self.scale for x in self.vector(value, field, 3))
        d = math.hypot(*v)
        if d > limit:
            raise self.error(field, f"{list(value)} lies {d:.3g} m from {link}; expected at most {limit:g} m: lengths "
                                    "are metres unless the spec says units: mm")  # fmt: skip
        return v

    def length(self, value: Any, field: str, lo: float, hi: float) -> float:
        """A length in metres, given in the spec's units, within [lo, hi] m."""
        return self.number(self.number(value, field) * self.scale, field, lo, hi)

    def vector(self, value: Any, field: str, n: int) -> tuple[float, ...]:
        if not isinstance(value, list | tuple) or len(value) != n:
            raise self.error(field, f"expected {n} numbers, got {value!r}")
        return tuple(self.number(v, f"{field}[{i}]") for i, v in enumerate(value))

    def per_joint(self, value: Any, field: str, joints: tuple[str, ...], lo: float = 0.0) -> dict[str, float]:
        """A list over ``joints`` or a mapping {joint: value} of a subset -> {joint: value}; values > ``lo``."""
        if value is None:
            return {}
        if isinstance(value, dict):
            unknown = sorted(str(k) for k in set(value) - set(joints))
            if unknown:
                raise self.error(field, f"{unknown} are not among the joints {list(joints)}")
            items = list(value.items())
        elif isinstance(value, list | tuple):
            if len(value) != len(joints):
                raise self.error(field, f"{len(value)} values for the {len(joints)} joints {list(joints)}; give one "
                                        "per joint or a mapping {joint: value}")  # fmt: skip
            items = list(zip(joints, value, strict=True))
        else:
            raise self.error(field, f"expected a list over {list(joints)} or a mapping {{joint: value}}")
        out = {}
        for j, v in items:
            out[j] = self.number(v, f"{field}.{j}")
            if out[j] <= lo:
                raise self.error(f"{field}.{j}", f"must be more than {lo:g}, got {v!r}")
        return out


def _resolve(r: _Reader, ref: Any, field: str, base: Path | None) -> Path:
    try:
        return resolve_model(r.string(ref, field), base)
    except ModelError as e:
        raise r.error(field, f"{e}") from None


def _model(r: _Reader, data: Any, base: Path | None, name: str) -> tuple[Path, Path | None]:
    """(the model file (a composed one materialised under the robot cache), the arm's own file if composed)."""
    if isinstance(data, str):
        path = _resolve(r, data, "model", base)
        if path.suffix.lower() not in (".xml", ".mjcf", ".urdf"):
            raise r.error("model", f"{path} is neither MJCF (.xml) nor URDF (.urdf)")
        return path, None
    d = r.mapping(data, "model", {"arm", "gripper", "mount", "prefix", "pos", "quat"})
    if not d:
        raise r.error("model", "missing: name the robot's MJCF/URDF file (or {arm, gripper, mount} to fit a gripper)")
    for key in ("arm", "gripper", "mount"):
        if key not in d:
            raise r.error(f"model.{key}", "missing; a composed model needs arm, gripper and mount")
    arm, gripper = _resolve(r, d["arm"], "model.arm", base), _resolve(r, d["gripper"], "model.gripper", base)
    prefix = d.get("prefix", "gripper_")
    if not isinstance(prefix, str):
        raise r.error("model.prefix", f"expected a string, got {prefix!r}")
    pos = r.vector(d.get("pos", [0, 0, 0]), "model.pos", 3)
    quat = r.vector(d.get("quat", [1, 0, 0, 0]), "model.quat", 4)
    if abs(np.linalg.norm(quat) - 1) > 1e-3:
        raise r.error("model.quat", f"{list(quat)} is not a unit quaternion (w, x, y, z)")
    try:
        return compose_model(arm, gripper, r.string(d["mount"], "model.mount"), name, prefix, pos, quat), arm
    except ModelError as e:
        raise r.error("model", str(e)) from None


def _joints(r: _Reader, info: ModelInfo, arm: tuple[str, ...], grip: tuple[str, ...]) -> None:
    """The named joints exist, are hinge/slide, and are the model's dofs in this order (arm, then fingers)."""
    names = info.joint_names
    for field, joints in (("arm.joints", arm), ("gripper.joints", grip)):
        missing = [j for j in joints if info.joint(j) is None]
        if missing:
            extra = ""
            if field == "gripper.joints" and set(names) <= set(arm):
                extra = f"; the model has no joints beyond the arm's: it has no gripper. {NO_GRIPPER_HELP}"
            raise r.error(field, f"the model {info.path} has no joint(s) {missing} (its joints: {list(names)}); name "
                                 f"them as the model does{extra}")  # fmt: skip
    both = set(arm) & set(grip)
    if both:
        raise r.error("gripper.joints", f"{sorted(both)} are arm joints too")
    if info.others:
        raise r.error("model", f"{info.path} has free or ball joints {list(info.others)}; give a fixed-base arm")
    want = (*arm, *grip)
    if names != want:
        raise r.error("arm.joints", f"the model's joints, in its order, are {list(names)}; the arm's joints then "
                                    f"the gripper's must be exactly those ({list(want)} given). A model with other "
                                    "moving parts cannot be simulated as this arm")  # fmt: skip


def _limits(r: _Reader, info: ModelInfo, joints: tuple[str, ...]) -> tuple[tuple[float, float], ...]:
    out = []
    for j in joints:
        mj = info.joint(j)
        if mj.limits is None:  # a continuous joint: one turn either way
            lim = (-2 * math.pi, 2 * math.pi) if mj.kind == "hinge" else None
            if lim is None:
                raise r.error("model", f"joint {j} of {info.path} slides without limits; give it a range")
            out.append(lim)
        else:
            out.append(mj.limits)
    return tuple(out)


def _kinematics(info: ModelInfo, arm: tuple[str, ...], ee_link: str, home: tuple[float, ...],
                limits: tuple[tuple[float, float], ...]) -> tuple[np.ndarray, float, np.ndarray]:  # fmt: skip
    """(shoulder [3], reach, T_base_ee at home [4,4]) from forward kinematics at q = 0 and at home."""
    import mujoco

    m = load_model(info.path)
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    jid = [m.joint(j).id for j in arm]
    p1, a1 = d.xanchor[jid[0]].copy(), d.xaxis[jid[0]].copy()
    if len(jid) > 1:
        p2, a2 = d.xanchor[jid[1]].copy(), d.xaxis[jid[1]].copy()
        # the point of axis 1 nearest axis 2 (the anchor's projection when they are parallel)
        w, b = p1 - p2, float(a1 @ a2)
        denom = 1.0 - b * b
        t = (b * (a2 @ w) - (a1 @ w)) / denom if denom > 1e-9 else float(a1 @ (p2 - p1))
        shoulder = p1 + t * a1
    else:
        shoulder = p1
    # A point on a hinge's axis is fixed both in the link before it and in the link after it, so a polyline from the
    # shoulder through one point on each later axis to the ee origin has rigid segments: its length bounds the ee
    # origin's distance from the shoulder whatever the joints do (plus a slide joint's stroke). The points are
    # chosen along the axes to make the bound tight (the UR5e's offsets along its axes: 1.30 m at the anchors,
    # 1.03 m here).
    anchors = np.array([d.xanchor[j] for j in jid[1:]]).reshape(-1, 3)
    axes = np.array([d.xaxis[j] for j in jid[1:]]).reshape(-1, 3)
    ee = d.xpos[m.body(ee_link).id].copy()

    def length(t: np.ndarray) -> float:
        pts = np.concatenate([shoulder[None], anchors + t[:, None] * axes, ee[None]])
        return float(np.sqrt((np.diff(pts, axis=0) ** 2).sum(axis=1) + 1e-18).sum())

    t0 = np.zeros(len(anchors))
    if len(anchors):
        from scipy.optimize import minimize

        best = minimize(length, t0, method="Powell", options={"xtol": 1e-9, "ftol": 1e-12})
        t0 = best.x if best.fun < length(t0) else t0
    reach = length(t0) + 1e-6
    for k, j in enumerate(jid):
        if int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_SLIDE):
            reach += max(abs(limits[k][0]), abs(limits[k][1]))
    d.qpos[:] = 0.0
    d.qpos[: len(home)] = home
    mujoco.mj_kinematics(m, d)
    b = m.body(ee_link).id
    T = np.eye(4)
    T[:3, :3] = d.xmat[b].reshape(3, 3)
    T[:3, 3] = d.xpos[b]
    return shoulder, reach, T


def _camera(r: _Reader, data: Any, field: str, bodies: tuple[str, ...]) -> CameraMount:
    d = r.mapping(data, field, {"link", "eye", "target", "up", "fov_deg", "width", "height"})
    for k in ("link", "eye", "target"):
        if k not in d:
            raise r.error(f"{field}.{k}", "missing")
    link = r.string(d["link"], f"{field}.link")
    if link not in bodies:
        raise r.error(f"{field}.link", f"{link!r} is not a link of the model (links: {list(bodies)})")
    eye, target = r.offset(d["eye"], f"{field}.eye", link, MAX_OFFSET_M), r.offset(d["target"], f"{field}.target",
                                                                                     link, 2.0)  # fmt: skip
    up = r.vector(d.get("up", [0, 0, 1]), f"{field}.up", 3)
    view = np.subtract(target, eye)
    if np.linalg.norm(view) < 1e-6 or np.linalg.norm(np.cross(view, up)) < 1e-6 * np.linalg.norm(view):
        raise r.error(field, "eye and target must differ and up must not be along the view")
    size = []
    for k, default in (("width", 640), ("height", 480)):
        v = d.get(k, default)
        if isinstance(v, bool) or not isinstance(v, int) or not 2 <= v <= 8192:
            raise r.error(f"{field}.{k}", f"expected a pixel count 2..8192, got {v!r}")
        size.append(v)
    fov = r.number(d.get("fov_deg", 60.0), f"{field}.fov_deg", 1.0, 179.0)
    return CameraMount(link=link, eye=eye, target=target, up=up, fov_deg=fov, width=size[0], height=size[1])


def _frames(r: _Reader, data: Any, bodies: tuple[str, ...]) -> tuple[tuple[str, NamedFrame], ...]:
    """``frames``: {NAME: {link, xyz, rpy}} or {NAME: LINK_OR_EARLIER_FRAME} (another name for it)."""
    out: dict[str, NamedFrame] = {}
    for name, v in r.mapping(data, "frames").items():
        field = f"frames.{name}"
        if not isinstance(name, str) or not name:
            raise r.error(field, f"{name!r}: a frame's name is text (the name poses are logged under)")
        if name in bodies:
            raise r.error(field, f"{name!r} is a link of the model already; a frame needs a name the model lacks")
        if isinstance(v, str):
            if v not in bodies and v not in out:
                raise r.error(field, f"{v!r} is neither a link of the model nor a frame above (links: {list(bodies)})")
            out[name] = out[v] if v in out else NamedFrame(link=v)
            continue
        d = r.mapping(v, field, {"link", "xyz", "rpy"})
        link = r.string(d.get("link"), f"{field}.link")
        if link not in bodies:
            raise r.error(f"{field}.link", f"{link!r} is not a link of the model (links: {list(bodies)})")
        xyz = r.offset(d.get("xyz", [0, 0, 0]), f"{field}.xyz", link, MAX_OFFSET_M)
        rpy = r.vector(d.get("rpy", [0, 0, 0]), f"{field}.rpy", 3)
        if max(abs(a) for a in rpy) > 2 * math.pi + 1e-9:
            raise r.error(f"{field}.rpy", f"{list(rpy)} exceeds 2 pi: the angles are radians")
        out[name] = NamedFrame(link=link, xyz=xyz, rpy=rpy)  # type: ignore[arg-type]
    return tuple(out.items())


def spec_from_dict(data: Any, source: str | os.PathLike | None = None) -> RobotSpec:
    """The :class:`RobotSpec` of a spec file's content ``data`` (see the module docstring); relative model paths
    resolve against ``source``'s folder. :class:`RobotSpecError` naming the field on any problem."""
    src = Path(source) if source is not None else None
    r = _Reader(str(src) if src is not None else "robot spec")
    d = r.mapping(data, "(top level)", TOP_KEYS)
    units = d.get("units", "m")
    if units not in ("m", "mm"):
        raise r.error("units", f"{units!r}: the spec's lengths are in m (the default) or mm")
    r.scale = 0.001 if units == "mm" else 1.0
    name = r.string(d.get("name"), "name")
    if not _NAME_RE.match(name):
        raise r.error("name", f"{name!r}: use letters, digits, '_' or '-', starting with a letter")
    robot_type = r.string(d.get("robot_type", name), "robot_type")
    path, arm_file = _model(r, d.get("model"), src.parent if src is not None else None, name)
    try:
        info = model_info(path)
        # a composed model is MJCF: an arm URDF's velocity limits are read from the URDF itself
        arm_info = model_info(arm_file) if arm_file is not None else None
    except ModelError as e:
        raise r.error("model", str(e)) from None

    def model_velocity(j: str) -> float | None:
        v = info.joint(j).velocity
        if v is None and arm_info is not None and arm_info.joint(j) is not None:
            v = arm_info.joint(j).velocity
        return v


    arm_d = r.mapping(d.get("arm"), "arm", {"joints", "home"})
    grip_keys = {"joints", "open", "closed", "state_names", "max_grasp_width", "pad_half_width", "min_grasp_height",
                 "force", "coupling"}  # fmt: skip
    grip_d = r.mapping(d.get("gripper"), "gripper", grip_keys)
    arm = r.names(arm_d.get("joints"), "arm.joints")
    if not grip_d.get("joints"):
        beyond = [j for j in info.joint_names if j not in arm]
        hint = (f" (the model's joints beyond the arm's: {beyond})" if beyond
                else " (the model has none beyond the arm's)")
        raise r.error("gripper.joints", f"missing{hint}; {NO_GRIPPER_HELP}")
    grip = r.names(grip_d.get("joints"), "gripper.joints")
    _joints(r, info, arm, grip)
    joints = (*arm, *grip)
    limits = _limits(r, info, joints)
    lim = np.asarray(limits)

    if "home" not in arm_d:
        raise r.error("arm.home", f"missing: the arm's rest pose, {len(arm)} joint values (rad)")
    home = r.vector(arm_d["home"], "arm.home", len(arm))
    for j, q, (lo, hi) in zip(arm, home, limits, strict=False):
        if not lo - 1e-9 <= q <= hi + 1e-9:
            raise r.error("arm.home", f"joint {j} = {q:g} is outside the model's limits [{lo:g}, {hi:g}]")
    opened = r.number(grip_d.get("open", float(lim[len(arm), 1])), "gripper.open")
    closed = r.number(grip_d.get("closed", float(lim[len(arm), 0])), "gripper.closed")
    for key, v in (("open", opened), ("closed", closed)):
        for j, (lo, hi) in zip(grip, lim[len(arm):], strict=True):
            if not lo - 1e-9 <= v <= hi + 1e-9:
                raise r.error(f"gripper.{key}", f"{v:g} is outside finger joint {j}'s limits [{lo:g}, {hi:g}]")
    if opened == closed:
        raise r.error("gripper", f"open and closed are both {opened:g}; the fingers must move between them")
    state_names = r.names(grip_d.get("state_names", list(grip)), "gripper.state_names")
    if len(state_names) != len(grip):
        raise r.error("gripper.state_names", f"{len(state_names)} names for the {len(grip)} finger joints")
    if set(state_names) & set(arm):
        raise r.error("gripper.state_names", "must differ from the arm's joint names")
    finger_links = tuple(dict.fromkeys(info.joint(j).body for j in grip))

    ee_d = r.mapping(d.get("end_effector"), "end_effector", {"link", "tcp", "approach", "closing", "tip_depth"})
    ee_link = r.string(ee_d.get("link"), "end_effector.link")
    if ee_link not in info.bodies:
        raise r.error("end_effector.link", f"{ee_link!r} is not a link of {path} (links: {list(info.bodies)})")
    for j in arm:
        if ee_link not in info.descendants(info.joint(j).body):
            raise r.error("end_effector.link", f"{ee_link!r} is not moved by arm joint {j}: give the link at the "
                                               "arm's end that the gripper hangs off")  # fmt: skip
    if ee_link in {info.joint(j).body for j in grip} or any(ee_link in info.descendants(f) for f in finger_links):
        raise r.error("end_effector.link", f"{ee_link!r} moves with the fingers; give the link they hang off")
    tcp = r.offset(ee_d.get("tcp", [0, 0, 0]), "end_effector.tcp", ee_link, MAX_OFFSET_M)
    approach = np.asarray(r.vector(ee_d.get("approach", [0, 0, 1]), "end_effector.approach", 3))
    closing = np.asarray(r.vector(ee_d.get("closing", [0, 1, 0]), "end_effector.closing", 3))
    if np.linalg.norm(approach) < 1e-6 or np.linalg.norm(closing) < 1e-6:
        raise r.error("end_effector", "approach and closing must be non-zero directions")
    approach, closing = approach / np.linalg.norm(approach), closing / np.linalg.norm(closing)
    if abs(approach @ closing) > 1e-3:
        raise r.error("end_effector", "approach and closing must be perpendicular")
    closing = closing - (closing @ approach) * approach
    closing /= np.linalg.norm(closing)
    tip_depth = r.length(ee_d.get("tip_depth", 0.0), "end_effector.tip_depth", 0.0, 0.5)

    opening = sum(abs(opened - closed) for j in grip if info.joint(j).kind == "slide")
    if "max_grasp_width" in grip_d:
        max_width = r.length(grip_d["max_grasp_width"], "gripper.max_grasp_width", 1e-3, 1.0)
    elif all(info.joint(j).kind == "slide" for j in grip):
        max_width = 0.9 * opening
    else:
        raise r.error("gripper.max_grasp_width", "missing: fingers that turn need the widest object they take (m)")
    pad = r.length(grip_d["pad_half_width"], "gripper.pad_half_width", 1e-4, 0.2) if "pad_half_width" in grip_d \
        else DEFAULTS["pad_half_width"]  # fmt: skip
    min_h = r.length(grip_d["min_grasp_height"], "gripper.min_grasp_height", 0.0, 0.5) if "min_grasp_height" in \
        grip_d else tip_depth + DEFAULTS["tip_clearance"]  # fmt: skip
    force = r.number(grip_d.get("force", DEFAULTS["grasp_force"]), "gripper.force", 1e-3, 1e4)
    coupling = r.number(grip_d.get("coupling", DEFAULTS["coupling"]), "gripper.coupling", 0.0, 1e7)

    provenance: dict[str, set[str]] = {}

    def pick(quantity: str, model_vals: dict, spec_vals: dict, default, first_spec: bool = False) -> tuple:
        out = []
        for j in joints if quantity in ("kp", "kv", "force_limit") else arm:
            m_v, s_v = model_vals.get(j), spec_vals.get(j)
            v, how = (s_v, "spec") if s_v is not None and (first_spec or m_v is None) else (m_v, "model")
            if v is None:
                v, how = default(j), "default"
            provenance.setdefault(quantity, set()).add(how)
            out.append(float(v))
        return tuple(out)

    ctrl = r.mapping(d.get("control"), "control", {"kp", "kv", "force_limit"})
    lims = r.mapping(d.get("limits"), "limits", {"velocity", "acceleration"})
    force_spec = r.per_joint(ctrl.get("force_limit"), "control.force_limit", joints)
    missing_force = [j for j in joints if info.joint(j).force is None and j not in force_spec]
    if missing_force:
        raise r.error("control.force_limit", f"the model gives no force limit for {missing_force}; give one per "
                                             "joint (N m for turning joints, N for sliding ones)")  # fmt: skip
    force_limit = pick("force_limit", {j: info.joint(j).force for j in joints}, force_spec, None, first_spec=True)
    fl = dict(zip(joints, force_limit, strict=True))
    kp = pick("kp", {j: info.joint(j).kp for j in joints}, r.per_joint(ctrl.get("kp"), "control.kp", joints),
              lambda j: DEFAULT_KP_PER_FORCE * fl[j], first_spec=True)  # fmt: skip
    kpd = dict(zip(joints, kp, strict=True))
    kv = pick("kv", {j: info.joint(j).kv for j in joints}, r.per_joint(ctrl.get("kv"), "control.kv", joints, lo=-1e-12),
              lambda j: DEFAULT_KV_PER_KP * kpd[j], first_spec=True)  # fmt: skip
    velocity = pick("velocity_limit", {j: model_velocity(j) for j in arm},
                    r.per_joint(lims.get("velocity"), "limits.velocity", arm),
                    lambda j: DEFAULT_VELOCITY[info.joint(j).kind])  # fmt: skip
    vel = dict(zip(arm, velocity, strict=True))
    acceleration = pick("acceleration_limit", {}, r.per_joint(lims.get("acceleration"), "limits.acceleration", arm),
                        lambda j: ACCELERATION_PER_VELOCITY * vel[j])  # fmt: skip

    cams_d = r.mapping(d.get("cameras"), "cameras")
    cameras = tuple((str(k), _camera(r, v, f"cameras.{k}", info.bodies)) for k, v in cams_d.items())
    frames = _frames(r, d.get("frames"), info.bodies)

    shoulder, reach, T_home = _kinematics(info, arm, ee_link, home, limits)
    axis = (T_home[:3, :3] @ closing)[:2]
    axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 1e-6 else np.array([0.0, 1.0])

    assets = _bundled_root()
    model_ref = str(path.relative_to(assets)) if assets is not None and path.is_relative_to(assets) else str(path)
    try:
        return RobotSpec(
            name=name, robot_type=robot_type, model=model_ref, arm_joints=arm, gripper_joints=grip,
            finger_links=finger_links, ee_link=ee_link, gripper_open=opened, gripper_closed=closed, home=home,
            joint_limits=limits, kp=kp, kv=kv, force_limit=force_limit, finger_coupling=coupling,
            velocity_limit=velocity, acceleration_limit=acceleration,
            shoulder=tuple(float(v) for v in shoulder), reach=reach,
            tcp_position=tcp, tcp_approach=tuple(approach.tolist()), tcp_closing=tuple(closing.tolist()),
            tip_depth=tip_depth, max_grasp_width=max_width, pad_half_width=pad, min_grasp_height=min_h,
            grasp_force=force, home_closing_axis=(float(axis[0]), float(axis[1])), cameras=cameras,
            finger_state_names=state_names, frames=frames, source=src,
            provenance=tuple((k, "+".join(sorted(v))) for k, v in provenance.items()),
        )  # fmt: skip
    except ValueError as e:
        raise r.error("(spec)", str(e)) from None


def _bundled_root() -> Path | None:
    a = genesis_assets_dir()
    return a.absolute() if a is not None else None


def load_robot_spec(path: str | os.PathLike) -> RobotSpec:
    """Read the robot spec file ``path`` (YAML, or JSON by its ``.json`` suffix)."""
    path = Path(path)
    if not path.is_file():
        raise RobotSpecError(f"robot spec file {path} not found")
    try:
        data = read_json(path, "robot spec") if path.suffix.lower() == ".json" else read_yaml(path, "robot spec")
    except InputError as e:
        raise RobotSpecError(str(e)) from None
    return spec_from_dict(data, path)
