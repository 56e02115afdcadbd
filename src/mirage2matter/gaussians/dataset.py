"""Training views from cameras + photos: downscale, undistort, valid-pixel masks, held-out split,
and initial points for imported (known) poses.

Images are undistorted once, up front, to the pinhole camera with the *same* K, so that the
renderer (pinhole only) and the photos agree. Undistortion pulls pixels from outside the photo
near the border; those pixels are marked invalid (and the mask eroded by ``erode_px``) so that
they count neither in the loss nor in the metrics.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..errors import M2MError
from ..geometry.camera import Camera
from .train import View

__all__ = [
    "DatasetError",
    "build_views",
    "downscale_camera",
    "downscale_image",
    "load_image",
    "make_view",
    "photo_view",
    "points_for_known_poses",
    "split_holdout",
    "undistort_image",
]


class DatasetError(M2MError, ValueError):
    """Unusable images or cameras; the message names the file and what to do."""


def _basename(name: str) -> str:
    return os.path.basename(name.replace("\\", "/"))


def load_image(path: str | os.PathLike[str], downscale: int = 1) -> np.ndarray:
    """RGB photo as float32 [H // f, W // f, 3] in [0, 1], downscaled by the integer ``f`` with
    area averaging (the image is first cropped to a multiple of ``f``, so pixel edges stay put)."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: image not found (check the file paths in transforms.json / the image folder)")
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise DatasetError(f"{path}: not a readable image; replace or remove it")
    return downscale_image(bgr[..., ::-1], downscale)


def downscale_image(rgb: np.ndarray, downscale: int = 1) -> np.ndarray:
    """uint8 or float [H,W,3] -> float32 [H // f, W // f, 3] in [0, 1] by area averaging."""
    import cv2

    f = int(downscale)
    if f < 1:
        raise ValueError(f"downscale must be an integer >= 1, got {downscale}")
    img = np.asarray(rgb)
    img = img.astype(np.float32) / 255.0 if img.dtype == np.uint8 else img.astype(np.float32)
    h, w = img.shape[0] // f, img.shape[1] // f
    if h < 1 or w < 1:
        raise ValueError(f"downscale {f} leaves no pixels of a {img.shape[1]}x{img.shape[0]} image")
    img = np.ascontiguousarray(img[: h * f, : w * f])
    if f > 1:
        img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    return img


def downscale_camera(camera: Camera, downscale: int) -> Camera:
    """The camera of ``downscale_image(..., downscale)``: size W // f x H // f, fx, fy, cx, cy / f
    (exact with pixel centres at +0.5; the crop to a multiple of f removes only right/bottom
    pixels). Distortion coefficients act on normalised coordinates and do not change."""
    f = int(downscale)
    if f < 1:
        raise ValueError(f"downscale must be an integer >= 1, got {downscale}")
    K = np.diag([1.0 / f, 1.0 / f, 1.0]) @ camera.K
    w, h = camera.width // f, camera.height // f
    return dataclasses.replace(camera, K=K, T_world_cam=camera.T_world_cam.copy(), width=w, height=h,
                               distortion=dict(camera.distortion))  # fmt: skip


