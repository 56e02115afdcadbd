"""Robot specs against their models (MuJoCo loads the MJCF in well under a second; no Genesis scene), the
registry, and the places that take a robot from its spec (world.yaml, the wrist camera, the dataset spec)."""

from __future__ import annotations

import numpy as np
import pytest

from mirage2matter.errors import M2MError
from mirage2matter.robots import DEFAULT_ROBOT, ROBOTS, RobotError, RobotSpec, get_robot


@pytest.fixture(scope="module", params=sorted(ROBOTS))
def robot(request) -> RobotSpec:
    return get_robot(request.param)


@pytest.fixture(scope="module")
def model(robot):
    mujoco = pytest.importorskip("mujoco")
    from mirage2matter.calib.kinematics import resolve_robot_path

    try:
        path = resolve_robot_path(robot.model)
    except FileNotFoundError:
        pytest.skip(f"{robot.model} is not installed (Genesis' bundled assets)")
    return mujoco.MjModel.from_xml_path(str(path))


def _joint(model, name: str) -> int:
    return model.joint(name).id


def test_registry_and_unknown_robot():
    assert DEFAULT_ROBOT in ROBOTS and get_robot(DEFAULT_ROBOT).name == DEFAULT_ROBOT
    with pytest.raises(RobotError, match=r"unknown robot 'ur42'; known robots: .*" + DEFAULT_ROBOT) as e:
        get_robot("ur42")
    assert isinstance(e.value, M2MError)


def test_names_and_sizes(robot):
    n_arm, n_grip = len(robot.arm_joints), len(robot.gripper_joints)
    assert robot.n_arm == n_arm and robot.n_dofs == n_arm + n_grip
    assert len(robot.state_names) == n_arm + n_grip and len(set(robot.state_names)) == n_arm + n_grip
    assert len(robot.action_names) == n_arm + 1 and robot.action_names[:n_arm] == robot.state_names[:n_arm]
    for values in (robot.kp, robot.kv, robot.force_limit):
        assert len(values) == n_arm + n_grip and min(values) > 0
    assert len(robot.home) == len(robot.velocity_limit) == len(robot.acceleration_limit) == n_arm
    assert min(robot.velocity_limit) > 0 and min(robot.acceleration_limit) > 0
    assert 0 < robot.tcp_offset < robot.tip_offset and robot.max_grasp_width < 2 * robot.gripper_open
    assert robot.home_q().shape == (robot.n_dofs,) and robot.home_q()[-1] == robot.gripper_open
    with pytest.raises(ValueError, match="home has 2 values"):
        RobotSpec(**{**robot.__dict__, "home": (0.0, 0.0)})


def test_spec_agrees_with_the_model(robot, model):
    """Joints exist in the model in dof order, home and gripper lie in their ranges, gains and force limits
    are the model's actuators' (where it has position actuators on the arm joints)."""
    names = [model.joint(i).name for i in range(model.njnt)]
    joints = (*robot.arm_joints, *robot.gripper_joints)
    assert [model.jnt_qposadr[_joint(model, j)] for j in joints] == list(range(robot.n_dofs)), names
    for j, q in zip(robot.arm_joints, robot.home, strict=True):
        lo, hi = model.jnt_range[_joint(model, j)]
        assert lo <= q <= hi, (j, q, lo, hi)
    for j in robot.gripper_joints:
        lo, hi = model.jnt_range[_joint(model, j)]
        assert (robot.gripper_closed, robot.gripper_open) == pytest.approx((lo, hi)), j
    bodies = {model.body(i).name for i in range(model.nbody)}
    assert {robot.ee_link, robot.wrist_camera.link, *robot.finger_links} <= bodies
    for a in range(model.nu):
        if model.actuator_trntype[a] != 0:  # tendon-driven (the coupled fingers)
            continue
        j = names[model.actuator_trnid[a][0]]
        if j in robot.arm_joints:
            i = robot.arm_joints.index(j)
            assert robot.kp[i] == pytest.approx(model.actuator_gainprm[a][0]), j
            assert robot.kv[i] == pytest.approx(-model.actuator_biasprm[a][2]), j
            assert robot.force_limit[i] == pytest.approx(model.actuator_forcerange[a][1]), j


