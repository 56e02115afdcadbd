"""Benchmarks behind ``m2m bench``: fixed synthetic inputs, warm-up, then timed runs.

Numbers from here are what DESIGN.md section 6 ("what fast means") is measured against, so the
inputs are deterministic (``tabletop_scene`` and ``orbit_cameras`` with a seed) and the timing
excludes one-off costs (numba JIT compile / cache load, CUDA context and kernel set-up).
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from typing import Any

from ..configs import ConfigError, ranged
from ..env.config import EpisodeSpec

__all__ = ["RenderBenchConfig", "bench_render"]

# The keys of bench_render's result, in the order the JSON line prints them.
RESULT_KEYS = ("backend", "gaussians", "width", "height", "sh_degree", "cameras_per_call", "ms_median", "ms_min",
               "ms_max", "ms_per_camera", "runs")  # fmt: skip


@dataclass(frozen=True)
class RenderBenchConfig:
    """What to render and how often.

    gaussians  size of the synthetic tabletop scene
    size       square image side in pixels
    backend    "auto", "cpu", "cuda" (or "reference", only sensible for tiny scenes)
    views      orbit cameras per round; every round renders each once
    repeats    timed rounds (so views * repeats timed renders)
    sh_degree  SH degree of the scene (0..3)
    cameras_per_call  cameras rendered by one call (``render_cameras``; 1: ``render``), e.g. 2 for a
               frame's head + wrist views, more for several episodes' frames at once
    warmup     untimed renders before timing (JIT compile, caches, CUDA set-up)
    seed       scene and camera seed
    """

    gaussians: int = ranged(100_000, ge=1, le=10**8)
    size: int = ranged(EpisodeSpec.size[0], ge=1, le=16384)
    backend: str = "auto"
    sh_degree: int = ranged(3, ge=0, le=3)
    cameras_per_call: int = ranged(1, ge=1, le=1024)
    views: int = ranged(8, ge=1, le=10_000)
    repeats: int = ranged(5, ge=1, le=10_000)
    warmup: int = ranged(2, ge=0, le=10_000)
    seed: int = ranged(0, ge=0, le=2**32 - 1)

    def validate(self) -> None:
        """Raise ConfigError naming the field, before any expensive work starts."""
        minimum = {"gaussians": 1, "size": 1, "views": 1, "repeats": 1, "warmup": 0, "seed": 0, "cameras_per_call": 1}
        for name, lo in minimum.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ConfigError(f"benchmark {name} must be an integer >= {lo}, got {v!r}")
        if not (isinstance(self.sh_degree, int) and 0 <= self.sh_degree <= 3):
            raise ConfigError(f"benchmark sh_degree must be 0..3, got {self.sh_degree!r}")


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def bench_render(
    config: RenderBenchConfig | None = None,
    *,
    log: Callable[[str], None] | None = _stderr,
    **overrides: Any,
) -> dict[str, Any]:
    """Time ``render`` on ``tabletop_scene(gaussians, sh_degree, seed)`` from ``orbit_cameras(views, size, size)``.

    Either pass a ``RenderBenchConfig`` or its fields as keywords (``bench_render(gaussians=2000,
    size=64)``); keywords override the config's fields. ``log`` receives progress lines (None: quiet).
    Returns ``{"backend", "gaussians", "width", "height", "sh_degree", "cameras_per_call", "ms_median",
    "ms_min", "ms_max", "ms_per_camera", "runs"}`` with the resolved backend, times of one call in
    milliseconds rounded to 0.01 (``ms_per_camera``: the median divided by the cameras per call) and ``runs``
    the number of timed calls.
    """
    known = {f.name for f in fields(RenderBenchConfig)}
    unknown = sorted(set(overrides) - known)
    if unknown:
        raise TypeError(f"bench_render got unknown option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    cfg = replace(config or RenderBenchConfig(), **overrides)
    cfg.validate()
    say = log or (lambda _msg: None)

    import torch

    from ..gaussians.render import render, render_cameras, resolve_backend
    from ..gaussians.synthetic import orbit_cameras, tabletop_scene

    backend = resolve_backend(cfg.backend)
    t0 = time.perf_counter()
    g = tabletop_scene(cfg.gaussians, cfg.sh_degree, cfg.seed)
    device = torch.device("cuda" if backend == "cuda" else "cpu")
    # Inputs live where the renderer works, so host-device copies are not part of the timing.
    g = g.to(device)
    cams = [
        (torch.from_numpy(vm).to(device), torch.from_numpy(K).to(device))
        for vm, K in orbit_cameras(cfg.views, cfg.size, cfg.size, seed=cfg.seed)
    ]
    say(
        f"bench render: tabletop scene of {cfg.gaussians:,} Gaussians (SH {cfg.sh_degree}) "
        f"in {time.perf_counter() - t0:.2f} s"
    )

    C = cfg.cameras_per_call
    # One call's cameras (C > 1): C consecutive orbit views (wrapping), stacked where the renderer works.
    batches = [
        tuple(torch.stack([cams[(i + j) % len(cams)][k] for j in range(C)]) for k in (0, 1))
        for i in range(len(cams) if C > 1 else 0)
    ]

    def call(i: int) -> None:
        if C == 1:
            render(g, cams[i][0], cams[i][1], cfg.size, cfg.size, backend=backend)
        else:
            render_cameras(g, batches[i][0], batches[i][1], cfg.size, cfg.size, backend=backend)

    def sync() -> None:
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    times_ms: list[float] = []
    with torch.no_grad():
        t0 = time.perf_counter()
        for i in range(cfg.warmup):
            call(i % len(cams))
        sync()
        if cfg.warmup:
            say(f"bench render: {cfg.warmup} warm-up render(s) on {backend} in {time.perf_counter() - t0:.2f} s")
        for _ in range(cfg.repeats):
            for i in range(len(cams)):
                sync()
                start = time.perf_counter()
                call(i)
                sync()
                times_ms.append((time.perf_counter() - start) * 1e3)
    say(
        f"bench render: {len(times_ms)} timed calls of {C} camera(s) at {cfg.size}x{cfg.size}, "
        f"median {statistics.median(times_ms):.2f} ms"
    )

    return {
        "backend": backend,
        "gaussians": cfg.gaussians,
        "width": cfg.size,
        "height": cfg.size,
        "sh_degree": cfg.sh_degree,
        "cameras_per_call": C,
        "ms_median": round(statistics.median(times_ms), 2),
        "ms_min": round(min(times_ms), 2),
        "ms_max": round(max(times_ms), 2),
        "ms_per_camera": round(statistics.median(times_ms) / C, 3),
        "runs": len(times_ms),
    }
