"""Robot specs against their models (MuJoCo reads a model in well under a second; no Genesis scene), the
registry, the spec files (a user's own robot: URDF, a composed arm + gripper, every refusal naming the file and
the field), and the places that take a robot from its spec (world.yaml, the wrist camera, the dataset spec)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from mirage2matter.errors import M2MError
from mirage2matter.robots import DEFAULT_ROBOT, ROBOTS, RobotError, RobotSpecError, get_robot
from mirage2matter.robots.model import genesis_assets_dir, load_model, model_info, resolve_model
from mirage2matter.robots.specfile import ACCELERATION_PER_VELOCITY, DEFAULT_KP_PER_FORCE, DEFAULT_VELOCITY

mujoco = pytest.importorskip("mujoco")
ASSETS = genesis_assets_dir()
needs_assets = pytest.mark.skipif(ASSETS is None or not (ASSETS / "xml").is_dir(), reason="no Genesis assets")
pytestmark = needs_assets


@pytest.fixture(scope="module", params=sorted(ROBOTS))
def robot(request):
    return get_robot(request.param)


@pytest.fixture(scope="module")
def model(robot):
    return load_model(resolve_model(robot.model))


def test_registry_and_unknown_robot():
    assert {"panda", "ur5e"} <= set(ROBOTS) and get_robot(DEFAULT_ROBOT).name == DEFAULT_ROBOT
    assert get_robot("ur5e") is get_robot("ur5e")  # read once
    with pytest.raises(RobotError, match=r"unknown robot 'ur42'; known robots: panda, ur5e") as e:
        get_robot("ur42")
    assert isinstance(e.value, M2MError)
    with pytest.raises(RobotSpecError, match=r"robot spec file nowhere/arm\.yaml not found"):
        get_robot("nowhere/arm.yaml")


def test_names_and_sizes(robot):
    n_arm, n_grip = len(robot.arm_joints), len(robot.gripper_joints)
    assert robot.n_arm == n_arm and robot.n_dofs == n_arm + n_grip
    assert len(robot.state_names) == n_arm + n_grip and len(set(robot.state_names)) == n_arm + n_grip
    assert len(robot.action_names) == n_arm + 1 and robot.action_names[:n_arm] == robot.state_names[:n_arm]
    for values in (robot.kp, robot.kv, robot.force_limit):
        assert len(values) == n_arm + n_grip and min(values) > 0
    assert len(robot.home) == len(robot.velocity_limit) == len(robot.acceleration_limit) == n_arm
    assert min(robot.velocity_limit) > 0 and min(robot.acceleration_limit) > 0
    assert robot.T_ee_tcp[2, 3] > 0 and robot.tip_depth > 0 and robot.max_grasp_width < 2 * robot.gripper_open
    assert np.allclose(robot.T_ee_tcp[:3, :3].T @ robot.T_ee_tcp[:3, :3], np.eye(3))
    assert robot.home_q().shape == (robot.n_dofs,) and robot.home_q()[-1] == robot.gripper_open


def test_spec_agrees_with_the_model(robot, model):
    """Joints in the model's dof order, limits the model's, home and gripper within them, the finger links the
    ones the finger joints move; arm gains and force limits the model's position actuators'."""
    names = [model.joint(i).name for i in range(model.njnt)]
    assert names == [*robot.arm_joints, *robot.gripper_joints]
    for k, j in enumerate(names):
        jid = model.joint(j).id
        assert model.jnt_qposadr[jid] == k
        assert robot.joint_limits[k] == pytest.approx(tuple(model.jnt_range[jid])), j
    lo, hi = robot.limits_array().T
    assert np.all(lo[: robot.n_arm] <= robot.home) and np.all(np.asarray(robot.home) <= hi[: robot.n_arm])
    for j in robot.gripper_joints:
        assert (robot.gripper_closed, robot.gripper_open) == pytest.approx(tuple(model.jnt_range[model.joint(j).id]))
    assert robot.finger_links == tuple(model.body(model.jnt_bodyid[model.joint(j).id]).name
                                       for j in robot.gripper_joints)  # fmt: skip
    bodies = {model.body(i).name for i in range(model.nbody)}
    assert {robot.ee_link, robot.wrist_camera.link, *robot.finger_links} <= bodies
    for a in range(model.nu):
        if model.actuator_trntype[a] != 0:  # tendon-driven (the coupled fingers)
            continue
        i = robot.arm_joints.index(names[model.actuator_trnid[a][0]])
        assert robot.kp[i] == pytest.approx(model.actuator_gainprm[a][0])
        assert robot.kv[i] == pytest.approx(-model.actuator_biasprm[a][2])
        assert robot.force_limit[i] == pytest.approx(model.actuator_forcerange[a][1])
    assert dict(robot.provenance)["kp"] == "model+spec"  # the arm's from the model, the fingers' from the spec


def test_reach_and_shoulder_bound_the_kinematics(robot, model):
    """No joint configuration puts the ee link farther from the shoulder than ``reach`` (and some come within 75 %
    of it); the shoulder lies on the first joint's axis at a fixed distance from the second's, whatever the
    joints do."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    lo, hi = robot.limits_array()[: robot.n_arm].T
    shoulder = np.asarray(robot.shoulder)
    j1, j2 = (model.joint(robot.arm_joints[k]).id for k in (0, 1))
    far, gaps = 0.0, []
    for _ in range(400):
        data.qpos[: robot.n_arm] = rng.uniform(lo, hi)
        mujoco.mj_kinematics(model, data)
        far = max(far, float(np.linalg.norm(data.xpos[model.body(robot.ee_link).id] - shoulder)))
        a1, p1 = data.xaxis[j1], data.xanchor[j1]
        assert np.linalg.norm(np.cross(shoulder - p1, a1)) < 1e-9  # on axis 1
        a2, p2 = data.xaxis[j2], data.xanchor[j2]
        gaps.append(np.linalg.norm(np.cross(shoulder - p2, a2)))  # distance to axis 2
    assert np.ptp(gaps) < 1e-9
    assert 0.75 * robot.reach < far <= robot.reach


