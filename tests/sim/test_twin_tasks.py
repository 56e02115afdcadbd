"""The Genesis twin of the sample world: state, cameras, planning, and the scripted tasks' real outcomes.

One twin per module (Genesis builds in ~15 s with warm kernel caches, ~110 s cold); every test resets it.
"""

import time

import numpy as np
import pytest

from mirage2matter.sim.planning import PlanningError, collision_free, ik, plan, segment_free, time_parameterize
from mirage2matter.sim.tasks import GraspTask, TaskError, parse_task, run_task, steps_per_tick, topdown
from mirage2matter.world import load_world
from mirage2matter.world.compose import WorldGaussians


@pytest.fixture(scope="module")
def twin(sim_ws):
    from mirage2matter.sim.twin import Twin, TwinOptions

    options = TwinOptions(render=True, camera_sizes={"head": (96, 72), "wrist": (64, 48)})
    tw = Twin.build(load_world(sim_ws / "world"), options)
    yield tw
    tw.close()


def test_state_and_poses(twin):
    twin.reset(seed=0, randomize=False)
    q = twin.robot_state()
    assert q.shape == (9,) and np.allclose(q[:7], twin.cfg.robot.home, atol=0.02)
    poses = twin.object_poses()
    assert set(poses) == {"banana", "croissant", "button", "button/cap"}
    # At the world's placements (the curved banana may roll onto its side while settling: xy within 2 cm).
    for name in ("croissant", "button"):
        assert np.allclose(poses[name][:3, 3], _placement(twin, name)[:3, 3], atol=0.01)
    assert np.linalg.norm(poses["banana"][:2, 3] - _placement(twin, "banana")[:2, 3]) < 0.02
    assert poses["button/cap"][2, 3] == pytest.approx(0.04, abs=0.002)  # rests on the 4 cm base


def _placement(twin, name):
    item = next(it for it in [*twin.cfg.objects, *twin.cfg.articulated] if it.name == name)
    return item.placement.matrix


def test_randomised_resets(twin):
    a = twin.reset(seed=3)
    b = twin.reset(seed=3)
    c = twin.reset(seed=4)
    assert all(np.allclose(a[k], b[k], atol=1e-4) for k in a)
    assert not np.allclose(a["banana"][:3, 3], c["banana"][:3, 3], atol=1e-3)
    r = twin.cfg.randomize
    for seed in range(5):
        poses = twin.reset(seed=seed)
        centres = {}
        for name, body in twin.bodies.items():
            c_xy = (poses[name][:3, :3] @ body.centre_obj + poses[name][:3, 3])[:2]
            assert r.x[0] - 0.03 <= c_xy[0] <= r.x[1] + 0.03 and r.y[0] - 0.03 <= c_xy[1] <= r.y[1] + 0.03
            centres[name] = (c_xy, body.footprint_radius)
        names = list(centres)
        for i in range(len(names)):
            for j in range(i + 1, len(names)):
                (ci, ri), (cj, rj) = centres[names[i]], centres[names[j]]
                assert np.linalg.norm(ci - cj) >= ri + rj  # footprints apart (objects may roll a little)


def test_start_regions_put_the_object_in_its_boxes(twin):
    """Targeted resets: the banana's centre lands in one of its boxes (two far-apart corners), the rest of the layout
    is drawn as usual (the others apart from it, and spread), and a seed still gives one layout."""
    boxes = [(0.55, 0.62, -0.3, -0.2), (0.35, 0.40, 0.22, 0.3)]
    seen = set()
    others = []
    for seed in range(6):
        poses = twin.reset(seed=seed, regions={"banana": boxes})
        body = twin.bodies["banana"]
        x, y = (poses["banana"][:3, :3] @ body.centre_obj + poses["banana"][:3, 3])[:2]
        inside = [
            i for i, (x0, x1, y0, y1) in enumerate(boxes) if x0 - 0.02 <= x <= x1 + 0.02 and y0 - 0.02 <= y <= y1 + 0.02
        ]
        assert inside, f"seed {seed}: banana at ({x:.3f}, {y:.3f}), outside {boxes}"
        seen.update(inside)
        others.append(poses["croissant"][:2, 3])
    assert seen == {0, 1}  # both boxes are used
    assert np.ptp(np.array(others), axis=0).max() > 0.1  # the croissant is not dragged along
    a = twin.reset(seed=9, regions={"banana": boxes})
    b = twin.reset(seed=9, regions={"banana": boxes})
    assert np.allclose(a["banana"], b["banana"], atol=1e-4)
    with pytest.raises(ValueError, match="kiwi"):
        twin.sample_poses(np.random.default_rng(0), regions={"kiwi": boxes})
    with pytest.raises(RuntimeError, match="start regions"):  # a box no layout can reach: a clear error, not a hang
        twin.sample_poses(np.random.default_rng(0), regions={"banana": [(0.9, 1.0, 0.9, 1.0)]})


