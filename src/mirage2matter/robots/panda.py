"""The Franka Emika Panda with its parallel gripper, as Genesis bundles it (MJCF, menagerie model)."""

from __future__ import annotations

from .spec import CameraMount, RobotSpec

__all__ = ["PANDA"]

PANDA = RobotSpec(
    name="panda",
    robot_type="franka_panda",
    model="xml/franka_emika_panda/panda.xml",
    arm_joints=tuple(f"joint{i}" for i in range(1, 8)),
    gripper_joints=("finger_joint1", "finger_joint2"),
    finger_links=("left_finger", "right_finger"),
    ee_link="hand",
    gripper_open=0.04,  # finger joint range 0..0.04 m per finger: an 8 cm opening
    gripper_closed=0.0,
    home=(0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785),  # the usual "ready" pose, hand pointing down
    # Genesis' Franka examples, fingers 10x stiffer: with kp 100 a closing pair lags, touches one side first and
    # rolls a round object away. The fingers are force-controlled when squeezing.
    kp=(4500, 4500, 3500, 3500, 2000, 2000, 2000, 1000, 1000),
    kv=(450, 450, 350, 350, 200, 200, 200, 40, 40),
    force_limit=(87, 87, 87, 87, 12, 12, 12, 100, 100),
    # The real fingers are geared together; Genesis loads two independent joints. A spring on their difference
    # couples them, so the first finger to touch pushes the object to the middle instead of the pair squeezing
    # it out sideways.
    finger_coupling=3000.0,
    velocity_limit=(2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61),  # datasheet; trajectories use a fraction
    acceleration_limit=(15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0),
    shoulder=(0.0, 0.0, 0.333),
    reach=0.316 + 0.384 + 0.088 + 0.107 + 0.11,  # link lengths from the shoulder + hand to the finger pads
    tcp_offset=0.1034,  # hand frame: the point between the finger pads along the approach axis
    tip_offset=0.1123,  # the fingertip ends (closed or open)
    max_grasp_width=0.072,  # the 8 cm opening with margin
    pad_half_width=0.012,
    min_grasp_height=0.012,  # fingertips (tip - tcp offset = 8.9 mm below the TCP) ~3 mm over the table
    grasp_force=20.0,
    home_closing_axis=(0.0, -1.0),  # at home the hand frame's closing axis (y) points along base -y
    # 7 cm off the approach axis, behind the fingers, looking at the point between the fingertips 14 cm ahead
    # (hand frame: z = approach, fingers close along y).
    wrist_camera=CameraMount(
        link="hand",
        eye=(0.07, 0.0, 0.0),
        target=(0.0, 0.0, 0.14),
        up=(1.0, 0.0, 0.0),
        fov_deg=70.0,
        width=640,
        height=480,
    ),
    finger_state_names=("finger_left", "finger_right"),
)
