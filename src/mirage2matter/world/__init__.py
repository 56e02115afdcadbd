"""The world: robot, cameras, scene Gaussians and placed objects in the robot-base frame (world.yaml), its
composition into one Gaussian world (world.ply), and edits (insert, move, duplicate, delete, SuperSplat
placement import, lighting match)."""

from .config import WorldConfig, WorldConfigError, load_world, save_world
from .sample import sample_world

__all__ = ["WorldConfig", "WorldConfigError", "load_world", "sample_world", "save_world"]