def test_twin_gaussians_follow_physics_bodies(twin):
    """The visual (Gaussians at the physics poses) and the physical body (Genesis collision geometry) agree."""
    twin.reset(seed=2)
    world = WorldGaussians.load(twin.cfg)
    poses = twin.object_poses()
    for name in ("banana", "croissant"):
        means = world.parts[name].at(poses[name]).means.numpy()
        verts = np.asarray(twin.bodies[name].entity.get_verts())
        assert np.abs(means.min(0) - verts.min(0)).max() < 0.006, name
        assert np.abs(means.max(0) - verts.max(0)).max() < 0.006, name


def test_cameras(twin):
    twin.reset(seed=0, randomize=False)
    T_head, K, w, h = twin.camera("head")
    assert np.allclose(T_head, twin.cfg.cameras["head"].T_mount_cam) and (w, h) == (96, 72)
    K_world = twin.cfg.cameras["head"].K
    assert np.allclose(K, [[K_world[1, 1] * 72 / 480, 0, 48], [0, K_world[1, 1] * 72 / 480, 36], [0, 0, 1]])
    T_wrist0, *_ = twin.camera("wrist")
    assert np.allclose(T_wrist0, twin.T_base_link("hand") @ twin.cfg.cameras["wrist"].T_mount_cam)
    q = twin.robot_state()
    q[0] += 0.5
    twin.set_robot_state(q)
    T_wrist1, *_ = twin.camera("wrist")
    assert np.linalg.norm(T_wrist1[:3, 3] - T_wrist0[:3, 3]) > 0.1  # the wrist camera moves with the hand
    out = twin.render_robot("head", 96, 72)
    assert out["rgb"].shape == (72, 96, 3) and out["rgb"].dtype == np.uint8
    assert out["depth"].shape == (72, 96) and out["robot_mask"].dtype == bool
    m = out["robot_mask"]
    assert 0.01 < m.mean() < 0.9
    assert np.isfinite(out["depth"][m]).all() and (out["depth"][m] > 0.3).all()
    # Our camera model and Genesis' render agree: robot links project onto robot pixels, at their depth.
    # Our camera model and Genesis' render agree: the robot's geometry projects onto robot pixels.
    X = np.asarray(twin.robot.get_verts(), dtype=np.float64)
    Xc = X @ np.linalg.inv(T_head)[:3, :3].T + np.linalg.inv(T_head)[:3, 3]
    uv = (Xc @ K.T)[:, :2] / Xc[:, 2:]
    inside = (uv[:, 0] >= 1) & (uv[:, 0] < 95) & (uv[:, 1] >= 1) & (uv[:, 1] < 71)
    iu, iv = uv[inside, 0].astype(int), uv[inside, 1].astype(int)
    grown = m.copy()  # one pixel of slack for rasterisation at the silhouette
    grown[1:] |= m[:-1]
    grown[:-1] |= m[1:]
    grown[:, 1:] |= m[:, :-1]
    grown[:, :-1] |= m[:, 1:]
    assert inside.sum() > 100 and grown[iv, iu].mean() > 0.95
    with pytest.raises(ValueError, match="renders 96x72"):
        twin.render_robot("head", 640, 480)


