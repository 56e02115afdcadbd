"""Hybrid frames (paper section 3.3, eq. ``composite``): the robot rendered by the simulator over the
Gaussian-splat render of the world, made depth-aware.

The paper's compositing is ``I = M * I_robot + (1 - M) * I_splat`` with M the robot's mask. That
pastes the robot over everything, including an object that is between the camera and the gripper.
Here the robot shows only where it is nearer than the splat surface:

    M' = M  and  (d_robot < d_splat + margin  or  splat alpha < alpha_min)

``d_splat`` is the splat's expected depth, trusted where its accumulated alpha is at least
``alpha_min`` (elsewhere there is no splat surface); ``margin`` favours the robot where the two
touch (fingers on an object) so that contact does not flicker. Everything here takes arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def robot_visible(
    robot_mask: np.ndarray,
    robot_depth: np.ndarray,
    splat_depth: np.ndarray,
    splat_alpha: np.ndarray,
    margin: float = 0.005,
    alpha_min: float = 0.5,
) -> np.ndarray:
    """bool [H,W]: robot pixels not hidden by a nearer splat surface (all depths camera-z metres)."""
    splat_z = np.where(splat_alpha >= alpha_min, splat_depth, np.inf)
    return robot_mask & (robot_depth < splat_z + margin)


def composite(
    splat_rgb: np.ndarray,
    robot_rgb: np.ndarray,
    robot_mask: np.ndarray,
    robot_depth: np.ndarray | None = None,
    splat_depth: np.ndarray | None = None,
    splat_alpha: np.ndarray | None = None,
    margin: float = 0.005,
    alpha_min: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Hybrid frame and the robot pixels shown in it.

    splat_rgb [H,W,3], robot_rgb [H,W,3]: uint8, or float in [0, 1] (the output takes splat_rgb's type)
    robot_mask [H,W] bool; robot_depth [H,W] camera-z m (inf where no geometry)
    splat_depth [H,W] expected camera-z depth; splat_alpha [H,W] accumulated opacity in [0, 1]

    Without the depths this is the paper's baseline: the robot mask pasted over the splat render.
    Returns (rgb [H,W,3], visible [H,W] bool).
    """
    if splat_rgb.shape != robot_rgb.shape or splat_rgb.shape[:2] != robot_mask.shape:
        raise ValueError(
            f"composite: image sizes differ (splat {splat_rgb.shape}, robot {robot_rgb.shape}, mask {robot_mask.shape})"
        )
    mask = robot_mask.astype(bool)
    if robot_depth is not None and splat_depth is not None:
        alpha = np.ones(mask.shape, np.float32) if splat_alpha is None else splat_alpha
        mask = robot_visible(mask, robot_depth, splat_depth, alpha, margin, alpha_min)
    out = splat_rgb.copy()
    robot = robot_rgb if robot_rgb.dtype == splat_rgb.dtype else _like(robot_rgb, splat_rgb.dtype)
    out[mask] = robot[mask]
    return out, mask


def _like(im: np.ndarray, dtype: np.dtype) -> np.ndarray:
    if np.dtype(dtype) == np.uint8:
        return np.clip(np.rint(im * 255.0), 0, 255).astype(np.uint8)
    return im.astype(dtype) / 255.0


@dataclass(frozen=True)
class ColorJitter:
    """A global light / colour change of the splat render: ``rgb' = gain * (contrast * (rgb - 0.5) + 0.5)
    + brightness`` per channel (gain [3] models the light's colour, brightness its strength)."""

    brightness: float = 0.0
    contrast: float = 1.0
    gain: tuple[float, float, float] = (1.0, 1.0, 1.0)

    @classmethod
    def sample(cls, rng: np.random.Generator, brightness: float = 0.08, contrast: float = 0.1, gain: float = 0.06):
        """Uniform jitter of the given half-ranges (0 = no jitter)."""
        return cls(
            brightness=float(rng.uniform(-brightness, brightness)),
            contrast=float(1.0 + rng.uniform(-contrast, contrast)),
            gain=tuple(float(g) for g in 1.0 + rng.uniform(-gain, gain, 3)),
        )

    @property
    def is_identity(self) -> bool:
        return self.brightness == 0.0 and self.contrast == 1.0 and self.gain == (1.0, 1.0, 1.0)

    def apply(self, rgb: np.ndarray) -> np.ndarray:
        """rgb float [H,W,3] in [0, 1] -> jittered float32, clipped to [0, 1]."""
        if self.is_identity:
            return rgb
        g = np.asarray(self.gain, np.float32)
        out = g * (self.contrast * (rgb.astype(np.float32) - 0.5) + 0.5) + self.brightness
        return np.clip(out, 0.0, 1.0)

    def to_json(self) -> dict:
        return {"brightness": self.brightness, "contrast": self.contrast, "gain": list(self.gain)}


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """float [H,W,3] in [0, 1] -> uint8."""
    return np.clip(np.rint(np.asarray(rgb, np.float32) * 255.0), 0, 255).astype(np.uint8)
