"""Metric alignment of SfM to the robot base (paper eqs. `icp`, `pose_update`).

A calibration target (ChArUco board, ArUco marker, AprilTag, ArUco grid) lies where the robot base will stand, at a
known pose ``T_base_board``. Its corners, detected in the keyframes and triangulated with the SfM cameras, give
scale, rotation and translation (Umeyama). Optionally (``icp``, off by default: it measured worse on the sample and
on a real capture) scaled ICP refines the fit of the SfM points around the target to the simulator's robot-base
region (the support surface the base stands on), with the corners kept as anchors so the plane cannot slide, and
only where the SfM saw that surface near the base. Points map as ``x' = s R x + t``; poses as ``R' = R R_wc``,
``t' = s R t_wc + t``.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import M2MError
from ..geometry.camera import Camera
from ..geometry.icp import scaled_icp
from ..geometry.sim3 import Sim3
from ..geometry.umeyama import umeyama
from .board import BoardSpec


class AlignError(M2MError, ValueError):
    """The board could not tie SfM to the robot base; the message says what to do."""


def default_T_base_board(spec: BoardSpec) -> np.ndarray:
    """The board centred on the base origin, printed face up, board x along base x and the printed
    image's top edge towards base +y (OpenCV's board frame has y down the print and z into it)."""
    w, h = spec.size
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [-w / 2, h / 2, 0.0]
    return T


def board_in_base(spec, pose_file: Path | None) -> np.ndarray:
    """T_base_board [4,4]: from ``pose_file`` (a JSON with T_base_board, at the top level or under "board"; the
    pipeline's board_pose), or :func:`default_T_base_board` without one."""
    if pose_file is None:
        return default_T_base_board(spec)
    data = json.loads(Path(pose_file).read_text(encoding="utf-8"))
    T = data.get("T_base_board") if isinstance(data, dict) else None
    if T is None and isinstance(data, dict) and isinstance(data.get("board"), dict):
        T = data["board"].get("T_base_board")
    T = np.asarray(T, dtype=np.float64) if T is not None else None
    if T is None or T.shape != (4, 4) or not np.isfinite(T).all():
        raise AlignError(f"{pose_file}: need T_base_board (4x4 numbers), at the top level or under 'board'")
    return T


def _undistorted_normalized(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """Pixel coordinates (our +0.5 convention) [M,2] -> normalised image coordinates [M,2] through the camera's lens
    (any model; NaN for a fisheye ray at 90 deg or more off the axis)."""
    rays = camera.pixel_rays(uv)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(rays[:, 2:] > 1e-9, rays[:, :2] / rays[:, 2:], np.nan)


@dataclass
class BoardTriangulation:
    ids: np.ndarray  # [M] the target's point ids
    points: np.ndarray  # [M,3] in the SfM frame
    n_views: np.ndarray  # [M] images each corner was seen in
    frames_with_board: list[str] = field(default_factory=list)
    frames_tried: list[str] = field(default_factory=list)
    reprojection_px: float = 0.0  # RMS over all observations


def triangulate_board_corners(
    cameras: list[Camera], images: list[np.ndarray], board: BoardSpec, min_views: int = 3
) -> BoardTriangulation:
    """Detect the board in each image (uint8 [H,W,3]) and triangulate each corner seen in
    ``min_views`` or more views (linear DLT on undistorted rays)."""
    import cv2

    obs: dict[int, list[tuple[int, np.ndarray]]] = {}
    tried, seen = [], []
    for k, (cam, image) in enumerate(zip(cameras, images, strict=True)):
        tried.append(cam.name)
        ids, corners = board.detect(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))
        if len(ids) < 4:
            continue
        seen.append(cam.name)
        xy = _undistorted_normalized(cam, corners.reshape(-1, 2) + 0.5)
        for cid, p in zip(ids.ravel(), xy, strict=True):
            if np.isfinite(p).all():
                obs.setdefault(int(cid), []).append((k, p))
    if len(seen) < 3:
        raise AlignError(
            f"the target ({board.describe()}) was detected in {len(seen)} of {len(tried)} keyframes (needs >= 3); "
            f"tried {', '.join(tried[:6])}{' ...' if len(tried) > 6 else ''}. Check its spec (type, size, id, "
            "dictionary) or film it closer; without a target, `align-scene --unaligned` keeps the SfM frame"
        )
    ids, points, n_views, sq_err = [], [], [], []
    for cid, views in sorted(obs.items()):
        if len(views) < min_views:
            continue
        rows = []
        for k, (x, y) in views:
            P = cameras[k].viewmat[:3]  # world -> camera [3,4]
            rows += [x * P[2] - P[0], y * P[2] - P[1]]
        X = np.linalg.svd(np.asarray(rows))[2][-1]
        X = X[:3] / X[3]
        for k, (x, y) in views:
            p = cameras[k].viewmat[:3, :3] @ X + cameras[k].viewmat[:3, 3]
            f = cameras[k].K[0, 0]
            sq_err.append(f * f * ((p[0] / p[2] - x) ** 2 + (p[1] / p[2] - y) ** 2))
        ids.append(cid)
        points.append(X)
        n_views.append(len(views))
    if len(ids) < 4:
        raise AlignError(
            f"only {len(ids)} board corners were seen in {min_views}+ keyframes; film the board from more views"
        )
    return BoardTriangulation(
        np.asarray(ids), np.asarray(points), np.asarray(n_views), seen, tried, float(np.sqrt(np.mean(sq_err)))
    )


@dataclass
class AlignResult:
    sim3_sfm_to_base: Sim3
    corner_rms_mm: float  # triangulated corners vs their known base positions, after alignment
    icp_rmse_mm: float | None  # board-region SfM points vs the support surface
    icp_points: int
    triangulation: BoardTriangulation
    method: str = "marker"  # "marker", "marker+icp" or "unaligned"
    note: str = ""  # why ICP was used, skipped or rejected

    def to_json(self) -> dict:
        tri = self.triangulation
        return {
            "method": self.method,
            "note": self.note,
            "sim3_sfm_to_base": self.sim3_sfm_to_base.to_json(),
            "corner_rms_mm": self.corner_rms_mm if np.isfinite(self.corner_rms_mm) else None,
            "icp_rmse_mm": self.icp_rmse_mm,
            "icp_points": self.icp_points,
            "corners_triangulated": len(tri.ids),
            "corner_reprojection_px": tri.reprojection_px,
            "frames_with_board": tri.frames_with_board,
            "frames_tried": len(tri.frames_tried),
        }


def support_region(
    T_base_board: np.ndarray,
    board: BoardSpec,
    extent: float = 0.3,
    spacing: float = 0.004,
    footprint_xy: np.ndarray | None = None,
) -> np.ndarray:
    """The simulator's robot-base region as points [M,3]: the support plane the board lies on,
    sampled every ``spacing`` metres over the board's square (side board size + 2 * ``extent``)
    grown to cover the robot base's ``footprint_xy`` [P,2] when a robot model gives one."""
    w, h = board.size
    half = max(w, h) / 2 + extent
    centre = T_base_board[:3, :3] @ np.array([w / 2, h / 2, 0.0]) + T_base_board[:3, 3]
    lo, hi = centre[:2] - half, centre[:2] + half
    if footprint_xy is not None and len(footprint_xy):
        lo = np.minimum(lo, np.min(footprint_xy, axis=0) - extent)
        hi = np.maximum(hi, np.max(footprint_xy, axis=0) + extent)
    xx, yy = np.meshgrid(np.arange(lo[0], hi[0] + 1e-9, spacing), np.arange(lo[1], hi[1] + 1e-9, spacing))
    return np.c_[xx.ravel(), yy.ravel(), np.full(xx.size, centre[2])]


def align_scene(
    cameras: list[Camera],
    images: list[np.ndarray],
    points_sfm: np.ndarray,
    board: BoardSpec,
    T_base_board: np.ndarray | None = None,
    icp: bool = False,
    footprint_xy: np.ndarray | None = None,
) -> AlignResult:
    """sim3_sfm_to_base from the target's triangulated corners; with ``icp``, refined by scaled ICP of the SfM points
    around it onto the support surface where the SfM saw that surface near the base (see stages.align.Config)."""
    T_base_board = default_T_base_board(board) if T_base_board is None else np.asarray(T_base_board, np.float64)
    tri = triangulate_board_corners(cameras, images, board)
    corners_base = board.points_board(tri.ids) @ T_base_board[:3, :3].T + T_base_board[:3, 3]
    sim = umeyama(tri.points, corners_base)
    rms_mm = float(1000 * np.sqrt(np.mean(np.sum((sim.apply(tri.points) - corners_base) ** 2, axis=1))))
    if rms_mm > 0.1 * board.feature_size * 1000:
        raise AlignError(
            f"the triangulated target does not have the shape of a {board.describe()} (corner residual {rms_mm:.1f} "
            f"mm after fitting, {len(tri.ids)} corners from {len(tri.frames_with_board)} keyframes); check its spec "
            "(sizes, dictionary) against the printed one; if it is right, the SfM poses of those keyframes are off: "
            "capture more views of the target (more keyframes, a slower orbit)"
        )
    icp_rmse, n_icp, method = None, 0, "marker"
    note = "the target alone (ICP off)" if not icp else ""
    if icp and len(points_sfm):
        target = support_region(T_base_board, board, footprint_xy=footprint_xy)
        lo, hi = target.min(0) - [0, 0, 0.02], target.max(0) + [0, 0, 0.02]
        moved = sim.apply(np.asarray(points_sfm, np.float64))
        near = np.all((moved >= lo) & (moved <= hi), axis=1)
        n_icp = int(near.sum())
        n_base = int(np.sum(near & _near_base(moved, footprint_xy)))
        if n_base < MIN_BASE_POINTS:
            # On a real capture with the base out of view the fit of a few table points slid the cameras 11 mm
            # (2.5 mm without ICP): the support plane is only evidence where it was reconstructed.
            note = (f"ICP skipped: {n_base} SfM points on the table within {100 * BASE_MARGIN_M:g} cm of the robot "
                    f"base (needs {MIN_BASE_POINTS}); the marker alone places the scene")  # fmt: skip
        else:
            result = scaled_icp(
                np.asarray(points_sfm)[near], target, init=sim, anchors=(tri.points, corners_base), trim_fraction=0.8
            )
            icp_corner_mm = float(1000 * np.sqrt(np.mean(np.sum((result.sim3.apply(tri.points) - corners_base) ** 2,
                                                                 axis=1))))  # fmt: skip
            if icp_corner_mm > 1.5 * rms_mm + 0.5:  # ICP pulled the marker off its known place: trust the marker
                note = (f"ICP rejected: it moved the marker corners to {icp_corner_mm:.1f} mm RMS from their known "
                        f"place (marker alone: {rms_mm:.1f} mm)")  # fmt: skip
            else:
                sim, icp_rmse, rms_mm, method = result.sim3, 1000 * result.rmse, icp_corner_mm, "marker+icp"
                note = f"marker + ICP over {n_icp} points ({n_base} near the base)"
    return AlignResult(sim, rms_mm, icp_rmse, n_icp, tri, method, note)


# ICP refines the fit only where the SfM saw the robot's support surface around the base.
MIN_BASE_POINTS = 50
BASE_MARGIN_M = 0.15


def _near_base(points_base: np.ndarray, footprint_xy: np.ndarray | None) -> np.ndarray:
    """[N] bool: points whose x, y lie within BASE_MARGIN_M of the base footprint's box (a 10 cm circle without
    a robot model)."""
    fp = np.asarray(footprint_xy, np.float64) if footprint_xy is not None and len(footprint_xy) else \
        np.array([[-0.1, -0.1], [0.1, 0.1]])  # fmt: skip
    lo, hi = fp.min(axis=0) - BASE_MARGIN_M, fp.max(axis=0) + BASE_MARGIN_M
    return np.all((points_base[:, :2] >= lo) & (points_base[:, :2] <= hi), axis=1)


def unaligned_result(cameras: list[Camera]) -> AlignResult:
    """The identity: the scene stays in the SfM frame (not metric, not the robot's), for scene-only use."""
    tri = BoardTriangulation(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64), [],
                             [c.name for c in cameras])  # fmt: skip
    note = "unaligned: the SfM frame, not metric and not the robot's (align-scene --unaligned)"
    return AlignResult(Sim3(1.0, np.eye(3), np.zeros(3)), float("nan"), None, 0, tri, "unaligned", note)


