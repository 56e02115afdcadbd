"""The Gaussian splat model: one data class of per-Gaussian tensors (DESIGN.md section 2)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

import torch

from .sh import num_sh_bases, sh_degree_from_bases


@dataclass
class Gaussians:
    """N anisotropic 3D Gaussians.

    means            [N, 3]  centres (world frame of whoever owns them)
    quats            [N, 4]  rotations, wxyz (need not be normalised; renderers normalise)
    log_scales       [N, 3]  per-axis log standard deviations; covariance R diag(exp(l)^2) R^T
    logit_opacities  [N]     opacity = sigmoid(logit)
    sh               [N, K, 3] SH coefficients, K = (degree+1)^2, DC first
    """

    means: torch.Tensor
    quats: torch.Tensor
    log_scales: torch.Tensor
    logit_opacities: torch.Tensor
    sh: torch.Tensor

    def __post_init__(self) -> None:
        n = self.means.shape[0] if self.means.ndim == 2 else -1
        expect = {
            "means": (n, 3),
            "quats": (n, 4),
            "log_scales": (n, 3),
            "logit_opacities": (n,),
        }
        for name, shape in expect.items():
            t = getattr(self, name)
            if tuple(t.shape) != shape:
                raise ValueError(f"Gaussians.{name} must have shape {shape}, got {tuple(t.shape)}")
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3:
            raise ValueError(f"Gaussians.sh must have shape ({n}, K, 3), got {tuple(self.sh.shape)}")
        sh_degree_from_bases(self.sh.shape[1])  # raises on a K that is not (d+1)^2

    # ---- derived quantities -------------------------------------------------------------
    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return sh_degree_from_bases(self.sh.shape[1])

    @property
    def opacities(self) -> torch.Tensor:
        return torch.sigmoid(self.logit_opacities)

    @property
    def scales(self) -> torch.Tensor:
        return torch.exp(self.log_scales)

    @property
    def device(self) -> torch.device:
        return self.means.device

    def tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def from_activated(
        cls,
        means: torch.Tensor,
        quats: torch.Tensor,
        scales: torch.Tensor,
        opacities: torch.Tensor,
        sh: torch.Tensor | None = None,
        rgb: torch.Tensor | None = None,
        sh_degree: int = 0,
    ) -> Gaussians:
        """Build from linear scales, opacities in (0,1) and either SH or a view-independent rgb."""
        if (sh is None) == (rgb is None):
            raise ValueError("give exactly one of sh or rgb")
        if sh is None:
            from .sh import rgb_to_sh_dc

            sh = torch.zeros(means.shape[0], num_sh_bases(sh_degree), 3, dtype=means.dtype, device=means.device)
            sh[:, 0] = rgb_to_sh_dc(rgb)
        op = opacities.clamp(1e-6, 1 - 1e-6)
        return cls(means, quats, torch.log(scales), torch.log(op) - torch.log1p(-op), sh)

    # ---- selection / combination --------------------------------------------------------
    def select(self, index: torch.Tensor | Sequence[int] | slice) -> Gaussians:
        """Subset by boolean mask [N], integer indices, or slice."""
        if not isinstance(index, slice | torch.Tensor):
            index = torch.as_tensor(index, dtype=torch.long, device=self.device)
        return Gaussians(**{k: v[index] for k, v in self.tensors().items()})

    def crop(self, aabb_min: Sequence[float] | torch.Tensor, aabb_max: Sequence[float] | torch.Tensor) -> Gaussians:
        """Gaussians whose means lie inside the axis-aligned box [aabb_min, aabb_max] (inclusive)."""
        lo = torch.as_tensor(aabb_min, dtype=self.means.dtype, device=self.device)
        hi = torch.as_tensor(aabb_max, dtype=self.means.dtype, device=self.device)
        if lo.shape != (3,) or hi.shape != (3,) or bool((lo > hi).any()):
            raise ValueError(f"crop box must be two 3-vectors with min <= max, got {lo.tolist()} / {hi.tolist()}")
        inside = ((self.means >= lo) & (self.means <= hi)).all(dim=1)
        return self.select(inside)

    def with_sh_degree(self, degree: int) -> Gaussians:
        """Truncate or zero-pad the SH bands to ``degree``."""
        k = num_sh_bases(degree)
        sh = self.sh[:, :k]
        if sh.shape[1] < k:
            pad = sh.new_zeros(sh.shape[0], k - sh.shape[1], 3)
            sh = torch.cat([sh, pad], dim=1)
        return Gaussians(self.means, self.quats, self.log_scales, self.logit_opacities, sh)

    @staticmethod
    def concat(parts: Sequence[Gaussians]) -> Gaussians:
        """Concatenate; SH is zero-padded to the highest degree among the parts."""
        if not parts:
            raise ValueError("concat needs at least one Gaussians")
        degree = max(p.sh_degree for p in parts)
        parts = [p.with_sh_degree(degree) for p in parts]
        return Gaussians(**{k: torch.cat([getattr(p, k) for p in parts]) for k in parts[0].tensors()})

    def map(self, fn) -> Gaussians:
        """Apply ``fn`` to every tensor (e.g. ``g.map(lambda t: t.detach().clone())``)."""
        return Gaussians(**{k: fn(v) for k, v in self.tensors().items()})

    def to(self, *args, **kwargs) -> Gaussians:
        return self.map(lambda t: t.to(*args, **kwargs))

    def detach(self) -> Gaussians:
        return self.map(lambda t: t.detach())

    def check_finite(self, source: str = "Gaussians") -> None:
        """Raise ValueError naming ``source`` and the first tensor holding NaN/Inf."""
        for name, t in self.tensors().items():
            bad = ~torch.isfinite(t)
            if bool(bad.any()):
                rows = bad.reshape(t.shape[0], -1).any(dim=1).nonzero().flatten()
                raise ValueError(
                    f"{source}: {name} has {rows.numel()} Gaussian(s) with NaN/Inf values "
                    f"(first at index {int(rows[0])}); fix or drop them before use"
                )