@pytest.mark.parametrize("seed", [0, 1])
def test_grasp_lifts_the_object(twin, seed):
    for name in ("banana", "croissant"):
        twin.reset(seed=seed)
        z0 = twin.object_poses()[name][2, 3]
        seen = []
        r = run_task(twin, parse_task(f"grasp {name}", twin.cfg), on_step=seen.append)
        assert r.success, r.reason
        assert twin.object_poses()[name][2, 3] - z0 > 0.05  # still up, in the hand
        assert len(seen) == len(r.steps) > 30 and r.steps[-1].t < 7.0
        assert r.steps[0].state.shape == (9,) and r.steps[0].action.shape == (8,)
        assert abs(r.steps[-1].state[7]) < 0.03  # fingers closed on it, not on air


def test_grasp_detour_reaches_beside_the_object_then_grasps(twin):
    """--detour 1: every demonstration first stops 4-10 cm beside the pre-grasp, then grasps as usual; the same
    task seed without the option is the plain approach (the draw is made either way)."""
    from mirage2matter.sim.tasks.motion import tcp_pose

    twin.reset(seed=3)
    task = parse_task("grasp banana --detour 1", twin.cfg)
    assert task.detour == 1.0 and task.text == "grasp banana --detour 1"
    tcps = []
    r = run_task(twin, task, np.random.default_rng(7), on_step=lambda rec: tcps.append(tcp_pose(twin)[:3, 3]))
    assert r.success, r.reason
    off = np.array(r.info["detour_m"])
    assert 0.04 <= np.linalg.norm(off) <= 0.10
    pre = np.array(r.info["grasp_tcp"]) + [0.0, 0.0, 0.10]
    # the hand really stood at the detour (within the arm's tracking error) before going to the grasp
    assert min(np.linalg.norm(t - (pre + [*off, 0.0])) for t in tcps) < 0.015
    twin.reset(seed=3)
    plain = run_task(twin, parse_task("grasp banana", twin.cfg), np.random.default_rng(7))
    assert plain.success and "detour_m" not in plain.info and len(plain.steps) < len(r.steps)
    assert np.allclose(plain.info["grasp_tcp"], r.info["grasp_tcp"])
    with pytest.raises(TaskError, match=r"--detour 1.5 must be in \(0, 1\]$"):
        parse_task("grasp banana --detour 1.5")


def _wrap_deg(a_rad):
    """An angle (rad) in degrees, wrapped to [-180, 180)."""
    return (np.degrees(a_rad) + 180.0) % 360.0 - 180.0


def _closing_yaw(T_base_tcp):
    """The yaw (rad) of the hand's closing axis (tool y) in pose ``T_base_tcp`` [4,4]."""
    return np.arctan2(T_base_tcp[1, 1], T_base_tcp[0, 1])


def test_toward_home_turns_at_most_slack():
    from mirage2matter.sim.tasks.grasp import toward_home

    home = np.radians(275.0)  # within 45 deg: home itself; beyond: 45 deg nearer, by the shorter way round
    cases = [(200.0, 245.0), (350.0, 305.0), (260.0, 275.0), (-80.0, 275.0), (96.0, 141.0), (94.0, 49.0)]
    for yaw_deg, want_deg in cases:
        got = np.degrees(toward_home(np.radians(yaw_deg), home, np.radians(45.0)))
        assert (got - want_deg + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-6), (yaw_deg, got)


def test_least_turn_first_reorders_only_the_ties():
    from mirage2matter.sim.tasks.grasp import least_turn_first

    home = np.radians(270.0)
    tcp = np.zeros(3)
    # yaw 10 deg needs an 80 deg turn (190 or 10 -> 270), 80 deg 10 deg (260), 120 deg 30 deg (300); 90 deg none
    cands = [(0.0007, tcp, np.radians(10.0)), (0.0009, tcp, np.radians(120.0)), (0.0010, tcp, np.radians(80.0)),
             (0.0040, tcp, np.radians(90.0))]  # fmt: skip
    got = [round(np.degrees(c[2])) for c in least_turn_first(cands, home, 0.002)]
    assert got == [80, 120, 10, 90]  # the fourth is no tie: it stays behind them though it needs no turn
    assert [round(np.degrees(c[2])) for c in least_turn_first(cands, home, 0.0001)] == [10, 120, 80, 90]
    assert least_turn_first([], home, 0.002) == []


