"""Stage ``head_view``: the scene rendered through the calibrated head camera, compared with a photo the
head camera took (PSNR, board corners) -> ``calib/head_view.png`` + ``head_view.json``. A wrong scale,
alignment or hand-eye shows up as pixels of offset."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..workspace import Workspace, WorkspaceError
from .base import Input, Log


@dataclass
class Config:
    """head-view settings.

    photo     an image the head camera took of the same scene (without one: the render alone)
    backend   renderer: auto (cuda when available), cpu, cuda
    """

    photo: Path | None = None
    backend: Literal["auto", "cpu", "cuda"] = "auto"


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    out = [Input(ws.scene_ply, made_by="train-scene"), Input(ws.handeye_file, made_by="calibrate-handeye"),
           Input(ws.alignment_file, made_by="align-scene")]  # fmt: skip
    return out + ([Input(Path(cfg.photo), field="head-view photo")] if cfg.photo is not None else [])


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    from ..calib.board import target_from_json
    from ..calib.headview import check_head_view, save_head_view
    from ..gaussians.ply import read_ply
    from ..inputs import read_image_rgb

    board = ws.board_on_table()
    if board is None:
        raise WorkspaceError(f"{ws.alignment_file}: no calibration target recorded; the head-view check draws it "
                             "(run `m2m align-scene` with a board)")  # fmt: skip
    photo = read_image_rgb(cfg.photo, "head photo") if cfg.photo is not None else None
    cam = head_camera(ws, "the head-view check", photo, cfg.photo)
    if photo is not None and cam.has_distortion:
        # the render is an ideal pinhole with the same K: take the lens out of the photo before comparing
        from ..gaussians.dataset import undistort_image

        ideal, _ = undistort_image(photo.astype(np.float32) / 255.0, cam)
        photo = np.clip(np.round(ideal * 255.0), 0, 255).astype(np.uint8)
    cam = dataclasses.replace(cam, distortion={}, distortion_model="")
    check = check_head_view(read_ply(ws.scene_ply), cam, photo, target_from_json(board[0]), board[1],
                            backend=cfg.backend)  # fmt: skip
    save_head_view(ws.head_view_png, check, photo)
    known, seen = check.corners_vs_known_px, check.corners_vs_photo_px
    trained_on = cfg.photo is not None and _scene_trained_on(ws, Path(cfg.photo))
    parts = [] if check.psnr is None else [f"PSNR {check.psnr:.2f} dB vs the photo"
                                           + (" (a training view: train-scene --head-photo)" if trained_on else "")]
    if known.get("n"):
        parts.append(f"board corners {known['median']:.2f} px (median, {known['n']}) from the board's known pose")
    if seen.get("n"):
        parts.append(f"{seen['median']:.2f} px from the photo's")
    return {**check.to_json(), "photo_trained_on": trained_on,
            "line": "; ".join(parts) or "rendered (the board is not seen in the render)"}


def head_camera(ws: Workspace, who: str, photo: np.ndarray | None = None, photo_path: Path | None = None):
    """The calibrated head camera (``geometry.camera.Camera``: K, T_base_headcam, image size, lens) from
    calibrate-handeye's result. ``photo`` [H,W,3], one the camera took (``photo_path``), gives the size when the
    calibration has none and must match it otherwise; ``who`` names the user in the errors."""
    from ..geometry.camera import Camera

    he = json.loads(ws.handeye_file.read_text())
    if he.get("mount") != "head":
        raise WorkspaceError(f"{ws.handeye_file}: mount is {he.get('mount')!r}; {who} needs a head camera (`m2m "
                             "calibrate-handeye --mount head`)")  # fmt: skip
    width, height = he.get("width"), he.get("height")
    if width is None:
        if photo is None:
            raise WorkspaceError(f"{ws.handeye_file} has no image size; give a head-camera photo (--photo)")
        height, width = photo.shape[:2]
    if photo is not None and photo.shape[:2] != (height, width):
        raise WorkspaceError(f"{photo_path} is {photo.shape[1]}x{photo.shape[0]} but the head camera is "
                             f"{width}x{height}; give a photo the head camera took")  # fmt: skip
    return Camera(he["K"], he["T_base_headcam"], width, height, "head", he.get("distortion") or {})


def _scene_trained_on(ws: Workspace, photo: Path) -> bool:
    """Whether the scene was trained on this photo (``train-scene --head-photo``, the same file contents): the
    check then measures a fit, not a new view."""
    from ..fingerprint import fingerprint

    try:
        metrics = json.loads(ws.scene_metrics.read_text())
        key = metrics.get("head_photo_fingerprint")
        if key is None and metrics["config"].get("head_photo"):  # a scene trained before the key was recorded
            key = fingerprint(Path(metrics["config"]["head_photo"]))
        return key is not None and fingerprint(photo) == key
    except (OSError, ValueError, KeyError, AttributeError, TypeError):
        return False


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.head_view_file]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.head_view_png, ws.head_view_file]
