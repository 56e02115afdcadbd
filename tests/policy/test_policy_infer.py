"""Deployment: observations in our datasets' keys, chunk execution, robot checks, bad checkpoints, user callables."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fixtures.policy_datasets import ROBOT
from mirage2matter.policy import (
    CallablePolicy,
    Policy,
    PolicyEnsemble,
    PolicyError,
    load_ensemble,
    load_policy,
    load_policy_callable,
    open_policy,
)
from mirage2matter.policy.infer import medoid


def _obs(rng, h=224, w=224, s=9) -> dict:
    return {
        "observation.images.head": rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
        "observation.images.wrist": rng.integers(0, 256, (h // 2, w // 2, 3), dtype=np.uint8),
        "observation.state": rng.normal(size=s).astype(np.float32),
    }


def test_policy_takes_any_image_size_and_checks_observations(tiny_run):
    _, out, _, _ = tiny_run
    policy = load_policy(out, robot_type=ROBOT.robot_type, state_names=ROBOT.state_names,
                         action_names=ROBOT.action_names, fps=10, cameras=("head", "wrist"))  # fmt: skip
    rng = np.random.default_rng(0)
    a = policy(_obs(rng))
    assert a.shape == (8,) and a.dtype == np.float32 and np.isfinite(a).all()
    assert policy.observation_keys == ("observation.images.head", "observation.images.wrist", "observation.state")
    obs = _obs(rng)
    with pytest.raises(PolicyError, match=r"lacks \['observation.images.wrist'\]"):
        policy({k: v for k, v in obs.items() if k != "observation.images.wrist"})
    with pytest.raises(PolicyError, match="observation.state must be 9 finite numbers"):
        policy({**obs, "observation.state": np.zeros(7, np.float32)})
    with pytest.raises(PolicyError, match="uint8"):
        policy({**obs, "observation.images.head": obs["observation.images.head"].astype(np.float32)})


def test_a_live_camera_s_image_is_cropped_about_its_centre_to_the_training_frames_aspect(tiny_run):
    """A policy trained on 64 x 48 head frames (and square wrist ones) given a camera's whole image of another
    aspect sees its centre crop of the frames' aspect (as a world draws frames: env.lens), not the image squashed."""
    from mirage2matter.policy.data import resize_area

    _, out, _, _ = tiny_run
    policy = load_policy(out)
    assert policy.frame_sizes == {"head": (64, 48), "wrist": (32, 32)} and policy.spec.image_size == 32
    obs = _obs(np.random.default_rng(3))
    wide = np.random.default_rng(4).integers(0, 256, (96, 256, 3), dtype=np.uint8)  # 2.67:1 against 4:3
    tall = np.random.default_rng(5).integers(0, 256, (200, 64, 3), dtype=np.uint8)
    for image, centre in ((wide, wide[:, 64:192]), (tall, tall[76:124])):
        chunk = policy.predict_chunk({**obs, "observation.images.head": image})
        np.testing.assert_array_equal(chunk, policy.predict_chunk({**obs, "observation.images.head": centre}))
        squashed = resize_area(image, policy.spec.image_size)  # what the policy took before: the image squashed
        assert not np.allclose(chunk, policy.predict_chunk({**obs, "observation.images.head": squashed}))
    # a policy saved before the frames' sizes were recorded squashes, as it was trained to
    policy.frame_sizes = {}
    np.testing.assert_array_equal(policy.predict_chunk({**obs, "observation.images.head": wide}),
                                  policy.predict_chunk({**obs, "observation.images.head": resize_area(wide, 32)}))