def test_reach_and_shoulder_bound_the_kinematics(robot, model):
    """No joint configuration puts the TCP farther from the shoulder than ``reach``; the shoulder is where the
    second joint's axis sits, whatever the first joint does."""
    from mirage2matter.calib.kinematics import RobotKinematics, resolve_robot_path

    kin = RobotKinematics(resolve_robot_path(robot.model))
    rng = np.random.default_rng(0)
    lo, hi = model.jnt_range[: robot.n_arm].T
    far = 0.0
    for _ in range(300):
        q = rng.uniform(lo, hi)
        T = kin.link_pose(q, robot.ee_link)
        tcp = T[:3, 3] + robot.tcp_offset * T[:3, 2]
        far = max(far, float(np.linalg.norm(tcp - robot.shoulder)))
        j2 = model.body(model.jnt_bodyid[_joint(model, robot.arm_joints[1])]).name
        assert np.allclose(kin.link_pose(q, j2)[:3, 3], robot.shoulder, atol=1e-9)
    assert 0.7 * robot.reach < far <= robot.reach


def test_home_points_the_gripper_down_with_the_closing_axis_as_specified(robot):
    from mirage2matter.calib.kinematics import RobotKinematics

    try:
        T = RobotKinematics(robot.model).link_pose(np.asarray(robot.home), robot.ee_link)
    except FileNotFoundError:
        pytest.skip(f"{robot.model} is not installed")
    assert T[:3, 2] @ [0, 0, -1] > 0.999  # approach axis straight down
    axis = np.array([*robot.home_closing_axis, 0.0])
    assert T[:3, 1] @ axis > 0.999


def test_world_robot_defaults_from_the_spec(tmp_path):
    from mirage2matter.world.config import RobotConfig, WorldConfig, WorldConfigError

    spec = get_robot(DEFAULT_ROBOT)
    r = RobotConfig()
    assert (r.name, r.file, r.ee_link, r.home) == (spec.name, spec.model, spec.ee_link, spec.home)
    assert r.spec is spec
    # A world.yaml written before robots had names: file / ee_link / home only.
    old = WorldConfig.from_dict({"robot": {"file": spec.model, "ee_link": spec.ee_link, "home": [0.1] * 7}}, tmp_path)
    assert old.robot.name == DEFAULT_ROBOT and old.robot.home == (0.1,) * 7
    assert WorldConfig.from_dict({}, tmp_path).robot == r
    d = old.to_dict()["robot"]
    assert d["name"] == DEFAULT_ROBOT and WorldConfig.from_dict({"robot": d}, tmp_path).robot == old.robot
    with pytest.raises(WorldConfigError, match="robot.name: unknown robot 'ur42'"):
        WorldConfig.from_dict({"robot": {"name": "ur42"}}, tmp_path)


def test_wrist_camera_and_dataset_names_come_from_the_spec(tmp_path):
    from mirage2matter.datagen.sim_source import SimSourceConfig
    from mirage2matter.sim.tasks import GraspTask
    from mirage2matter.world.config import WorldConfig
    from mirage2matter.world.sample import default_wrist_camera

    spec = get_robot(DEFAULT_ROBOT)
    cam = default_wrist_camera()
    m = spec.wrist_camera
    assert cam.mount == m.link == spec.ee_link and (cam.width, cam.height) == (m.width, m.height)
    assert np.allclose(cam.T_mount_cam, m.T_link_cam)
    assert cam.K[1, 1] == pytest.approx(0.5 * m.height / np.tan(np.radians(0.5 * m.fov_deg)))
    ds = SimSourceConfig(world=WorldConfig(root=tmp_path), task=GraspTask("banana")).spec()
    assert ds.state_names == spec.state_names and ds.action_names == spec.action_names
    assert ds.robot_type == spec.robot_type


def test_world_validation_checks_the_model_against_the_spec(tmp_path):
    """A model lacking the named robot's joints, or a home of the wrong length, is refused before any
    simulator is built."""
    from mirage2matter.calib.kinematics import resolve_robot_path
    from mirage2matter.world.config import RobotConfig, WorldConfig, WorldConfigError
    from mirage2matter.world.validate import validate_world

    spec = get_robot(DEFAULT_ROBOT)
    hand_only = resolve_robot_path(spec.model).parent / "hand.xml"  # the Panda's gripper without its arm
    if not hand_only.is_file():
        pytest.skip(f"{hand_only} is not installed")
    validate_world(WorldConfig(root=tmp_path))
    with pytest.raises(WorldConfigError, match=r"lacks the joints \['joint1'"):
        validate_world(WorldConfig(root=tmp_path, robot=RobotConfig(file=str(hand_only))))
    with pytest.raises(WorldConfigError, match=r"robot\.home: 3 joint value\(s\) for the robot.s 7 joints"):
        validate_world(WorldConfig(root=tmp_path, robot=RobotConfig(home=(0.0, 0.0, 0.0))))