@pytest.mark.parametrize("seed", [0, 3])  # the plain grasp turns the wrist 60 deg and -40 deg
def test_grasp_slack_turns_the_wrist_less(twin, seed):
    """--slack 45: the same grasp spot with the hand turned 45 deg less towards its yaw at home (not at all when the
    grasp asks less), and the closing fingers square the banana up: it is still lifted."""
    from mirage2matter.sim.tasks.motion import tcp_pose

    def turn(yaw_rad):  # the wrist's turn from home, degrees in [-180, 180)
        return _wrap_deg(yaw_rad - twin.spec.home_closing_yaw)

    runs = {}
    for text in ("grasp banana", "grasp banana --slack 45"):
        twin.reset(seed=seed)
        r = run_task(twin, parse_task(text, twin.cfg), np.random.default_rng(7))
        assert r.success, (text, r.reason)
        T = tcp_pose(twin)  # the hand's closing axis (tool y) now, holding the banana
        runs[text] = (turn(np.radians(r.info["grasp_yaw_deg"])), turn(_closing_yaw(T)), r.info)
    (plain, plain_now, plain_info), (slack, slack_now, slack_info) = runs.values()
    assert np.allclose(plain_info["grasp_tcp"], slack_info["grasp_tcp"])
    assert abs(slack) == pytest.approx(max(abs(plain) - 45.0, 0.0), abs=1e-6) and slack * plain >= 0
    assert abs(plain_now - plain) < 5.0 and abs(slack_now - slack) < 5.0  # the arm really turned that far


@pytest.mark.parametrize("seed", [0, 3])  # the plain grasp turns the wrist 60 deg and -40 deg
def test_grasp_tie_takes_the_least_turn_among_equal_grasps(twin, seed):
    """--tie 2: of the grasps scoring within 2 mm of the best (on the banana: the same spot, closing angles tens
    of degrees apart) the one needing the least wrist turn; it still lifts the banana and the arm really turns so."""
    from mirage2matter.sim.tasks.grasp import grasp_candidates
    from mirage2matter.sim.tasks.motion import placed, tcp_pose

    def turn(yaw_rad):  # the wrist's turn from home, degrees in [-180, 180)
        return _wrap_deg(yaw_rad - twin.spec.home_closing_yaw)

    twin.reset(seed=seed)
    spec = twin.spec
    cands = grasp_candidates(*placed(twin, "banana"), twin.cfg.table_z, max_width=spec.max_grasp_width,
                             pad_half_width=spec.pad_half_width, min_height=spec.min_grasp_height)  # fmt: skip
    ties = [c for c in cands if c[0] <= cands[0][0] + 0.002]
    least = min(min(abs(turn(c[2])), abs(turn(c[2] + np.pi))) for c in ties)
    runs = {}
    for text in ("grasp banana", "grasp banana --tie 2"):
        twin.reset(seed=seed)
        r = run_task(twin, parse_task(text, twin.cfg), np.random.default_rng(7))
        assert r.success, (text, r.reason)
        T = tcp_pose(twin)
        runs[text] = (turn(np.radians(r.info["grasp_yaw_deg"])), turn(_closing_yaw(T)), r.info)
    (plain, _, plain_info), (tie, tie_now, tie_info) = runs.values()
    assert len(ties) >= 3 and abs(tie) == pytest.approx(least, abs=1e-6) and abs(tie) <= abs(plain) - 9.9
    assert np.linalg.norm(np.subtract(plain_info["grasp_tcp"], tie_info["grasp_tcp"])) < 0.01  # the same spot
    assert abs(tie_now - tie) < 5.0


def test_grasp_look_hovers_above_the_grasp_before_turning(twin):
    """--look 0.5: the hand stops 10 cm over the chosen grasp at its start yaw for 0.5 s (5 ticks), then turns to
    the grasp's yaw (seed 0: a 60 deg turn), and still lifts the banana."""
    from mirage2matter.sim.tasks.motion import tcp_pose

    twin.reset(seed=0)
    T0 = tcp_pose(twin)
    yaw0 = _closing_yaw(T0)
    poses = []
    r = run_task(twin, parse_task("grasp banana --look 0.5", twin.cfg), np.random.default_rng(7),
                 on_step=lambda _rec: poses.append(tcp_pose(twin)))  # fmt: skip
    assert r.success, r.reason
    assert r.info["look_s"] == 0.5
    above = np.asarray(r.info["grasp_tcp"]) + [0.0, 0.0, 0.10]

    hovering = [np.linalg.norm(T[:3, 3] - above) < 0.015 and abs(_wrap_deg(_closing_yaw(T) - yaw0)) < 5.0
                for T in poses]  # fmt: skip
    run = max(len(k) for k in "".join("x" if h else " " for h in hovering).split(" "))
    assert run >= 5
    assert abs(_wrap_deg(np.radians(r.info["grasp_yaw_deg"]) - yaw0)) > 20.0  # and then it turned


