import math

import numpy as np
import pytest
import torch

from mirage2matter.geometry.rotation import (
    axis_angle_to_matrix,
    matrix_to_quat,
    quat_conjugate,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
    random_quat,
    random_rotation,
    rotation_angle,
    rotvec_to_matrix,
)


def _edge_rotations() -> np.ndarray:
    """Identity, 180-degree turns about axes and diagonals, 90-degree turns, near-180 turns: [M, 3, 3]."""
    axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, 0, 1], [0, 1, 1], [1, 1, 1], [1, -1, 0.5]], float)
    mats = [np.eye(3)]
    for angle in (math.pi, math.pi / 2, -math.pi / 2, math.pi - 1e-7, 1e-9):
        mats.extend(axis_angle_to_matrix(axes, np.full(len(axes), angle)))
    # Signed permutation matrices with det +1 (180-degree turns in disguise).
    mats.append(np.diag([-1.0, -1.0, 1.0]))
    mats.append(np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]]))
    return np.stack(mats)


def _is_rotation(R: np.ndarray, tol: float = 1e-12) -> bool:
    eye = np.broadcast_to(np.eye(3), R.shape)
    return bool(np.allclose(np.swapaxes(R, -1, -2) @ R, eye, atol=tol) and np.allclose(np.linalg.det(R), 1.0))


def test_random_rotation_is_seeded_and_valid():
    a, b = random_rotation(50, seed=3), random_rotation(50, seed=3)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, random_rotation(50, seed=4))
    assert a.shape == (50, 3, 3) and _is_rotation(a)
    assert random_rotation(seed=0).shape == (3, 3)
    assert random_rotation((2, 5), seed=0).shape == (2, 5, 3, 3)


def test_random_rotation_is_roughly_uniform():
    # Haar measure: E[trace R] = 0 and E[R] = 0; a biased sampler (e.g. uniform Euler angles) fails this.
    R = random_rotation(20000, seed=0)
    assert abs(np.trace(R, axis1=-2, axis2=-1).mean()) < 0.05
    assert np.abs(R.mean(axis=0)).max() < 0.03


@pytest.mark.parametrize("source", ["random", "edge"])
def test_matrix_quat_round_trip(source):
    R = random_rotation(500, seed=1) if source == "random" else _edge_rotations()
    q = matrix_to_quat(R)
    assert q.shape == (*R.shape[:-2], 4)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
    assert (q[..., 0] >= 0).all()
    np.testing.assert_allclose(quat_to_matrix(q), R, atol=1e-12)


def test_quat_round_trip_matches_up_to_sign():
    q = random_quat(500, seed=2)
    q[:10, 0] = 0.0  # w = 0: 180-degree turns
    q = quat_normalize(q)
    back = matrix_to_quat(quat_to_matrix(q))
    # q and -q are the same rotation; with w >= 0 they agree except exactly at w = 0.
    dist = np.minimum(np.abs(back - q).max(-1), np.abs(back + q).max(-1))
    assert dist.max() < 1e-12
    np.testing.assert_allclose(back[10:], q[10:], atol=1e-12)


def test_quat_to_matrix_known_values():
    # 90 degrees about z maps x to y.
    q = np.array([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
    np.testing.assert_allclose(quat_to_matrix(q) @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-15)
    # Unnormalised input is normalised.
    np.testing.assert_allclose(quat_to_matrix(3 * q), quat_to_matrix(q), atol=1e-15)
    np.testing.assert_allclose(axis_angle_to_matrix(np.array([0, 0, 2.0]), math.pi / 2), quat_to_matrix(q), atol=1e-15)


def test_quat_multiply_composes_rotations():
    q1, q2 = random_quat(100, seed=5), random_quat(100, seed=6)
    np.testing.assert_allclose(
        quat_to_matrix(quat_multiply(q1, q2)), quat_to_matrix(q1) @ quat_to_matrix(q2), atol=1e-12
    )
    ident = quat_multiply(q1, quat_conjugate(q1))
    np.testing.assert_allclose(ident, np.broadcast_to([1.0, 0, 0, 0], ident.shape), atol=1e-12)
    # Not commutative: the order matters.
    assert not np.allclose(quat_multiply(q1, q2), quat_multiply(q2, q1))


def test_rotvec_and_axis_angle_agree():
    rv = np.random.default_rng(0).normal(size=(200, 3))
    angle = np.linalg.norm(rv, axis=-1)
    np.testing.assert_allclose(rotvec_to_matrix(rv), axis_angle_to_matrix(rv, angle), atol=1e-12)
    np.testing.assert_allclose(
        rotation_angle(rotvec_to_matrix(rv)),
        np.minimum(angle % (2 * np.pi), 2 * np.pi - angle % (2 * np.pi)),
        atol=1e-9,
    )
    np.testing.assert_allclose(rotvec_to_matrix(np.zeros(3)), np.eye(3), atol=0)


def test_rotvec_gradient_finite_at_zero():
    rv = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    R = rotvec_to_matrix(rv)
    R[0, 1].backward()
    assert torch.isfinite(rv.grad).all()
    # d R / d rv at 0 is the hat map: R[0, 1] = -rv_z to first order.
    torch.testing.assert_close(rv.grad, torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))


def test_torch_matches_numpy_and_keeps_dtype_device():
    R = random_rotation(20, seed=7)
    for dtype in (torch.float32, torch.float64):
        Rt = torch.as_tensor(R, dtype=dtype)
        q = matrix_to_quat(Rt)
        assert isinstance(q, torch.Tensor) and q.dtype == dtype
        np.testing.assert_allclose(q.numpy(), matrix_to_quat(R), atol=1e-6 if dtype == torch.float32 else 1e-12)
        assert quat_to_matrix(q).dtype == dtype
    # numpy float32 in -> numpy float32 out.
    assert matrix_to_quat(R.astype(np.float32)).dtype == np.float32


def test_matrix_to_quat_gradients_finite_at_edge_cases():
    R = torch.tensor(_edge_rotations(), requires_grad=True)
    matrix_to_quat(R).sum().backward()
    assert torch.isfinite(R.grad).all()
