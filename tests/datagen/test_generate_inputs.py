"""``datagen.generate`` takes a loaded world and a parsed task: its checks before any worker starts, and the
world part of the dataset fingerprint (content, not a path). No simulator is built."""

from __future__ import annotations

import numpy as np
import pytest

from mirage2matter.datagen import GenerateConfig, GenerateError, RunConfig, generate, task_slug
from mirage2matter.datagen.simulated import world_fingerprint
from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.sim.tasks import GraspTask, PressTask
from mirage2matter.world.config import CameraConfig, ObjectConfig, PartConfig, WorldConfig

ONE = RunConfig(episodes=1)


def _world(root, cameras=("head", "wrist")) -> WorldConfig:
    cam = CameraConfig(mount="base", T_mount_cam=np.eye(4), K=np.eye(3), width=64, height=48)
    obj = ObjectConfig("banana", PartConfig(None, None), Sim3.identity())
    return WorldConfig(root=root, cameras={c: cam for c in cameras}, objects=[obj])


def test_refused_before_any_worker(tmp_path):
    cfg = GenerateConfig(ONE)
    with pytest.raises(GenerateError, match="no calibrated camera wrist"):
        generate(_world(tmp_path, cameras=("head",)), GraspTask("banana"), tmp_path / "ds", cfg, progress=False)
    with pytest.raises(GenerateError, match="no object named 'kiwi'"):
        generate(_world(tmp_path), GraspTask("kiwi"), tmp_path / "ds", cfg, progress=False)
    with pytest.raises(GenerateError, match="no press button named 'banana'"):
        generate(_world(tmp_path), PressTask("banana"), tmp_path / "ds", cfg, progress=False)
    assert not (tmp_path / "ds").exists()


def test_world_fingerprint_is_the_content(tmp_path):
    a, b = _world(tmp_path / "a"), _world(tmp_path / "a")
    assert world_fingerprint(a) == world_fingerprint(b)
    b.table_z = 0.01
    assert world_fingerprint(a) != world_fingerprint(b)


def test_task_slug():
    assert task_slug("push croissant --distance 0.1") == "push_croissant_distance_0_1"
    assert task_slug("!!") == "dataset"


def test_the_source_travels_to_workers_as_objects(tmp_path):
    """Workers are spawned processes or Ray actors: the world and the task are pickled, never re-parsed."""
    import pickle

    from mirage2matter.datagen.sim_source import SimSourceConfig, SimSourceFactory
    from mirage2matter.sim.tasks import PushTask

    world, task = _world(tmp_path), PushTask("banana", direction=(0.0, 2.0))
    back = pickle.loads(pickle.dumps(SimSourceFactory(SimSourceConfig(world=world, task=task)))).cfg
    assert back.task == task and back.task.direction == (0.0, 1.0)
    assert back.world.to_dict() == world.to_dict() and back.world.root == world.root
    assert back.to_json()["task"] == task.to_json()


@pytest.mark.parametrize("option, bad", [("object_shrink", 1.0), ("table_texture", -0.1)])
def test_a_randomization_option_enters_the_fingerprint_only_when_used(tmp_path, option, bad):
    """Datasets made before the option keep their fingerprint (no resume starts over); one made with it differs."""
    from mirage2matter.datagen.sim_source import SimSourceConfig
    from mirage2matter.env.config import Randomization
    from mirage2matter.stages.generate import Config

    world, task = _world(tmp_path), GraspTask("banana")
    plain = SimSourceConfig(world=world, task=task).to_json()["randomization"]
    used = SimSourceConfig(world=world, task=task, randomization=Randomization(**{option: 0.3})).to_json()
    assert option not in plain and used["randomization"][option] == 0.3
    assert getattr(Config(task=("grasp banana",), **{option: 0.3}).generation().randomization, option) == 0.3
    with pytest.raises(GenerateError, match=f"{option} must be in"):
        Config(task=("grasp banana",), **{option: bad}).validate()


def test_a_splat_server_is_refused_with_ray_and_is_not_part_of_the_dataset(tmp_path):
    """--splat-server is how the same episodes are drawn, not which: the fingerprint ignores it; it serves local
    worker processes only, so Ray with it is refused before anything starts."""
    from mirage2matter.datagen import dataset_fingerprint

    world, task = _world(tmp_path), GraspTask("banana")
    plain, served = GenerateConfig(ONE), GenerateConfig(ONE, splat_server=True)
    assert dataset_fingerprint(world, task, plain) == dataset_fingerprint(world, task, served)
    world.cameras = {c: CameraConfig(mount="base", T_mount_cam=np.eye(4), K=np.array([[50.0, 0, 32], [0, 50.0, 24],
                     [0, 0, 1]]), width=64, height=48) for c in ("head", "wrist")}  # fmt: skip
    with pytest.raises(GenerateError, match="cannot serve Ray actors"):
        cfg = GenerateConfig(RunConfig(episodes=1, ray_address="local"), splat_server=True)
        generate(world, task, tmp_path / "ds", cfg, progress=False)
    assert not (tmp_path / "ds").exists()


