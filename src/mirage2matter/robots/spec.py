"""What the rest of the package may know about a robot: one frozen :class:`RobotSpec` per robot.

Everything robot-specific (model file, joint names, home, PD gains, limits, gripper geometry, tool centre,
camera mounts, dataset names) lives in one spec, so the simulator, the planner, the scripted tasks, the
calibration tools and the dataset writer agree, and a second robot is one new spec file (``robots.specfile``
reads one, taking limits and reach from the model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import M2MError

__all__ = ["CameraMount", "NamedFrame", "RobotError", "RobotSpec", "RobotSpecError"]


@dataclass(frozen=True)
class CameraMount:
    """A camera rigidly fixed to a robot link, aimed by a look-at in the link's frame.

    link      the link the camera is fixed to
    eye       camera centre (m, link frame)
    target    a point on the optical axis (m, link frame)
    up        the link-frame direction that points up in the image
    fov_deg   vertical field of view of the default camera (degrees)
    width     default image width (px)
    height    default image height (px)
    """

    link: str
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float]
    fov_deg: float
    width: int
    height: int

    @property
    def T_link_cam(self) -> np.ndarray:
        """[4,4] camera pose in the link's frame (OpenCV axes)."""
        from ..geometry.camera import look_at_pose  # not at import: the command line imports robots, not torch

        return look_at_pose(eye=self.eye, target=self.target, up=self.up)


@dataclass(frozen=True)
class NamedFrame:
    """A frame fixed to a link of the model under a name the model does not have: what a controller or another
    description calls a pose (libfranka's end effector "EE", a flange, franka_ros's ``panda_hand_tcp``), so robot
    poses logged in it (hand-eye) resolve to a link.

    link  the model's link it is fixed to
    xyz   its origin in the link's frame (m)
    rpy   its rotation in the link's frame (rad; fixed axes x, y, z: R = Rz(yaw) Ry(pitch) Rx(roll), as URDF)
    """

    link: str
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def T_link_frame(self) -> np.ndarray:
        """[4,4] the frame's pose in the link's frame."""
        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", self.rpy).as_matrix()  # fixed axes, as hand-eye's rpy poses
        T[:3, 3] = self.xyz
        return T

    def describe(self) -> str:
        """E.g. "hand + 103.4 mm along z"."""
        moved = [f"{1000 * v:+.1f} mm along {a}" for a, v in zip("xyz", self.xyz, strict=True) if abs(v) > 5e-5]
        turned = [f"{math.degrees(v):+.1f} deg about {a}" for a, v in zip("xyz", self.rpy, strict=True)
                  if abs(v) > 1e-6]
        return self.link + (" " + ", ".join(moved + turned) if moved or turned else "")


