"""A policy's open-loop action error on expert episodes (``bench.policy_gap``): chunk i is scored against the
expert's actions t..t+K-1 in action-std units, per renderer, on successful episodes only."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from mirage2matter.bench.policy_gap import open_loop_error

K, A, T = 4, 3, 9


def _episode(seed: int, success: bool = True) -> dict:
    rng = np.random.default_rng(seed)
    ep = {"action": rng.normal(size=(T, A)).astype(np.float32), "state": np.arange(T + 1, dtype=np.float32)[:, None],
          "success": success, "seed": seed}  # fmt: skip
    for r, level in (("hybrid", 0), ("ground_truth", 255)):  # the renderer is told apart by its pixels
        ep[f"{r}.head"] = np.full((T + 1, 4, 4, 3), level, np.uint8)
    return ep


class Oracle:
    """Predicts the expert's own next K actions (found by the state's step index), plus ``bias`` on ground-truth
    frames and a one-step lag when ``lag``."""

    def __init__(self, episodes: list[dict], bias: float, lag: bool = False) -> None:
        self.meta = SimpleNamespace(cameras=("head",))
        self.action_std = np.full(A, 2.0, np.float32)
        self.episodes, self.bias, self.lag = episodes, bias, lag
        self.calls = 0

    def predict_chunk(self, obs: dict) -> np.ndarray:
        self.calls += 1
        t = int(obs["observation.state"][0])
        ep = next(e for e in self.episodes if e["success"])
        t = max(0, t - 1) if self.lag else t
        chunk = np.zeros((K, A), np.float32)
        future = ep["action"][t : t + K]
        chunk[: len(future)] = future
        return chunk + (self.bias if obs["observation.images.head"][0, 0, 0] == 255 else 0.0)


def test_the_expert_itself_scores_zero_and_a_bias_scores_its_size_in_std_units() -> None:
    eps = [_episode(1), _episode(2, success=False)]  # the failed episode is not compared
    oracle = Oracle(eps, bias=0.5)
    err = open_loop_error(oracle, eps, stride=1)
    assert err["hybrid"] == pytest.approx(0.0, abs=1e-7)
    assert err["ground_truth"] == pytest.approx(0.5 / 2.0)  # |bias| / std on every compared action
    assert oracle.calls == 2 * T  # every step of the one successful episode, both renderers

    err_lag = open_loop_error(Oracle(eps, bias=0.0, lag=True), eps, stride=3)
    assert err_lag["hybrid"] > 0.1 and err_lag["hybrid"] == pytest.approx(err_lag["ground_truth"])


def test_nothing_to_compare_is_an_error() -> None:
    with pytest.raises(ValueError, match="no successful expert episode"):
        open_loop_error(Oracle([_episode(1)], 0.0), [_episode(1, success=False)])
