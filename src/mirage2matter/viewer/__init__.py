"""The twin in a browser (``m2m view``): a viser scene of the world's Gaussians, the robot at a joint state, the
keyframe cameras, the head and wrist cameras, the board and the collision meshes; objects dragged in the page are
written back through the world edit path (the command's callback); a dataset or evaluation episode plays on a time
slider; the whole scene exports as one HTML file that opens without a server.

Modules: ``config`` (the settings), ``inputs`` (what a workspace holds, typed), ``splats`` (Gaussians -> viser's
arrays), ``kinematics`` (link poses at a joint state), ``episodes`` (recorded episodes), ``scene`` (the scene nodes),
``app`` (the viewer: GUI, drag, playback, export).
"""

from __future__ import annotations

from .config import ViewerConfig
from .inputs import ViewerInputs

__all__ = ["ViewerConfig", "ViewerInputs"]
