"""Closed-loop evaluation helpers (mirage2matter.evaluation) on a toy environment."""

import numpy as np
import pytest

from mirage2matter.evaluation import evaluate_policy, wilson_interval


def test_wilson_interval_matches_the_textbook_values():
    # Agresti & Coull's worked values: 8/10 successes -> (0.490, 0.943); 0/50 -> (0, 0.071)
    assert wilson_interval(8, 10) == pytest.approx((0.4902, 0.9433), abs=1e-4)
    lo, hi = wilson_interval(0, 50)
    assert lo == 0.0 and hi == pytest.approx(0.0713, abs=1e-4)
    assert wilson_interval(50, 50)[1] == 1.0 and wilson_interval(0, 0) == (0.0, 1.0)


class _Line:
    """Reach x >= 1 in steps of the action; terminated on success, truncated after 5 steps."""

    def reset(self, seed=None):
        self.x, self.t = 0.0, 0
        self.start = 0.5 if seed % 2 else 0.0  # odd seeds start half way
        self.x = self.start
        return {"observation.state": np.array([self.x], np.float32)}, {}

    def step(self, action):
        self.x += float(action[0])
        self.t += 1
        obs = {"observation.state": np.array([self.x], np.float32)}
        return obs, float(self.x >= 1), self.x >= 1, self.t >= 5, {}


def test_evaluation_counts_terminations_as_successes():
    summary, frames = evaluate_policy(_Line(), lambda obs: np.array([0.15]), episodes=6, seed=0, progress=False,
                                      log=lambda s: None, camera="observation.state")  # fmt: skip
    # 0.15 x 5 = 0.75: only the episodes starting at 0.5 get there
    assert summary["successes"] == 3 and summary["episodes"] == 6
    assert [r["success"] for r in summary["runs"]] == [False, True] * 3
    assert summary["wilson95"] == list(wilson_interval(3, 6)) and len(frames) == 2
