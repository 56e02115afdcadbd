"""The Gaussian world at a physics state: static scene + each movable part's Gaussians at its pose.

Each movable part (an object, a button cap) holds its Gaussians in its own object frame; at a
physics pose ``T_base_obj`` (rigid) they are ``apply_sim3(local, Sim3(scale, R, t))``, the object's
placement scale with the pose's rotation and translation, SH bands rotated too (world/config.py).

The world's tensors are concatenated once, on the device its backend renders on (a GPU for "cuda"); moving a
part overwrites its rows in place, so a frame costs the parts' transforms and the render, not a copy of the whole
scene. :class:`SplatWorldBatch` holds B copies of one world (B episodes in lockstep) in one ``[B, N, ...]`` stack
and renders all of them, from all their cameras, in one call on a GPU.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch

from ..gaussians.model import Gaussians
from ..gaussians.transform import apply_sim3
from ..geometry.sim3 import Sim3
from .options import MAX_SUPERSAMPLE


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
    min_opacity  Gaussians (scene and parts) fainter than this are dropped (alone they barely show; the
                 object reconstructions hold many: half the banana's are below 0.03)
    backend      gaussians.render backend ("auto": CUDA if available, else the numba CPU rasterizer)
    pose_tolerance  a part's Gaussians are re-posed only when its pose moved more than this (max abs entry
                 of T_base_obj: metres / rotation entries ~ radians; 1e-5 is 0.01 mm, far below a pixel)
    antialias    gsplat's antialiased mode (``gaussians.render.render``): objects seen smaller than they were
                 reconstructed (a far head camera at 128 px) keep their thin shapes instead of swelling
    supersample  s: every view drawn at s x its size and box-averaged down (rgb, alpha; depth weighted by alpha), so
                 Gaussians far smaller than a pixel add their area, not the rasterizer's minimum footprint (classic
                 3DGS dilates each to about a pixel: at 128 px a thin object swells); costs ~s^2 the pixels
    """

    sh_degree: int = 3
    min_opacity: float = 0.0
    backend: str = "auto"
    cull: bool = True  # drop Gaussians that cannot reach the image before rendering (same pixels, less work)
    pose_tolerance: float = 1e-5
    antialias: bool = False
    supersample: int = 1

    def __post_init__(self) -> None:
        if int(self.supersample) != self.supersample or not 1 <= self.supersample <= MAX_SUPERSAMPLE:
            raise ValueError(f"supersample must be an integer from 1 to {MAX_SUPERSAMPLE}, got {self.supersample}")


def supersampled_K(K: np.ndarray, s: int) -> np.ndarray:
    """Intrinsics [...,3,3] of the same view at s x the size (pixel centres at half-integers: each output pixel is
    the mean of the s x s pixels that tile it)."""
    Ks = np.array(K, np.float64, copy=True)
    Ks[..., :2, :] *= s
    return Ks