def test_supersample_enters_the_fingerprint_only_when_used(tmp_path):
    """--supersample changes the frames, so the dataset: off (1) keeps the fingerprint of datasets made before the
    option; on, the source records it and the hybrid renderer gets it."""
    from mirage2matter.datagen import dataset_fingerprint
    from mirage2matter.datagen.simulated import _source
    from mirage2matter.env.config import hybrid_options
    from mirage2matter.stages.generate import Config

    world, task = _world(tmp_path), GraspTask("banana")
    plain, ss = GenerateConfig(ONE), GenerateConfig(ONE, hybrid=hybrid_options(supersample=4))
    assert "supersample" not in _source(world, task, plain).to_json()["hybrid"]["splat"]
    assert _source(world, task, ss).to_json()["hybrid"]["splat"]["supersample"] == 4
    assert _source(world, task, ss).env_config().hybrid.splat.supersample == 4
    assert dataset_fingerprint(world, task, plain) != dataset_fingerprint(world, task, ss)
    assert Config(task=("grasp banana",), supersample=3).generation().hybrid.splat.supersample == 3
    with pytest.raises(GenerateError, match="supersample must be from 1"):
        Config(task=("grasp banana",), supersample=0).validate()


def test_start_regions_are_checked_and_enter_the_fingerprint_only_when_used(tmp_path):
    """--start-region (targeted demonstrations): parsed and checked against the world before any worker starts;
    datasets made before the option keep their fingerprint, one made with it differs."""
    from mirage2matter.datagen import dataset_fingerprint
    from mirage2matter.datagen.simulated import _source
    from mirage2matter.env.config import Randomization
    from mirage2matter.stages.generate import Config

    world, task = _world(tmp_path), GraspTask("banana")
    cfg = Config(task=("grasp banana",), start_region=("banana:0.55,0.62,-0.3,-0.2", " banana : 0.35,0.4,0.2,0.3"))
    rand = cfg.generation().randomization
    assert rand.start_regions == (("banana", 0.55, 0.62, -0.3, -0.2), ("banana", 0.35, 0.4, 0.2, 0.3))
    assert rand.regions() == {"banana": [(0.55, 0.62, -0.3, -0.2), (0.35, 0.4, 0.2, 0.3)]}
    plain = GenerateConfig(ONE)
    aimed = GenerateConfig(ONE, randomization=rand)
    assert "start_regions" not in _source(world, task, plain).to_json()["randomization"]
    assert dataset_fingerprint(world, task, plain) != dataset_fingerprint(world, task, aimed)
    for text in ("banana", "banana:0.5,0.6,0.1", "banana:a,b,c,d", ":0.5,0.6,0.1,0.2"):
        with pytest.raises(GenerateError, match="object:x_min,x_max,y_min,y_max"):
            Config(task=("grasp banana",), start_region=(text,)).validate()
    bad = {
        "kiwi": (("kiwi", 0.4, 0.5, 0.0, 0.1), "no object of that name"),
        "reversed": (("banana", 0.5, 0.4, 0.0, 0.1), "must be x_min < x_max"),
        "empty": (("banana", 0.5, 0.6, 0.1, 0.1), "must be x_min < x_max"),
        "outside": (("banana", 0.9, 1.0, 0.0, 0.1), "outside the world's randomize region"),
    }
    for region, message in bad.values():
        with pytest.raises(GenerateError, match=message):
            generate(world, task, tmp_path / "ds", GenerateConfig(ONE,
                     randomization=Randomization(start_regions=(region,))), progress=False)  # fmt: skip
    assert not (tmp_path / "ds").exists()


def test_takeover_ticks_are_drawn_per_seed_and_a_policy_that_succeeds_first_ends_the_attempt():
    """The takeover's policy acts for a number of ticks drawn from the episode's seed (in [lo, hi], the same for the
    same seed); when the task succeeds under the policy before that, the attempt ends there (nothing for the expert
    to correct) instead of the expert re-doing a finished task. A fake environment and policy: no simulator."""
    from mirage2matter.datagen.config import Takeover
    from mirage2matter.datagen.sim_source import SimEpisodeSource

    class Env:
        def __init__(self, succeed_at=None):
            self.t, self.succeed_at = 0, succeed_at

        def step(self, action):
            self.t += 1
            return {"t": self.t}, 0.0, self.t == self.succeed_at, False, {}

    class Policy:
        calls = resets = 0

        def reset(self):
            Policy.resets += 1

        def __call__(self, obs):
            Policy.calls += 1
            return np.zeros(8, np.float32)

    def source(env, steps):
        src = SimEpisodeSource.__new__(SimEpisodeSource)  # no twin built: only the policy's half of an attempt
        src.cfg = type("Cfg", (), {"takeover": Takeover(("p",), steps)})()
        src.env, src.policy = env, Policy()
        return src

    draws = [source(Env(), (5, 9))._policy_first({"t": 0}, seed)[:2] for seed in range(40)]
    assert all(obs["t"] == n and 5 <= n <= 9 for obs, n in draws)
    assert len({n for _, n in draws}) == 5  # every count in the range is drawn
    assert [source(Env(), (5, 9))._policy_first({"t": 0}, 7)[1] for _ in range(3)] == [draws[7][1]] * 3
    assert source(Env(), (0, 0))._policy_first({"t": 0}, 3)[1] == 0  # lo = hi = 0: the expert from the start

    obs, n, _, why = source(Env(succeed_at=3), (6, 6))._policy_first({"t": 0}, 1)
    assert n == 3 and obs["t"] == 3 and "succeeded on its own at step 3, before its takeover at step 6" in why
    assert source(Env(succeed_at=30), (6, 6))._policy_first({"t": 0}, 1)[3] == ""
    assert Policy.resets == 46  # a fresh policy state (its chunks) every episode
    assert Takeover(("p",), (9, 3)).problems() and Takeover((), (1, 2)).problems()
    assert not Takeover(("p",), (0, 60)).problems()