def test_home_points_the_gripper_down_with_the_closing_axis_as_specified(robot):
    from mirage2matter.robots.kinematics import RobotKinematics

    kin = RobotKinematics(robot.name)  # a robot name: its model, its end-effector link by default
    T = kin.link_pose(np.asarray(robot.home)) @ robot.T_ee_tcp
    assert np.allclose(T, RobotKinematics(robot.model).link_pose(np.asarray(robot.home), robot.ee_link)
                       @ robot.T_ee_tcp)  # fmt: skip
    assert T[:3, 2] @ [0, 0, -1] > 0.999  # the tool's approach axis straight down
    assert T[:3, 1] @ np.array([*robot.home_closing_axis, 0.0]) > 0.999
    assert 0.3 < np.linalg.norm(T[:2, 3]) < robot.reach  # ahead of the base, over the table


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
    # The UR5e's composed model lives in the robot cache: world.yaml names the robot, not the generated file.
    ur = WorldConfig.from_dict({"robot": {"name": "ur5e"}}, tmp_path)
    assert ur.robot.file == get_robot("ur5e").model and "file" not in ur.to_dict()["robot"]
    assert WorldConfig.from_dict(ur.to_dict(), tmp_path).robot == ur.robot


@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_wrist_camera_and_dataset_names_come_from_the_spec(tmp_path, name):
    from mirage2matter.datagen.sim_source import SimSourceConfig
    from mirage2matter.sim.tasks import GraspTask
    from mirage2matter.world.config import RobotConfig, WorldConfig
    from mirage2matter.world.sample import default_wrist_camera

    spec = get_robot(name)
    cam = default_wrist_camera(robot=spec)
    m = spec.wrist_camera
    assert cam.mount == m.link == spec.ee_link and (cam.width, cam.height) == (m.width, m.height)
    assert np.allclose(cam.T_mount_cam, m.T_link_cam)
    assert cam.K[1, 1] == pytest.approx(0.5 * m.height / np.tan(np.radians(0.5 * m.fov_deg)))
    world = WorldConfig(root=tmp_path, robot=RobotConfig(name=name))
    ds = SimSourceConfig(world=world, task=GraspTask("banana")).spec()
    assert ds.state_names == spec.state_names and ds.action_names == spec.action_names
    assert ds.robot_type == spec.robot_type
    assert len(ds.state_names) == spec.n_dofs and ds.action_names[-1] == "gripper"