def undistort_image(image: np.ndarray, camera: Camera, erode_px: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Undistort ``image`` [H,W,C] (float) taken by ``camera`` to the pinhole camera with the same K (any lens
    model the camera has: radial-tangential or fisheye).

    Returns (undistorted [H,W,C] float32, valid [H,W] bool): a pixel is valid when its whole
    bilinear footprint came from inside the photo, minus an ``erode_px`` border. Without
    distortion the image is returned as is with an all-true mask.
    """
    import cv2

    h, w = image.shape[:2]
    if (w, h) != (camera.width, camera.height):
        raise DatasetError(f"{camera.name}: image is {w}x{h} but its camera says {camera.width}x{camera.height}")
    try:
        distorted = camera.has_distortion
    except ValueError as e:
        raise DatasetError(str(e)) from None
    if not distorted:
        return np.ascontiguousarray(image, dtype=np.float32), np.ones((h, w), bool)
    # each output (pinhole) pixel centre reads the photo where the lens imaged its ray; -0.5: cv2.remap puts
    # pixel centres at integers. Rays with no place in the photo (a fisheye's beyond 90 deg) read nothing.
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    src = camera.distort_pixels(np.c_[u.ravel(), v.ravel()]) - 0.5
    src[~np.isfinite(src).all(axis=1)] = -1e6
    map_x = src[:, 0].reshape(h, w).astype(np.float32)
    map_y = src[:, 1].reshape(h, w).astype(np.float32)
    out = cv2.remap(image.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    ones = np.ones((h, w), np.float32)
    cover = cv2.remap(ones, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    valid = (cover > 0.999).astype(np.uint8)
    if erode_px > 0:
        kernel = np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)
        valid = cv2.erode(valid, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return out.reshape(image.shape).astype(np.float32, copy=False), valid.astype(bool)


def photo_view(camera: Camera, photo: np.ndarray, downscale: int = 1, keep: np.ndarray | None = None,
               erode_px: int = 2) -> View:
    """A training view from one photo [H,W,3] (uint8 or float in [0, 1]) that ``camera`` took (its full-size
    pinhole + lens): area-downscaled by ``downscale`` and undistorted like the keyframes. ``keep`` [H,W] bool marks
    the pixels that show the scene (False: the robot, a person); a downscaled pixel is kept only when all of its
    footprint is."""
    h, w = np.asarray(photo).shape[:2]
    if (w, h) != (camera.width, camera.height):
        raise DatasetError(f"{camera.name}: photo is {w}x{h} but its camera says {camera.width}x{camera.height}")
    small = downscale_camera(camera, downscale)
    img, valid = undistort_image(downscale_image(photo, downscale), small, erode_px)
    if keep is not None:
        if keep.shape != (h, w):
            raise DatasetError(f"{camera.name}: mask is {keep.shape[1]}x{keep.shape[0]}, the photo {w}x{h}")
        frac = downscale_image(keep.astype(np.float32), downscale)  # the kept fraction of each pixel's footprint
        frac, _ = undistort_image(frac[..., None], small, 0)  # the mask through the same lens as the photo
        valid &= frac[..., 0] > 0.999
    if not valid.any():
        raise DatasetError(f"{camera.name}: no pixel of the photo is left to train on (check its mask)")
    return make_view(small, img, None if valid.all() else valid)


def split_holdout(n: int, every: int = 8) -> tuple[list[int], list[int]]:
    """(train indices, held-out indices): every ``every``-th view (0, every, 2 every, ...) is held
    out, as in the 3DGS / Mip-NeRF 360 evaluation protocol. ``every <= 0``: no hold-out."""
    if every <= 0:
        return list(range(n)), []
    held = [i for i in range(n) if i % every == 0]
    return [i for i in range(n) if i % every != 0], held


def make_view(camera: Camera, image: np.ndarray, mask: np.ndarray | None = None) -> View:
    """A ``View`` from a (pinhole, already undistorted) camera and image [H,W,3] float in [0,1]."""
    return View(
        image=torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32)),
        viewmat=torch.as_tensor(camera.viewmat, dtype=torch.float32),
        K=torch.as_tensor(camera.K, dtype=torch.float32),
        mask=None if mask is None else torch.from_numpy(np.ascontiguousarray(mask, dtype=bool)),
        name=camera.name,
    )


def build_views(
    cameras: Sequence[Camera],
    image_dir: str | os.PathLike[str],
    downscale: int = 1,
    holdout_every: int = 8,
    erode_px: int = 2,
) -> tuple[list[View], list[View]]:
    """(train views, held-out views) for ``cameras`` (sorted by name; every ``holdout_every``-th
    held out). Each camera's image is ``image_dir / camera.name`` (or its basename there), loaded,
    area-downscaled by ``downscale`` and undistorted with the camera's distortion; the view's
    mask holds the valid undistorted pixels."""
    image_dir = Path(image_dir)
    cams = sorted(cameras, key=lambda c: c.name)
    if not cams:
        raise DatasetError("no cameras to build training views from")
    views = []
    for cam in cams:
        path = image_dir / cam.name
        if not path.is_file():
            path = image_dir / _basename(cam.name)
        small = downscale_camera(cam, downscale)
        img, mask = undistort_image(load_image(path, downscale), small, erode_px)
        views.append(make_view(small, img, None if mask.all() else mask))
    train_idx, held_idx = split_holdout(len(views), holdout_every)
    return [views[i] for i in train_idx], [views[i] for i in held_idx]


def points_for_known_poses(
    cameras: Sequence[Camera],
    image_dir: str | os.PathLike[str],
    work_dir: str | os.PathLike[str],
    sfm_downscale: float = 0.5,
    sfm_config: Any = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Initial points for training from given poses (e.g. a ``transforms.json``).

    Runs our SfM on the images in ``image_dir`` (all of them), fits the similarity that maps its
    camera centres onto the given ones (cameras matched by file basename) and maps its points with
    it. Returns (points_world [M,3] float64 in the given poses' frame, colors [M,3] uint8, info
    with the pose comparison). ``work_dir / "colmap"`` receives the SfM output.
    """
    from ..geometry.sim3 import Sim3
    from ..sfm.colmap import SfMConfig, compare_poses, run_sfm

    given = {_basename(c.name): c.T_world_cam for c in cameras}
    if len(given) != len(cameras):
        raise DatasetError("camera names must have distinct basenames to be matched with the images")
    config = sfm_config or SfMConfig(downscale=sfm_downscale)
    sfm = run_sfm(image_dir, Path(work_dir) / "colmap", config)
    estimated = {_basename(n): T for n, T in sfm.poses.items()}
    if len(set(estimated) & set(given)) < 3:
        raise DatasetError(
            f"{image_dir}: only {len(set(estimated) & set(given))} SfM-registered images have a given pose; "
            "the image names must match the camera names"
        )
    cmp = compare_poses(estimated, given)
    sim = Sim3.from_json(cmp["sim3_est_to_ref"])
    points = sim.apply(sfm.points.astype(np.float64))
    info = {k: v for k, v in cmp.items() if k != "per_camera"}
    info.update(registered=sfm.registered, total=sfm.total, sfm_seconds=sfm.seconds, num_points=len(points))
    return points, sfm.colors.copy(), info
