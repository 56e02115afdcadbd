import math

import numpy as np
import pytest
import torch

from mirage2matter.geometry.rotation import axis_angle_to_matrix, random_rotation, rotation_angle
from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.geometry.umeyama import umeyama

TRUE = Sim3(1.23, axis_angle_to_matrix(np.array([0.3, -0.5, 0.8]), math.radians(37.0)), [0.4, -1.1, 2.5])


def _points(n: int = 40, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.0, 1.0, size=(n, 3))


def _rot_err_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(float(rotation_angle(a.T @ b)))


def test_recovers_exact_similarity():
    src = _points()
    est = umeyama(src, TRUE.apply(src))
    assert est.allclose(TRUE, atol=1e-10)
    assert abs(est.scale - 1.23) < 1e-12


def test_recovers_many_random_similarities_including_large_rotations():
    rng = np.random.default_rng(1)
    for i in range(20):
        true = Sim3(float(rng.uniform(0.2, 5.0)), random_rotation(seed=rng), rng.normal(size=3) * 3)
        src = _points(10, seed=i)
        assert umeyama(src, true.apply(src)).allclose(true, atol=1e-9)


def test_noisy_fit_is_close_but_not_exact():
    src = _points(200, seed=2)
    dst = TRUE.apply(src) + np.random.default_rng(3).normal(scale=0.01, size=src.shape)
    est = umeyama(src, dst)
    assert 0 < abs(est.scale - TRUE.scale) < 0.01
    assert 0 < _rot_err_deg(est.rotation, TRUE.rotation) < 0.5
    assert 0 < np.linalg.norm(est.translation - TRUE.translation) < 0.01
    # It is the least-squares optimum: the true transform does no better on the noisy data.
    resid = lambda s: np.sum((s.apply(src) - dst) ** 2)
    assert resid(est) <= resid(TRUE)


def test_rigid_mode_fixes_scale():
    src = _points()
    rigid = Sim3.rigid(TRUE.rotation, TRUE.translation)
    est = umeyama(src, rigid.apply(src), with_scale=False)
    assert est.scale == 1.0 and est.allclose(rigid, atol=1e-10)
    # With scaled data, rigid mode still returns scale 1 but the best rotation.
    est2 = umeyama(src, TRUE.apply(src), with_scale=False)
    assert est2.scale == 1.0
    assert _rot_err_deg(est2.rotation, TRUE.rotation) < 1e-6


def test_reflection_is_not_returned():
    # dst is a mirror image of src: the best orthogonal map is a reflection; we must return a rotation.
    src = _points(30, seed=4)
    dst = src * np.array([1.0, 1.0, -1.0])
    est = umeyama(src, dst)
    assert np.linalg.det(est.rotation) > 0.999


def test_coplanar_points_work():
    src = _points(20, seed=5)
    src[:, 2] = 0.0
    assert umeyama(src, TRUE.apply(src)).allclose(TRUE, atol=1e-9)
    assert umeyama(src[:3], TRUE.apply(src[:3])).allclose(TRUE, atol=1e-9)  # the minimum: 3 points


def test_weights_ignore_outliers():
    src = _points(30, seed=6)
    dst = TRUE.apply(src)
    dst[:5] += 10.0  # gross outliers
    w = np.ones(30)
    w[:5] = 0.0
    assert umeyama(src, dst, weights=w).allclose(TRUE, atol=1e-9)
    assert not umeyama(src, dst).allclose(TRUE, atol=1e-2)
    # Uniform weights of any magnitude equal no weights.
    assert umeyama(src, dst, weights=np.full(30, 7.0)).allclose(umeyama(src, dst), atol=1e-12)


def test_accepts_torch_input():
    src = _points()
    est = umeyama(torch.tensor(src, dtype=torch.float32), torch.tensor(TRUE.apply(src), dtype=torch.float32))
    assert est.allclose(TRUE, atol=1e-4)


@pytest.mark.parametrize(
    ("src", "dst", "kwargs", "match"),
    [
        (np.zeros((2, 3)), np.zeros((2, 3)), {}, "at least 3"),
        (np.zeros((5, 3)), np.zeros((4, 3)), {}, r"\[N, 3\]"),
        (np.zeros((5, 2)), np.zeros((5, 2)), {}, r"\[N, 3\]"),
        (np.zeros((5, 3)), np.zeros((5, 3)), {}, "coincide"),
        (np.outer(np.arange(6.0), [1.0, 2.0, 3.0]), np.outer(np.arange(6.0), [3.0, 1.0, 0.0]), {}, "degenerate"),
        (np.eye(3) * [1, 2, 3], np.eye(3), {"weights": np.ones(2)}, "weights"),
        (np.eye(3) * [1, 2, 3], np.eye(3), {"weights": -np.ones(3)}, "non-negative"),
        (np.eye(3) * [1, 2, 3], np.eye(3), {"weights": np.array([1.0, 1.0, 0.0])}, "at least 3"),
        (np.full((4, 3), np.nan), np.zeros((4, 3)), {}, "NaN"),
    ],
)
def test_rejects_bad_input(src, dst, kwargs, match):
    with pytest.raises(ValueError, match=match):
        umeyama(src, dst, **kwargs)


def test_rejects_collinear_src_even_with_spread_dst():
    src = np.outer(np.linspace(-1, 1, 10), [1.0, 1.0, 0.0])
    dst = _points(10, seed=7)
    with pytest.raises(ValueError, match="degenerate"):
        umeyama(src, dst)
    src_noisy = src + np.random.default_rng(8).normal(scale=1e-15, size=src.shape)
    with pytest.raises(ValueError, match="degenerate"):
        umeyama(src_noisy, dst)