def test_world_validation_checks_the_model_against_the_spec(tmp_path):
    """A model lacking the named robot's joints, or a home of the wrong length, is refused before any
    simulator is built."""
    from mirage2matter.world.config import RobotConfig, WorldConfig, WorldConfigError
    from mirage2matter.world.validate import validate_world

    spec = get_robot(DEFAULT_ROBOT)
    hand_only = resolve_model(spec.model).parent / "hand.xml"  # the Panda's gripper without its arm
    validate_world(WorldConfig(root=tmp_path))
    with pytest.raises(WorldConfigError, match=r"lacks the joints \['joint1'"):
        validate_world(WorldConfig(root=tmp_path, robot=RobotConfig(file=str(hand_only))))
    with pytest.raises(WorldConfigError, match=r"robot\.home: 3 joint value\(s\) for the robot.s 7 joints"):
        validate_world(WorldConfig(root=tmp_path, robot=RobotConfig(home=(0.0, 0.0, 0.0))))
    # the UR5e's model under the Panda's name
    with pytest.raises(WorldConfigError, match=r"lacks the joints"):
        validate_world(WorldConfig(root=tmp_path, robot=RobotConfig(file=get_robot("ur5e").model)))


# ---- a user's own robot: spec files ------------------------------------------------------------------------
PANDA_URDF = "urdf/panda_bullet/panda.urdf"


def _urdf_spec(**changes) -> dict:
    """Genesis' bundled Panda URDF (pybullet's: it has velocity limits and efforts, no gains) as a user's spec."""
    spec = {
        "name": "panda_urdf",
        "model": PANDA_URDF,
        "arm": {"joints": [f"panda_joint{i}" for i in range(1, 8)], "home": [0, -0.785, 0, -2.356, 0, 1.571, 0.785]},
        "gripper": {"joints": ["panda_finger_joint1", "panda_finger_joint2"]},
        "end_effector": {"link": "panda_hand", "tcp": [0, 0, 0.1034], "tip_depth": 0.0089},
        "cameras": {"wrist": {"link": "panda_hand", "eye": [0.07, 0, 0], "target": [0, 0, 0.14], "up": [1, 0, 0]}},
    }
    for key, value in changes.items():
        section, _, field = key.partition("__")
        if field:
            spec[section] = {**spec[section], field: value}
        elif value is None:
            spec.pop(section)
        else:
            spec[section] = value
    return spec


def _write(tmp_path: Path, spec: dict, name: str = "robot.yaml") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(spec) if name.endswith(".json") else yaml.safe_dump(spec))
    return path


