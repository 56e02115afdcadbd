"""Shared helpers of the renderer tests: image agreement and simple pinhole cameras."""

from __future__ import annotations

import math

import numpy as np
import torch


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR in dB of two images in [0, 1] (any device/dtype)."""
    mse = torch.mean((a.detach().double().cpu() - b.detach().double().cpu()) ** 2).item()
    return 10.0 * math.log10(1.0 / max(mse, 1e-30))


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World-to-camera [4,4] (OpenCV axes: x right, y down, z forward)."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])  # rows: camera axes in world coordinates
    V = np.eye(4)
    V[:3, :3], V[:3, 3] = R, -R @ eye
    return V


def intrinsics(
    width: int, height: int, fov_deg: float = 60.0, offset: tuple[float, float] = (0.0, 0.0), aspect: float = 1.0
) -> np.ndarray:
    """K [3,3] for a horizontal field of view; ``offset`` moves the principal point off the centre
    and ``aspect`` = fy / fx, so tests can exercise non-trivial intrinsics."""
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    cx, cy = width / 2 + offset[0], height / 2 + offset[1]
    return np.array([[f, 0.0, cx], [0.0, aspect * f, cy], [0.0, 0.0, 1.0]])
