"""TEST DOUBLE: a fake episode source for the runner / writer tests (no simulator, no rendering).

Episodes are smooth synthetic pictures and random state/action arrays drawn from the attempt seed,
so the same seed gives the same bytes; attempts whose seed is divisible by 4 "fail". ``delay``
slows every attempt down (for the kill test)."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np

from mirage2matter.datagen import Attempt
from mirage2matter.export import DatasetSpec, EpisodeData

BUILDS_ENV = "M2M_TEST_FAKE_BUILDS"  # a file to log every FakeSource built to (workers inherit the environment)

# Any names do: the writers know no robot.
SPEC = DatasetSpec(
    state_names=tuple(f"q{i}" for i in range(9)), action_names=tuple(f"a{i}" for i in range(8)),
    cameras={"head": (32, 48), "wrist": (32, 32)},
)


class FakeSource:
    def __init__(self, delay: float = 0.0, task: str = "grasp banana"):
        self.spec = SPEC
        self.delay = delay
        self.task = task
        if os.environ.get(BUILDS_ENV):  # one line per source built (a worker pool's test counts them)
            with open(os.environ[BUILDS_ENV], "a") as f:
                f.write(f"{os.getpid()} {task}\n")

    def retarget(self, factory) -> bool:
        """Another task's episodes from this source (as the simulator's source: only the task may differ)."""
        if not isinstance(factory, FakeFactory) or factory.delay != self.delay:
            return False
        self.task = factory.task
        return True

    def run(self, attempt: int, seed: int) -> Attempt:
        time.sleep(self.delay)
        rng = np.random.default_rng(seed)
        if seed % 4 == 0:
            return Attempt(False, "fake failure", record={"seed_mod4": 0})
        t = int(rng.integers(4, 10))
        images = {}
        for cam, (h, w) in SPEC.cameras.items():
            yy, xx = np.mgrid[0:h, 0:w]
            base = rng.uniform(20, 200, 3)
            frames = [np.clip(base + 30 * np.stack([xx / w, yy / h, np.full_like(xx, i / t, float)], -1), 0, 255)
                      for i in range(t)]  # fmt: skip
            images[cam] = np.stack(frames).astype(np.uint8)
        state = rng.normal(size=(t, 9)).astype(np.float32)
        action = rng.normal(size=(t, 8)).astype(np.float32)
        record = {"object_xy": rng.uniform(-1, 1, 2).tolist()}
        return Attempt(True, "", EpisodeData(self.task, images, state, action), record, {"fake": 0.001})


@dataclass(frozen=True)
class FakeFactory:
    delay: float = 0.0
    task: str = "grasp banana"

    def __call__(self) -> FakeSource:
        return FakeSource(self.delay, self.task)


@dataclass(frozen=True)
class SpawnOnlyFactory(FakeFactory):
    """A FakeFactory that also holds what pickles only into a process as it is spawned (a lock, as a splat server's
    handle holds queues and shared buffers)."""

    inherited: object = None