def test_a_urdf_robot_reads_its_limits_from_the_model(tmp_path):
    """Velocity limits and efforts from the URDF's <limit>, the rest documented defaults; a fixed link (the hand)
    is kept as a link; the spec loads from YAML and from JSON alike."""
    path = _write(tmp_path, _urdf_spec())
    spec = get_robot(str(path))
    assert spec.name == "panda_urdf" and spec.robot_type == "panda_urdf" and spec.source == path.resolve()
    assert spec.velocity_limit == (2.175,) * 4 + (2.61,) * 3  # the URDF's
    assert spec.acceleration_limit == pytest.approx([ACCELERATION_PER_VELOCITY * v for v in spec.velocity_limit])
    assert spec.force_limit == (87.0,) * 4 + (12.0,) * 3 + (20.0, 20.0)  # URDF effort
    assert spec.kp == pytest.approx([DEFAULT_KP_PER_FORCE * f for f in spec.force_limit])
    assert dict(spec.provenance) == {"velocity_limit": "model", "acceleration_limit": "default",
                                     "force_limit": "model", "kp": "default", "kv": "default"}  # fmt: skip
    assert spec.joint_limits[3] == pytest.approx((-3.1416, 0.0)) and spec.joint_limits[7] == pytest.approx((0, 0.04))
    assert (spec.gripper_open, spec.gripper_closed) == (0.04, 0.0)  # the finger range's ends
    assert spec.finger_state_names == ("panda_finger_joint1", "panda_finger_joint2")
    assert spec.finger_links == ("panda_leftfinger", "panda_rightfinger")
    assert spec.max_grasp_width == pytest.approx(0.072)
    assert spec.shoulder == pytest.approx((0, 0, 0.333))
    assert spec.reach == pytest.approx(get_robot("panda").reach, abs=1e-5)  # the same arm as the MJCF
    # the spec gives speeds the model has: the model's win (the spec's fill only what a model lacks)
    faster = get_robot(str(_write(tmp_path, _urdf_spec(limits={"velocity": [9.0] * 7}), "faster.yaml")))
    assert faster.velocity_limit == spec.velocity_limit
    as_json = get_robot(str(_write(tmp_path, _urdf_spec(), "robot.json")))
    assert as_json.velocity_limit == spec.velocity_limit and as_json.model == spec.model
    # an MJCF has no speed limits: without the spec's, the documented default
    mjcf = _urdf_spec(model="xml/franka_emika_panda/panda.xml", arm={"joints": [f"joint{i}" for i in range(1, 8)],
                      "home": [0, -0.785, 0, -2.356, 0, 1.571, 0.785]}, gripper={"joints": ["finger_joint1",
                      "finger_joint2"], "open": 0.03}, end_effector={"link": "hand"}, cameras=None,
                      control={"force_limit": {"finger_joint1": 100, "finger_joint2": 100}})  # fmt: skip
    plain = get_robot(str(_write(tmp_path, mjcf, "mjcf.yaml")))
    assert plain.velocity_limit == (DEFAULT_VELOCITY["hinge"],) * 7 and plain.gripper_open == 0.03
    with pytest.raises(KeyError, match="no 'wrist' camera mount"):
        plain.camera_mount("wrist")


def test_world_yaml_names_a_spec_file_relative_to_itself(tmp_path):
    from mirage2matter.world.config import RobotConfig, WorldConfig, read_world, save_world

    folder = tmp_path / "robots"
    folder.mkdir()
    path = _write(folder, _urdf_spec())
    world = WorldConfig(root=tmp_path / "world", robot=RobotConfig(name=str(path)))
    saved = save_world(world)
    text = saved.read_text()
    assert "name: ../robots/robot.yaml" in text and PANDA_URDF in text
    back = read_world(saved)
    assert back.robot == world.robot and back.robot.spec.name == "panda_urdf"
    # a dataset of this world is another one when the spec file's content changes (same path, same world.yaml)
    from mirage2matter.datagen.simulated import world_fingerprint

    before = world_fingerprint(back)
    _write(folder, _urdf_spec(gripper__coupling=100.0))
    assert world_fingerprint(read_world(saved)) != before and read_world(saved).robot.spec.finger_coupling == 100.0


def test_a_composed_arm_and_gripper(tmp_path):
    """A URDF arm without a gripper (KUKA iiwa) fitted with the Franka hand at its last link: one model whose
    joints are the arm's then the fingers'; the arm's URDF efforts kept; the tool centre where the hand puts it."""
    spec = {
        "name": "iiwa_hand",
        "model": {"arm": "urdf/kuka_iiwa/model.urdf", "gripper": "xml/franka_emika_panda/hand.xml",
                  "mount": "lbr_iiwa_link_7", "pos": [0, 0, 0.045]},
        "arm": {"joints": [f"lbr_iiwa_joint_{i}" for i in range(1, 8)], "home": [0, 0.6, 0, -1.2, 0, 1.3, 0]},
        "gripper": {"joints": ["gripper_finger_joint1", "gripper_finger_joint2"]},
        "end_effector": {"link": "gripper_hand", "tcp": [0, 0, 0.1034]},
        "control": {"force_limit": {"gripper_finger_joint1": 100, "gripper_finger_joint2": 100}},
    }  # fmt: skip
    robot = get_robot(str(_write(tmp_path, spec)))
    info = model_info(resolve_model(robot.model))
    assert info.joint_names == (*robot.arm_joints, *robot.gripper_joints)
    assert robot.force_limit[:7] == (300.0,) * 7 and robot.velocity_limit == (10.0,) * 7  # the iiwa URDF's
    from mirage2matter.robots.kinematics import RobotKinematics

    kin = RobotKinematics(str(tmp_path / "robot.yaml"))
    q = np.asarray(robot.home)
    T_hand, T_flange = kin.link_pose(q), kin.link_pose(q, "lbr_iiwa_link_7")
    offset = np.linalg.inv(T_flange) @ T_hand
    assert np.allclose(offset[:3, 3], [0, 0, 0.045], atol=1e-9)  # the hand 4.5 cm out of the flange
    assert abs(abs(np.trace(offset[:3, :3])) - 1) < 1e-9 or np.allclose(offset[:3, :3], np.eye(3), atol=1e-9)


