"""The Gymnasium environment of the sample world's twin: Gymnasium's own checker, spaces that are the datasets'
features, episodes, and bad input refused with a clear M2MError (most before Genesis is started)."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest

import mirage2matter.env  # noqa: F401  (registers mirage2matter/Twin-v0)
from mirage2matter.env import ENV_ID, EnvError
from mirage2matter.env.config import EpisodeSpec
from mirage2matter.errors import EpisodeStalled, M2MError
from mirage2matter.sim.tasks import GraspTask, TaskError
from mirage2matter.world import load_world

SIZE = (32, 24)  # (width, height): small frames keep the renders cheap


@pytest.fixture(scope="module")
def ws(sample_world_ws):
    return sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0)


@pytest.fixture(scope="module")
def world(ws):
    return load_world(ws / "world")


@pytest.fixture(scope="module")
def env(ws):
    e = gymnasium.make(ENV_ID, world=ws / "world", task="grasp banana", size=SIZE, horizon=4)  # a world folder
    yield e
    e.close()


def test_gymnasium_env_checker_passes(env):
    from gymnasium.utils.env_checker import check_env

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)  # also makes one environment per render mode and one to close twice
    # joint targets in radians are not a [-1, 1] box, and should not be: they are the datasets' actions
    others = [str(w.message) for w in caught if "symmetric and normalized" not in str(w.message)]
    assert not [m for m in others if "WARN" in m], others


def test_spaces_are_the_datasets_features(env, world):
    from mirage2matter.datagen.sim_source import SimSourceConfig

    features = SimSourceConfig(world=world, task=GraspTask("banana"), episode=EpisodeSpec(SIZE)).spec().features()
    obs_space = env.observation_space
    assert set(obs_space.spaces) == {k for k in features if k.startswith("observation.")}
    for key, space in obs_space.spaces.items():
        assert list(space.shape) == features[key]["shape"], key
        assert space.dtype == (np.uint8 if features[key]["dtype"] == "video" else np.dtype(features[key]["dtype"]))
    assert list(env.action_space.shape) == features["action"]["shape"] and env.action_space.dtype == np.float32
    spec = world.robot.spec
    assert env.unwrapped.action_names == tuple(features["action"]["names"]) == spec.action_names
    lo, hi = env.action_space.low, env.action_space.high
    assert lo[-1] == pytest.approx(min(spec.gripper_open, spec.gripper_closed))
    assert hi[-1] == pytest.approx(max(spec.gripper_open, spec.gripper_closed))
    assert env.unwrapped.metadata["render_fps"] == 10


def test_an_episode_steps_ticks_and_truncates_at_the_horizon(env):
    obs, info = env.reset(seed=7)
    assert info == {"seed": 7, "task": "pick up the banana"}
    q0 = obs["observation.state"]
    n_arm = env.unwrapped.twin.spec.n_arm
    hold = np.append(q0[:n_arm], q0[n_arm]).astype(np.float32)  # stay where it is, gripper open
    for t in range(1, 5):
        obs, reward, terminated, truncated, info = env.step(hold)
        assert info["step"] == t and info["sim_s"] == pytest.approx(0.1 * t)
        assert not terminated and reward == 0.0 and truncated == (t == 4)
    assert {"reset", "physics", "splat_render", "robot_render"} <= set(info["timings"])
    assert np.abs(obs["observation.state"] - q0).max() < 0.01
    assert obs["observation.images.head"].shape == (SIZE[1], SIZE[0], 3)
    # the same seed, the same episode; another seed, other start poses
    a, _ = env.reset(seed=7)
    b, _ = env.reset(seed=7)
    c, _ = env.reset(seed=8)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert not np.array_equal(a["observation.images.head"], c["observation.images.head"])


def test_bad_actions_are_clear_errors(env):
    env.reset(seed=0)
    n = env.action_space.shape[0]
    with pytest.raises(M2MError, match=rf"an action is float32 \[{n}\].*got shape \(3,\)"):
        env.step(np.zeros(3, np.float32))
    with pytest.raises(M2MError, match="NaN"):
        env.step(np.full(n, np.nan, np.float32))


def test_a_stalled_render_ends_the_episode_and_the_next_reset_goes_on(env, monkeypatch):
    obs, _ = env.reset(seed=3)
    renderer = env.unwrapped.renderer
    render = renderer.render

    def stalled():
        renderer.timings["ground_truth_stalls"] = 3.0  # the renderer's count reaches the episode's timings
        raise EpisodeStalled("stalled 3 times on one state")

    n_arm = env.unwrapped.twin.spec.n_arm
    hold = obs["observation.state"][: n_arm + 1]  # stay where it is, gripper open
    monkeypatch.setattr(renderer, "render", stalled)
    with pytest.raises(EpisodeStalled):
        env.step(hold)
    assert env.unwrapped.timings["ground_truth_stalls"] == 3.0
    monkeypatch.setattr(renderer, "render", render)
    with pytest.raises(M2MError, match="call reset"):  # the stalled episode is over
        env.step(hold)
    again, _ = env.reset(seed=3)
    assert all(np.array_equal(again[k], obs[k]) for k in obs)  # the same episode as before the stall


def test_bad_input_is_refused_before_genesis_starts(world, ws, tmp_path):
    from mirage2matter.env.twin_env import TwinEnv

    with pytest.raises(TaskError, match="no press button named 'banana'"):
        TwinEnv(world, "press banana")
    with pytest.raises(TaskError, match="no object named 'kiwi'"):
        TwinEnv(world, GraspTask("kiwi"))
    blind = world.copy()
    del blind.cameras["wrist"]
    with pytest.raises(EnvError, match="no calibrated camera wrist.*calibrate"):
        TwinEnv(blind, "grasp banana")
    with pytest.raises(EnvError, match="ground_truth renderer needs a sample's ground truth.*none was given"):
        TwinEnv(world, "grasp banana", renderer="ground_truth")
    with pytest.raises(EnvError, match="has no ground_truth.json.*use renderer='hybrid'"):
        TwinEnv(world, "grasp banana", renderer="ground_truth", ground_truth=ws)  # a capture of one's own
    with pytest.raises(EnvError, match="unknown renderer 'raytraced'"):
        TwinEnv(world, "grasp banana", renderer="raytraced")
    with pytest.raises(EnvError, match=r"unknown option\(s\) \['sise'\]"):
        TwinEnv(world, "grasp banana", sise=64)
    with pytest.raises(EnvError, match="fps must be a positive integer dividing the physics rate"):
        TwinEnv(world, "grasp banana", fps=30)
    with pytest.raises(EnvError, match="no world.yaml there"):
        TwinEnv(tmp_path, "grasp banana")
    with pytest.raises(EnvError, match="render_mode"):
        TwinEnv(world, "grasp banana", render_mode="human")


def test_object_shrink_draws_smaller_objects_with_the_same_episode(ws):
    """Randomization.object_shrink: the episode's other choices unchanged, the objects' Gaussians scaled about their
    base (the banana's footprint in the head camera smaller), the physics untouched."""
    from mirage2matter.env import TwinEnv
    from mirage2matter.env.config import Randomization

    plain = TwinEnv(ws / "world", "grasp banana", size=(96, 72), horizon=2)
    shrunk = TwinEnv(
        ws / "world", "grasp banana", size=(96, 72), horizon=2, randomization=Randomization(object_shrink=0.5)
    )
    try:
        o1, _ = plain.reset(seed=7)
        o2, _ = shrunk.reset(seed=7)
        d1, d2 = plain.draw, shrunk.draw
        assert d1.object_scale == 1.0 and 0.5 <= d2.object_scale < 1.0
        assert (d1.reset_seed, d1.task_seed) == (d2.reset_seed, d2.task_seed)
        np.testing.assert_allclose(plain.start_poses["banana"], shrunk.start_poses["banana"])  # same physics
        extents = []
        for e in (plain, shrunk):
            s = e.renderer.splat
            means = s.gaussians.means[s._slices["banana"]].numpy()
            extents.append(np.ptp(means[:, :2], axis=0).max())
            assert means[:, 2].min() > -0.01  # shrunk about its base: still on the table
        assert extents[1] == pytest.approx(extents[0] * d2.object_scale, rel=1e-3)
        assert not np.array_equal(o1["observation.images.head"], o2["observation.images.head"])
    finally:
        plain.close()
        shrunk.close()


def test_table_texture_recolours_only_the_table_with_the_same_episode(ws):
    """Randomization.table_texture: the episode's other choices unchanged, only the table's Gaussians re-coloured
    (the objects' and the rest of the scene's as built), and the next episode without a look gets the
    reconstruction's table back exactly."""
    from mirage2matter.env import TwinEnv
    from mirage2matter.env.config import Randomization
    from mirage2matter.env.episode import EpisodeDraw

    plain = TwinEnv(ws / "world", "grasp banana", size=(96, 72), horizon=2)
    textured = TwinEnv(
        ws / "world", "grasp banana", size=(96, 72), horizon=2, randomization=Randomization(table_texture=0.3)
    )
    try:
        o1, _ = plain.reset(seed=7)
        g0 = textured.renderer.splat.gaussians.sh[:, 0].clone()
        o2, _ = textured.reset(seed=7)
        d1, d2 = plain.draw, textured.draw
        assert d1.table_texture is None and d2.table_texture is not None
        assert (d1.reset_seed, d1.task_seed, d1.jitter) == (d2.reset_seed, d2.task_seed, d2.jitter)
        np.testing.assert_allclose(plain.start_poses["banana"], textured.start_poses["banana"])  # same physics
        r = textured.renderer
        idx = r._table.rows.numpy()  # found at the textured episode's start
        assert len(idx) > 100
        changed = (textured.renderer.splat.gaussians.sh[:, 0] != g0).any(dim=1).numpy()
        assert changed[idx].mean() > 0.9 and not np.delete(changed, idx).any()  # the table and nothing else
        assert not np.array_equal(o1["observation.images.head"], o2["observation.images.head"])
        r.start_episode(EpisodeDraw(d2.seed, d2.jitter, d2.T_cam_camj, d2.reset_seed, d2.task_seed))
        assert (r.splat.gaussians.sh[:, 0] == g0).all()  # the reconstruction's table, exactly
    finally:
        plain.close()
        textured.close()
