"""A workspace folder and what the stages have left in it (DESIGN.md section 3).

Only paths and the one rule every later stage needs: which posed cameras and points to use. After
``align-scene`` they are the SfM ones mapped into the robot-base frame by
``calib/sim3_sfm_to_base.json`` (eq. ``pose_update``); before it, the SfM frame itself.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .geometry.camera import Camera
from .geometry.sim3 import Sim3

__all__ = ["PosedCapture", "Workspace", "WorkspaceError", "fingerprint"]


class WorkspaceError(RuntimeError):
    """A stage's input is missing from the workspace; the message names the stage to run."""


@dataclass
class PosedCapture:
    """Keyframe cameras and SfM points in one frame.

    cameras   sorted by name; ``name`` is the image path relative to ``image_dir``
    points    [M, 3] float64; colors [M, 3] uint8 RGB
    frame     "base" (metric, robot base) or "sfm" (arbitrary SfM frame and scale)
    """

    cameras: list[Camera]
    points: np.ndarray
    colors: np.ndarray
    image_dir: Path
    frame: str
    sim3_sfm_to_base: Sim3 | None = None


@dataclass(frozen=True)
class Workspace:
    root: Path

    def __init__(self, root: str | os.PathLike[str]) -> None:
        object.__setattr__(self, "root", Path(root))

    @property
    def capture(self) -> Path:
        return self.root / "capture"

    @property
    def sfm(self) -> Path:
        return self.root / "sfm"

    @property
    def calib(self) -> Path:
        return self.root / "calib"

    @property
    def scene(self) -> Path:
        return self.root / "scene"

    @property
    def objects(self) -> Path:
        return self.root / "objects"

    @property
    def world(self) -> Path:
        return self.root / "world"

    @property
    def datasets(self) -> Path:
        return self.root / "datasets"

    def require(self, path: Path, stage: str) -> Path:
        if not path.exists():
            raise WorkspaceError(f"{path} not found; run `m2m {stage} -w {self.root}` first")
        return path

    def posed_capture(self, require_base: bool = False) -> PosedCapture:
        """The keyframes' cameras and the SfM points, in the base frame when ``align-scene`` has
        run (``require_base`` makes that mandatory), else in the SfM frame."""
        import pycolmap

        from .sfm import load_sfm_summary

        self.require(self.sfm / "sfm.json", "sfm")
        _, cameras = load_sfm_summary(self.sfm)
        rec = pycolmap.Reconstruction(str(self.require(self.sfm / "model", "sfm")))
        pts = list(rec.points3D.values())
        points = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)
        colors = np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3)
        sim_path = self.calib / "sim3_sfm_to_base.json"
        cameras = sorted(cameras, key=lambda c: c.name)
        if not sim_path.is_file():
            if require_base:
                self.require(sim_path, "align-scene")
            return PosedCapture(cameras, points, colors, self.capture, "sfm")
        from .calib.align import apply_to_cameras

        sim = Sim3.from_json(json.loads(sim_path.read_text())["sim3_sfm_to_base"])
        return PosedCapture(apply_to_cameras(sim, cameras), sim.apply(points), colors, self.capture, "base", sim)


def fingerprint(*parts: Any) -> str:
    """A short stable hash of JSON-able ``parts`` and of the bytes of any ``Path`` among them
    (the stage-skipping key: same inputs and config -> same fingerprint)."""
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, Path):
            h.update(p.read_bytes() if p.is_file() else b"<missing>")
        else:
            h.update(json.dumps(p, sort_keys=True, default=str).encode())
        h.update(b"\0")
    return h.hexdigest()[:16]