BAD = [
    # (changes to the URDF spec, the field named, words of the advice)
    ({"model": "nope/arm.urdf"}, "model", "not found"),
    ({"model": "xml/franka_emika_panda/README.md"}, "model", "neither MJCF"),
    ({"arm__joints": ["panda_joint1", "panda_joint8"]}, "arm.joints", r"no joint\(s\) \['panda_joint8'\]"),
    ({"gripper": None}, "gripper.joints", "needs a gripper"),
    ({"gripper__joints": ["panda_joint7"]}, "gripper.joints", "are arm joints too"),
    ({"arm__joints": [f"panda_joint{i}" for i in (2, 1, 3, 4, 5, 6, 7)]}, "arm.joints", "in its order"),
    ({"arm__home": [0, 0, 0, -1, 0, -1, 0]}, "arm.home", r"panda_joint6 = -1 is outside"),
    ({"arm__home": [0, 0]}, "arm.home", "expected 7 numbers"),
    ({"gripper__open": 0.08}, "gripper.open", "outside finger joint"),
    ({"end_effector__link": "flange"}, "end_effector.link", "'flange' is not a link"),
    ({"end_effector__link": "panda_leftfinger"}, "end_effector.link", "moves with the fingers"),
    ({"end_effector__closing": [0, 0, 1]}, "end_effector", "perpendicular"),
    ({"cameras": {"wrist": {"link": "gopro", "eye": [0, 0, 0], "target": [0, 0, 1]}}}, "cameras.wrist.link", "gopro"),
    ({"control": {"kp": [1, 2]}}, "control.kp", "2 values for the 9 joints"),
    ({"limits": {"velocity": {"elbow": 1}}}, "limits.velocity", r"\['elbow'\] are not among"),
    ({"colour": "red"}, r"\(top level\)", r"unknown key\(s\) \['colour'\]"),
    ({"name": "my arm"}, "name", "letters, digits"),
]


@pytest.mark.parametrize("changes,field,advice", BAD, ids=[b[1] + ":" + b[2][:20] for b in BAD])
def test_a_bad_spec_file_is_named_with_its_field(tmp_path, changes, field, advice):
    path = _write(tmp_path, _urdf_spec(**changes))
    with pytest.raises(RobotSpecError, match=rf"{path}: {field}: .*{advice}"):
        get_robot(str(path))


def test_an_arm_without_a_gripper_is_refused_with_what_to_do(tmp_path):
    """The KUKA iiwa URDF has no gripper: naming finger joints it lacks says so and how to fit one."""
    spec = {"name": "iiwa", "model": "urdf/kuka_iiwa/model.urdf",
            "arm": {"joints": [f"lbr_iiwa_joint_{i}" for i in range(1, 8)], "home": [0] * 7},
            "gripper": {"joints": ["finger_joint1"]}, "end_effector": {"link": "lbr_iiwa_link_7"}}  # fmt: skip
    path = _write(tmp_path, spec)
    with pytest.raises(RobotSpecError, match=r"gripper\.joints: .*it has no gripper.*model: \{arm: ARM_FILE, gripper"):
        get_robot(str(path))
    spec["gripper"] = {}
    with pytest.raises(RobotSpecError, match=r"gripper\.joints: missing \(the model has none beyond the arm's\)"):
        get_robot(str(_write(tmp_path, spec, "b.yaml")))
    spec["model"] = {"arm": "urdf/kuka_iiwa/model.urdf", "gripper": "xml/franka_emika_panda/hand.xml", "mount": "tip"}
    with pytest.raises(RobotSpecError, match=r"model: .*no site or link named 'tip'.*lbr_iiwa_link_7"):
        get_robot(str(_write(tmp_path, spec, "c.yaml")))


