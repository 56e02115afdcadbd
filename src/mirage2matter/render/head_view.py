"""Check the calibrated head camera against the reconstructed scene.

Render the scene Gaussians (robot-base frame) from ``T_base_headcam`` and compare with a photo the
head camera took: PSNR, and where the ChArUco board lands — corners detected in the render against
the same corners detected in the photo, and against the board's known pose projected through the
calibrated camera. A wrong scale, alignment or hand-eye shows up as pixels of offset.

The photo shows the robot, which the scene has taken out: the robot's own per-link Gaussians, posed by forward
kinematics at the photo's joint state, are drawn in the same splat pass as the scene (``render.splat_world``, as
the hybrid renderer draws them), so the robot's pixels are compared with the robot, not with the room behind it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write
from ..calib.board import BoardSpec
from ..geometry.camera import Camera

__all__ = ["HeadViewCheck", "check_head_view", "detect_corners"]


def detect_corners(image_rgb: np.ndarray, board: BoardSpec) -> dict[int, np.ndarray]:
    """The target's point id -> pixel [2] (pixel centres at +0.5) in ``image_rgb`` [H,W,3] uint8."""
    import cv2

    ids, corners = board.detect(cv2.cvtColor(image_rgb, cv2.COLOR_RGB2GRAY))
    return {int(i): c + 0.5 for i, c in zip(ids.ravel(), corners.reshape(-1, 2), strict=True)}


@dataclass
class HeadViewCheck:
    """render uint8 [H,W,3]; psnr vs the photo (dB, None without one); corner offsets in pixels:
    render vs photo detections, render vs the board's known pose, and photo vs the known pose (median / max, ids
    used): the last is the calibration alone (no render), the others what the scene's Gaussians draw.
    With the robot drawn: robot_mask bool [H,W], the pixels the robot covers (drawn alone, alpha >= 0.5), and the
    PSNR vs the photo on them (psnr_robot) and on the rest (psnr_elsewhere)."""

    render: np.ndarray
    psnr: float | None = None
    corners_vs_photo_px: dict[str, float] = field(default_factory=dict)
    corners_vs_known_px: dict[str, float] = field(default_factory=dict)
    photo_vs_known_px: dict[str, float] = field(default_factory=dict)
    robot_mask: np.ndarray | None = None
    psnr_robot: float | None = None
    psnr_elsewhere: float | None = None

    def to_json(self) -> dict[str, Any]:
        out = {
            "psnr": self.psnr,
            "corners_vs_photo_px": self.corners_vs_photo_px,
            "corners_vs_known_px": self.corners_vs_known_px,
            "photo_vs_known_px": self.photo_vs_known_px,
        }
        if self.robot_mask is not None:
            out.update(robot_drawn=True, robot_fraction=float(self.robot_mask.mean()), psnr_robot=self.psnr_robot,
                       psnr_elsewhere=self.psnr_elsewhere)  # fmt: skip
        return out


def _offsets(a: dict[int, np.ndarray], b: dict[int, np.ndarray]) -> dict[str, float]:
    common = sorted(set(a) & set(b))
    if not common:
        return {"n": 0}
    d = np.linalg.norm(np.array([a[i] for i in common]) - np.array([b[i] for i in common]), axis=1)
    return {"n": len(common), "median": float(np.median(d)), "max": float(d.max())}


def _render_scene(gaussians, camera: Camera, background, backend: str) -> np.ndarray:
    """float32 [H,W,3] in [0,1]: ``gaussians`` alone from the head camera."""
    import torch

    from ..gaussians.render import render

    with torch.no_grad():
        out = render(
            gaussians,
            torch.as_tensor(camera.viewmat, dtype=torch.float32),
            torch.as_tensor(camera.K, dtype=torch.float32),
            camera.width,
            camera.height,
            torch.tensor(background, dtype=torch.float32),
            backend,
        )
    return out.rgb.clamp(0, 1).cpu().numpy()


