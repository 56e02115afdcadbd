"""The world: robot, cameras, scene Gaussians and placed objects in the robot-base frame (world.yaml), its
composition into one Gaussian world (world.ply), and edits (insert, move, duplicate, delete, SuperSplat
placement import, lighting match). A world comes from a reconstruction (``world_from_reconstruction``) or,
as a stand-in, from the bundled sample's ground truth (``sample_world``)."""

from .config import WorldConfig, WorldConfigError, save_world
from .io import load_world
from .reconstruction import ReconstructionOptions, world_from_reconstruction
from .sample import sample_world

__all__ = [
    "ReconstructionOptions",
    "WorldConfig",
    "WorldConfigError",
    "load_world",
    "sample_world",
    "save_world",
    "world_from_reconstruction",
]
