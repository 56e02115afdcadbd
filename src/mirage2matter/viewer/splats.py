"""Gaussians as viser draws them: centres, covariances, colours and opacities (the SH's view-independent part)."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..gaussians.ply import read_ply

__all__ = ["SH_C0", "SplatArrays", "read_splats"]

SH_C0 = 0.28209479177387814  # the degree-0 SH basis: colour = SH_C0 * dc + 0.5


@dataclass
class SplatArrays:
    """N Gaussians in viser's terms, in the frame of whoever owns them.

    centers      float32 [N,3] (m)
    covariances  float32 [N,3,3] (m^2)
    rgbs         float32 [N,3] in 0..1 (the SH's DC band: what every view sees)
    opacities    float32 [N,1] in 0..1
    """

    centers: np.ndarray
    covariances: np.ndarray
    rgbs: np.ndarray
    opacities: np.ndarray

    def __len__(self) -> int:
        return int(self.centers.shape[0])

    def scaled(self, s: float) -> SplatArrays:
        """The same Gaussians scaled by ``s`` about the origin (a placement's scale)."""
        return SplatArrays(self.centers * s, self.covariances * s * s, self.rgbs, self.opacities)

    def kwargs(self) -> dict[str, np.ndarray]:
        return {"centers": self.centers, "covariances": self.covariances, "rgbs": self.rgbs,
                "opacities": self.opacities}  # fmt: skip


def read_splats(path: str | os.PathLike, max_gaussians: int) -> SplatArrays:
    """A 3DGS PLY as :class:`SplatArrays`, at most ``max_gaussians`` of them (a uniform sample); ``PlyFormatError``
    naming the file for one that is damaged."""
    import torch

    g = read_ply(path)
    with torch.no_grad():
        opacity = g.opacities.numpy()
        # a uniform sample keeps the scene's look; the most opaque alone are its large background Gaussians (a haze)
        rng = np.random.default_rng(0)
        keep = np.arange(len(g)) if len(g) <= max_gaussians else np.sort(rng.choice(len(g), max_gaussians, False))
        q = g.quats[keep].numpy().astype(np.float64)
        q /= np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-12)
        w, x, y, z = q.T
        R = np.stack([
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ], axis=1)  # fmt: skip
        var = np.exp(2.0 * g.log_scales[keep].numpy().astype(np.float64))  # [N,3]
        cov = np.einsum("nij,nj,nkj->nik", R, var, R)  # R diag(s^2) R^T
        rgb = np.clip(SH_C0 * g.sh[keep, 0].numpy() + 0.5, 0.0, 1.0)
        return SplatArrays(
            centers=g.means[keep].numpy().astype(np.float32),
            covariances=cov.astype(np.float32),
            rgbs=rgb.astype(np.float32),
            opacities=opacity[keep, None].astype(np.float32),
        )
