"""The auxiliary targets (policy.targets): where the tool centre will be, from the demonstrations' actions."""

from __future__ import annotations

import json

import numpy as np

from fixtures import SAMPLE
from fixtures.policy_datasets import build_dataset, spec_for, tiny_config
from mirage2matter.policy import load_episodes, load_policy, train_policy
from mirage2matter.policy.targets import future_tcp, robot_for, tcp_of_actions


def test_tcp_of_actions_is_where_the_simulator_put_the_hand():
    # the sample's hand-eye views: joints and the hand pose Genesis reported for them when the sample was made
    views = json.loads((SAMPLE / "handeye" / "joints.json").read_text())["views"]
    spec = robot_for("franka_panda")
    actions = np.array([v["joints"][: spec.n_arm] + [spec.gripper_open] for v in views])
    expected = np.array([(np.asarray(v["T_base_hand"]) @ spec.T_ee_tcp)[:3, 3] for v in views])
    assert np.abs(tcp_of_actions(actions, spec) - expected).max() < 1e-5  # m


def test_future_tcp_looks_ahead_within_each_episode(tmp_path):
    build_dataset(tmp_path / "ds", spec_for(), seeds=(0, 1, 2))
    demos = load_episodes(tmp_path / "ds", 16)
    spec = robot_for(demos.meta.robot_type)
    out = future_tcp(demos, (1, 5), spec)
    tcp = tcp_of_actions(demos.action, spec)
    assert out.shape == (demos.n_frames, 6)
    for s, n in zip(demos.starts, demos.lengths, strict=True):  # a plain loop: t + h, never past the episode
        for t in range(s, s + n):
            assert np.array_equal(out[t, :3], tcp[min(t + 1, s + n - 1)])
            assert np.array_equal(out[t, 3:], tcp[min(t + 5, s + n - 1)])


def test_training_with_the_auxiliary_target_learns_it_and_deploys_without_it(tmp_path):
    build_dataset(tmp_path / "ds", spec_for(), seeds=(0, 1), length=12)
    cfg = tiny_config(aux_horizons=(2, 4), aux_weight=1.0)
    summary = train_policy(tmp_path / "ds", tmp_path / "run", cfg, log=lambda s: None, progress=False)
    assert summary["loss"]["aux_last"] < 0.5 * summary["loss"]["aux_first"]
    policy = load_policy(tmp_path / "run")
    assert policy.spec.aux_dim == 6
    obs = {"observation.images.head": np.zeros((48, 64, 3), np.uint8),
           "observation.images.wrist": np.zeros((32, 32, 3), np.uint8), "observation.state": np.zeros(9)}  # fmt: skip
    assert policy(obs).shape == (8,)