def test_temporal_ensembling_and_replanning(tiny_run):
    _, out, _, _ = tiny_run
    k = 4  # the tiny run's chunk
    chunks = [np.full((k, 8), float(10 * i), np.float32) + np.arange(k, dtype=np.float32)[:, None]
              for i in range(6)]  # fmt: skip
    policy = load_policy(out, ensemble_decay=0.5)
    calls = iter(chunks)
    policy.predict_chunk = lambda obs: next(calls)
    got = [float(policy({})[0]) for _ in range(6)]
    # step t averages chunk j's entry t - j over the last k chunks, oldest weighted most: exp(-0.5 i)
    for t in range(6):
        js = [j for j in range(max(0, t - k + 1), t + 1)]
        w = np.exp(-0.5 * np.arange(len(js)))
        assert got[t] == pytest.approx(sum(wi * (10 * j + t - j) for wi, j in zip(w, js, strict=True)) / w.sum())
    policy.reset()
    calls = iter(chunks)
    assert float(policy({})[0]) == 0.0  # after reset, only the new chunk counts

    replan = load_policy(out, replan_every=2)
    calls = iter(chunks)
    replan.predict_chunk = lambda obs: next(calls)
    # a chunk every 2 steps, executed in order: chunk0[0], chunk0[1], chunk1[0], chunk1[1], ...
    assert [float(replan({})[0]) for _ in range(5)] == [0.0, 1.0, 10.0, 11.0, 20.0]
    with pytest.raises(PolicyError, match="replan_every"):
        load_policy(out, replan_every=k + 1)


def test_an_ensemble_averages_its_members_chunks_and_executes_them_as_one_policy(tiny_run, tmp_path):
    _, out, _, _ = tiny_run
    rng = np.random.default_rng(1)
    obs = _obs(rng)
    single = load_policy(out)
    same = load_ensemble([out, out])
    assert isinstance(same, PolicyEnsemble) and same.action_dim == 8
    assert same.observation_keys == single.observation_keys
    np.testing.assert_allclose(same.predict_chunk(obs), single.predict_chunk(obs), atol=1e-6)
    np.testing.assert_allclose(same(obs), single(obs), atol=1e-6)  # the same execution (temporal ensembling)

    k = 4  # the tiny run's chunk
    ens = load_ensemble([out, out], ensemble_decay=0.0)
    ens.members[0].predict_chunk = lambda o: np.zeros((k, 8), np.float32)
    ens.members[1].predict_chunk = lambda o: np.full((k, 8), 2.0, np.float32) + np.arange(k)[:, None]
    assert ens.predict_chunk(obs)[:, 0].tolist() == [1.0, 1.5, 2.0, 2.5]  # the members' mean chunk
    assert [float(ens(obs)[0]) for _ in range(2)] == [1.0, 1.25]  # step 1: mean of chunk0[1] and chunk1[0]
    replan = load_ensemble([out, out], replan_every=2)
    replan.members[0].predict_chunk = replan.members[1].predict_chunk = lambda o: np.arange(k)[:, None] * np.ones(8)
    assert [float(replan(obs)[0]) for _ in range(3)] == [0.0, 1.0, 0.0]

    # members of another rate cannot join; the robot checks reach every member
    other = tmp_path / "other"
    other.mkdir()
    blob = torch.load(out / "policy.pt", weights_only=True)
    blob["meta"]["fps"] = 20
    torch.save(blob, other / "policy.pt")
    with pytest.raises(PolicyError, match=r"other/policy.pt cannot join an ensemble with .*policy.pt: its rate differ"):
        load_ensemble([out, other])
    with pytest.raises(PolicyError, match=r"policy.pt: this policy was trained for 10 Hz, not 20 Hz"):
        load_ensemble([out, out], fps=20)
    with pytest.raises(PolicyError, match=r"robot_type 'franka_panda'.*not 'ur5e'"):
        load_ensemble([out, out]).check_matches(robot_type="ur5e")
    with pytest.raises(PolicyError, match="two or more"):
        PolicyEnsemble([single])


def test_a_medoid_ensemble_executes_the_member_chunk_nearest_the_others(tiny_run):
    """Two members that go either way around and one between them: the mean of the outer two is a motion none of
    them makes; the medoid is the middle member's own chunk."""
    _, out, _, _ = tiny_run
    obs = _obs(np.random.default_rng(2))
    k = 4
    ens = load_ensemble([out, out, out], ensemble_decay=0.0, combine="medoid")
    assert ens.combine == "medoid"
    left, right = np.full((k, 8), -3.0, np.float32), np.full((k, 8), 3.0, np.float32)
    middle = np.full((k, 8), 0.5, np.float32) + np.arange(k)[:, None]
    for m, c in zip(ens.members, (left, middle, right), strict=True):
        m.predict_chunk = lambda o, c=c: c
    np.testing.assert_array_equal(ens.predict_chunk(obs), middle)
    # the first of equals
    assert medoid(np.stack([middle, middle, middle])) == 0
    with pytest.raises(PolicyError, match="medoid ensemble needs three or more"):
        load_ensemble([out, out], combine="medoid")
    with pytest.raises(PolicyError, match="combine must be one of mean, medoid"):
        load_ensemble([out, out], combine="median")