def box_down(rgb: np.ndarray, alpha: np.ndarray, depth: np.ndarray, s: int):
    """(rgb [...,sH,sW,3], alpha [...,sH,sW], depth [...,sH,sW]) -> the same at [...,H,W]: rgb and alpha averaged over
    each s x s block, depth averaged with alpha weights (the expected depth of what the block shows; 0 where nothing
    covers it)."""
    if s == 1:
        return rgb, alpha, depth
    *lead, H, W = alpha.shape
    blocks = lambda a: a.reshape(*lead, H // s, s, W // s, s, *a.shape[len(lead) + 2:])
    mean = lambda a: blocks(a).mean(axis=(len(lead) + 1, len(lead) + 3), dtype=np.float32)
    a = mean(alpha)
    ad = mean(alpha * depth)
    d = np.where(a > 0, ad / np.maximum(a, 1e-12), 0.0).astype(np.float32)
    return mean(rgb), a, d


def rendered_rows(g: Gaussians, options: SplatRenderOptions) -> Gaussians:
    """What of ``g`` a splat world with ``options`` draws: Gaussians at least ``min_opacity`` opaque, SH bands up to
    ``sh_degree`` (detached; same device)."""
    g = g.detach()
    if options.min_opacity > 0:
        g = g.select(g.opacities >= options.min_opacity)
    return g.with_sh_degree(min(options.sh_degree, g.sh_degree))


class SplatWorld:
    """Static scene + movable parts, posed and rendered per frame."""

    def __init__(self, static: Gaussians | None, parts: list[MovablePart], options: SplatRenderOptions | None = None):
        from ..gaussians.render import resolve_backend

        self.options = options or SplatRenderOptions()
        # the rows live where the renderer reads them: a GPU world is not copied to the GPU at every frame
        self.device = torch.device("cuda" if resolve_backend(self.options.backend) == "cuda" else "cpu")

        def lean(g: Gaussians) -> Gaussians:
            return rendered_rows(g, self.options).to(self.device, torch.float32)

        chunks: list[Gaussians] = []
        if static is not None and len(static):
            chunks.append(lean(static))
        self.parts = [MovablePart(p.name, lean(p.local), p.scale) for p in parts]
        names = [p.name for p in self.parts]
        if len(set(names)) != len(names):
            raise ValueError(f"movable part names must be unique, got {names}")
        self._slices: dict[str, slice] = {}
        start = sum(len(c) for c in chunks)
        self.static_rows = slice(0, start)  # the scene's rows (they never move; recolouring them is the caller's)
        for p in self.parts:
            self._slices[p.name] = slice(start, start + len(p.local))
            start += len(p.local)
            chunks.append(p.local)
        if not chunks:
            raise ValueError("the splat world is empty: no scene Gaussians and no parts")
        self.gaussians = Gaussians.concat(chunks).map(lambda t: t.contiguous().clone())
        self._radius = self._cull_radius(self.gaussians)  # [N], kept current by set_poses
        self.poses: dict[str, np.ndarray] = {}
        self.version = 0  # bumped whenever a part is re-posed (what cached frames depend on)
        self.reset_cache()

    @classmethod
    def from_files(cls, parts: dict, options: SplatRenderOptions | None = None) -> SplatWorld:
        """The world of a splat layer's description ``{"scene": PLY path or None, "parts": [[name, PLY path,
        placement scale], ...]}`` (``env.hybrid.splat_parts``): the scene's Gaussians static, each part's movable."""
        from ..gaussians.ply import read_ply

        movable = [MovablePart(name, read_ply(path), scale) for name, path, scale in parts["parts"]]
        static = read_ply(parts["scene"]) if parts["scene"] is not None else None
        return cls(static, movable, options)

    def __len__(self) -> int:
        return len(self.gaussians)

    def set_poses(self, poses: dict[str, np.ndarray]) -> None:
        """Move each named part to its physics pose ``T_base_obj`` [4,4] (parts not named stay put)."""
        for p in self.parts:
            T = poses.get(p.name)
            if T is None:
                continue
            T = np.asarray(T, np.float64)
            last = self.poses.get(p.name)
            if last is not None and np.abs(last - T).max() <= self.options.pose_tolerance:
                continue  # unchanged (resting objects jitter by micrometres in physics): keep the rows
            moved = apply_sim3(p.local, Sim3(p.scale, T[:3, :3], T[:3, 3]))
            sl = self._slices[p.name]
            g = self.gaussians
            with torch.no_grad():
                g.means[sl] = moved.means
                g.quats[sl] = moved.quats
                g.log_scales[sl] = moved.log_scales
                g.sh[sl, : moved.sh.shape[1]] = moved.sh
                self._radius[sl] = self._cull_radius(moved)
            self.poses[p.name] = T.copy()
            self.version += 1

    def render(self, viewmat: np.ndarray, K: np.ndarray, width: int, height: int, background=(0.0, 0.0, 0.0)):
        """(rgb float32 [H,W,3] in [0,1], alpha [H,W], depth [H,W] camera-z m) as numpy."""
        return self._render(self.gaussians, viewmat, K, width, height, background, self._radius)

    def render_camera(self, name: str, viewmat, K, width: int, height: int, background=(0.0, 0.0, 0.0)):
        """:meth:`render` for a camera that may move (the wrist camera): its last frame is returned again while
        no part has been re-posed and the camera moved less than ``options.pose_tolerance`` (an arm at rest)."""
        view = np.asarray(viewmat, np.float64)
        key = (np.asarray(K, np.float64).tobytes(), int(width), int(height), tuple(background), self.version)
        last = self._last.get(name)
        if last is not None and last[0] == key and np.abs(last[1] - view).max() <= self.options.pose_tolerance:
            return last[2]
        out = self.render(view, K, width, height, background)
        self._last[name] = (key, view.copy(), out)
        return out

    # ---- static cameras: render what does not move once ----------------------------------------------------
    def reset_cache(self) -> None:
        """Forget the cached backgrounds (call when an episode starts: the parts' rest poses change)."""
        self._cache: dict[str, dict] = {}
        self._last: dict[str, tuple] = {}  # render_camera's last frame per camera
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
        for p in self.parts:
            pose = self.poses.get(p.name)
            if pose is None or p.name in self._moving:
                continue
            rest = self._rest.setdefault(p.name, pose)
            if np.abs(pose - rest).max() > self.options.pose_tolerance:
                self._moving.add(p.name)
        key = (np.asarray(viewmat, np.float64).tobytes(), np.asarray(K, np.float64).tobytes(), width, height,
               tuple(background), frozenset(self._moving))  # fmt: skip
        entry = self._cache.get(name)
        if entry is None or entry["key"] != key:
            keep = torch.ones(len(self.gaussians), dtype=torch.bool, device=self.device)
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
        # the moving parts' rows are slices: views (no copy), with their cached cull radii
        sls = [self._slices[n] for n in sorted(self._moving)]
        pieces = [self.gaussians.select(sl) for sl in sls]
        fg = pieces[0] if len(pieces) == 1 else Gaussians.concat(pieces)
        radius = torch.cat([self._radius[sl] for sl in sls])
        fg_rgb, fg_alpha, fg_depth = self._render(fg, viewmat, K, width, height, (0.0, 0.0, 0.0), radius)
        front = (fg_alpha > 0) & ((fg_depth < bg_depth) | (bg_alpha < 0.5))
        a = fg_alpha[..., None]
        rgb = np.where(front[..., None], fg_rgb + (1.0 - a) * bg_rgb, bg_rgb)
        alpha = np.where(front, fg_alpha + (1.0 - fg_alpha) * bg_alpha, bg_alpha)
        depth = np.where(front & (fg_alpha >= 0.5), fg_depth, bg_depth)
        return np.clip(rgb, 0.0, 1.0), alpha, depth

    @staticmethod
    def _cull_radius(g: Gaussians) -> torch.Tensor:
        """[N] metres: past the renderers' cut-off (<= 3.33 sigma, alpha 1/255) along the longest axis."""
        return 3.5 * torch.exp(g.log_scales.max(dim=1).values)

    @staticmethod
    def _in_view(g: Gaussians, viewmat, K, width: int, height: int, radius: torch.Tensor | None = None) -> torch.Tensor:
        """bool [N]: Gaussians whose 3-sigma extent can reach the image (a conservative frustum test, so the
        render of the kept ones equals the render of all; near plane as the renderers'). ``radius`` [N]:
        :meth:`_cull_radius` of ``g`` when the caller has it."""
        from ..gaussians.render.conventions import NEAR_PLANE

        V = torch.as_tensor(viewmat, dtype=g.means.dtype, device=g.means.device)
        Kt = torch.as_tensor(K, dtype=g.means.dtype, device=g.means.device)
        pc = g.means @ V[:3, :3].T + V[:3, 3]
        z = pc[:, 2]
        zc = z.clamp_min(NEAR_PLANE)
        r = SplatWorld._cull_radius(g) if radius is None else radius
        f = torch.maximum(Kt[0, 0], Kt[1, 1])
        # Projected radius in pixels, doubled: off-axis the projection stretches a footprint by up to
        # 1 + (x/z)^2 (the renderers clamp x/z at 1.3x the half field of view); + the low-pass filter's spread.
        rp = 2.0 * f * r / zc + 4.0
        u = Kt[0, 0] * pc[:, 0] / zc + Kt[0, 2]
        v = Kt[1, 1] * pc[:, 1] / zc + Kt[1, 2]
        return (z > NEAR_PLANE) & (u > -rp) & (u < width + rp) & (v > -rp) & (v < height + rp)

    def _render(self, gaussians: Gaussians, viewmat, K, width, height, background, radius=None):
        from ..gaussians.render import render

        s = int(self.options.supersample)
        K, width, height = supersampled_K(K, s), int(width) * s, int(height) * s
        if self.options.cull:
            keep = self._in_view(gaussians, viewmat, K, width, height, radius)
            if not bool(keep.all()):
                gaussians = gaussians.select(keep.nonzero().squeeze(1))  # indices: one scan, not one per tensor

        out = render(
            gaussians,
            torch.as_tensor(viewmat, dtype=torch.float32),
            torch.as_tensor(K, dtype=torch.float32),
            int(width),
            int(height),
            background=torch.as_tensor(background, dtype=torch.float32),
            backend=self.options.backend,
            antialias=self.options.antialias,
        )
        as_np = lambda t: t.detach().to("cpu", torch.float32).numpy()
        return box_down(np.clip(as_np(out.rgb), 0.0, 1.0), as_np(out.alpha), as_np(out.depth), s)


class SplatWorldBatch:
    """B copies of one :class:`SplatWorld` (B episodes stepped in lockstep), each posed on its own, rendered
    together: on a GPU one gsplat call draws every copy from its C cameras (at 224x224 one camera alone leaves most
    of the GPU idle); elsewhere copy by copy, camera by camera, the same images.

    The copies are the rows of one ``[B, N, ...]`` stack. :meth:`set_poses` takes every copy's part poses at once
    and re-poses each part for all the copies it moved in in one batched transform (not one small GPU job per
    copy); :meth:`forget` starts a copy afresh (a new episode), :meth:`set_scale` draws a copy's parts at its own
    scale (an episode's object scale). Every camera renders the whole world each frame (no static-camera background
    cache: a batched GPU call costs less than its bookkeeping).
    """

    def __init__(self, world: SplatWorld, batch: int):
        if batch < 1:
            raise ValueError(f"a splat world batch needs at least one copy, got {batch}")
        self.options, self.parts, self._slices = world.options, world.parts, world._slices
        self.sh_degree = world.gaussians.sh_degree
        self.stack = {k: t.unsqueeze(0).repeat(batch, *[1] * t.ndim) for k, t in world.gaussians.tensors().items()}
        self._poses: list[dict[str, np.ndarray]] = [{} for _ in range(batch)]
        self.scale = np.ones(batch)  # [B] each copy's factor on its parts' placement scales
        # Copy b as a SplatWorld on row b (views: posing the stack moves it), for the CPU path's renders. A part's
        # cull radius depends on its scales alone, which a rigid pose keeps: the world's radii hold for every copy.
        self.worlds: list[SplatWorld] = []
        for b in range(batch):
            w = copy.copy(world)
            w.gaussians = Gaussians(**{k: t[b] for k, t in self.stack.items()})
            w.poses, w.version = {}, 0
            w.reset_cache()
            self.worlds.append(w)

    def __len__(self) -> int:
        return len(self.worlds)

    def forget(self, b: int) -> None:
        """Copy ``b`` starts a new episode: its next poses are applied exactly, not skipped as unchanged."""
        self._poses[b] = {}

    def set_scale(self, b: int, factor: float) -> None:
        """Copy ``b``'s parts drawn at ``factor`` x their placement scale about their origin, from its next poses on
        (every part is re-posed at them)."""
        if not factor > 0:
            raise ValueError(f"a copy's scale factor must be positive, got {factor}")
        self.scale[b] = float(factor)
        self.forget(b)

    def set_poses(self, poses: list[dict[str, np.ndarray] | None]) -> None:
        """Copy b's parts to ``poses[b]`` ({name: T_base_obj [4,4]}; None or a missing name: unchanged)."""
        if len(poses) != len(self):
            raise ValueError(f"set_poses needs one pose dict per copy ({len(self)}), got {len(poses)}")
        tol = self.options.pose_tolerance
        for p in self.parts:
            idx, Ts = [], []
            for b, d in enumerate(poses):
                T = None if d is None else d.get(p.name)
                if T is None:
                    continue
                T = np.asarray(T, np.float64)
                last = self._poses[b].get(p.name)
                if last is not None and np.abs(last - T).max() <= tol:
                    continue
                idx.append(b)
                Ts.append(T)
                self._poses[b][p.name] = T.copy()
            if idx:
                self._pose_part(p, idx, np.stack(Ts))

    def _pose_part(self, p: MovablePart, idx: list[int], T: np.ndarray) -> None:
        """Part ``p`` in copies ``idx`` at poses T [B',4,4], all in one batched transform."""
        from ..gaussians.transform import apply_rigid_batch

        moved = apply_rigid_batch(p.local, p.scale * self.scale[idx], T[:, :3, :3], T[:, :3, 3])
        sl, rows = self._slices[p.name], torch.as_tensor(idx, device=p.local.means.device)
        with torch.no_grad():
            for k in ("means", "quats", "log_scales"):
                self.stack[k][rows, sl] = moved[k]
            self.stack["sh"][rows, sl, : moved["sh"].shape[2]] = moved["sh"]

    def render(self, viewmats, Ks, width: int, height: int, background=(0.0, 0.0, 0.0), copies=None):
        """Every copy b from its cameras (viewmats [B,C,4,4] world-to-camera, Ks [B,C,3,3]) -> (rgb [B,C,H,W,3] in
        [0,1], alpha [B,C,H,W], depth [B,C,H,W] camera-z m), float32 numpy. ``copies``: only these copies (indices,
        in order; the leading axis of the inputs and outputs is theirs), e.g. the episodes that asked for a frame."""
        from ..gaussians.render import gpu_out_of_memory, render_gsplat_batch

        viewmats, Ks = np.asarray(viewmats, np.float64), np.asarray(Ks, np.float64)
        rows = list(range(len(self.worlds))) if copies is None else [int(b) for b in copies]
        B = len(rows)
        if not rows or min(rows) < 0 or max(rows) >= len(self.worlds) or len(set(rows)) != B:
            raise ValueError(f"copies must be distinct indices below {len(self.worlds)}, got {copies}")
        if viewmats.ndim != 4 or viewmats.shape[0] != B or viewmats.shape[2:] != (4, 4) or \
                Ks.shape != (*viewmats.shape[:2], 3, 3):  # fmt: skip
            raise ValueError(f"a batch of {B} worlds renders viewmats [{B},C,4,4] and Ks [{B},C,3,3], got "
                             f"{viewmats.shape} and {Ks.shape}")  # fmt: skip
        if self.worlds[0].device.type != "cuda" or self.stack["means"].shape[1] == 0:  # gsplat dies on N = 0
            outs = [[self.worlds[b].render(v, k, width, height, background) for v, k in zip(vs, ks, strict=True)]
                    for b, vs, ks in zip(rows, viewmats, Ks, strict=True)]  # fmt: skip
            return tuple(np.stack([np.stack([o[i] for o in row]) for row in outs]) for i in range(3))
        stack = self.stack
        if rows != list(range(len(self.worlds))):
            sel = torch.as_tensor(rows, device=self.stack["means"].device)
            stack = {k: t.index_select(0, sel) for k, t in self.stack.items()}
        s = int(self.options.supersample)
        try:
            f32 = lambda a: torch.tensor(np.asarray(a, np.float32))  # a copy: the inputs may be read-only views
            out = render_gsplat_batch(stack, self.sh_degree, f32(viewmats), f32(supersampled_K(Ks, s)), int(width) * s,
                                      int(height) * s, f32(background), self.options.antialias)  # fmt: skip
        except torch.cuda.OutOfMemoryError as e:
            lower = "the episodes per batch, the image size, the supersampling or the Gaussians (min_opacity)"
            raise gpu_out_of_memory(f"rendering {B}x{viewmats.shape[1]} cameras of", self.stack["means"].shape[1],
                                    width * s, height * s, lower) from e  # fmt: skip
        as_np = lambda t: t.to("cpu").numpy()
        return box_down(as_np(out.rgb.clamp(0.0, 1.0)), as_np(out.alpha), as_np(out.depth), s)