def test_the_composed_model_is_self_contained_and_its_visual_meshes_known():
    """The UR5e + hand model lives in its own folder with copies of both models' meshes (so the low-polygon render
    copy can be made like a bundled model's), and the hand's visual meshes are found through its prefixed classes."""
    import xml.etree.ElementTree as ET

    from mirage2matter.env.robot_proxy import _visual_mesh_files

    path = resolve_model(get_robot("ur5e").model)
    root = ET.parse(path).getroot()
    files = [m.get("file") for m in root.iter("mesh")]
    assert files and all((path.parent / "meshes" / f).is_file() for f in files)
    visual = _visual_mesh_files(path)
    names = {Path(v).name.split("_", 1)[1] for v in visual}
    assert {"hand_0.obj", "finger_1.obj", "upperarm_0.obj", "wrist3.obj"} <= names
    assert not names & {"hand.stl", "finger_0.obj"}  # used by collision geoms: never decimated


def test_the_pandas_named_frames_are_franka_s():
    """The frames the Panda's spec names for what Franka's software calls the hand's frames: libfranka's EE at the
    "ready" pose is where Franka documents it (0.307, 0, 0.487, pointing down), and franka_description's
    panda_link8 / panda_hand agree with the links of that name in an independent model (pybullet's Panda URDF)."""
    from mirage2matter.robots.kinematics import KinematicsError, RobotKinematics

    spec, kin, urdf = get_robot("panda"), RobotKinematics("panda"), RobotKinematics(PANDA_URDF)
    T_ee = kin.link_pose(np.asarray(spec.home), "EE")
    assert np.allclose(T_ee[:3, 3], [0.307, 0.0, 0.487], atol=5e-4)
    assert np.allclose(T_ee[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-3)
    assert kin.frame("EE")[0] == "hand"
    n, limits = kin.chain("EE")
    assert n == 7 and np.array_equal(limits, kin.chain("hand")[1])
    rng = np.random.default_rng(0)
    for q in rng.uniform(limits[:, 0], limits[:, 1], (5, 7)):
        for name in ("panda_link8", "panda_hand"):
            assert np.allclose(kin.link_pose(q, name), urdf.link_pose(q, name), atol=1e-6), name
        assert np.allclose(kin.link_pose(q, "fr3_hand_tcp"), kin.link_pose(q, "EE"))
    with pytest.raises(KinematicsError, match="link 'tool9' not in panda.xml.*frames the robot's spec names: EE"):
        kin.link_pose(spec.home, "tool9")


# Universal Robots' published DH parameters of the UR5e: base (the controller's) -> tool0, in metres and radians
UR5E_DH = {"d": [0.1625, 0, 0, 0.1333, 0.0997, 0.0996], "a": [0, -0.425, -0.3922, 0, 0, 0],
           "alpha": [np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0]}  # fmt: skip


def _ur5e_dh(q: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    for theta, d, a, alpha in zip(q, UR5E_DH["d"], UR5E_DH["a"], UR5E_DH["alpha"], strict=True):
        ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
        T = T @ np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d],
                          [0, 0, 0, 1]])  # fmt: skip
    return T


