"""Hybrid rendering (paper section 3.3): the Gaussian world posed by physics, composited with the
simulator's robot render, depth-aware. Takes arrays and Gaussians, never a simulator.

The torch-backed names load on first use, so that the settings' bounds (``render.options``) and the table's
texture read without torch.
"""

from ..lazy import lazy_names

_LAZY = {
    # not the function composite: its module's name is the same, and once the module is imported the package's
    # attribute is the module (``from mirage2matter.render.composite import composite``)
    "ColorJitter": "composite", "robot_visible": "composite", "to_uint8": "composite",
    "MovablePart": "splat_world", "SplatRenderOptions": "splat_world", "SplatWorld": "splat_world",
    "SplatWorldBatch": "splat_world",
}  # fmt: skip

__getattr__ = lazy_names(__name__, _LAZY)

__all__ = sorted(_LAZY)
