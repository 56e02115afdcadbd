"""What every rendering backend returns."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class RenderOutput:
    """rgb [H,W,3] (background composited), alpha [H,W] accumulated opacity,
    depth [H,W] expected camera-z depth of the visible Gaussians (0 where nothing is seen)."""

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
