"""Gaussian splats: the model, PLY I/O, SH, transforms and renderers. Knows no physics or pipeline."""

from .model import Gaussians
from .ply import PlyFormatError, read_ply, write_ply
from .sh import num_sh_bases, rgb_to_sh_dc, sh_basis, sh_to_rgb
from .sh_rotation import rotate_sh
from .transform import apply_sim3

__all__ = [
    "Gaussians",
    "PlyFormatError",
    "apply_sim3",
    "num_sh_bases",
    "read_ply",
    "rgb_to_sh_dc",
    "rotate_sh",
    "sh_basis",
    "sh_to_rgb",
    "write_ply",
]
