"""Stage ``sfm``: camera poses and sparse points of the keyframes (COLMAP) -> ``sfm/``; or poses imported
from a transforms.json or a COLMAP model (their images copied into ``capture/``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np

from ..capture import load_keyframes
from ..configs import ranged
from ..geometry.camera import load_intrinsics
from ..sfm import SfMConfig, SfMError, compare_poses, run_sfm
from ..workspace import Workspace
from .base import Input, Log


@dataclass
class Config:
    """sfm settings.

    matching         image pairs to match: auto (exhaustive below 40 images), sequential, exhaustive
    downscale        extract features at 1/downscale of the keyframes' resolution
    intrinsics       known camera intrinsics held fixed (our JSON with K, width, height, distortion, OpenCV's
                     calibration YAML/XML, ROS camera_info, COLMAP cameras.txt or RealSense JSON; or such an
                     object under "camera"; radial-tangential or equidistant fisheye lens; `m2m intrinsics FILE`
                     shows how it reads): more accurate poses than self-calibration
    from_transforms  import poses from an instant-ngp / nerfstudio transforms.json instead (copies its images
                     into capture/, triangulates points with the given poses; keeps its world frame)
    from_colmap      import a COLMAP sparse model instead (needs images)
    images           with from_colmap: the folder the model's image names are relative to
    """

    # where the cameras' intrinsics come from, one at a time (an import brings its own): given one on the command
    # line, a stage command drops the others m2m.yaml holds (for that run, and saves that)
    EXCLUSIVE: ClassVar = (("intrinsics", "from_transforms", "from_colmap"),)

    matching: Literal["auto", "sequential", "exhaustive"] = SfMConfig.matching
    downscale: float = ranged(1.0, ge=1, le=16)
    intrinsics: Path | None = None
    from_transforms: Path | None = None
    from_colmap: Path | None = None
    images: Path | None = None

    def validate(self) -> None:
        if not self.downscale > 0:
            raise SfMError(f"sfm: downscale must be positive, got {self.downscale}")
        given = [n for n in self.EXCLUSIVE[0] if getattr(self, n) is not None]
        if len(given) > 1:
            raise SfMError(f"sfm: {' and '.join(given)} are both given; give one: an import (from_transforms, "
                           "from_colmap) brings its cameras' own intrinsics, intrinsics is for SfM on keyframes")
        if self.from_colmap is not None and self.images is None:
            raise SfMError("sfm: from_colmap needs images (the folder the model's image names are relative to)")


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    given = [(cfg.intrinsics, "intrinsics"), (cfg.from_transforms, "from_transforms"), (cfg.from_colmap, "from_colmap"),
             (cfg.images, "images")]  # fmt: skip
    out = [Input(Path(p), field=f"sfm {name}") for p, name in given if p is not None]
    if cfg.from_transforms is None and cfg.from_colmap is None:
        out.append(Input(ws.keyframes_file, made_by="capture"))
    return out


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    from ..sfm.importers import import_colmap_model, import_transforms
    from ..sfm.known_poses import with_fixed_intrinsics

    config = SfMConfig(matching=cfg.matching, downscale=1.0 / cfg.downscale)
    if cfg.intrinsics is not None:
        config = with_fixed_intrinsics(config, load_intrinsics(cfg.intrinsics))
    if cfg.from_transforms is not None:
        result = import_transforms(cfg.from_transforms, ws.capture_dir, ws.sfm_dir, config)
        how = f"imported {result.total} posed images from {cfg.from_transforms}; triangulated with those poses"
    elif cfg.from_colmap is not None:
        result = import_colmap_model(cfg.from_colmap, cfg.images, ws.capture_dir, ws.sfm_dir)
        how = f"imported the COLMAP model {cfg.from_colmap}"
    else:
        result = run_sfm(ws.capture_dir, ws.sfm_dir, config)
        how = f"registered {result.registered}/{result.total} keyframes"
    from ..capture.coverage import scene_coverage

    coverage = scene_coverage(result.cameras, result.points)  # what to film more, while the user still can
    return {
        "registered": result.registered, "total": result.total, "points": len(result.points),
        "reprojection_px": result.mean_reprojection_error, "seconds": result.seconds, "coverage": coverage.to_json(),
        "line": f"{how}, {len(result.points):,} points, reprojection {result.mean_reprojection_error:.2f} px (mean); "
        f"{coverage.line}",
    }  # fmt: skip


def compare(ws: Workspace, cfg: Config, gt: dict) -> dict[str, Any]:
    posed = ws.posed_capture(frame="sfm")
    keyframes = load_keyframes(ws.capture_dir)["keyframes"]
    reference = {k["file"]: np.asarray(gt["frames"][k["frame_index"]]["T_base_cam"]) for k in keyframes}
    err = compare_poses({c.name: c.T_world_cam for c in posed.cameras}, reference)
    return {
        "rotation_deg": err["rotation_deg_median"], "centre_frac": err["center_frac_median"],
        "line": f"; vs ground truth {err['rotation_deg_median']:.3f} deg / {100 * err['center_frac_median']:.3f}% "
        "(median, after a Sim3 fit)",
    }  # fmt: skip


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.sfm_file]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.sfm_dir] + ([ws.capture_dir] if cfg.from_transforms is not None or cfg.from_colmap is not None else [])
