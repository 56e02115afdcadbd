"""Per-episode table texture: the reconstructed table's colour and grain re-drawn at random (domain randomisation).

Why: on the bundled sample a grasp policy trained in the reconstruction misjudged where the banana was in the
sample's ground-truth world mostly because of the table, not the banana: pasting the reconstruction's table
pixels into ground-truth first frames took the policy's open-loop error on its failed episodes from 0.068 to
0.031 (action-std units; the banana's pixels: 0.041; the floor and walls: 0.062). Every generated episode shows
the same reconstructed wood grain, so a network can use the grain as a landmark; a real table (or the
ground-truth one) has other grain. With ``Randomization.table_texture`` each episode evens the table's Gaussians'
colours out towards their mean, then multiplies them by a per-channel gain and a smooth random grain field (a few
plane waves over the table),
so nothing about the table's texture is the same from one demonstration to the next.

Which Gaussians are "the table": the scene's within ``band`` of the table plane and ``radius`` of the robot
base, coloured (saturation >= ``min_saturation``: the black-and-white calibration board and grey mounts keep
their look, they are not wood).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["TableGaussians", "TableTexture", "table_rows"]


def table_rows(
    means: np.ndarray,
    rgb: np.ndarray,
    table_z: float,
    band: float = 0.02,
    radius: float = 1.5,
    min_saturation: float = 0.2,
) -> np.ndarray:
    """bool [N]: which of the scene's Gaussians (``means`` [N, 3] base frame, ``rgb`` [N, 3] in [0, 1]) are the
    table top."""
    means, rgb = np.asarray(means, np.float64), np.asarray(rgb, np.float64)
    hi, lo = rgb.max(axis=1), rgb.min(axis=1)
    sat = (hi - lo) / np.maximum(hi, 1e-3)
    near = np.abs(means[:, 2] - table_z) <= band
    inside = np.linalg.norm(means[:, :2], axis=1) <= radius
    return near & inside & (sat >= min_saturation)


@dataclass(frozen=True)
class TableTexture:
    """One episode's table look:
    ``rgb' = clip(((1 - flatten) * rgb + flatten * mean(rgb)) * gain * (1 + amplitude * grain(x, y)), 0, 1)``.

    flatten     how much of the reconstruction's own grain is evened out towards the table's mean colour
    gain        [3] per-channel colour gain (the wood's tint and brightness)
    amplitude   strength of the grain field
    waves       [K, 2] spatial frequencies (cycles per metre, in the base frame's x-y) of the grain's plane waves
    phases      [K] their phases (radians)
    """

    flatten: float
    gain: tuple[float, float, float]
    amplitude: float
    waves: tuple[tuple[float, float], ...]
    phases: tuple[float, ...]

    @classmethod
    def sample(cls, rng: np.random.Generator, strength: float, n_waves: int = 6) -> TableTexture:
        """A random look of half-range ``strength`` (flattening in [0, min(1, 2 s)], gains in [1 - s, 1 + s], grain
        amplitude in [0, s]); grain wavelengths 2-30 cm in random directions."""
        flatten = float(rng.uniform(0.0, min(1.0, 2.0 * strength)))
        gain = tuple(float(g) for g in 1.0 + rng.uniform(-strength, strength, 3))
        amplitude = float(rng.uniform(0.0, strength))
        wavelength = rng.uniform(0.02, 0.30, n_waves)
        angle = rng.uniform(0.0, np.pi, n_waves)
        waves = np.stack([np.cos(angle), np.sin(angle)], axis=1) / wavelength[:, None]
        phases = rng.uniform(0.0, 2.0 * np.pi, n_waves)
        return cls(flatten, gain, amplitude, tuple(map(tuple, waves.tolist())), tuple(phases.tolist()))

    def grain(self, xy: np.ndarray) -> np.ndarray:
        """float [N] zero-mean, unit-variance field at base-frame points ``xy`` [N, 2]."""
        w, ph = np.asarray(self.waves, np.float64), np.asarray(self.phases, np.float64)
        arg = 2.0 * np.pi * np.asarray(xy, np.float64) @ w.T + ph  # [N, K]
        return np.cos(arg).sum(axis=1) * np.sqrt(2.0 / len(ph))

    def apply(self, rgb: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """float32 [N, 3]: ``rgb`` [N, 3] in [0, 1] of the table's Gaussians at ``xy`` [N, 2] with this look."""
        rgb = np.asarray(rgb, np.float64)
        if len(rgb):
            rgb = (1.0 - self.flatten) * rgb + self.flatten * rgb.mean(axis=0)
        factor = np.asarray(self.gain, np.float64)[None, :] * (1.0 + self.amplitude * self.grain(xy))[:, None]
        return np.clip(rgb * factor, 0.0, 1.0).astype(np.float32)

    def to_json(self) -> dict:
        return {"flatten": self.flatten, "gain": list(self.gain), "amplitude": self.amplitude,
                "waves": [list(w) for w in self.waves], "phases": list(self.phases)}  # fmt: skip


@dataclass(frozen=True)
class TableGaussians:
    """The table's Gaussians in a splat world, as built: ``rows`` (torch long [M], on the world's device) of its
    tensors, their base-frame ``xy`` [M, 2], SH DC ``dc`` (torch [M, 3]) and ``rgb`` [M, 3] in [0, 1]. What a
    renderer re-colours per episode (``sh[rows, 0] = sh_dc(texture)``) and restores."""

    rows: object
    xy: np.ndarray
    dc: object
    rgb: np.ndarray

    @classmethod
    def find(cls, gaussians, scene_rows: slice, table_z: float) -> TableGaussians:
        """The table among ``gaussians``' scene rows (``scene_rows``: the static scene's slice)."""
        import torch

        from ..gaussians.sh import SH_C0

        sh = gaussians.sh[scene_rows, 0].detach()
        rgb = (0.5 + SH_C0 * sh).clamp(0.0, 1.0).cpu().numpy()
        rows = np.flatnonzero(table_rows(gaussians.means[scene_rows].detach().cpu().numpy(), rgb, table_z))
        idx = torch.from_numpy(rows + scene_rows.start).to(gaussians.means.device)
        return cls(idx, gaussians.means[idx, :2].detach().cpu().numpy(), gaussians.sh[idx, 0].detach().clone(),
                   rgb[rows])  # fmt: skip

    def sh_dc(self, texture: TableTexture | None):
        """torch [M, 3]: the rows' SH DC in ``texture``'s look (None: as built), on the world's device and dtype."""
        import torch

        from ..gaussians.sh import rgb_to_sh_dc

        if texture is None or not len(self.rgb):
            return self.dc
        return rgb_to_sh_dc(torch.from_numpy(texture.apply(self.rgb, self.xy)).to(self.dc.device, self.dc.dtype))
