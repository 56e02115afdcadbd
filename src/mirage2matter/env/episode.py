"""The per-episode randomisation, drawn from the episode's seed: the one function behind ``TwinEnv.reset(seed)``
and so behind every generated episode (generation resets the environment with the attempt's seed).

Every random choice is drawn up front, in a fixed order, so the seed fully describes the episode: the splat
world's colour / light jitter, a small mount jitter per camera, the seed of the twin's reset (object start
poses) and a seed for the task's own choices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..render.composite import ColorJitter
from ..render.table_texture import TableTexture
from .config import Randomization

__all__ = ["EpisodeDraw", "draw_episode"]


@dataclass(frozen=True)
class EpisodeDraw:
    """Every random choice of one episode.

    seed          the episode's seed (what it was drawn from)
    jitter        colour / light jitter of the splat world
    T_cam_camj    {camera: [4,4]} rigid mount jitter in the camera's own frame (``T_mount_cam @ T_cam_camj``)
    reset_seed    seed of the twin's reset (``Twin.reset``: object start poses)
    task_seed     seed of the task's own random choices
    object_scale  scale of the objects' Gaussians about their base (``Randomization.object_shrink``; 1: as built)
    table_texture the table's look (``Randomization.table_texture``; None: as reconstructed)
    """

    seed: int
    jitter: ColorJitter
    T_cam_camj: dict[str, np.ndarray]
    reset_seed: int
    task_seed: int
    object_scale: float = 1.0
    table_texture: TableTexture | None = None


def _small_rotation(rng: np.random.Generator, max_deg: float) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = math.radians(rng.uniform(-max_deg, max_deg))
    Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(a) * Kx + (1 - math.cos(a)) * Kx @ Kx


def draw_episode(seed: int, randomization: Randomization, cameras: tuple[str, ...]) -> EpisodeDraw:
    """The episode of ``seed``: the same seed gives the same draw, in generation and in the environment."""
    rnd = randomization
    rng = np.random.default_rng(int(seed))
    jitter = ColorJitter.sample(rng, rnd.brightness, rnd.contrast, rnd.gain)
    T_cam_camj = {}
    for c in cameras:
        T = np.eye(4)
        T[:3, :3] = _small_rotation(rng, rnd.camera_deg) if rnd.camera_deg > 0 else np.eye(3)
        T[:3, 3] = rng.uniform(-rnd.camera_m, rnd.camera_m, 3) if rnd.camera_m > 0 else 0.0
        T_cam_camj[c] = T
    reset_seed = int(rng.integers(2**31))
    task_seed = int(rng.integers(2**31))
    # drawn last, and only when asked for: every other choice of a seed stays what it was without it
    scale = float(rng.uniform(1.0 - rnd.object_shrink, 1.0)) if rnd.object_shrink > 0 else 1.0
    texture = None
    if rnd.table_texture > 0:
        texture = TableTexture.sample(rng, rnd.table_texture)
    return EpisodeDraw(int(seed), jitter, T_cam_camj, reset_seed, task_seed, scale, texture)