@dataclass(frozen=True)
class RobotSpec:
    """One robot arm with a parallel gripper, base at the origin of the robot-base frame (z up, metres).

    name                identifier in world.yaml (``robot.name``) and :func:`~mirage2matter.robots.get_robot`
    robot_type          LeRobot's ``robot_type`` of datasets recorded with it
    model               the MJCF/URDF file (an absolute path, or one inside Genesis' bundled assets)
    arm_joints          the arm's joint names in the model, base to tip (the model's first dofs)
    gripper_joints      the finger joint names in the model (the dofs after the arm's)
    finger_links        the links the finger joints move (they may touch what the gripper holds)
    ee_link             the link the gripper hangs off (IK target, tool centre, wrist camera mount)
    gripper_open        finger joint value of the open gripper (m or rad per finger)
    gripper_closed      finger joint value of the closed gripper
    home                the arm's rest joints [n_arm] (rad)
    joint_limits        (lo, hi) of every joint [n_dofs] (from the model)
    kp                  PD position gains [n_dofs]
    kv                  PD velocity gains [n_dofs]
    force_limit         joint force / torque limits [n_dofs] (N, N m)
    finger_coupling     spring (N/m) on the difference of the finger joints while squeezing (0: none)
    velocity_limit      arm joint speed limits [n_arm] (rad/s)
    acceleration_limit  arm joint acceleration limits [n_arm] (rad/s^2)
    shoulder            xyz (m, base frame): the point of the first joint's axis nearest the second's
    reach               no joint configuration puts the ee link's origin farther than this (m) from the shoulder
    tcp_position        the tool centre (between the finger pads) in the ee link's frame (m)
    tcp_approach        the unit approach axis (towards the fingertips) in the ee link's frame
    tcp_closing         the unit axis the fingers close along in the ee link's frame (normal to the approach)
    tip_depth           how far (m) the fingertip ends reach beyond the tool centre along the approach
    max_grasp_width     widest object slab (m) the open fingers take, with margin
    pad_half_width      half the fingers' width (m) across the closing axis, with margin
    min_grasp_height    lowest tool-centre height (m) over the table for a top-down grasp (the fingertips clear it)
    grasp_force         squeezing force (N per finger) while holding
    home_closing_axis   xy direction (base frame) of the fingers' closing axis at home: top-down grasps with
                        the closing axis near it need the least wrist rotation (see ``home_closing_yaw``)
    cameras             (name, mount) of the cameras on the robot ("wrist": the default hand camera)
    frames              (name, frame) of frames fixed to the model's links under other names (a controller's
                        end-effector frame), for robot poses logged in them
    finger_state_names  names of the finger entries of ``observation.state``
    source              the spec file it was read from (None: made in code)
    provenance          (quantity, where its values came from: "model", "spec" or "default") for the limits and
                        gains, so a user can see which numbers their model gave
    """

    name: str
    robot_type: str
    model: str
    arm_joints: tuple[str, ...]
    gripper_joints: tuple[str, ...]
    finger_links: tuple[str, ...]
    ee_link: str
    gripper_open: float
    gripper_closed: float
    home: tuple[float, ...]
    joint_limits: tuple[tuple[float, float], ...]
    kp: tuple[float, ...]
    kv: tuple[float, ...]
    force_limit: tuple[float, ...]
    finger_coupling: float
    velocity_limit: tuple[float, ...]
    acceleration_limit: tuple[float, ...]
    shoulder: tuple[float, float, float]
    reach: float
    tcp_position: tuple[float, float, float]
    tcp_approach: tuple[float, float, float]
    tcp_closing: tuple[float, float, float]
    tip_depth: float
    max_grasp_width: float
    pad_half_width: float
    min_grasp_height: float
    grasp_force: float
    home_closing_axis: tuple[float, float]
    cameras: tuple[tuple[str, CameraMount], ...]
    finger_state_names: tuple[str, ...]
    frames: tuple[tuple[str, NamedFrame], ...] = ()
    source: Path | None = None
    provenance: tuple[tuple[str, str], ...] = field(default=(), compare=False)

    def __post_init__(self) -> None:
        n_arm, n_all = len(self.arm_joints), len(self.arm_joints) + len(self.gripper_joints)
        sizes = {"home": (self.home, n_arm), "velocity_limit": (self.velocity_limit, n_arm),
                 "acceleration_limit": (self.acceleration_limit, n_arm), "kp": (self.kp, n_all),
                 "kv": (self.kv, n_all), "force_limit": (self.force_limit, n_all),
                 "joint_limits": (self.joint_limits, n_all),
                 "finger_state_names": (self.finger_state_names, len(self.gripper_joints))}  # fmt: skip
        wrong = [f"{k} has {len(v)} values, expected {n}" for k, (v, n) in sizes.items() if len(v) != n]
        if wrong:
            raise ValueError(f"robot {self.name!r}: " + "; ".join(wrong))
        a, c = np.asarray(self.tcp_approach, np.float64), np.asarray(self.tcp_closing, np.float64)
        if abs(np.linalg.norm(a) - 1) > 1e-6 or abs(np.linalg.norm(c) - 1) > 1e-6 or abs(a @ c) > 1e-6:
            raise ValueError(f"robot {self.name!r}: tcp_approach and tcp_closing must be orthogonal unit vectors")

    @property
    def n_arm(self) -> int:
        """Arm joints (the first dofs of the model)."""
        return len(self.arm_joints)

    @property
    def n_dofs(self) -> int:
        """Arm + finger joints."""
        return len(self.arm_joints) + len(self.gripper_joints)

    @property
    def T_ee_tcp(self) -> np.ndarray:
        """[4,4] the tool frame in the ee link's frame: origin at the tool centre, z = approach, y = closing."""
        z, y = np.asarray(self.tcp_approach, np.float64), np.asarray(self.tcp_closing, np.float64)
        T = np.eye(4)
        T[:3, :3] = np.stack([np.cross(y, z), y, z], axis=1)
        T[:3, 3] = self.tcp_position
        return T

    @property
    def home_closing_yaw(self) -> float:
        """Yaw (rad, base frame) of ``home_closing_axis``."""
        return math.atan2(self.home_closing_axis[1], self.home_closing_axis[0])

    def camera_mount(self, name: str) -> CameraMount:
        """The mount of the robot's camera ``name``; KeyError naming the robot's cameras otherwise."""
        for n, m in self.cameras:
            if n == name:
                return m
        have = [n for n, _ in self.cameras]
        raise KeyError(f"robot {self.name!r} has no {name!r} camera mount (its cameras: {have}); add cameras.{name} "
                       "to its spec file")  # fmt: skip

    def frame(self, name: str) -> NamedFrame | None:
        """The named frame ``name`` (None: the spec names no such frame; it may still be a link of the model)."""
        return dict(self.frames).get(name)

    @property
    def wrist_camera(self) -> CameraMount:
        """The default camera on the hand (wrist view)."""
        return self.camera_mount("wrist")

    @property
    def state_names(self) -> tuple[str, ...]:
        """``observation.state``: the arm joints (rad) then the fingers."""
        return (*self.arm_joints, *self.finger_state_names)

    @property
    def action_names(self) -> tuple[str, ...]:
        """``action``: the arm joint targets then one gripper target (per finger)."""
        return (*self.arm_joints, "gripper")

    def home_q(self, gripper: float | None = None) -> np.ndarray:
        """[n_dofs] the home arm joints with every finger at ``gripper`` (default: open)."""
        g = self.gripper_open if gripper is None else gripper
        return np.concatenate([np.asarray(self.home, dtype=np.float64), [g] * len(self.gripper_joints)])

    def limits_array(self) -> np.ndarray:
        """[n_dofs, 2] :attr:`joint_limits` as an array."""
        return np.asarray(self.joint_limits, dtype=np.float64).reshape(-1, 2)


class RobotError(M2MError, ValueError):
    """An unknown robot name; the message lists the known robots."""


class RobotSpecError(RobotError):
    """A robot spec file (or its model) that cannot describe a robot: the message names the file, the field and
    what to do."""
