"""Gaussian splats: the model, PLY I/O, transforms and renderers. Knows no physics or pipeline."""

from .model import Gaussians
from .sh import num_sh_bases, rgb_to_sh_dc, sh_basis, sh_to_rgb

__all__ = ["Gaussians", "num_sh_bases", "rgb_to_sh_dc", "sh_basis", "sh_to_rgb"]