def apply_to_cameras(sim3: Sim3, cameras: list[Camera]) -> list[Camera]:
    """Cameras in the base frame: eq. `pose_update` (rotation R R_wc, centre s R c + t)."""
    out = []
    for cam in cameras:
        T = sim3.apply_pose(cam.T_world_cam)
        out.append(dataclasses.replace(cam, T_world_cam=T, distortion=dict(cam.distortion)))
    return out


def overlay_keyframe(cameras_base: list[Camera], frames_with_board: list[str]) -> int:
    """Index of the keyframe to draw the base into: of those that see the board, the one that sees the base's origin
    nearest its image centre (a wrist view sees the board and not the base); the first of them when none sees it."""
    best, best_d = None, np.inf
    for i, cam in enumerate(cameras_base):
        if cam.name not in frames_with_board:
            continue
        best = i if best is None else best
        uv, z = cam.project(np.zeros((1, 3)))
        off = uv[0] / [cam.width, cam.height] - 0.5  # the origin from the image centre, in image sides
        if z[0] > 0 and np.abs(off).max() < 0.5 and np.hypot(*off) < best_d:
            best, best_d = i, float(np.hypot(*off))
    if best is None:
        raise ValueError("no keyframe sees the board")
    return best


def draw_base_overlay(
    images: list[np.ndarray], cameras_base: list[Camera], frames_with_board: list[str], footprint_xy=None,
    robot_mask: Callable[[Camera], np.ndarray] | None = None,
) -> np.ndarray:  # fmt: skip
    """The robot base footprint [P,2] (from the robot model, else a 10 cm circle at the origin) and the base
    axes (x red, y green, z blue, 15 cm) drawn into a keyframe (uint8 [H,W,3]) that sees the board
    (:func:`overlay_keyframe`); with ``robot_mask(camera) -> bool [H,W]``, the robot's outline at its capture joint
    state too (yellow): on the robot in the picture when the joints and the alignment are right."""
    import cv2

    k = overlay_keyframe(cameras_base, frames_with_board)
    cam, image = cameras_base[k], images[k].copy()
    if robot_mask is not None:
        contours, _ = cv2.findContours(robot_mask(cam).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(image, contours, -1, (255, 255, 0), 2, cv2.LINE_AA)
    if footprint_xy is None:
        t = np.linspace(0, 2 * np.pi, 64)
        footprint_xy = 0.1 * np.c_[np.cos(t), np.sin(t)]
    outline = np.c_[footprint_xy, np.zeros(len(footprint_xy))]
    axes = np.array([[0, 0, 0], [0.15, 0, 0], [0, 0.15, 0], [0, 0, 0.15]], float)

    def px(points):
        uv, depth = cam.project(points)
        return [tuple(int(round(v)) for v in p - 0.5) for p in uv], depth

    outline_px, _ = px(outline)
    cv2.polylines(image, [np.asarray(outline_px, np.int32)], True, (255, 0, 255), 2, cv2.LINE_AA)
    (o, x, y, z), _ = px(axes)
    for end, colour in ((x, (255, 0, 0)), (y, (0, 255, 0)), (z, (0, 0, 255))):
        cv2.line(image, o, end, colour, 2, cv2.LINE_AA)
    return image
