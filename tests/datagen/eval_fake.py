"""TEST DOUBLE: an evaluation job (``eval_workers.EvalJob``'s interface) on a toy environment, for the Ray evaluation
tests: no simulator, no rendering.

The environment reaches x >= 1 in steps of the action; where an episode starts is drawn from its seed and moved by
the bytes of a "world" file (read where the job is built: shipped to Ray workers as content, ``portable``);
``delay`` slows every step down (to kill a node mid-run)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mirage2matter.datagen.shipping import ShippedFactory, pack
from mirage2matter.ray_cluster import RayResources


class LineEnv:
    def __init__(self, world: str, delay: float):
        self.shift, self.delay = sum(Path(world).read_bytes()) % 7 / 20, delay

    def reset(self, seed=None):
        rng = np.random.default_rng(seed)
        self.x, self.t = float(rng.uniform(0, 0.6)) + self.shift, 0
        self.start_poses = {"puck": np.array([[1, 0, 0, self.x], [0, 1, 0, 0.25], [0, 0, 1, 0], [0, 0, 0, 1.0]])}
        return self._obs(), {}

    def _obs(self) -> dict:
        img = np.full((8, 8, 3), int(255 * min(self.x, 1.0)), np.uint8)
        return {"observation.state": np.array([self.x], np.float32), "observation.images.head": img}

    def step(self, action):
        time.sleep(self.delay)
        self.x += float(action[0])
        self.t += 1
        info = {} if self.x >= 1 else {"reason": "not there yet"} if self.t >= 5 else {}
        return self._obs(), float(self.x >= 1), self.x >= 1, self.t >= 5, info


def policy(obs) -> np.ndarray:
    return np.array([0.1], np.float32)


@dataclass(frozen=True, eq=False)
class LineJob:
    world: str  # a file of a workspace: its folder's parent is shipped
    delay: float = 0.0
    camera: str | None = None
    max_episode_seconds: float | None = None

    def build(self):
        return LineEnv(self.world, self.delay), policy

    def portable(self):
        return ShippedFactory(self, pack([Path(self.world)], Path(self.world).parent.parent))

    def resources(self) -> RayResources:
        return RayResources()
