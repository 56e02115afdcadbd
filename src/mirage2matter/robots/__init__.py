"""Robots: one :class:`RobotSpec` per robot (model file, joints, home, gains, limits, gripper geometry, tool centre,
camera mounts, dataset names). Code outside this package takes robot facts from a spec, never from constants of
its own (DESIGN.md section 4).

A robot is named by a registered name (the spec files shipped in ``robots/specs/``: ``panda``, ``ur5e``) or by the
path of a user's own spec file (YAML or JSON, see ``robots.specfile``): :func:`get_robot` takes either.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

from .spec import CameraMount, RobotError, RobotSpec, RobotSpecError
from .specfile import load_robot_spec

__all__ = [
    "DEFAULT_ROBOT", "ROBOTS", "CameraMount", "RobotError", "RobotSpec", "RobotSpecError", "get_robot",
    "is_spec_file", "register_robot",
]  # fmt: skip

SPECS_DIR = Path(__file__).parent / "specs"
# The shipped robots: name -> spec file.
ROBOTS: dict[str, Path] = {p.stem: p for p in sorted(SPECS_DIR.glob("*.yaml"))}
_REGISTERED: dict[str, RobotSpec] = {}

DEFAULT_ROBOT = "panda"  # the robot of a world.yaml that names none, and of the bundled sample
SPEC_SUFFIXES = (".yaml", ".yml", ".json")


def register_robot(spec: RobotSpec) -> RobotSpec:
    """Make ``spec`` known by its name (a robot made in code; a second spec of a taken name is refused)."""
    if spec.name in ROBOTS or (spec.name in _REGISTERED and _REGISTERED[spec.name] != spec):
        raise ValueError(f"a robot named {spec.name!r} is already registered")
    _REGISTERED[spec.name] = spec
    return spec


def is_spec_file(robot: str | os.PathLike) -> bool:
    """Whether ``robot`` names a spec file (a YAML/JSON path) rather than a registered robot."""
    return Path(robot).suffix.lower() in SPEC_SUFFIXES


@lru_cache(maxsize=32)
def _load(path: str, mtime_ns: int, size: int) -> RobotSpec:
    return load_robot_spec(path)


def _load_file(path: Path) -> RobotSpec:
    if not path.is_file():
        raise RobotSpecError(f"robot spec file {path} not found; give a registered robot ({', '.join(ROBOTS)}) or "
                             "the path of a robot spec YAML/JSON")  # fmt: skip
    st = path.stat()
    return _load(str(path.resolve()), st.st_mtime_ns, st.st_size)


def get_robot(robot: str | os.PathLike) -> RobotSpec:
    """The robot ``robot``: a registered name, or a robot spec file (``.yaml`` / ``.yml`` / ``.json``; relative to
    the working directory). :class:`RobotError` naming the known robots for an unknown name,
    :class:`RobotSpecError` naming the file and field for a bad spec file. Specs are read once per file version."""
    if isinstance(robot, RobotSpec):
        return robot
    if isinstance(robot, str | os.PathLike) and is_spec_file(robot):
        return _load_file(Path(robot))
    if isinstance(robot, str) and robot in _REGISTERED:
        return _REGISTERED[robot]
    if isinstance(robot, str) and robot in ROBOTS:
        return _load_file(ROBOTS[robot])
    known = sorted({*ROBOTS, *_REGISTERED})
    raise RobotError(f"unknown robot {robot!r}; known robots: {', '.join(known)} (or the path of a robot spec "
                     "file, .yaml or .json)")  # fmt: skip
