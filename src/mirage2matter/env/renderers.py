"""The environment's observation renderers, one name each (``EnvConfig.renderer``).

A renderer is built together with the twin it renders (a builder takes the :class:`EnvConfig` and returns
``(twin, renderer)``), since what the twin must draw depends on it: the hybrid renderer needs Genesis cameras
that draw only the robot; a ground-truth renderer may render its own scene and need no twin cameras at all.

- ``hybrid`` (:mod:`.hybrid`): the Gaussian world + the composited Genesis robot; what generation records.
- ``ground_truth`` (:mod:`.ground_truth`): the sample's textured-mesh world as its video was rendered (textures
  filtered trilinearly: :class:`~.ground_truth.GroundTruthFrames`), driven by the twin's state; it needs a sample's
  ground truth (``EnvConfig.ground_truth``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

import numpy as np

from .config import EnvConfig, EnvError
from .hybrid import build_hybrid
from .lens import LensFrames, lens_plan

if TYPE_CHECKING:
    from ..sim.twin import Twin
    from .episode import EpisodeDraw

__all__ = ["RENDERERS", "FrameRenderer", "RendererBuilder", "build_renderer"]


class FrameRenderer(Protocol):
    """Frames of the twin's current state, one per observed camera (``EnvConfig.cameras``, ``EnvConfig.size``)."""

    timings: dict[str, float]  # seconds per part of the render since the episode started

    def start_episode(self, draw: EpisodeDraw) -> None:
        """After the twin's reset: the episode's randomisation (colour jitter...); forget per-episode caches."""

    def render(self) -> dict[str, np.ndarray]:
        """{camera: uint8 [H,W,3]} of the twin's current state (cameras where ``twin.camera`` puts them)."""

    def close(self) -> None:
        """Free what the renderer holds beyond the twin (the environment closes the twin)."""


RendererBuilder = Callable[[EnvConfig], "tuple[Twin, FrameRenderer]"]


def _ground_truth(cfg: EnvConfig) -> tuple[Twin, FrameRenderer]:
    from .ground_truth import build_ground_truth

    return build_ground_truth(cfg)


RENDERERS: dict[str, RendererBuilder] = {"hybrid": build_hybrid, "ground_truth": _ground_truth}


def build_renderer(cfg: EnvConfig) -> tuple[Twin, FrameRenderer]:
    """The twin and the renderer named by ``cfg.renderer``, its frames through each camera's lens (``env.lens``)."""
    builder = RENDERERS.get(cfg.renderer)
    if builder is None:
        raise EnvError(f"unknown renderer {cfg.renderer!r}; renderers: {', '.join(RENDERERS)}")
    plan = lens_plan(cfg)  # cameras as calibrated: a lens, an off-centre principal point
    if plan is None:
        return builder(cfg)
    twin, inner = builder(plan.render_config(cfg))
    return twin, LensFrames(inner, plan)