@pytest.mark.parametrize("text,seed,body", [("grasp banana", 1, "banana"), ("press button", 5, "button:cap"),
                                             ("push croissant --direction 0,1 --distance 0.1", 0, "croissant")])
def test_a_task_from_a_start_touching_its_object(twin, text, seed, body):
    """A start the planner refuses - the fingers on the object, where a policy can leave them (generate --takeover) -
    is not a failed episode, whatever the task: the expert first lifts the hand straight up, opening, then runs as
    usual; from a clear start nothing changes (the replay tests)."""
    from mirage2matter.sim.tasks.motion import tcp_pose

    class Touching(Exception):
        pass

    def act_until_touching(a):
        twin.act(a, steps_per_tick(twin, 10.0))
        with twin.restoring():
            if any(body in pair for pair in twin.colliding_pairs(twin.robot_state())):
                raise Touching

    twin.reset(seed=seed)
    with pytest.raises(Touching):  # the expert stopped where the robot first touches the object
        run_task(twin, parse_task(text, twin.cfg), act=act_until_touching)
    with twin.restoring():
        assert not collision_free(twin, twin.robot_state())  # a start the planner refuses
    tcps = []
    r = run_task(twin, parse_task(text, twin.cfg), on_step=lambda rec: tcps.append(tcp_pose(twin)[:3, 3]))
    assert r.success, r.reason
    assert tcps[6][2] - tcps[0][2] > 0.02  # up first, clear of the object


def test_press_button(twin):
    twin.reset(seed=5)
    r = run_task(twin, parse_task("press button", twin.cfg))
    assert r.success, r.reason
    assert r.info["max_travel_m"] >= twin.cfg.articulated[0].threshold
    assert twin.button_travel("button") < 0.002  # the spring pushed the cap back up


def test_push_and_pull(twin):
    for text, seed in (("push croissant --direction 0,1 --distance 0.1", 0), ("pull banana --distance 0.1", 1)):
        twin.reset(seed=seed)
        spec = parse_task(text, twin.cfg)
        r = run_task(twin, spec)
        assert r.success, r.reason
        assert r.info["error_m"] <= spec.tolerance
        assert np.linalg.norm(r.info["displacement_m"]) > 0.07


def test_unknown_target_raises(twin):
    with pytest.raises(TaskError, match="no object named 'kiwi'"):
        run_task(twin, GraspTask("kiwi"))


def test_plan_around_an_obstacle(twin):
    """Hand low on either side of the button: the straight joint path sweeps through it; RRTConnect goes round."""
    twin.reset(seed=0, randomize=False)
    bx, by = twin.object_poses()["button"][:2, 3]
    q0 = twin.robot_state()
    axis = np.array([0.0, -1.0])
    T_ee_tcp, n_arm = twin.spec.T_ee_tcp, twin.spec.n_arm
    qa = ik(twin, topdown(np.array([bx, by - 0.12, 0.03]), axis, T_ee_tcp), q0)
    qb = ik(twin, topdown(np.array([bx, by + 0.12, 0.03]), axis, T_ee_tcp), np.concatenate([qa, q0[n_arm:]]))
    fingers = q0[n_arm:]
    assert not segment_free(twin, qa, qb, fingers)
    # found within the planner's timeout (else PlanningError); no wall-clock assert: on a loaded CPU the
    # simplification after the search can push the total past any fixed bound (11.1 s beside a scene training)
    path = plan(twin, np.concatenate([qa, fingers]), qb, timeout=10.0)
    assert len(path) >= 3 and np.allclose(path[0], qa) and np.allclose(path[-1], qb)
    # the path is a function of the plan's seed: not of the clock, nor of the plans made before it (an episode
    # is a function of its seed, whichever worker runs it after whatever attempts)
    plan(twin, np.concatenate([qa, fingers]), qb, timeout=10.0, seed=5)
    assert np.array_equal(plan(twin, np.concatenate([qa, fingers]), qb, timeout=10.0), path)
    dense = time_parameterize(path, 0.01, 0.5, robot=twin.spec)
    with twin.restoring():
        for q in dense[::2]:
            assert collision_free(twin, np.concatenate([q, fingers])), "the planned path collides"
    # The hand went over (or round) the button: somewhere it rose above the button's top.
    with twin.restoring():
        heights = []
        for q in dense[::5]:
            twin.robot.set_qpos(np.concatenate([q, fingers]))
            heights.append((twin.T_base_link() @ T_ee_tcp)[2, 3])
    assert max(heights) > 0.055


