"""What a keyframe would show without the objects: the support plane seen from the other keyframes.

A point of the table plane seen at pixel p of keyframe i is seen by keyframe j where the plane's
homography H_j H_i^-1 sends p. The median over the other keyframes of those warped pixels is the
bare table at p: an object hides a given table point from only some of the keyframes (those
looking at it across the object). Right next to an object's foot most keyframes are hidden and a
plain median shows the object itself, so a pixel of the object's lower edge looks like its own
background and the matting drops it; given the object's proxy (``hidden``: where it covers each
keyframe), the keyframes that look through it do not vote. Shadows lie on the plane and are
background too.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geometry.camera import Camera, opencv_K
from .support import Plane

__all__ = ["Roi", "plane_homography", "table_background"]

Roi = tuple[int, int, int, int]  # x0, y0, x1, y1 (pixels, x1/y1 exclusive)


def _plane_basis(plane: Plane) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = plane.normal
    e1 = np.cross(n, [0.0, 1.0, 0.0]) if abs(n[1]) < 0.9 else np.cross(n, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    return -plane.offset * n, e1, e2


def plane_homography(camera: Camera, plane: Plane) -> np.ndarray:
    """H [3,3]: plane coordinates (a, b, 1) -> OpenCV pixel coordinates (centres at integers)."""
    origin, e1, e2 = _plane_basis(plane)
    V = camera.viewmat
    M = np.c_[V[:3, :3] @ e1, V[:3, :3] @ e2, V[:3, :3] @ origin + V[:3, 3]]
    return opencv_K(camera.K) @ M


def table_background(
    i: int,
    cameras: Sequence[Camera],
    images: Sequence[np.ndarray],
    roi: Roi,
    plane: Plane,
    min_views: int = 3,
    hidden: Sequence[np.ndarray | None] | None = None,
) -> np.ndarray:
    """Background [h,w,3] float32 (NaN where fewer than ``min_views`` keyframes see the table point)
    of keyframe ``i`` inside ``roi``, from the other keyframes' ``images`` [H,W,3] float32 in [0,1]
    warped through the support plane. ``hidden`` [H,W] bool per keyframe (None: nothing hidden) marks
    where an object may stand between that keyframe and the table: those pixels vote only for table
    points that fewer than ``min_views`` keyframes see unhidden (under the object's foot)."""
    import cv2

    x0, y0, x1, y1 = roi
    w, h = x1 - x0, y1 - y0
    H_i = plane_homography(cameras[i], plane)
    to_roi = np.array([[1.0, 0, x0], [0, 1.0, y0], [0, 0, 1.0]])
    nan3 = (float("nan"),) * 3
    warped, covered = [], []
    for j, cam_j in enumerate(cameras):
        if j == i:
            continue
        H = plane_homography(cam_j, plane) @ np.linalg.inv(H_i) @ to_roi  # roi pixel -> pixel of j
        inverse = cv2.WARP_INVERSE_MAP
        warped.append(cv2.warpPerspective(images[j], H, (w, h), flags=cv2.INTER_LINEAR | inverse, borderValue=nan3))
        hid = None if hidden is None else hidden[j]
        if hid is None:
            covered.append(np.zeros((h, w), bool))
        else:
            hid_u8 = np.ascontiguousarray(hid, np.uint8)
            covered.append(cv2.warpPerspective(hid_u8, H, (w, h), flags=cv2.INTER_NEAREST | inverse, borderValue=0) > 0)
    stack = np.stack(warped)  # [V,h,w,3]
    clear = np.where(np.stack(covered)[..., None], np.nan, stack)
    out = np.full((h, w, 3), np.nan, np.float32)
    ok_clear = np.isfinite(clear[..., 0]).sum(0) >= min_views
    if ok_clear.any():
        out[ok_clear] = _nanmedian_first_axis(clear[:, ok_clear])
    under = ~ok_clear & (np.isfinite(stack[..., 0]).sum(0) >= min_views)  # hidden from (nearly) all
    if under.any():
        out[under] = _nanmedian_first_axis(stack[:, under])
    return out


def _nanmedian_first_axis(x: np.ndarray) -> np.ndarray:
    """``np.nanmedian(x, axis=0)`` (NaN where a column has no number) without its masked-array path, which took
    ~70 % of the matting's background time: sort (NaNs go last) and average the middle two of the numbers."""
    s = np.sort(x, axis=0)
    n = np.isfinite(s).sum(0)
    lo = np.take_along_axis(s, np.maximum((n - 1) // 2, 0)[None], 0)[0]
    hi = np.take_along_axis(s, (n // 2)[None], 0)[0]
    return np.where(n > 0, (lo + hi) / 2, np.nan).astype(x.dtype, copy=False)
