"""Loading a world: parse ``world.yaml`` (``world.config``), then check it (``world.validate``).

Kept apart from both so that neither imports the other's importer (no import circle).
"""

from __future__ import annotations

import os

from .config import WorldConfig, WorldConfigError, read_world, world_yaml_path
from .validate import validate_world

__all__ = ["load_world"]


def load_world(world: str | os.PathLike, validate: bool = True) -> WorldConfig:
    """Read a world.yaml (the file, or the world folder holding it) and, by default, validate it."""
    path = world_yaml_path(world)
    cfg = read_world(path)
    if validate:
        try:
            validate_world(cfg)
        except WorldConfigError as e:
            raise WorldConfigError(f"{path}: {e}") from None
    return cfg
