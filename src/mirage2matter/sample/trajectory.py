"""A hand-held orbit around the table: the camera path of the sample video.

A person walks around the table holding a phone at chest height, pointing it roughly at the
workspace: the radius and height drift slowly, the aim wanders a little, and the hand adds small
shakes. Everything comes from one seeded generator, so a seed gives the same path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geometry.camera import look_at_pose


@dataclass(frozen=True)
class OrbitConfig:
    """Camera path of the sample video (robot-base frame, metres, degrees, seconds)."""

    duration_s: float = 24.0
    fps: float = 30.0
    target: tuple[float, float, float] = (0.35, 0.0, 0.0)  # workspace centre on the table top
    radius: tuple[float, float] = (0.95, 1.35)  # horizontal distance to the target, min..max
    height: tuple[float, float] = (0.35, 0.75)  # above the table top, min..max
    start_azimuth_deg: float = -160.0  # 0 = in front of the robot (+x), counter-clockwise seen from above
    sweep_deg: float = 320.0  # how far round the table the person walks
    aim_wander: float = 0.06  # metres the aim point drifts
    shake_translation: float = 0.006  # metres of hand shake
    shake_rotation_deg: float = 0.6

    def validate(self) -> None:
        if self.duration_s <= 0 or self.fps <= 0:
            raise ValueError(f"duration_s and fps must be positive, got {self.duration_s} s at {self.fps} fps")
        for name in ("radius", "height"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ValueError(f"{name} must be a range 0 < min <= max, got {lo}..{hi}")

    @property
    def n_frames(self) -> int:
        return int(round(self.duration_s * self.fps))


def _smooth_noise(rng: np.random.Generator, t: np.ndarray, n_waves: int, min_period: float, max_period: float):
    """A smooth random signal in about [-1, 1]: a few sines of random periods and phases. t [T] seconds."""
    periods = rng.uniform(min_period, max_period, n_waves)
    phases = rng.uniform(0, 2 * math.pi, n_waves)
    weights = rng.uniform(0.5, 1.0, n_waves)
    signal = (weights[:, None] * np.sin(2 * math.pi * t[None] / periods[:, None] + phases[:, None])).sum(0)
    return signal / weights.sum()


def _small_rotation(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rotation matrix of a small rotation vector (radians), exact via Rodrigues."""
    v = np.array([rx, ry, rz])
    angle = np.linalg.norm(v)
    if angle < 1e-12:
        return np.eye(3)
    k = v / angle
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * Kx + (1 - math.cos(angle)) * Kx @ Kx


def orbit_poses(config: OrbitConfig = OrbitConfig(), seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps [T] (s) and camera poses T_base_cam [T,4,4] (OpenCV axes) along the orbit."""
    config.validate()
    rng = np.random.default_rng(seed)
    n = config.n_frames
    t = np.arange(n) / config.fps
    # Walking speed varies a little; the azimuth still covers exactly the sweep.
    pace = np.cumsum(1.0 + 0.25 * _smooth_noise(rng, t, 3, 4.0, 10.0))
    pace = (pace - pace[0]) / (pace[-1] - pace[0])
    azimuth = np.radians(config.start_azimuth_deg + config.sweep_deg * pace)
    r_lo, r_hi = config.radius
    h_lo, h_hi = config.height
    radius = r_lo + (r_hi - r_lo) * 0.5 * (1 + _smooth_noise(rng, t, 3, 6.0, 14.0))
    height = h_lo + (h_hi - h_lo) * 0.5 * (1 + _smooth_noise(rng, t, 3, 5.0, 12.0))
    target = np.asarray(config.target, float)
    eyes = np.stack(
        [target[0] + radius * np.cos(azimuth), target[1] + radius * np.sin(azimuth), target[2] + height], -1
    )
    aims = target[None] + config.aim_wander * np.stack([_smooth_noise(rng, t, 3, 3.0, 8.0) for _ in range(3)], -1)
    # Hand shake: faster, smaller; translation and rotation.
    shake_t = config.shake_translation * np.stack([_smooth_noise(rng, t, 4, 0.4, 1.5) for _ in range(3)], -1)
    shake_r = np.radians(config.shake_rotation_deg) * np.stack(
        [_smooth_noise(rng, t, 4, 0.3, 1.2) for _ in range(3)], -1
    )
    poses = np.empty((n, 4, 4))
    for i in range(n):
        T = look_at_pose(eyes[i] + shake_t[i], aims[i])
        T[:3, :3] = T[:3, :3] @ _small_rotation(*shake_r[i])
        poses[i] = T
    return t, poses
