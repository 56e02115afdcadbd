"""Closed-loop evaluation helpers (mirage2matter.evaluation) on a toy environment."""

import numpy as np
import pytest

from mirage2matter.errors import EpisodeStalled
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
        c, s = np.cos(np.radians(30 * seed)), np.sin(np.radians(30 * seed))  # a heading of 30 deg per seed
        self.start_poses = {"puck": np.array([[c, -s, 0, self.start], [s, c, 0, 0.25], [0, 0, 1, 0], [0, 0, 0, 1.0]])}
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
    assert [r["start_xy"] for r in summary["runs"][:2]] == [{"puck": [0.0, 0.25]}, {"puck": [0.5, 0.25]}]
    assert [r["start_yaw_deg"]["puck"] for r in summary["runs"]] == [0.0, 30.0, 60.0, 90.0, 120.0, 150.0]


class _SlowFromStep:
    """A _Line whose steps take 0.2 s of a fake clock, then 30 s from step 3 on (a renderer gone slow in one
    pose); ``timings`` as TwinEnv keeps them."""

    def __init__(self, clock: list[float]):
        self.line, self.clock, self.timings = _Line(), clock, {}

    def reset(self, seed=None):
        self.timings = {"physics": 0.0}
        return self.line.reset(seed)

    def step(self, action):
        dt = 0.2 if self.line.t < 3 else 30.0
        self.clock[0] += dt
        self.timings["physics"] += dt
        return self.line.step(action)


def test_an_episode_past_the_wall_clock_limit_is_cut_and_counted_a_failure():
    now = [0.0]
    env = _SlowFromStep(now)

    def run(speed: float, limit: float | None) -> dict:
        return evaluate_policy(env, lambda obs: np.array([speed]), episodes=1, seed=0, progress=False, keep_frames=0,
                               log=lambda s: None, max_episode_seconds=limit, clock=lambda: now[0])[0]  # fmt: skip

    # 0.3 per step: x reaches 1.2 at step 4, which ends at 0.6 + 30 s: a success (a finished step counts)
    ok = run(0.3, 20.0)
    assert ok["successes"] == 1 and ok["cut"] == 0 and ok["runs"][0]["max_step_seconds"] == pytest.approx(30.0)
    # 0.1 per step: still running after step 4 (30.6 s > 20 s): cut there, a failure, with the env's timings
    cut = run(0.1, 20.0)
    (row,) = cut["runs"]
    assert cut["successes"] == 0 and cut["cut"] == 1 and row["cut"] and row["steps"] == 4
    assert "wall-clock limit" in row["reason"] and row["timings"] == {"physics": pytest.approx(30.6)}
    # no limit: the same episode runs to its horizon (truncated after 5 steps), not cut
    full = run(0.1, None)
    assert full["cut"] == 0 and full["runs"][0]["steps"] == 5 and "cut" not in full["runs"][0]


class _StallsAt(_Line):
    """A _Line whose renderer stalls for good: seed 1 at its second step, seed 2 already at its reset (its start
    picture); the next reset works (as TwinEnv's ground-truth renderer restarts)."""

    def reset(self, seed=None):
        self.seed = seed
        if seed == 2:
            raise EpisodeStalled("the renderer stalled 3 times on one state")
        return super().reset(seed)

    def step(self, action):
        if self.seed == 1 and self.t == 1:
            raise EpisodeStalled("the renderer stalled 3 times on one state")
        return super().step(action)


def test_an_episode_whose_env_stalls_is_cut_and_the_evaluation_goes_on():
    saved = []
    summary, frames = evaluate_policy(_StallsAt(), lambda obs: np.array([0.3]), episodes=4, progress=False,
                                      log=lambda s: None, camera="observation.state", on_episode=saved.append)
    # every seed has its record, saved as it came (a killed run resumes after them); 0.3 x 4 >= 1: seeds 0 and 3 pass
    assert [r["seed"] for r in saved] == [0, 1, 2, 3] and summary["runs"] == saved
    assert [r["success"] for r in saved] == [True, False, False, True] and summary["cut"] == 2
    stalled_step, stalled_reset = saved[1], saved[2]
    assert stalled_step["cut"] and stalled_step["steps"] == 2 and "stalled at step 2" in stalled_step["reason"]
    assert stalled_reset["cut"] and stalled_reset["steps"] == 0 and "stalled 3 times" in stalled_reset["reason"]
    assert "cut" not in saved[0] and "cut" not in saved[3]
    # the first two episodes' pictures are kept: all of seed 0's (4 steps), seed 1's up to its stall
    assert [len(f) for f in frames] == [5, 2]
