"""Generation is the environment with the scripted expert acting: a generated episode's recorded actions, stepped
open-loop through a fresh environment from ``reset(seed=the episode's seed)``, reproduce it - joint states within
1e-3 rad at every step, the same success, and the same hybrid frames as generation rendered before video encoding
(PSNR >= 40 dB)."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

from mirage2matter.env import ENV_ID
from mirage2matter.env.config import EpisodeSpec
from mirage2matter.env.twin_env import STATE_KEY, image_key
from mirage2matter.world import load_world


@pytest.fixture(scope="module")
def world(sample_world_ws):
    return load_world(sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0) / "world")


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(((a.astype(np.float64) - b.astype(np.float64)) ** 2).mean())
    return 10 * np.log10(255.0**2 / max(mse, 1e-12))


def _generate(world, text: str, seed: int, size: tuple[int, int]):
    from mirage2matter.datagen.sim_source import SimEpisodeSource, SimSourceConfig
    from mirage2matter.sim.tasks import parse_task

    source = SimEpisodeSource(SimSourceConfig(world=world, task=parse_task(text, world), episode=EpisodeSpec(size)))
    try:
        return source.run(0, seed)
    finally:
        source.env.close()


def _replay(world, text: str, seed: int, size: tuple[int, int], episode) -> dict:
    env = gymnasium.make(ENV_ID, world=world, task=text, size=size, horizon=None)
    try:
        obs, info = env.reset(seed=seed)
        worst_q, worst_psnr, succeeded_at = 0.0, np.inf, None
        for t, action in enumerate(episode.action):
            worst_q = max(worst_q, float(np.abs(obs[STATE_KEY] - episode.state[t]).max()))
            for c, frames in episode.images.items():
                worst_psnr = min(worst_psnr, _psnr(obs[image_key(c)], frames[t]))
            obs, _, terminated, _, info = env.step(action)
            if terminated and succeeded_at is None:
                succeeded_at = t + 1
        return {"max_dq": worst_q, "min_psnr": worst_psnr, "succeeded_at": succeeded_at, "steps": len(episode.action)}
    finally:
        env.close()


def _check(world, text: str, seed: int, size: tuple[int, int]) -> dict:
    attempt = _generate(world, text, seed, size)
    assert attempt.success, attempt.reason
    r = _replay(world, text, seed, size, attempt.episode)
    print(f"\n{text!r} seed {seed} at {size[0]}x{size[1]}: {r}")
    assert r["max_dq"] <= 1e-3, r
    assert r["succeeded_at"] is not None and r["succeeded_at"] <= r["steps"], r  # the same success, within it
    assert r["min_psnr"] >= 40.0, r
    return r


def test_replayed_grasp_reproduces_the_generated_episode(world):
    _check(world, "grasp banana", seed=1234, size=(32, 24))


@pytest.mark.slow
@pytest.mark.parametrize(
    "text",
    ["grasp banana", "grasp croissant", "press button", "push croissant --direction 0,1 --distance 0.1",
     "pull banana --distance 0.1"],
)  # fmt: skip
def test_replay_of_every_task_at_full_size(world, text):
    for seed in (11, 12):
        _check(world, text, seed, size=(224, 224))


def test_a_splat_server_draws_the_same_episode(world):
    """Generation's workers can hand their splat layer to one batched renderer (``--splat-server``, for a GPU): the
    same episode, with the episode's own object scale and table look, states identical and frames as the
    in-process renderer draws them (>= 40 dB; it draws the head camera over a cached background)."""
    from mirage2matter.datagen.sim_source import SimEpisodeSource, SimSourceConfig
    from mirage2matter.env.config import Randomization
    from mirage2matter.env.hybrid import splat_parts
    from mirage2matter.render.splat_server import SplatServer
    from mirage2matter.sim.tasks import parse_task

    cfg = SimSourceConfig(world=world, task=parse_task("grasp banana", world), episode=EpisodeSpec((32, 24)),
                          randomization=Randomization(object_shrink=0.3, table_texture=0.3))  # fmt: skip
    runs = []
    server = SplatServer(splat_parts(world), cfg.hybrid.splat, slots=1, cameras=len(cfg.episode.cameras),
                         size=cfg.episode.size, background=cfg.hybrid.background, table_z=world.table_z)  # fmt: skip
    with server as handle:
        for splat_server in (None, handle):
            source = SimEpisodeSource(cfg, splat_server)
            try:
                assert (source.env.renderer.splat is None) == (splat_server is not None)
                runs.append(source.run(0, 1234))
            finally:
                source.env.close()
    local, served = runs
    assert local.success and served.success, (local.reason, served.reason)
    np.testing.assert_array_equal(local.episode.state, served.episode.state)
    for c, frames in local.episode.images.items():
        worst = min(_psnr(a, b) for a, b in zip(frames, served.episode.images[c], strict=True))
        assert worst >= 40.0, (c, worst)
    assert server.stats["frames"] == len(local.episode.action) + 1  # every frame drawn there (the last one too)


@pytest.mark.slow
def test_generate_with_a_splat_server_and_two_workers_writes_a_valid_dataset(world, tmp_path):
    """The server's handle travels into spawned worker processes, which draw through it: a dataset an independent
    reader loads, every frame drawn by the server."""
    from mirage2matter.datagen import GenerateConfig, RunConfig, generate
    from mirage2matter.export.validate import validate
    from mirage2matter.sim.tasks import parse_task

    cfg = GenerateConfig(RunConfig(episodes=2, workers=2, preview=0), EpisodeSpec((32, 24)), splat_server=True)
    s = generate(world, parse_task("grasp banana", world), tmp_path / "ds", cfg, progress=False)
    assert s["episodes"] == 2 and validate(s["dataset"]) == []
    assert s["splat_server"]["frames"] >= s["frames"] and s["splat_server"]["largest_batch"] <= 2
