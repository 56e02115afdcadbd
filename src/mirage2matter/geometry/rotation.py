"""Rotation helpers: unit quaternions (wxyz) <-> matrices, products, axis-angle, random rotations.

Every function accepts torch tensors (any float dtype / device, autograd-friendly) or numpy arrays
(computed in float64 through torch and handed back as numpy in the input's float dtype).
Shapes are batched: leading ``...`` dimensions broadcast.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import wraps
from typing import TypeVar

import numpy as np
import torch

Array = TypeVar("Array", torch.Tensor, np.ndarray)

__all__ = [
    "axis_angle_to_matrix",
    "matrix_to_quat",
    "quat_conjugate",
    "quat_multiply",
    "quat_normalize",
    "quat_to_matrix",
    "random_quat",
    "random_rotation",
    "rotation_angle",
    "rotvec_to_matrix",
]


def _numpy_compatible(fn: Callable[..., torch.Tensor]) -> Callable:
    """Let a torch implementation take numpy arrays: run it in float64, return numpy in the input's dtype."""

    @wraps(fn)
    def wrapper(*args, **kwargs):
        arrays = [a for a in (*args, *kwargs.values()) if isinstance(a, np.ndarray)]
        if not arrays:
            return fn(*args, **kwargs)
        out_dtype = np.result_type(*(a.dtype for a in arrays), np.float32)  # ints -> float

        def conv(a):
            if isinstance(a, np.ndarray):
                # np.array copies: from_numpy warns on read-only arrays (e.g. Sim3's) and must not alias them.
                return torch.from_numpy(np.array(a, dtype=np.float64))
            return torch.tensor(a, dtype=torch.float64) if isinstance(a, int | float) else a

        out = fn(*map(conv, args), **{k: conv(v) for k, v in kwargs.items()})
        return out.numpy().astype(out_dtype, copy=False)

    return wrapper


@_numpy_compatible
def quat_normalize(q: Array, eps: float = 1e-12) -> Array:
    """Scale quaternions to unit norm. q [..., 4] -> [..., 4]."""
    return q / q.norm(dim=-1, keepdim=True).clamp_min(eps)


@_numpy_compatible
def quat_conjugate(q: Array) -> Array:
    """Conjugate (the inverse for unit quaternions). q [..., 4] wxyz -> [..., 4]."""
    return q * q.new_tensor([1.0, -1.0, -1.0, -1.0])


@_numpy_compatible
def quat_multiply(a: Array, b: Array) -> Array:
    """Hamilton product a * b (rotate by b, then by a). a, b [..., 4] wxyz -> [..., 4]."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


@_numpy_compatible
def quat_to_matrix(q: Array) -> Array:
    """Rotation matrices from quaternions (normalised here). q [..., 4] wxyz -> R [..., 3, 3]."""
    w, x, y, z = quat_normalize(q).unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = [
        1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
        2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
        2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
    ]  # fmt: skip
    return torch.stack(rows, dim=-1).reshape(*q.shape[:-1], 3, 3)


@_numpy_compatible
def matrix_to_quat(R: Array) -> Array:
    """Unit quaternions from rotation matrices, w >= 0. R [..., 3, 3] -> q [..., 4] wxyz.

    Shepperd's method: of the four algebraically equal formulas, use the one whose square root
    is largest, so no division by a near-zero number (exact for 180-degree turns too).
    """
    m00, m01, m02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    m10, m11, m12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    m20, m21, m22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    # 4 * (w^2, x^2, y^2, z^2)
    sq = torch.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], dim=-1)
    # Candidate i is 4*q_i times the quaternion; clamping keeps unused branches finite (and their grads).
    root = sq.clamp_min(1e-12).sqrt()  # 2 |q_i|
    cands = torch.stack(
        [
            torch.stack([sq[..., 0], m21 - m12, m02 - m20, m10 - m01], dim=-1),
            torch.stack([m21 - m12, sq[..., 1], m01 + m10, m02 + m20], dim=-1),
            torch.stack([m02 - m20, m01 + m10, sq[..., 2], m12 + m21], dim=-1),
            torch.stack([m10 - m01, m02 + m20, m12 + m21, sq[..., 3]], dim=-1),
        ],
        dim=-2,
    ) / (2 * root[..., :, None])  # [..., 4 candidates, 4]
    best = sq.argmax(dim=-1)
    q = torch.take_along_dim(cands, best[..., None, None].expand(*best.shape, 1, 4), dim=-2).squeeze(-2)
    q = quat_normalize(q)
    return torch.where(q[..., :1] < 0, -q, q)


@_numpy_compatible
def axis_angle_to_matrix(axis: Array, angle: Array | float) -> Array:
    """Rodrigues. axis [..., 3] (normalised here), angle [...] radians (right-hand rule) -> R [..., 3, 3]."""
    axis = axis / axis.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    angle = torch.as_tensor(angle, dtype=axis.dtype, device=axis.device)
    half, axis = torch.broadcast_tensors(0.5 * angle[..., None], axis)
    q = torch.cat([torch.cos(half[..., :1]), torch.sin(half) * axis], dim=-1)
    return quat_to_matrix(q)


@_numpy_compatible
def rotvec_to_matrix(rotvec: Array) -> Array:
    """Rotation vector (axis * angle) -> R. rotvec [..., 3] -> [..., 3, 3]; exact and smooth near zero."""
    angle = rotvec.norm(dim=-1, keepdim=True)
    half = 0.5 * angle
    # sin(a/2)/a, with its Taylor series where a is tiny so the gradient stays finite at 0.
    small = angle < 1e-4
    safe = torch.where(small, torch.ones_like(angle), angle)
    sinc_half = torch.where(small, 0.5 - angle * angle / 48.0, torch.sin(half) / safe)
    return quat_to_matrix(torch.cat([torch.cos(half), sinc_half * rotvec], dim=-1))


def _rng(seed: int | np.random.Generator | None) -> np.random.Generator:
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def random_quat(size: int | tuple[int, ...] | None = None, seed: int | np.random.Generator | None = None) -> np.ndarray:
    """Uniformly distributed unit quaternions (wxyz, w >= 0), float64. size None -> [4], else [*size, 4]."""
    shape = () if size is None else (size,) if isinstance(size, int) else tuple(size)
    q = _rng(seed).standard_normal((*shape, 4))  # isotropic Gaussian -> uniform on S^3
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def random_rotation(
    size: int | tuple[int, ...] | None = None, seed: int | np.random.Generator | None = None
) -> np.ndarray:
    """Uniformly distributed (Haar) rotation matrices, float64. size None -> [3, 3], else [*size, 3, 3]."""
    return quat_to_matrix(random_quat(size, seed))


def rotation_angle(R: Array) -> Array:
    """Rotation angle in [0, pi] of R [..., 3, 3] -> [...] (via the quaternion, accurate near 0 and pi)."""
    q = matrix_to_quat(R)
    if isinstance(q, np.ndarray):
        return 2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))
    return 2.0 * torch.atan2(q[..., 1:].norm(dim=-1), q[..., 0].abs())
