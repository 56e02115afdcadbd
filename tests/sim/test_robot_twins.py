"""Every shipped robot in the Genesis twin of the sample world: Genesis' kinematics agree with MuJoCo's (the hand-eye
chain's) on the spec's model, inverse kinematics gives back a pose forward kinematics made, and (for the robots
the other sim tests do not cover) a planned grasp lifts the banana. One twin per robot (~20-30 s to build warm)."""

from __future__ import annotations

import numpy as np
import pytest

from mirage2matter.geometry.rotation import rotation_angle
from mirage2matter.robots import DEFAULT_ROBOT, ROBOTS, get_robot
from mirage2matter.world import load_world


@pytest.fixture(scope="module", params=sorted(ROBOTS))
def twin(request, sample_world_ws):
    from mirage2matter.sim.twin import Twin, TwinOptions

    robot = {} if request.param == DEFAULT_ROBOT else {"robot": request.param}  # the default's: sim_ws' world
    ws = sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0, **robot)
    tw = Twin.build(load_world(ws / "world"), TwinOptions(render=False))
    yield tw
    tw.close()


def _random_q(spec, rng: np.random.Generator, spread: float = 0.6) -> np.ndarray:
    """Arm joints near home (within the limits), fingers open."""
    lo, hi = spec.limits_array()[: spec.n_arm].T
    q = np.clip(np.asarray(spec.home) + rng.uniform(-spread, spread, spec.n_arm), lo, hi)
    return np.concatenate([q, [spec.gripper_open] * len(spec.gripper_joints)])


def test_the_twin_is_the_spec_and_agrees_with_the_hand_eye_kinematics(twin):
    from mirage2matter.robots.kinematics import RobotKinematics

    spec = twin.spec
    assert twin.cfg.robot.spec is get_robot(twin.cfg.robot.name) and twin.robot.n_dofs == spec.n_dofs
    lo, hi = twin.joint_limits
    assert np.allclose(np.stack([lo, hi], axis=1), spec.limits_array(), atol=1e-5)  # the model's, read twice
    twin.reset(seed=0, randomize=False)
    assert np.allclose(twin.robot_state(), spec.home_q(), atol=0.05)
    with twin.restoring():  # at home the robot touches nothing, open or closed (the fingers on each other are fine)
        assert twin.colliding_pairs(spec.home_q(spec.gripper_open)) == []
        assert twin.colliding_pairs(spec.home_q(spec.gripper_closed)) == []
    kin = RobotKinematics(twin.cfg.robot.name)
    rng = np.random.default_rng(0)
    with twin.restoring():
        for _ in range(5):
            q = _random_q(spec, rng)
            twin.robot.set_qpos(q)
            for link in (spec.ee_link, spec.wrist_camera.link, *spec.finger_links):
                T_gs, T_mj = twin.T_base_link(link), kin.link_pose(q, link)
                assert np.linalg.norm(T_gs[:3, 3] - T_mj[:3, 3]) < 1e-4, link
                assert rotation_angle(T_gs[:3, :3].T @ T_mj[:3, :3]) < 1e-3, link


def test_ik_gives_back_a_forward_kinematics_pose(twin):
    from mirage2matter.sim.planning import ik

    spec = twin.spec
    twin.reset(seed=0, randomize=False)
    q0 = twin.robot_state()
    rng = np.random.default_rng(1)
    for _ in range(4):
        q = _random_q(spec, rng, 0.4)
        with twin.restoring():
            twin.robot.set_qpos(q)
            T = twin.T_base_link()
        q_ik = ik(twin, T, q0, check_collision=False)
        with twin.restoring():
            twin.robot.set_qpos(np.concatenate([q_ik, q0[spec.n_arm :]]))
            T_back = twin.T_base_link()
        assert np.linalg.norm(T_back[:3, 3] - T[:3, 3]) < 0.002
        assert np.degrees(rotation_angle(T_back[:3, :3].T @ T[:3, :3])) < 1.0
    assert np.allclose(twin.robot_state(), q0, atol=1e-6)


def test_a_planned_grasp_lifts_the_banana(twin):
    """The default robot's tasks are test_twin_tasks'; here the others pick the banana from its placement."""
    from mirage2matter.sim.tasks import parse_task, run_task

    if twin.cfg.robot.name == DEFAULT_ROBOT:
        pytest.skip("the default robot's tasks: tests/sim/test_twin_tasks.py")
    twin.reset(seed=0, randomize=False)
    r = run_task(twin, parse_task("grasp banana", twin.cfg))
    assert r.success, r.reason
    assert r.info["max_lift_m"] > 0.05 and len(r.steps[0].state) == twin.spec.n_dofs
    assert len(r.steps[0].action) == twin.spec.n_arm + 1


USER_URDF_SPEC = """\
name: panda_urdf
model: urdf/panda_bullet/panda.urdf   # Genesis' pybullet Panda: a URDF with speed limits and efforts, no gains
arm:
  joints: [panda_joint1, panda_joint2, panda_joint3, panda_joint4, panda_joint5, panda_joint6, panda_joint7]
  home: [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
gripper: {joints: [panda_finger_joint1, panda_finger_joint2], coupling: 3000, pad_half_width: 0.012}
control:
  kp: [4500, 4500, 3500, 3500, 2000, 2000, 2000, 1000, 1000]
  kv: [450, 450, 350, 350, 200, 200, 200, 40, 40]
  force_limit: {panda_finger_joint1: 100, panda_finger_joint2: 100}
end_effector: {link: panda_hand, tcp: [0, 0, 0.1034], tip_depth: 0.0089}
cameras:
  wrist: {link: panda_hand, eye: [0.07, 0, 0], target: [0, 0, 0.14], up: [1, 0, 0], fov_deg: 70}
"""


@pytest.mark.slow
def test_a_users_urdf_robot_in_the_twin(tmp_path_factory, sample_world_ws):
    """A user's own robot from a URDF spec file: the twin keeps its fixed hand link (Genesis would merge it away),
    its URDF speed limits drive the planner, and it grasps and presses (measured: 10/10 grasps, 10/10 presses,
    9/10 pushes on seeds 1000-1009)."""
    from mirage2matter.sim.tasks import evaluate, parse_task
    from mirage2matter.sim.twin import Twin, TwinOptions

    spec_file = tmp_path_factory.mktemp("robot") / "panda_urdf.yaml"
    spec_file.write_text(USER_URDF_SPEC)
    ws = sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0, robot=str(spec_file))
    cfg = load_world(ws / "world")
    assert cfg.robot.spec.velocity_limit == (2.175,) * 4 + (2.61,) * 3 and cfg.cameras["wrist"].mount == "panda_hand"
    with Twin.build(cfg, TwinOptions(render=False)) as twin:
        assert twin.ee_link.name == "panda_hand"
        for text in ("grasp banana", "press button"):
            assert evaluate(twin, parse_task(text, cfg), episodes=3, seed=1000)["success_rate"] == 1.0, text
