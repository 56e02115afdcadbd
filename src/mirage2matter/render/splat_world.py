"""The Gaussian world at a physics state: static scene + each movable part's Gaussians at its pose.

Each movable part (an object, a button cap) holds its Gaussians in its own object frame; at a
physics pose ``T_base_obj`` (rigid) they are ``apply_sim3(local, Sim3(scale, R, t))``, the object's
placement scale with the pose's rotation and translation, SH bands rotated too (world/config.py).

The world's tensors are concatenated once; moving a part overwrites its rows in place, so a frame
costs the parts' transforms and the render, not a copy of the whole scene.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..gaussians.model import Gaussians
from ..gaussians.transform import apply_sim3
from ..geometry.sim3 import Sim3


@dataclass
class MovablePart:
    """name: the key of its pose in the simulator's object poses; local: Gaussians in its object frame;
    scale: its placement scale (object frame -> base)."""

    name: str
    local: Gaussians
    scale: float = 1.0


@dataclass(frozen=True)
class SplatRenderOptions:
    """Speed / quality knobs of the per-frame splat renders.

    sh_degree    highest SH band rendered (view-dependent colour costs per Gaussian per view)
    min_opacity  static-scene Gaussians fainter than this are dropped (they barely show)
    backend      gaussians.render backend ("auto": CUDA if available, else the numba CPU rasterizer)
    """

    sh_degree: int = 3
    min_opacity: float = 0.0
    backend: str = "auto"
    cull: bool = True  # drop Gaussians that cannot reach the image before rendering (same pixels, less work)


class SplatWorld:
    """Static scene + movable parts, posed and rendered per frame."""

    def __init__(self, static: Gaussians | None, parts: list[MovablePart], options: SplatRenderOptions | None = None):
        self.options = options or SplatRenderOptions()
        degree = self.options.sh_degree
        chunks: list[Gaussians] = []
        if static is not None and len(static):
            static = static.detach()
            if self.options.min_opacity > 0:
                static = static.select(static.opacities >= self.options.min_opacity)
            chunks.append(static.with_sh_degree(min(degree, static.sh_degree)))
        self.parts = [MovablePart(p.name, p.local.detach().with_sh_degree(min(degree, p.local.sh_degree)), p.scale)
                      for p in parts]  # fmt: skip
        names = [p.name for p in self.parts]
        if len(set(names)) != len(names):
            raise ValueError(f"movable part names must be unique, got {names}")
        self._slices: dict[str, slice] = {}
        start = sum(len(c) for c in chunks)
        for p in self.parts:
            self._slices[p.name] = slice(start, start + len(p.local))
            start += len(p.local)
            chunks.append(p.local)
        if not chunks:
            raise ValueError("the splat world is empty: no scene Gaussians and no parts")
        self.gaussians = Gaussians.concat(chunks).map(lambda t: t.to(torch.float32).contiguous().clone())
        self.poses: dict[str, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.gaussians)

    def set_poses(self, poses: dict[str, np.ndarray]) -> None:
        """Move each named part to its physics pose ``T_base_obj`` [4,4] (parts not named stay put)."""
        for p in self.parts:
            T = poses.get(p.name)
            if T is None:
                continue
            T = np.asarray(T, np.float64)
            if p.name in self.poses and np.array_equal(self.poses[p.name], T):
                continue  # unchanged: keep the rows as they are
            moved = apply_sim3(p.local, Sim3(p.scale, T[:3, :3], T[:3, 3]))
            sl = self._slices[p.name]
            g = self.gaussians
            with torch.no_grad():
                g.means[sl] = moved.means
                g.quats[sl] = moved.quats
                g.log_scales[sl] = moved.log_scales
                g.sh[sl, : moved.sh.shape[1]] = moved.sh
            self.poses[p.name] = T.copy()

    def render(self, viewmat: np.ndarray, K: np.ndarray, width: int, height: int, background=(0.0, 0.0, 0.0)):
        """(rgb float32 [H,W,3] in [0,1], alpha [H,W], depth [H,W] camera-z m) as numpy."""
        return self._render(self.gaussians, viewmat, K, width, height, background)

    # ---- static cameras: render what does not move once ----------------------------------------------------
    def reset_cache(self) -> None:
        """Forget the cached backgrounds (call when an episode starts: the parts' rest poses change)."""
        self._cache: dict[str, dict] = {}
        self._rest: dict[str, np.ndarray] = {}
        self._moving: set[str] = set()

    def render_static_camera(self, name: str, viewmat, K, width: int, height: int, background=(0.0, 0.0, 0.0)):
        """Like :meth:`render` for a camera that stays put during the episode (the head camera).

        The scene and every part that has not moved since the first call (after :meth:`reset_cache`)
        are rendered once as a background; each frame renders only the parts that have moved and
        composites them over it by depth. A part counts as moving from its first displacement on (the
        background is then redrawn once without it). An approximation of the joint render at the
        moving parts' outlines (two layers instead of one sorted blend); exact elsewhere.
        """
        if not hasattr(self, "_cache"):
            self.reset_cache()
        for p in self.parts:
            pose = self.poses.get(p.name)
            if pose is None or p.name in self._moving:
                continue
            rest = self._rest.setdefault(p.name, pose)
            if np.abs(pose - rest).max() > 1e-6:
                self._moving.add(p.name)
        key = (np.asarray(viewmat, np.float64).tobytes(), np.asarray(K, np.float64).tobytes(), width, height,
               tuple(background), frozenset(self._moving))  # fmt: skip
        entry = self._cache.get(name)
        if entry is None or entry["key"] != key:
            keep = torch.ones(len(self.gaussians), dtype=torch.bool)
            for n in self._moving:
                keep[self._slices[n]] = False
            entry = {
                "key": key,
                "layer": self._render(self.gaussians.select(keep), viewmat, K, width, height, background),
            }
            self._cache[name] = entry
        bg_rgb, bg_alpha, bg_depth = entry["layer"]
        if not self._moving:
            return bg_rgb, bg_alpha, bg_depth
        rows = torch.zeros(len(self.gaussians), dtype=torch.bool)
        for n in self._moving:
            rows[self._slices[n]] = True
        fg_rgb, fg_alpha, fg_depth = self._render(
            self.gaussians.select(rows), viewmat, K, width, height, (0.0, 0.0, 0.0)
        )
        front = (fg_alpha > 0) & ((fg_depth < bg_depth) | (bg_alpha < 0.5))
        a = fg_alpha[..., None]
        rgb = np.where(front[..., None], fg_rgb + (1.0 - a) * bg_rgb, bg_rgb)
        alpha = np.where(front, fg_alpha + (1.0 - fg_alpha) * bg_alpha, bg_alpha)
        depth = np.where(front & (fg_alpha >= 0.5), fg_depth, bg_depth)
        return np.clip(rgb, 0.0, 1.0), alpha, depth

    @staticmethod
    def _in_view(g: Gaussians, viewmat, K, width: int, height: int) -> torch.Tensor:
        """bool [N]: Gaussians whose 3-sigma extent can reach the image (a conservative frustum test, so the
        render of the kept ones equals the render of all; near plane as the renderers')."""
        from ..gaussians.render.conventions import NEAR_PLANE

        V = torch.as_tensor(viewmat, dtype=g.means.dtype)
        Kt = torch.as_tensor(K, dtype=g.means.dtype)
        pc = g.means @ V[:3, :3].T + V[:3, 3]
        z = pc[:, 2]
        zc = z.clamp_min(NEAR_PLANE)
        r = 3.5 * torch.exp(g.log_scales.max(dim=1).values)  # the renderers cut at <= 3.33 sigma (alpha 1/255)
        f = torch.maximum(Kt[0, 0], Kt[1, 1])
        # Projected radius in pixels, doubled: off-axis the projection stretches a footprint by up to
        # 1 + (x/z)^2 (the renderers clamp x/z at 1.3x the half field of view); + the low-pass filter's spread.
        rp = 2.0 * f * r / zc + 4.0
        u = Kt[0, 0] * pc[:, 0] / zc + Kt[0, 2]
        v = Kt[1, 1] * pc[:, 1] / zc + Kt[1, 2]
        return (z > NEAR_PLANE) & (u > -rp) & (u < width + rp) & (v > -rp) & (v < height + rp)

    def _render(self, gaussians: Gaussians, viewmat, K, width, height, background):
        from ..gaussians.render import render

        if self.options.cull:
            keep = self._in_view(gaussians, viewmat, K, width, height)
            if not bool(keep.all()):
                gaussians = gaussians.select(keep)

        out = render(
            gaussians,
            torch.as_tensor(viewmat, dtype=torch.float32),
            torch.as_tensor(K, dtype=torch.float32),
            int(width),
            int(height),
            background=torch.as_tensor(background, dtype=torch.float32),
            backend=self.options.backend,
        )
        as_np = lambda t: t.detach().to("cpu", torch.float32).numpy()
        return np.clip(as_np(out.rgb), 0.0, 1.0), as_np(out.alpha), as_np(out.depth)
