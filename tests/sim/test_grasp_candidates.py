"""Top-down grasp candidates on a surface sample (numpy only, no Genesis)."""

import math

import numpy as np

from mirage2matter.sim.tasks.grasp import grasp_candidates, yaw_choices

_GRIPPER = dict(max_width=0.072, pad_half_width=0.012, min_height=0.012)


def _banana(n: int = 4000, seed: int = 0) -> np.ndarray:
    """[N,3] surface sample of a banana-like curved tube: an arc of radius 0.12 m over 80 deg, 1.6 cm thick, lying
    on the table (z = 0)."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(-0.7, 0.7, n)  # along the arc (rad)
    phi = rng.uniform(0.0, 2.0 * math.pi, n)  # around the tube
    r_tube = 0.016
    rho = 0.12 + r_tube * np.cos(phi)
    return np.stack([rho * np.cos(t) - 0.12, rho * np.sin(t), r_tube + r_tube * np.sin(phi)], axis=1)


def _turned(points: np.ndarray, theta: float, at: np.ndarray) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return points @ R.T + at


def test_a_turned_object_gets_the_same_grasp_in_its_own_frame():
    """With ``yaw0`` = the object's heading, the best grasp turns with the object (the same place on it, the same
    closing axis relative to it) whatever the heading; on the fixed world grid it jumped from heading to heading."""
    pts = _banana()
    at = np.array([0.45, -0.1, 0.0])
    ref = None
    for deg in (0.0, 7.0, 23.0, 64.0, 118.0, 151.0, -97.0):
        theta = math.radians(deg)
        placed = _turned(pts, theta, at)
        com = placed.mean(axis=0)
        best = grasp_candidates(placed, com, **_GRIPPER, yaw0=theta)[0]
        _, tcp, yaw = best
        c, s = math.cos(-theta), math.sin(-theta)
        local_xy = np.array([[c, -s], [s, c]]) @ (tcp[:2] - at[:2])
        local_yaw = (yaw - theta) % math.pi
        if ref is None:
            ref = (local_xy, local_yaw, tcp[2])
            continue
        assert np.linalg.norm(local_xy - ref[0]) < 0.003, deg
        assert min(abs(local_yaw - ref[1]), math.pi - abs(local_yaw - ref[1])) < math.radians(1.0), deg
        assert abs(tcp[2] - ref[2]) < 0.003


def test_yaw_choices_are_the_two_hand_yaws_nearest_home_first():
    a, b = yaw_choices(math.radians(-30.0), math.radians(275.0))
    assert math.isclose(math.degrees(a), 330.0) and math.isclose(math.degrees(b), 150.0)
    assert all(0.0 <= w < 2.0 * math.pi for w in yaw_choices(7.5, 0.0))
