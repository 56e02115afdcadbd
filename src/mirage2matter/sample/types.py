"""What the sample's asset builder hands to its renderer."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh


@dataclass
class PlacedAsset:
    """A textured mesh in its own object frame (metres), placed in the robot-base frame.

    mesh         trimesh.Trimesh with ``visual`` = TextureVisuals (uv [V,2] + image) or vertex colours
    T_base_obj   [4,4] rigid pose of the object frame in the robot-base frame (z up, origin at the base)
    category     "static" (room, table), "board" (the ChArUco board), "object" (graspable),
                 "button" (press button), "distractor"
    """

    name: str
    mesh: trimesh.Trimesh
    T_base_obj: np.ndarray
    category: str
    meta: dict = field(default_factory=dict)  # e.g. mass, board spec, button travel
