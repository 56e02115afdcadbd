import numpy as np
import pytest

from mirage2matter.geometry.icp import scaled_icp
from mirage2matter.geometry.rotation import axis_angle_to_matrix
from mirage2matter.geometry.sim3 import Sim3


def _scene(rng: np.random.Generator, n: int = 3000) -> np.ndarray:
    """An asymmetric set of surfaces: a table top, a box and a cylinder (no symmetry to slide along)."""
    table = np.c_[rng.uniform(-0.6, 0.8, n), rng.uniform(-0.4, 0.5, n), np.zeros(n)]
    box = rng.uniform([0.2, 0.1, 0.0], [0.35, 0.3, 0.12], (n // 3, 3))
    box[:, 2] = np.where(rng.random(n // 3) < 0.5, 0.12, box[:, 2])  # top face + a volume of side points
    theta, h = rng.uniform(0, 2 * np.pi, n // 3), rng.uniform(0, 0.2, n // 3)
    cyl = np.c_[-0.3 + 0.05 * np.cos(theta), -0.2 + 0.05 * np.sin(theta), h]
    return np.concatenate([table, box, cyl])


def test_recovers_a_similarity_from_a_20_percent_10_degree_start():
    rng = np.random.default_rng(0)
    target = _scene(rng)
    truth = Sim3(1.37, axis_angle_to_matrix(np.array([0.3, -0.5, 0.8]), 0.9), np.array([0.4, -1.1, 0.25]))
    # the same surface samples with 1 mm noise (point-to-point ICP cannot pin scale on a resampled plane)
    source = truth.inverse().apply(target + rng.normal(0, 0.001, target.shape))
    error = Sim3(1.2, axis_angle_to_matrix(np.array([1.0, 1.0, 0.0]), np.radians(10)), np.array([0.03, -0.02, 0.02]))
    init = error @ truth  # 20% scale and 10 degrees off, a few cm out
    result = scaled_icp(source, target, init=init)
    assert abs(result.sim3.scale / truth.scale - 1) < 5e-4
    dR = result.sim3.rotation.T @ truth.rotation
    assert np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))) < 0.05
    assert np.linalg.norm(result.sim3.translation - truth.translation) < 1e-3
    # and the start really was wrong (the test can fail)
    assert abs(init.scale / truth.scale - 1) > 0.15


def test_anchors_pin_a_plane_that_alone_would_slide():
    rng = np.random.default_rng(1)
    plane = np.c_[rng.uniform(-1, 1, (4000, 2)), np.zeros(4000)]
    truth = Sim3(1.0, np.eye(3), np.array([0.05, -0.04, 0.0]))
    source = truth.inverse().apply(plane)
    corners = np.array([[0.1, 0.1, 0.0], [0.4, 0.1, 0.0], [0.1, 0.5, 0.0], [0.3, 0.3, 0.0]])
    anchors = (truth.inverse().apply(corners), corners)
    result = scaled_icp(source, plane, anchors=anchors, with_scale=False)
    assert np.linalg.norm(result.sim3.translation - truth.translation) < 1e-3


def test_bad_input():
    with pytest.raises(ValueError, match="source"):
        scaled_icp(np.zeros((2, 3)), np.zeros((5, 3)))
