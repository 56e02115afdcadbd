"""Robots: one :class:`RobotSpec` per robot (model file, joints, home, gains, limits, gripper geometry, camera
mounts, dataset names), registered by name. Code outside this package takes robot facts from a spec, never
from constants of its own (DESIGN.md section 4).
"""

from __future__ import annotations

from ..errors import M2MError
from .panda import PANDA
from .spec import CameraMount, RobotSpec

__all__ = ["DEFAULT_ROBOT", "ROBOTS", "CameraMount", "RobotError", "RobotSpec", "get_robot", "register_robot"]


class RobotError(M2MError, ValueError):
    """An unknown robot name; the message lists the known robots."""


ROBOTS: dict[str, RobotSpec] = {}


def register_robot(spec: RobotSpec) -> RobotSpec:
    """Add ``spec`` to :data:`ROBOTS` under its name (a second spec of the same name is refused)."""
    if spec.name in ROBOTS and ROBOTS[spec.name] is not spec:
        raise ValueError(f"a robot named {spec.name!r} is already registered")
    ROBOTS[spec.name] = spec
    return spec


register_robot(PANDA)

DEFAULT_ROBOT = PANDA.name  # the robot of a world.yaml that names none, and of the bundled sample


def get_robot(name: str) -> RobotSpec:
    """The registered robot ``name``; :class:`RobotError` naming the known robots otherwise."""
    try:
        return ROBOTS[name]
    except (KeyError, TypeError):
        raise RobotError(f"unknown robot {name!r}; known robots: {', '.join(sorted(ROBOTS))}") from None
