"""The moved robot kept out of SfM's features.

A robot that moves while the capture is filmed (``capture_moves``) is a rigid body moving against the room, and
SfM's matcher pairs its features across the move: an epipolar check lets a point slide along its line. On the
two-pose sample, 16 keyframes gave board corners 2.54 mm RMS (one pose: < 1 mm) and cameras 10.6 mm / 0.54 deg
from the truth. So the sfm stage runs SfM twice. The first run, as it is, places the cameras well enough for a mask
(those 10.6 mm and 0.54 deg are ~5 px at the robot); the board aligns it to the robot's base. Each keyframe filmed
after a move then gets a mask (COLMAP extracts no features where it is black): the robot's silhouette at the joint
state of its video frame, through that camera and its lens, grown by 2 % of the image. The second run, with the
masks, is the stage's result (that sample: corners 0.29 mm, cameras 2.1 mm / 0.09 deg). The first pose keeps its
features: they are static until the first move, and align-scene's robot points (its check of the board's
alignment and of ``capture_joints``) come from them.

A keyframe the first run left unregistered is placed by the board's corners alone (PnP through the first run's
lens); one that shows too little of the board keeps its features, and the stage line says so.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import atomic_dir, atomic_write, replace_dir
from ..calib.align import AlignError, align_scene, apply_to_cameras
from ..calib.handeye import detect_board_pose
from ..calib.robot_view import grow_mask, robot_silhouette
from ..geometry.camera import Camera
from ..geometry.sim3 import invert_rigid
from ..robots.capture_poses import CapturePoses
from ..robots.spec import RobotSpec
from ..robots.surface import robot_surface
from .colmap import SfMConfig, SfMResult, list_images, run_sfm

__all__ = ["GROW_FRACTION", "MIN_CORNERS", "RobotMasks", "board_camera", "lens_silhouette", "moved_keyframes",
           "run_sfm_without_moved_robot", "write_robot_masks"]  # fmt: skip

# A board pose from fewer corners is not trusted: on the bundled sample's video, 16-24 corners placed every frame within
# 3.6 mm of the truth, 13 corners 12 mm off, 10 (a strip at the image's edge) 46 mm.
MIN_CORNERS = 16
# The mask is grown by this fraction of the image's longer side (13 px at 640): the first run's cameras are a few
# pixels off at the robot (~5 px on the two-pose sample's 16 keyframes), the model's meshes a few millimetres off the
# real casting, and SIFT's descriptor window (~6 x the keypoint's scale) reaches past a keypoint's own pixel.
GROW_FRACTION = 0.02


def board_camera(image_path: Path, board, T_base_board: np.ndarray, lens: Camera) -> Camera | None:
    """The keyframe's camera (base frame) from the board's corners it shows, by the hand-eye calibration's PnP
    through ``lens`` (its K and lens model; its pose ignored); None when it shows fewer than :data:`MIN_CORNERS`."""
    import cv2

    gray = cv2.imread(str(image_path), cv2.IMREAD_GRAYSCALE)
    seen = None if gray is None else detect_board_pose(gray, board, lens, min_corners=MIN_CORNERS)
    if seen is None:
        return None
    return dataclasses.replace(lens, T_world_cam=T_base_board @ invert_rigid(seen.T_cam_board), name=image_path.name,
                               distortion=dict(lens.distortion))  # fmt: skip


def lens_silhouette(camera: Camera, links, grow_px: int) -> np.ndarray:
    """bool [H,W]: the robot's links as ``camera`` sees them through its lens, grown by ``grow_px``: drawn by an
    ideal pinhole on a canvas wide enough for the lens's extent, then looked up where each pixel's ray lands."""
    if not camera.has_distortion:
        return robot_silhouette(camera, links, grow_px)
    h, w = camera.height, camera.width
    step = max(1, round(max(w, h) / 960))  # a lookup per step x step pixels (1 up to ~1280 px wide, then 2, ...)
    v, u = np.mgrid[0:h:step, 0:w:step]
    ideal = camera.undistort_pixels(np.c_[u.ravel() + 0.5, v.ravel() + 0.5])
    ok = np.isfinite(ideal).all(axis=1)
    lo = np.floor(np.nanmin(ideal[ok], axis=0)).astype(int) - 1
    hi = np.ceil(np.nanmax(ideal[ok], axis=0)).astype(int) + 1
    lo, hi = np.maximum(lo, [-2 * w, -2 * h]), np.minimum(hi, [3 * w, 3 * h])  # a lens's far rim: not the robot's
    K = camera.K.copy()
    K[0, 2] -= lo[0]
    K[1, 2] -= lo[1]
    canvas = Camera(K, camera.T_world_cam, int(hi[0] - lo[0]), int(hi[1] - lo[1]))
    sil = robot_silhouette(canvas, links)
    iu, iv = np.floor(ideal[:, 0] - lo[0]).astype(np.int64), np.floor(ideal[:, 1] - lo[1]).astype(np.int64)
    ok &= (iu >= 0) & (iv >= 0) & (iu < canvas.width) & (iv < canvas.height)
    hit = np.zeros(len(ideal), bool)
    hit[ok] = sil[iv[ok], iu[ok]]
    small = hit.reshape(u.shape).astype(np.uint8)
    full = np.repeat(np.repeat(small, step, axis=0), step, axis=1)[:h, :w]
    return grow_mask(full, grow_px + step - 1)


@dataclass
class RobotMasks:
    """What :func:`write_robot_masks` did.

    masked       keyframes filmed after a move whose robot was masked
    by_board     of those, the ones the first run left unregistered, placed by the board's corners alone
    unplaced     keyframes filmed after a move that could not be placed: their features kept
    robot_px     per masked keyframe, the fraction of its pixels masked
    """

    masked: list[str] = field(default_factory=list)
    by_board: list[str] = field(default_factory=list)
    unplaced: list[str] = field(default_factory=list)
    robot_px: dict[str, float] = field(default_factory=dict)

    @property
    def line(self) -> str:
        line = f"the moved robot masked out of {len(self.masked)} keyframes' features"
        if self.by_board:
            line += f" ({len(self.by_board)} placed by the board alone)"
        if self.unplaced:
            line += (f"; {len(self.unplaced)} filmed after a move neither registered nor showing the board: their "
                     f"features kept ({', '.join(self.unplaced[:3])})")  # fmt: skip
        return line

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def moved_keyframes(keyframes: Sequence[dict], poses: CapturePoses) -> dict[str, int]:
    """{keyframe: pose} of capture/keyframes.json's keyframes filmed after a move (pose >= 1)."""
    at = {k["file"]: poses.index_at(int(k["frame_index"])) for k in keyframes}
    return {n: p for n, p in at.items() if p > 0}


