"""A real camera's lens on the sample maker's pinhole renders: the rays of a distorted camera's pixels, and an image
resampled through that lens from a wider pinhole render.

Genesis' rasterizer renders pinhole images only (square pixels, principal point at the centre). A camera with a lens
(radial-tangential distortion, an off-centre principal point, fx != fy) is made in two steps: render a centred
pinhole whose field of view covers every ray the lens takes in (:func:`pinhole_cover`), then let each pixel of the
distorted image read that render where its ray lands (:func:`resample_through_lens`, 2 x 2 samples per pixel).
:func:`lens_rays` is also what the hand-eye test bed traces its board rays with (``sample.handeye_capture``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geometry.camera import Camera

__all__ = ["LENSES", "LensConfig", "lens_rays", "pinhole_cover", "resample_through_lens"]


@dataclass(frozen=True)
class LensConfig:
    """A video camera's intrinsics and lens (pixels at the sample's image size; pixel centres at +0.5).

    name            what the sample's command line calls it (``m2m sample make --lens NAME``)
    fx, fy          focal lengths (px)
    cx, cy          principal point (px)
    distortion      OpenCV radial-tangential coefficients (k1, k2, p1, p2, k3)
    """

    name: str
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float, float]

    def camera(self, width: int, height: int) -> Camera:
        """The lens as a :class:`Camera` of ``width`` x ``height`` (pose: identity)."""
        k1, k2, p1, p2, k3 = self.distortion
        K = np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])
        return Camera(K, np.eye(4), width, height, self.name, {"k1": k1, "k2": k2, "p1": p1, "p2": p2, "k3": k3})


LENSES: dict[str, LensConfig | None] = {
    "pinhole": None,  # the renderer's own camera: no distortion, principal point at the centre (the bundled sample)
    # A phone's main camera at 640x480 (video mode, ~69 deg across with the lens): barrel distortion (k1 < 0, the
    # image corners ~35 px inside where a pinhole puts them), a principal point 4.6 / 3.1 px off the centre, fx and fy
    # 0.1 % apart, and the small decentring (p1, p2) of a real lens assembly; sizes as phone calibrations report them.
    "phone": LensConfig("phone", fx=497.3, fy=497.8, cx=324.6, cy=236.9,
                        distortion=(-0.16, 0.07, 0.0009, -0.0006, 0.0)),
}


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


def resample_through_lens(image: np.ndarray, focal: float, rays: np.ndarray, supersample: int = 2) -> np.ndarray:
    """The image [H, W, 3] uint8 a lens takes of the scene that a centred pinhole of focal length ``focal`` (px)
    rendered as ``image`` [h, w, 3] uint8: each sample of ``rays`` [H*s, W*s, 2] (:func:`lens_rays` with
    ``supersample`` s) reads ``image`` bilinearly where its ray lands, and each pixel averages its s x s samples (a
    sensor pixel integrates its area)."""
    import cv2

    h, w = image.shape[:2]
    s = int(supersample)
    H, W = rays.shape[0] // s, rays.shape[1] // s
    map_x = (rays[..., 0] * focal + 0.5 * w - 0.5).astype(np.float32)  # cv2.remap: pixel centres at integers
    map_y = (rays[..., 1] * focal + 0.5 * h - 0.5).astype(np.float32)
    if map_x.min() < -0.5 or map_y.min() < -0.5 or map_x.max() > w - 0.5 or map_y.max() > h - 0.5:
        raise ValueError(f"the lens sees past the {w}x{h} pinhole render; render it wider (pinhole_cover)")
    samples = cv2.remap(image.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out = samples.reshape(H, s, W, s, -1).mean(axis=(1, 3))
    return np.clip(np.round(out), 0, 255).astype(np.uint8).reshape(H, W, *image.shape[2:])
