"""TEST DOUBLE: a fake episode source for the runner / writer tests (no simulator, no rendering).

Episodes are smooth synthetic pictures and random state/action arrays drawn from the attempt seed,
so the same seed gives the same bytes; attempts whose seed is divisible by 4 "fail". ``delay``
slows every attempt down (for the kill test). ``texture``: a file of the "world" the pictures depend on (read where
the source is built: shipped to Ray workers as content, ``portable``); ``die_at``: the worker running that attempt
exits at once, the first time only (``die_marker`` remembers it), as a killed worker does."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mirage2matter.datagen import Attempt
from mirage2matter.datagen.shipping import ShippedFactory, pack
from mirage2matter.export import DatasetSpec, EpisodeData

BUILDS_ENV = "M2M_TEST_FAKE_BUILDS"  # a file to log every FakeSource built to (workers inherit the environment)

# Any names do: the writers know no robot.
SPEC = DatasetSpec(
    state_names=tuple(f"q{i}" for i in range(9)),
    action_names=tuple(f"a{i}" for i in range(8)),
    fps=10,
    cameras={"head": (32, 48), "wrist": (32, 32)},
)


class FakeSource:
    def __init__(self, delay: float = 0.0, task: str = "grasp banana", texture: str = "", die_at: int = -1,
                 die_marker: str = ""):  # fmt: skip
        self.spec = SPEC
        self.delay = delay
        self.task = task
        self.shift = sum(Path(texture).read_bytes()) % 40 if texture else 0
        self.die_at, self.die_marker = die_at, die_marker
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
        if attempt == self.die_at:
            try:
                os.close(os.open(self.die_marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
                os._exit(1)  # the worker dies mid-attempt, once
            except FileExistsError:
                pass
        rng = np.random.default_rng(seed)
        if seed % 4 == 0:
            return Attempt(False, "fake failure", record={"seed_mod4": 0})
        t = int(rng.integers(4, 10))
        images = {}
        for cam, (h, w) in SPEC.cameras.items():
            yy, xx = np.mgrid[0:h, 0:w]
            base = rng.uniform(20, 200, 3) + self.shift
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
    texture: str = ""  # a file in a workspace (shipped from <workspace>, the folder above its folder)
    die_at: int = -1
    die_marker: str = ""

    def __call__(self) -> FakeSource:
        return FakeSource(self.delay, self.task, self.texture, self.die_at, self.die_marker)

    def portable(self) -> ShippedFactory | FakeFactory:
        if not self.texture:
            return self
        return ShippedFactory(self, pack([Path(self.texture)], Path(self.texture).parents[1]))


@dataclass(frozen=True)
class SpawnOnlyFactory(FakeFactory):
    """A FakeFactory that also holds what pickles only into a process as it is spawned (a lock, as a splat server's
    handle holds queues and shared buffers)."""

    inherited: object = None
