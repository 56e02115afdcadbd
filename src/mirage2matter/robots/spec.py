"""What the rest of the package may know about a robot: one frozen :class:`RobotSpec` per robot.

Everything robot-specific (model file, joint names, home, PD gains, limits, gripper geometry, camera
mounts, dataset names) lives in one spec, so the simulator, the planner, the scripted tasks, the
calibration tools and the dataset writer agree, and a second robot is one new spec.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geometry.camera import look_at_pose

__all__ = ["CameraMount", "RobotSpec"]


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
        return look_at_pose(eye=self.eye, target=self.target, up=self.up)


@dataclass(frozen=True)
class RobotSpec:
    """One robot arm with a parallel gripper, base at the origin of the robot-base frame (z up, metres).

    name                identifier in world.yaml (``robot.name``) and :func:`~mirage2matter.robots.get_robot`
    robot_type          LeRobot's ``robot_type`` of datasets recorded with it
    model               MJCF/URDF file: a path, or one inside Genesis' bundled assets
    arm_joints          the arm's joint names in the model, base to tip (the first dofs)
    gripper_joints      the finger joint names in the model (the dofs after the arm's)
    finger_links        the finger link names (they may touch what the gripper holds)
    ee_link             the link the gripper hangs off (IK target, wrist camera mount)
    gripper_open        finger joint value of the open gripper (m per finger)
    gripper_closed      finger joint value of the closed gripper (m per finger)
    home                the arm's rest joints [n_arm] (rad)
    kp                  PD position gains [n_arm + n_gripper]
    kv                  PD velocity gains [n_arm + n_gripper]
    force_limit         joint force / torque limits [n_arm + n_gripper] (N, N m)
    finger_coupling     spring (N/m) on the difference of the finger joints while squeezing
    velocity_limit      arm joint speed limits [n_arm] (rad/s)
    acceleration_limit  arm joint acceleration limits [n_arm] (rad/s^2)
    shoulder            xyz (m, base frame) of the first joint axis' intersection with the second
    reach               distance (m) from the shoulder beyond which no hand pose is reachable
    tcp_offset          distance (m) along the ee link's approach axis (z) to the point between the finger pads
    tip_offset          distance (m) along the approach axis to the fingertip ends
    max_grasp_width     widest object slab (m) the open fingers take, with margin
    pad_half_width      half the fingers' width (m) across the closing axis, with margin
    min_grasp_height    lowest TCP height (m) over the table for a top-down grasp (the fingertips clear it)
    grasp_force         squeezing force (N per finger) while holding
    home_closing_axis   xy direction (base frame) of the fingers' closing axis at home: top-down grasps with
                        the closing axis near it need the least wrist rotation (see ``home_closing_yaw``)
    wrist_camera        the default camera on the hand (wrist view)
    finger_state_names  names of the finger entries of ``observation.state``
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
    kp: tuple[float, ...]
    kv: tuple[float, ...]
    force_limit: tuple[float, ...]
    finger_coupling: float
    velocity_limit: tuple[float, ...]
    acceleration_limit: tuple[float, ...]
    shoulder: tuple[float, float, float]
    reach: float
    tcp_offset: float
    tip_offset: float
    max_grasp_width: float
    pad_half_width: float
    min_grasp_height: float
    grasp_force: float
    home_closing_axis: tuple[float, float]
    wrist_camera: CameraMount
    finger_state_names: tuple[str, ...]

    def __post_init__(self) -> None:
        n_arm, n_all = len(self.arm_joints), len(self.arm_joints) + len(self.gripper_joints)
        sizes = {"home": (self.home, n_arm), "velocity_limit": (self.velocity_limit, n_arm),
                 "acceleration_limit": (self.acceleration_limit, n_arm), "kp": (self.kp, n_all),
                 "kv": (self.kv, n_all), "force_limit": (self.force_limit, n_all),
                 "finger_state_names": (self.finger_state_names, len(self.gripper_joints))}  # fmt: skip
        wrong = [f"{k} has {len(v)} values, expected {n}" for k, (v, n) in sizes.items() if len(v) != n]
        if wrong:
            raise ValueError(f"robot {self.name!r}: " + "; ".join(wrong))

    @property
    def n_arm(self) -> int:
        """Arm joints (the first dofs of the model)."""
        return len(self.arm_joints)

    @property
    def n_dofs(self) -> int:
        """Arm + finger joints."""
        return len(self.arm_joints) + len(self.gripper_joints)

    @property
    def home_closing_yaw(self) -> float:
        """Yaw (rad, base frame) of ``home_closing_axis``."""
        return math.atan2(self.home_closing_axis[1], self.home_closing_axis[0])

    @property
    def state_names(self) -> tuple[str, ...]:
        """``observation.state``: the arm joints (rad) then the fingers (m)."""
        return (*self.arm_joints, *self.finger_state_names)

    @property
    def action_names(self) -> tuple[str, ...]:
        """``action``: the arm joint targets then one gripper target (m per finger)."""
        return (*self.arm_joints, "gripper")

    def home_q(self, gripper: float | None = None) -> np.ndarray:
        """[n_dofs] the home arm joints with every finger at ``gripper`` (default: open)."""
        g = self.gripper_open if gripper is None else gripper
        return np.concatenate([np.asarray(self.home, dtype=np.float64), [g] * len(self.gripper_joints)])
