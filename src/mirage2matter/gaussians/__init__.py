"""Gaussian splats: the model, PLY I/O, SH, transforms and renderers. Knows no physics or pipeline.

The torch-backed names load on first use, so that the training settings (``gaussians.config``) read without torch.
"""

from ..lazy import lazy_names

_LAZY = {
    "Gaussians": "model", "PlyFormatError": "ply", "read_ply": "ply", "write_ply": "ply", "num_sh_bases": "sh",
    "rgb_to_sh_dc": "sh", "sh_basis": "sh", "sh_to_rgb": "sh", "rotate_sh": "sh_rotation", "apply_sim3": "transform",
}  # fmt: skip

__getattr__ = lazy_names(__name__, _LAZY)

__all__ = sorted(_LAZY)
