"""The simulator's episode source moved to another task (a worker pool's workers serve every task of a generate run
with one twin): its episodes are the ones a source built for that task makes."""

from __future__ import annotations

import numpy as np
import pytest

from mirage2matter.datagen.sim_source import SimEpisodeSource, SimSourceConfig, SimSourceFactory
from mirage2matter.env.config import EpisodeSpec
from mirage2matter.sim.tasks import parse_task
from mirage2matter.world import load_world

SIZE = (32, 24)


@pytest.fixture(scope="module")
def world(sample_world_ws):
    return load_world(sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0) / "world")


def _config(world, text: str, size=SIZE) -> SimSourceConfig:
    return SimSourceConfig(world=world, task=parse_task(text, world), episode=EpisodeSpec(size))


def test_a_retargeted_source_makes_the_new_tasks_episodes(world):
    fresh = SimEpisodeSource(_config(world, "grasp banana"))
    try:
        want = fresh.run(0, 4321)
    finally:
        fresh.close()
    assert want.success, want.reason

    source = SimEpisodeSource(_config(world, "press button"))
    try:
        pressed = source.run(0, 99)  # an episode of another task first: the arm and the button moved
        assert pressed.success, pressed.reason
        assert source.retarget(SimSourceFactory(_config(world, "grasp banana")))
        assert source.task.instruction == want.episode.task and source.env.instruction == want.episode.task
        got = source.run(0, 4321)
        # other frames, or a splat server's handle: the source cannot serve them and says so (a new one is built)
        assert not source.retarget(SimSourceFactory(_config(world, "grasp banana", size=(48, 32))))
        assert not source.retarget(SimSourceFactory(_config(world, "grasp banana"), splat_server=object()))
    finally:
        source.close()
    assert got.success, got.reason
    assert got.episode.task == want.episode.task
    assert np.array_equal(got.episode.state, want.episode.state)
    assert np.array_equal(got.episode.action, want.episode.action)
    for camera, frames in want.episode.images.items():
        assert np.array_equal(got.episode.images[camera], frames), camera
    assert _without_clock(got.record) == _without_clock(want.record)


def _without_clock(record: dict) -> dict:
    """An attempt's record less the task's wall-clock reading (the one field that is not a function of the seed)."""
    return {**record, "task_info": {k: v for k, v in record["task_info"].items() if k != "wall_s"}}