def test_the_ur5e_s_named_frames_are_universal_robots():
    """tool0 in ur_base (what UR's controller reports as the TCP pose with no TCP offset, in its base frame) agrees
    with UR's published DH kinematics at random joint states: the same rotation, the position within the model's
    mm-rounded link lengths; flange and base_link sit as ur_description's fixed joints put them."""
    from scipy.spatial.transform import Rotation

    from mirage2matter.robots.kinematics import RobotKinematics

    kin = RobotKinematics("ur5e")
    n, limits = kin.chain("tool0")
    assert n == 6 and kin.chain("ur_base")[0] == 0 and kin.frame("base_link")[0] == "base"
    rng = np.random.default_rng(0)
    for q in rng.uniform(np.maximum(limits[:, 0], -np.pi), np.minimum(limits[:, 1], np.pi), (20, 6)):
        T_base_tool0 = np.linalg.inv(kin.link_pose(q, "ur_base")) @ kin.link_pose(q, "tool0")
        T_dh = _ur5e_dh(q)
        assert np.allclose(T_base_tool0[:3, :3], T_dh[:3, :3], atol=1e-9)
        assert np.linalg.norm(T_base_tool0[:3, 3] - T_dh[:3, 3]) < 2e-3  # 1.0 mm median, 1.5 max: mm-rounded lengths
        T_flange_tool0 = np.linalg.inv(kin.link_pose(q, "flange")) @ kin.link_pose(q, "tool0")
        assert np.allclose(T_flange_tool0[:3, :3], Rotation.from_euler("xyz", [np.pi / 2, 0, np.pi / 2]).as_matrix())
        assert np.allclose(T_flange_tool0[:3, 3], 0)
    T_base_link_ur_base = np.linalg.inv(kin.link_pose(q, "base_link")) @ kin.link_pose(q, "ur_base")
    assert np.allclose(T_base_link_ur_base, np.diag([-1.0, -1.0, 1.0, 1.0]), atol=1e-12)


BAD_FRAMES = [
    ({"EE": {"link": "gopro", "xyz": [0, 0, 0.1]}}, "frames.EE.link", "'gopro' is not a link"),
    ({"panda_hand": {"link": "panda_link8"}}, "frames.panda_hand", "is a link of the model already"),
    ({"EE": {"link": "panda_hand", "xyz": [0, 0, 103.4]}}, "frames.EE.xyz", "units: mm"),
    ({"EE": {"link": "panda_hand", "rpy": [0, 0, -45]}}, "frames.EE.rpy", "exceeds 2 pi: the angles are radians"),
    ({"tcp": "EE"}, "frames.tcp", "'EE' is neither a link of the model nor a frame above"),
    ({7: "panda_hand"}, "frames.7", "a frame's name is text"),
]


@pytest.mark.parametrize("frames,field,advice", BAD_FRAMES, ids=[b[1] + ":" + b[2][:20] for b in BAD_FRAMES])
def test_a_bad_named_frame_is_named_with_its_field(tmp_path, frames, field, advice):
    path = _write(tmp_path, {**_urdf_spec(), "frames": frames})
    with pytest.raises(RobotSpecError, match=rf"{path}: {field}: .*{advice}"):
        get_robot(str(path))


def test_a_named_frame_turned_and_moved(tmp_path):
    """A frame with a rotation (rpy as URDF: fixed axes x, y, z) and another name for it."""
    from mirage2matter.robots.kinematics import RobotKinematics

    frames = {"tool": {"link": "panda_hand", "xyz": [0.01, 0.02, 0.1], "rpy": [0.1, -0.2, 0.3]}, "tool_alias": "tool"}
    path = _write(tmp_path, {**_urdf_spec(), "frames": frames})
    spec, kin = get_robot(str(path)), RobotKinematics(str(path))
    def turn(axis: int, a: float) -> np.ndarray:  # about one axis, right-handed
        R, i, j = np.eye(3), (axis + 1) % 3, (axis + 2) % 3
        R[i, i] = R[j, j] = np.cos(a)
        R[i, j], R[j, i] = -np.sin(a), np.sin(a)
        return R

    T_hand_tool = np.eye(4)
    T_hand_tool[:3, :3] = turn(2, 0.3) @ turn(1, -0.2) @ turn(0, 0.1)  # URDF's rpy: Rz(yaw) Ry(pitch) Rx(roll)
    T_hand_tool[:3, 3] = [0.01, 0.02, 0.1]
    assert np.allclose(spec.frame("tool").T_link_frame, T_hand_tool)
    q = np.asarray(spec.home)
    assert np.allclose(kin.link_pose(q, "tool_alias"), kin.link_pose(q, "panda_hand") @ T_hand_tool)
    assert spec.frame("tool").describe() == ("panda_hand +10.0 mm along x, +20.0 mm along y, +100.0 mm along z, "
                                             "+5.7 deg about x, -11.5 deg about y, +17.2 deg about z")
