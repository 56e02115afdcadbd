"""The viewer's settings."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ViewerConfig"]


@dataclass
class ViewerConfig:
    """``m2m view`` settings.

    host           the address the page is served on (127.0.0.1: this machine only)
    port           the page's port; refused when in use
    max_gaussians  most Gaussians sent to the browser per splat layer (the scene, each object, the robot), a uniform
                   sample kept: a browser draws ~1M at interactive rates, and an exported page carries them all
    joints         the robot's arm joint state (rad) shown when no episode plays (None: the robot's home)
    thumbnail_px   the width of the keyframe images drawn in their frustums
    frustum_m      the size of a keyframe camera's frustum (m)
    """

    host: str = "127.0.0.1"
    port: int = 8080
    max_gaussians: int = 400_000
    joints: tuple[float, ...] | None = None
    thumbnail_px: int = 96
    frustum_m: float = 0.06
