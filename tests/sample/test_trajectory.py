import numpy as np
import pytest

from mirage2matter.geometry.camera import look_at_pose
from mirage2matter.sample.trajectory import OrbitConfig, orbit_poses


def test_look_at_points_the_optical_axis_at_the_target():
    eye, target = np.array([1.0, -0.5, 0.7]), np.array([0.2, 0.1, 0.0])
    T = look_at_pose(eye, target)
    R = T[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    # the target projects to the principal point: its camera-frame x, y are 0 and z > 0
    p_cam = R.T @ (target - eye)
    assert abs(p_cam[0]) < 1e-12 and abs(p_cam[1]) < 1e-12 and p_cam[2] > 0
    # OpenCV: image y (down) has a negative world-z component when the world is z-up
    assert R[2, 1] < 0


def test_orbit_is_deterministic_and_hand_held():
    cfg = OrbitConfig(duration_s=6.0, fps=10.0)
    t, P = orbit_poses(cfg, seed=3)
    t2, P2 = orbit_poses(cfg, seed=3)
    assert np.array_equal(P, P2) and np.array_equal(t, t2)
    assert not np.allclose(P, orbit_poses(cfg, seed=4)[1])
    assert P.shape == (60, 4, 4) and np.allclose(np.diff(t), 0.1)
    centres = P[:, :3, 3]
    target = np.asarray(cfg.target)
    radius = np.linalg.norm(centres[:, :2] - target[:2], axis=1)
    height = centres[:, 2] - target[2]
    assert radius.min() >= cfg.radius[0] - 0.02 and radius.max() <= cfg.radius[1] + 0.02
    assert height.min() >= cfg.height[0] - 0.02 and height.max() <= cfg.height[1] + 0.02
    # it looks at the workspace all along (within the aim wander and shake)
    to_target = target - centres
    to_target /= np.linalg.norm(to_target, axis=1, keepdims=True)
    assert (to_target * P[:, :3, 2]).sum(1).min() > np.cos(np.radians(8))
    # the walk covers the configured sweep of azimuth
    az = np.unwrap(np.arctan2(centres[:, 1] - target[1], centres[:, 0] - target[0]))
    assert abs(np.degrees(az[-1] - az[0]) - cfg.sweep_deg) < 10
    # hand-held: not a perfect circle, yet smooth (no frame-to-frame jumps beyond the walking pace)
    assert radius.std() > 0.01 and height.std() > 0.01
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    assert steps.max() < 2.0 * steps.mean()


def test_bad_config_is_rejected():
    with pytest.raises(ValueError, match="radius"):
        orbit_poses(OrbitConfig(radius=(1.0, 0.5)))
    with pytest.raises(ValueError, match="fps"):
        orbit_poses(OrbitConfig(fps=0))