def _render_with_robot(gaussians, robot: dict, T_base_link: dict[str, np.ndarray], camera: Camera, background,
                       backend: str) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(rgb float32 [H,W,3], the robot's pixels bool [H,W]): the scene and the robot's links ({link: Gaussians in
    its frame}) posed at ``T_base_link`` in one splat pass, as the hybrid renderer composes them; the robot's pixels
    from the robot drawn alone (alpha >= 0.5)."""
    from .splat_world import MovablePart, SplatRenderOptions, SplatWorld

    missing = sorted(set(robot) - set(T_base_link))
    if missing:
        raise ValueError(f"no pose for the robot's link(s) {', '.join(missing)}")
    options = SplatRenderOptions(backend=backend)
    parts = [MovablePart(link, g) for link, g in robot.items()]
    view = (camera.viewmat, camera.K, camera.width, camera.height)
    worlds = [SplatWorld(gaussians, parts, options), SplatWorld(None, parts, options)]
    for w in worlds:
        w.set_poses(T_base_link)
    rgb = worlds[0].render(*view, background)[0]
    alpha = worlds[1].render(*view)[1]
    return rgb, alpha >= 0.5


def _psnr_on(rgb: np.ndarray, photo: np.ndarray, mask: np.ndarray) -> float | None:
    """PSNR (dB, data range 1) of ``rgb`` vs ``photo`` (float [H,W,3]) over ``mask`` [H,W]; None when it is empty."""
    if not mask.any():
        return None
    mse = float(np.mean((rgb[mask] - photo[mask]) ** 2))
    return float(-10.0 * np.log10(max(mse, 1e-12)))


def check_head_view(
    gaussians,
    camera: Camera,
    photo: np.ndarray | None = None,
    board: BoardSpec | None = None,
    T_base_board: np.ndarray | None = None,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    backend: str = "auto",
    robot: dict | None = None,
    T_base_link: dict[str, np.ndarray] | None = None,
) -> HeadViewCheck:
    """Render ``gaussians`` from the head ``camera`` (T_world_cam = T_base_headcam) and compare. ``robot``: the
    robot's Gaussians per link ({link: Gaussians in the link's frame}, ``gaussians.robot``), drawn with the scene at
    ``T_base_link`` ({link: [4,4]}, forward kinematics at the photo's joint state); None: the scene alone."""
    import torch

    from ..gaussians.losses import psnr

    if robot:
        if T_base_link is None:
            raise ValueError("the robot's Gaussians need its link poses (T_base_link) to be drawn")
        rgb, robot_mask = _render_with_robot(gaussians, robot, T_base_link, camera, background, backend)
    else:
        rgb, robot_mask = _render_scene(gaussians, camera, background, backend), None
    result = HeadViewCheck(render=(rgb * 255 + 0.5).astype(np.uint8), robot_mask=robot_mask)
    if photo is not None:
        if photo.shape[:2] != (camera.height, camera.width):
            raise ValueError(
                f"the head photo is {photo.shape[1]}x{photo.shape[0]} but the camera is {camera.width}x{camera.height}"
            )
        seen = photo[..., :3].astype(np.float32) / 255
        result.psnr = float(psnr(torch.from_numpy(rgb), torch.from_numpy(seen)))
        if robot_mask is not None:
            result.psnr_robot = _psnr_on(rgb, seen, robot_mask)
            result.psnr_elsewhere = _psnr_on(rgb, seen, ~robot_mask)
    if board is not None:
        seen = detect_corners(result.render, board)
        in_photo = detect_corners(photo[..., :3], board) if photo is not None else {}
        if photo is not None:
            result.corners_vs_photo_px = _offsets(seen, in_photo)
        if T_base_board is not None:
            known = _known_corners(board, T_base_board, camera, sorted(set(seen) | set(in_photo)))
            result.corners_vs_known_px = _offsets(seen, known)
            if photo is not None:
                result.photo_vs_known_px = _offsets(in_photo, known)
    return result


def _known_corners(board: BoardSpec, T_base_board: np.ndarray, camera: Camera, ids: list[int]
                   ) -> dict[int, np.ndarray]:  # fmt: skip
    """The board's points ``ids`` at its known pose, projected through ``camera`` (those in front of it)."""
    pts = board.points_board(np.asarray(ids, np.int64)) @ T_base_board[:3, :3].T + T_base_board[:3, 3]
    uv, z = camera.project(pts)
    return {pid: uv[k] for k, pid in enumerate(ids) if z[k] > 0}


def save_head_view(out_png: Path, check: HeadViewCheck, photo: np.ndarray | None) -> None:
    """``out_png``: the render (beside the photo when there is one) and ``out_png`` with .json: the check's
    figures; each written atomically."""
    from PIL import Image

    out_png = Path(out_png)
    sheet = check.render if photo is None else np.concatenate([check.render, photo], axis=1)
    with atomic_write(out_png, "wb") as f:
        Image.fromarray(sheet).save(f, format="PNG")
    with atomic_write(out_png.with_suffix(".json"), "w", encoding="utf-8") as f:
        json.dump(check.to_json(), f, indent=1)