def test_unreachable_target_fails_fast(twin):
    twin.reset(seed=0, randomize=False)
    q0 = twin.robot_state()
    T_far = topdown(np.array([1.6, 0.0, 0.2]), np.array([0.0, 1.0]), twin.spec.T_ee_tcp)
    t0 = time.perf_counter()
    with pytest.raises(PlanningError, match="beyond its reach"):
        ik(twin, T_far, q0)
    T_odd = np.eye(4)  # hand pointing up, 5 cm above the table, inside the robot's own base
    T_odd[:3, 3] = (0.05, 0.0, 0.05)
    with pytest.raises(PlanningError, match="unreachable|collides"):
        ik(twin, T_odd, q0)
    assert time.perf_counter() - t0 < 5.0
    assert np.allclose(twin.robot_state(), q0, atol=1e-6)  # queries leave the robot where it was


def test_act_is_one_control_tick(twin):
    """The arm and gripper commands move linearly to the action over the tick; a closed gripper squeezes."""
    spec = twin.spec
    twin.reset(seed=0, randomize=False)
    home = np.append(twin.home[: spec.n_arm], spec.gripper_open)
    assert np.allclose(twin.command, home)
    target = home.copy()
    target[0] += 0.1
    target[-1] = 0.5 * (spec.gripper_open + spec.gripper_closed)
    twin.act(target, 10)
    assert np.allclose(twin.command, target)
    q = twin.robot_state()
    assert 0.03 < q[0] < 0.1  # on its way, lagging the command a little
    assert abs(q[spec.n_arm] - target[-1]) < 0.5 * abs(spec.gripper_open - target[-1])
    shut = target.copy()
    shut[-1] = spec.gripper_closed
    for _ in range(3):
        twin.act(shut, 10)
    assert np.abs(twin.robot_state()[spec.n_arm :] - spec.gripper_closed).max() < 0.002  # squeezed shut
    lo, hi = twin.action_limits
    twin.act(hi + 1.0, 10)  # beyond every limit: clipped to them
    assert np.allclose(twin.command, hi)
    with pytest.raises(ValueError, match=f"an action has {spec.n_arm + 1} values"):
        twin.act(np.zeros(3), 10)


@pytest.mark.parametrize(
    "text, seed",
    [("grasp croissant", 2), ("press button", 3), ("push croissant --direction 0,1 --distance 0.1", 4),
     ("pull banana --distance 0.1", 5)],
)  # fmt: skip
def test_scripted_episode_replays_through_act(twin, text, seed):
    """The recorded actions, acted from the same reset, reproduce the states and the success of the script."""
    task = parse_task(text, twin.cfg)
    twin.reset(seed=seed)
    r = run_task(twin, task)
    assert r.success, r.reason
    twin.reset(seed=seed)
    monitor = task.monitor(twin, 0.1)
    worst = 0.0
    for rec in r.steps:
        worst = max(worst, float(np.abs(twin.robot_state() - rec.state).max()))
        assert rec.action.dtype == np.float32 and rec.action.shape == (twin.spec.n_arm + 1,)
        twin.act(rec.action, 10)
        monitor.update(twin)
    # Each tick depends on the state alone (Twin.act): measured 0 on every task (the bar is 1e-3 rad)
    assert worst < 1e-9 and monitor.success
