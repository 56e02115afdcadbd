"""Hybrid rendering (paper section 3.3): the Gaussian world posed by physics, composited with the
simulator's robot render, depth-aware. Takes arrays and Gaussians, never a simulator."""

from .composite import ColorJitter, composite, robot_visible, to_uint8
from .splat_world import MovablePart, SplatRenderOptions, SplatWorld, SplatWorldBatch

__all__ = [
    "ColorJitter",
    "MovablePart",
    "SplatRenderOptions",
    "SplatWorld",
    "SplatWorldBatch",
    "composite",
    "robot_visible",
    "to_uint8",
]
