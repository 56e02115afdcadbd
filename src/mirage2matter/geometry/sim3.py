"""Similarity transforms ``x' = s R x + t`` (DESIGN.md section 1). Rigid transforms are Sim3 with s = 1."""

from __future__ import annotations

import json
import math
import os
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import torch

Array = TypeVar("Array", torch.Tensor, np.ndarray)

ORTHONORMAL_TOL = 1e-6


def _frozen(a: Any, shape: tuple[int, ...], name: str) -> np.ndarray:
    if isinstance(a, torch.Tensor):
        a = a.detach().cpu().numpy()
    arr = np.array(a, dtype=np.float64)  # always a private copy
    if arr.shape != shape:
        raise ValueError(f"Sim3.{name} must have shape {shape}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"Sim3.{name} has NaN/Inf entries: {arr.tolist()}")
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False)
class Sim3:
    """Similarity transform acting on points as ``x' = scale * rotation @ x + translation``.

    scale        float > 0
    rotation     [3, 3] float64, orthonormal with det +1
    translation  [3]    float64

    ``a @ b`` applies ``b`` first, then ``a``. Arrays are stored read-only (the class is immutable).
    """

    scale: float
    rotation: np.ndarray
    translation: np.ndarray

    def __post_init__(self) -> None:
        s = float(self.scale)
        if not (math.isfinite(s) and s > 0):
            raise ValueError(f"Sim3.scale must be finite and > 0, got {self.scale!r}")
        R = _frozen(self.rotation, (3, 3), "rotation")
        t = _frozen(self.translation, (3,), "translation")
        ortho_err = float(np.abs(R.T @ R - np.eye(3)).max())
        if ortho_err > ORTHONORMAL_TOL:
            raise ValueError(
                f"Sim3.rotation is not orthonormal: max |R^T R - I| = {ortho_err:.3g} > {ORTHONORMAL_TOL:g} "
                "(a scaled or sheared matrix? put the scale in Sim3.scale)"
            )
        det = float(np.linalg.det(R))
        if abs(det - 1.0) > ORTHONORMAL_TOL:
            raise ValueError(f"Sim3.rotation must have det +1, got {det:.6g} (a reflection is not a rotation)")
        object.__setattr__(self, "scale", s)
        object.__setattr__(self, "rotation", R)
        object.__setattr__(self, "translation", t)

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def identity(cls) -> Sim3:
        return cls(1.0, np.eye(3), np.zeros(3))

    @classmethod
    def rigid(cls, rotation: Any, translation: Any) -> Sim3:
        """Rigid transform (scale 1). rotation [3, 3], translation [3]."""
        return cls(1.0, rotation, translation)

    @classmethod
    def from_matrix(cls, M: Any) -> Sim3:
        """From a 4x4 matrix [[sR, t], [0, 0, 0, 1]] (numpy, torch or nested lists)."""
        M = M.detach().cpu().numpy() if isinstance(M, torch.Tensor) else np.asarray(M, dtype=np.float64)
        if M.shape != (4, 4):
            raise ValueError(f"Sim3.from_matrix needs a 4x4 matrix, got shape {M.shape}")
        if np.abs(M[3] - [0.0, 0.0, 0.0, 1.0]).max() > ORTHONORMAL_TOL:
            raise ValueError(f"Sim3.from_matrix: last row must be [0, 0, 0, 1], got {M[3].tolist()}")
        sR = M[:3, :3].astype(np.float64)
        s = float(np.sqrt(np.sum(sR * sR) / 3.0))  # every column of sR has norm s
        if not s > 0:
            raise ValueError("Sim3.from_matrix: the 3x3 block is zero, scale would be 0")
        return cls(s, sR / s, M[:3, 3])

    # ---- algebra ------------------------------------------------------------------------
    @property
    def matrix(self) -> np.ndarray:
        """Homogeneous [4, 4] float64 matrix with sR top-left and t in the last column."""
        M = np.eye(4)
        M[:3, :3] = self.scale * self.rotation
        M[:3, 3] = self.translation
        return M

    @property
    def is_rigid(self) -> bool:
        return abs(self.scale - 1.0) <= 1e-12

    def __matmul__(self, other: Sim3) -> Sim3:
        """Composition: ``(a @ b).apply(x) == a.apply(b.apply(x))``."""
        if not isinstance(other, Sim3):
            return NotImplemented
        return Sim3(
            self.scale * other.scale,
            self.rotation @ other.rotation,
            self.scale * self.rotation @ other.translation + self.translation,
        )

    def inverse(self) -> Sim3:
        """``x = (1/s) R^T (x' - t)``."""
        Rt = self.rotation.T
        return Sim3(1.0 / self.scale, Rt, -(Rt @ self.translation) / self.scale)

    def allclose(self, other: Sim3, atol: float = 1e-9) -> bool:
        return bool(np.allclose(self.matrix, other.matrix, rtol=0.0, atol=atol))

    # ---- acting on things ---------------------------------------------------------------
    def apply(self, points: Array) -> Array:
        """Transform points. [..., 3] numpy or torch -> same type, dtype (floats) and device; autograd passes."""
        if isinstance(points, torch.Tensor):
            dtype = points.dtype if points.is_floating_point() else torch.get_default_dtype()
            sR = torch.tensor(self.scale * self.rotation, dtype=dtype, device=points.device)
            t = torch.tensor(self.translation, dtype=dtype, device=points.device)
            return points.to(dtype) @ sR.T + t
        pts = np.asarray(points)
        dtype = pts.dtype if np.issubdtype(pts.dtype, np.floating) else np.float64
        out = pts.astype(np.float64, copy=False) @ (self.scale * self.rotation).T + self.translation
        return out.astype(dtype, copy=False)

    def apply_rotation(self, R: Array) -> Array:
        """Rotate orientations: ``R' = self.rotation @ R``. R [..., 3, 3] numpy or torch -> same type/dtype/device."""
        if isinstance(R, torch.Tensor):
            return torch.tensor(self.rotation, dtype=R.dtype, device=R.device) @ R
        R = np.asarray(R)
        return (self.rotation @ R.astype(np.float64, copy=False)).astype(R.dtype, copy=False)

    def apply_pose(self, T: Array) -> Array:
        """Move a rigid pose (e.g. ``T_world_cam``): ``R' = R R_wc``, ``t' = s R t_wc + t``.

        T [..., 4, 4] numpy or torch -> same type/dtype/device. The result stays rigid: a camera
        keeps its intrinsics, only its position is scaled with the scene.
        """
        out = T.clone() if isinstance(T, torch.Tensor) else np.array(T, copy=True)
        out[..., :3, :3] = self.apply_rotation(T[..., :3, :3])
        out[..., :3, 3] = self.apply(T[..., :3, 3])
        return out

    # ---- serialisation ------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """``{"scale": float, "rotation": 3x3 nested list, "translation": [3]}``."""
        return {"scale": self.scale, "rotation": self.rotation.tolist(), "translation": self.translation.tolist()}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Sim3:
        if not isinstance(data, dict):
            raise ValueError(f"Sim3 JSON must be an object, got {type(data).__name__}")
        missing = {"scale", "rotation", "translation"} - set(data)
        if missing:
            raise ValueError(f"Sim3 JSON lacks {sorted(missing)}; expected keys scale, rotation, translation")
        return cls(float(data["scale"]), data["rotation"], data["translation"])

    def save(self, path: str | os.PathLike) -> None:
        """Write JSON atomically (temporary file in the same folder, then rename)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        # Not mkstemp: its 0600 mode would survive the rename; "x" mode with a unique name honours the umask.
        tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
        try:
            with open(tmp, "x") as f:
                json.dump(self.to_json(), f, indent=2)
                f.write("\n")
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    @classmethod
    def load(cls, path: str | os.PathLike) -> Sim3:
        with open(path) as f:
            try:
                data = json.load(f)
            except json.JSONDecodeError as e:
                raise ValueError(f"{path}: not valid JSON ({e})") from e
        try:
            return cls.from_json(data)
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from e

    def __repr__(self) -> str:
        r = np.array2string(self.rotation, precision=6, separator=", ").replace("\n", "")
        t = np.array2string(self.translation, precision=6, separator=", ")
        return f"Sim3(scale={self.scale:.8g}, rotation={r}, translation={t})"


def invert_rigid(T: np.ndarray) -> np.ndarray:
    """Inverse [4,4] of a rigid transform [4,4]: [R^T, -R^T t] (exact, no general matrix inverse)."""
    T = np.asarray(T, dtype=np.float64)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out