def write_robot_masks(out_dir: Path, image_dir: Path, names: Sequence[str], moved: dict[str, int],
                      cameras_base: Sequence[Camera], spec: RobotSpec, poses: CapturePoses, board,
                      T_base_board: np.ndarray) -> RobotMasks:
    """COLMAP's masks (``out_dir/<keyframe>.png``: 0 where no feature may be, 255 elsewhere) for every keyframe in
    ``names``: the robot's silhouette at its pose for those ``moved`` ({keyframe: pose}), through its camera in
    ``cameras_base`` (the first run's, in the base frame) or else the board's; white for the rest (COLMAP extracts
    no features from an image whose mask is missing). Written whole or not at all."""
    import cv2

    result = RobotMasks()
    by_name = {c.name: c for c in cameras_base}
    lens = cameras_base[0]
    some = cv2.imread(str(image_dir / names[0]), cv2.IMREAD_GRAYSCALE)
    h, w = some.shape[:2]
    grow = max(4, round(GROW_FRACTION * max(w, h)))
    links = {p: robot_surface(spec, poses.joints[p]) for p in sorted(set(moved.values()))}
    with atomic_dir(out_dir) as tmp:
        for name in sorted(names):
            cam = None
            if name in moved:
                cam = by_name.get(name)
                if cam is None:
                    cam = board_camera(image_dir / name, board, T_base_board, lens)
                    (result.by_board if cam is not None else result.unplaced).append(name)
            if cam is None:
                cv2.imwrite(str(tmp / f"{name}.png"), np.full((h, w), 255, np.uint8))
                continue
            sil = lens_silhouette(cam, links[moved[name]], grow)
            cv2.imwrite(str(tmp / f"{name}.png"), np.where(sil, 0, 255).astype(np.uint8))
            result.masked.append(name)
            result.robot_px[name] = round(float(sil.mean()), 4)
    return result


def run_sfm_without_moved_robot(
    image_dir: Path,
    out_dir: Path,
    config: SfMConfig,
    keyframes: Sequence[dict],
    spec: RobotSpec,
    poses: CapturePoses,
    board,
    T_base_board: np.ndarray,
    log: Callable[[str], None] = lambda _: None,
) -> tuple[SfMResult, RobotMasks | None, str]:
    """:func:`~.colmap.run_sfm` of ``image_dir`` into ``out_dir`` with the robot masked out of the keyframes
    (capture/keyframes.json's records) filmed after a move of ``poses``: a first run, aligned by ``board`` at
    ``T_base_board``, places the cameras for the masks; the second run is the result. Returns (result, the masks,
    ""), or (the one run, unmasked, None, why not) when no keyframe follows a move or the board did not place the
    first run. The masks are kept in ``out_dir/masks/``, what was done in ``out_dir/robot_masks.json``."""
    from PIL import Image

    moved = moved_keyframes(keyframes, poses)
    if not moved:
        return run_sfm(image_dir, out_dir, config), None, "no keyframe was filmed after the first move's frame"
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{out_dir.name}-first-", dir=out_dir.parent) as tmp:
        log(f"sfm: the robot moved while filming ({len(moved)} keyframes after the move): a first SfM run places "
            "the cameras for its masks")  # fmt: skip
        first = run_sfm(image_dir, Path(tmp) / "first", config)
        images = [np.asarray(Image.open(Path(image_dir) / c.name).convert("RGB")) for c in first.cameras]
        try:
            aligned = align_scene(first.cameras, images, first.points, board, T_base_board)
        except AlignError as e:  # the first run is what SfM without masks gives: it is the result
            replace_dir(Path(tmp) / "first", out_dir)
            first = dataclasses.replace(first, model_dir=out_dir / "model")
            return first, None, f"the board did not place the first run's cameras: {e}"
        del images
        cameras_base = apply_to_cameras(aligned.sim3_sfm_to_base, first.cameras)
        masks = write_robot_masks(Path(tmp) / "masks", Path(image_dir), list_images(Path(image_dir)), moved,
                                  cameras_base, spec, poses, board, T_base_board)  # fmt: skip
        result = run_sfm(image_dir, out_dir, dataclasses.replace(config, mask_dir=str(Path(tmp) / "masks")))
        shutil.copytree(Path(tmp) / "masks", out_dir / "masks")
    record = {**masks.to_json(), "first_run": {"registered": first.registered, "total": first.total,
              "corner_rms_mm": aligned.corner_rms_mm}}  # fmt: skip
    with atomic_write(out_dir / "robot_masks.json", "w", encoding="utf-8") as f:
        json.dump(record, f, indent=1)
    return result, masks, ""
