"""The world: robot, cameras, scene Gaussians and placed objects in the robot-base frame (world.yaml), its
composition into one Gaussian world (world.ply), and edits (insert, move, duplicate, delete, SuperSplat
placement import, lighting match). A world comes from the workspace's reconstruction (``from_workspace``) or,
as a stand-in, from the bundled sample's ground truth (``sample_world``)."""

from .config import WorldConfig, WorldConfigError, load_world, save_world
from .sample import sample_world
from .workspace import WorkspaceWorldOptions, from_workspace

__all__ = [
    "WorkspaceWorldOptions",
    "WorldConfig",
    "WorldConfigError",
    "from_workspace",
    "load_world",
    "sample_world",
    "save_world",
]
