"""Stage ``handeye``: the camera's mount in the robot's kinematic chain from images of a ChArUco board and
the robot's joint angles (Tsai-Lenz + reprojection refinement) -> ``calib/handeye.json``."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..atomic import atomic_write
from ..calib.board import BoardSpec
from ..calib.handeye import HandEyeError, calibrate_from_files
from ..geometry.camera import load_intrinsics
from ..workspace import Workspace
from .base import Input, Log


@dataclass
class Config:
    """calibrate-handeye settings.

    images      folder of the camera's images of the ChArUco board
    joints      JSON {"robot", "link", "views": [{"image", "joints"}]}: the robot's joint angles per image
    board       the board's spec JSON
    intrinsics  the camera's intrinsics: a JSON with K (3x3), width and height (or such an object under
                "head_camera")
    mount       head: eye-to-hand, the camera fixed in the base (T_base_headcam); wrist: eye-in-hand
    method      OpenCV's closed-form hand-eye solver
    robot       robot model file (default: the joints file's, else the default robot's)
    link        the link holding the board (head) or the camera (wrist) (default: the joints file's, else the
                robot's end-effector link)
    refine      refine the closed form by the board corners' reprojection error
    """

    images: Path | None = None
    joints: Path | None = None
    board: Path | None = None
    intrinsics: Path | None = None
    mount: Literal["head", "wrist"] = "head"
    method: Literal["tsai", "park", "horaud", "andreff", "daniilidis"] = "tsai"
    robot: str | None = None
    link: str | None = None
    refine: bool = True

    def validate(self) -> None:
        missing = [n for n in ("images", "joints", "board", "intrinsics") if getattr(self, n) is None]
        if missing:
            raise HandEyeError(f"calibrate-handeye: give {', '.join('--' + n for n in missing)}")


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    names = ("images", "joints", "board", "intrinsics")
    return [Input(Path(getattr(cfg, n)), field=f"handeye {n}") for n in names if getattr(cfg, n) is not None]


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    cam = load_intrinsics(cfg.intrinsics, keys=("head_camera",))
    result, out = calibrate_from_files(
        cfg.images, cfg.joints, BoardSpec.load(cfg.board), cam.K, mount=cfg.mount, method=cfg.method,
        robot=cfg.robot, link=cfg.link, refine=cfg.refine,
    )  # fmt: skip
    out.update(width=cam.width, height=cam.height)
    ws.calib_dir.mkdir(parents=True, exist_ok=True)
    with atomic_write(ws.handeye_file, "w", encoding="utf-8") as f:
        json.dump(out, f, indent=1)
    how = f"{cfg.mount}, {cfg.method}{' + reprojection refinement' if cfg.refine else ''}"
    return {
        "views": len(out["per_view"]), "skipped": len(out["skipped"]),
        "residual_deg": out["residual_deg_median"], "residual_mm": out["residual_mm_median"],
        "line": f"camera mount ({how}) from {len(out['per_view'])} views ({len(out['skipped'])} skipped); residual "
        f"median {out['residual_deg_median']:.3f} deg / {out['residual_mm_median']:.2f} mm",
    }  # fmt: skip


def compare(ws: Workspace, cfg: Config, gt: dict) -> dict[str, Any]:
    from ..geometry.rotation import rotation_angle

    he = json.loads(ws.handeye_file.read_text())
    if "T_base_headcam" not in he:
        return {"line": ""}
    X, T = np.asarray(he["T_base_headcam"]), np.asarray(gt["head_camera"]["T_base_headcam"])
    r = float(np.degrees(rotation_angle(X[:3, :3].T @ T[:3, :3])))
    t = float(1000 * np.linalg.norm(X[:3, 3] - T[:3, 3]))
    return {"rotation_deg": r, "translation_mm": t, "line": f"; vs ground truth {r:.3f} deg / {t:.2f} mm"}


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.handeye_file]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.handeye_file]
