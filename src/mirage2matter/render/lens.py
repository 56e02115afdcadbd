"""A camera's lens on pinhole renders: the rays of a distorted camera's pixels, and an image resampled through that
lens from a wider pinhole render.

The splat rasterizer and Genesis render pinhole images only (square pixels, principal point at the centre). A camera
with a lens (radial-tangential or fisheye distortion, an off-centre principal point, fx != fy) is drawn in two steps:
render a centred pinhole whose field of view covers every ray the lens takes in (:func:`pinhole_cover`), then let
each pixel of the distorted image read that render where its ray lands (:func:`resample_through_lens`). The sample
maker films its phone lens so (``sample.make``, 2 x 2 samples per pixel), the environment draws a calibrated camera's
lens so (``env.lens``), and the hand-eye test bed traces its board rays with :func:`lens_rays`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..geometry.camera import Camera

__all__ = ["MAX_COVER", "centred_K", "depth_through_lens", "lens_cover", "lens_rays", "pinhole_cover",
           "resample_through_lens"]

# The widest pinhole render a lens may ask for, in image sizes per side: past it the pinhole's edges are stretched
# thin (a fisheye near 180 deg needs an unbounded one) and the render's cost grows with the square.
MAX_COVER = 3.0


def lens_rays(camera: Camera, supersample: int = 2) -> np.ndarray:
    """Normalised pinhole coordinates (x, y) = (X / Z, Y / Z) [H*s, W*s, 2] of the rays that ``camera`` (its K and
    lens) images at each of ``s`` x ``s`` sample points per pixel, sample centres at ((i + 0.5) / s) in pixels."""
    s = int(supersample)
    u = (np.arange(camera.width * s) + 0.5) / s  # our convention: pixel centres at +0.5
    v = (np.arange(camera.height * s) + 0.5) / s
    uu, vv = np.meshgrid(u, v)
    uv = camera.undistort_pixels(np.c_[uu.ravel(), vv.ravel()])  # where a pinhole with the same K sees the rays
    xy = np.c_[(uv[:, 0] - camera.cx - camera.K[0, 1] * (uv[:, 1] - camera.cy) / camera.fy) / camera.fx,
               (uv[:, 1] - camera.cy) / camera.fy]  # fmt: skip
    return xy.reshape(camera.height * s, camera.width * s, 2)


def pinhole_cover(rays: np.ndarray, focal: float, size: tuple[int, int], margin_px: float = 4.0) -> tuple[int, int]:
    """(width, height) of the centred pinhole of focal length ``focal`` (px) that sees every ray of ``rays`` [h, w, 2]
    with ``margin_px`` to spare, at least ``size`` (width, height) and differing from it by even numbers, so that a
    pinhole of ``size`` with the same focal length is an exact centred crop of it (whole pixels)."""
    half = np.abs(rays.reshape(-1, 2)).max(axis=0) * focal + margin_px
    out = []
    for n, h in zip(size, half, strict=True):
        m = max(int(n), 2 * math.ceil(h))
        out.append(m + (m - int(n)) % 2)
    return out[0], out[1]


def centred_K(focal: float, size: tuple[int, int]) -> np.ndarray:
    """Intrinsics [3,3] of the centred pinhole of focal length ``focal`` (px, square pixels) and ``size`` (width,
    height): the render :func:`resample_through_lens` and :func:`depth_through_lens` read."""
    w, h = size
    return np.array([[focal, 0.0, 0.5 * w], [0.0, focal, 0.5 * h], [0.0, 0.0, 1.0]])


def lens_cover(camera: Camera, focal: float, margin_px: float = 2.0) -> tuple[np.ndarray, tuple[int, int]]:
    """(rays [H, W, 2] of ``camera``'s pixels, one each (:func:`lens_rays`); (width, height) of the centred pinhole of
    focal length ``focal`` that covers them (:func:`pinhole_cover`)). ValueError, worded to follow "its lens", when
    the lens sees too wide for a pinhole render: rays at or past 90 deg, or over :data:`MAX_COVER` x the image per
    side."""
    rays = lens_rays(camera, supersample=1)
    size = (camera.width, camera.height)
    if np.isfinite(rays).all():
        w, h = pinhole_cover(rays, focal, size, margin_px)
        if w <= MAX_COVER * size[0] and h <= MAX_COVER * size[1]:
            return rays, (w, h)
    raise ValueError(f"sees too wide for a pinhole render at {size[0]}x{size[1]} (over {MAX_COVER:g}x the image per "
                     "side, or rays at 90 deg: a fisheye near 180 deg)")  # fmt: skip


def resample_through_lens(image: np.ndarray, focal: float, rays: np.ndarray, supersample: int = 2) -> np.ndarray:
    """The image [H, W, 3] uint8 a lens takes of the scene that a centred pinhole of focal length ``focal`` (px)
    rendered as ``image`` [h, w, 3] uint8: each sample of ``rays`` [H*s, W*s, 2] (:func:`lens_rays` with
    ``supersample`` s) reads ``image`` bilinearly where its ray lands, and each pixel averages its s x s samples (a
    sensor pixel integrates its area)."""
    import cv2

    s = int(supersample)
    H, W = rays.shape[0] // s, rays.shape[1] // s
    map_x, map_y = _maps(rays, focal, image.shape[1], image.shape[0])
    samples = cv2.remap(image.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out = samples.reshape(H, s, W, s, -1).mean(axis=(1, 3))
    return np.clip(np.round(out), 0, 255).astype(np.uint8).reshape(H, W, *image.shape[2:])


def depth_through_lens(depth: np.ndarray, focal: float, rays: np.ndarray) -> np.ndarray:
    """The depth [H, W] float32 of the lens's pixels (``rays`` [H, W, 2], one per pixel) from a centred pinhole's
    depth [h, w] of focal length ``focal`` (the same camera frame: a point's depth is the same in both): each pixel
    takes the nearest render pixel's, never a blend across an edge."""
    import cv2

    map_x, map_y = _maps(rays, focal, depth.shape[1], depth.shape[0])
    return cv2.remap(np.asarray(depth, np.float32), map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)


def _maps(rays: np.ndarray, focal: float, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap's maps (pixel centres at integers) reading a centred ``w`` x ``h`` pinhole where ``rays`` land."""
    map_x = (rays[..., 0] * focal + 0.5 * w - 0.5).astype(np.float32)
    map_y = (rays[..., 1] * focal + 0.5 * h - 0.5).astype(np.float32)
    if map_x.min() < -0.5 or map_y.min() < -0.5 or map_x.max() > w - 0.5 or map_y.max() > h - 0.5:
        raise ValueError(f"the lens sees past the {w}x{h} pinhole render; render it wider (pinhole_cover)")
    return map_x, map_y