def test_checkpoint_of_another_robot_or_that_does_not_load(tiny_run, tmp_path):
    _, out, _, _ = tiny_run
    with pytest.raises(PolicyError, match=r"policy.pt: this policy was trained for robot_type 'franka_panda'.*"
                                          r"not 'ur5e'.*Train one on datasets of this robot"):  # fmt: skip
        load_policy(out, robot_type="ur5e")
    with pytest.raises(PolicyError, match=r"action 8 .* not 7"):
        load_policy(out, action_names=ROBOT.action_names[:7])
    with pytest.raises(PolicyError, match="20 Hz"):
        load_policy(out, fps=20)
    with pytest.raises(PolicyError, match=r"camera\(s\) \['wrist'\]"):
        load_policy(out, cameras=["head"])
    with pytest.raises(PolicyError, match="holds no policy.pt"):
        load_policy(tmp_path)
    with pytest.raises(PolicyError, match="not found"):
        load_policy(tmp_path / "nothing.pt")
    (tmp_path / "policy.pt").write_bytes(b"garbage")
    with pytest.raises(PolicyError, match=r"policy.pt does not load as a policy checkpoint.*re-train"):
        load_policy(tmp_path)
    torch.save({"format": "lerobot", "weights": {}}, tmp_path / "policy.pt")
    with pytest.raises(PolicyError, match="load_policy_callable"):
        load_policy(tmp_path)
    blob = torch.load(out / "policy.pt", weights_only=True)
    blob["weights"] = {k: v[:1] if v.ndim else v for k, v in blob["weights"].items()}
    torch.save(blob, tmp_path / "policy.pt")
    with pytest.raises(PolicyError, match="do not fit its model"):
        load_policy(tmp_path)
    # an unfinished run's folder (checkpoint only) says how to finish it
    (tmp_path / "policy.pt").unlink()
    torch.save(torch.load(out / "checkpoint.pt", weights_only=True), tmp_path / "checkpoint.pt")
    with pytest.raises(PolicyError, match="unfinished run"):
        load_policy(tmp_path)


def test_user_callables(tmp_path, tiny_run):
    mod = tmp_path / "my_policy.py"
    mod.write_text(
        "import numpy as np\n"
        "class Replay:\n"
        "    def __init__(self): self.t = 0\n"
        "    def reset(self): self.t = 0\n"
        "    def __call__(self, obs):\n"
        "        self.t += 1\n"
        "        return np.full(8, self.t)\n"
        "replay = Replay()\n"
        "def bad(obs): return [0.0] * 3\n"
        "def nan(obs): return [float('nan')] * 8\n"
        "not_callable = 3\n"
    )
    p = load_policy_callable(f"{mod}:replay", action_dim=8)
    assert isinstance(p, CallablePolicy)
    assert p({})[0] == 1 and p({})[0] == 2 and p({}).dtype == np.float32
    p.reset()
    assert p({})[0] == 1
    with pytest.raises(PolicyError, match="returned 3 action values; the robot takes 8"):
        load_policy_callable(f"{mod}:bad", action_dim=8)({})
    with pytest.raises(PolicyError, match="NaN"):
        load_policy_callable(f"{mod}:nan")({})
    with pytest.raises(PolicyError, match="not callable"):
        load_policy_callable(f"{mod}:not_callable")
    with pytest.raises(PolicyError, match="has no attribute 'missing'"):
        load_policy_callable(f"{mod}:missing")
    with pytest.raises(PolicyError, match="importing no_such_module_xyz failed"):
        load_policy_callable("no_such_module_xyz:fn")
    with pytest.raises(PolicyError, match="expected 'module:function'"):
        load_policy_callable("just_a_name")
    assert callable(load_policy_callable("numpy:zeros_like"))  # an installed module by name
    assert isinstance(open_policy(f"{mod}:replay"), CallablePolicy)
    assert isinstance(open_policy(tiny_run[1]), Policy)
