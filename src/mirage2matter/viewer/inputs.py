"""What the viewer draws, gathered by the command from a workspace: typed objects and files, any of them absent."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import M2MError

if TYPE_CHECKING:
    from ..geometry.camera import Camera
    from ..robots import RobotSpec
    from ..world.config import WorldConfig

__all__ = ["Board", "ViewerError", "ViewerInputs"]


class ViewerError(M2MError, ValueError):
    """Something the viewer cannot show (a port in use, an episode that is not there, another robot's dataset)."""


@dataclass
class Board:
    """The calibration target on the base: ``T_base_board`` [4,4] (its first corner, z along its normal) and its
    layout (``board`` of calib/sim3_sfm_to_base.json: squares_x, squares_y, square in m for a ChArUco board)."""

    T_base_board: np.ndarray
    layout: dict[str, Any]


@dataclass
class ViewerInputs:
    """Everything ``m2m view`` may draw; None or empty where the stage that writes it has not run.

    world            world.yaml parsed (objects, placements, cameras, the robot); None before ``m2m compose``
    scene_ply        the scene's Gaussians when there is no world yet (``train-scene``'s)
    robot            the robot (the world's, else the workspace's)
    robot_gaussians  the folder of the robot's per-link Gaussians (robot.json + <link>.ply, link frames), or None
    keyframes        the keyframe cameras in the base frame (``name``: the image under ``image_dir``)
    image_dir        the keyframes' folder
    board            the calibration target, or None
    datasets         {name: dataset folder}
    evals            {name: evaluation report folder}
    missing          what is not there yet and the command that makes it, one line each
    """

    robot: RobotSpec
    world: WorldConfig | None = None
    scene_ply: Path | None = None
    robot_gaussians: Path | None = None
    keyframes: list[Camera] = field(default_factory=list)
    image_dir: Path | None = None
    board: Board | None = None
    datasets: dict[str, Path] = field(default_factory=dict)
    evals: dict[str, Path] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)
