"""Plan a 3DGS training run that fits a wall-clock budget on this machine.

The iteration count comes from the measured time of one step on the initial Gaussians (x
``growth`` for the larger model densification makes); the densification, SH and evaluation
schedules scale with it, and ``max_seconds`` stops the run at the budget whatever happens.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from .model import Gaussians
from .train import TrainConfig, View, view_loss

__all__ = ["budgeted_config", "estimate_step_seconds"]


def estimate_step_seconds(g: Gaussians, views: Sequence[View], config: TrainConfig, n: int = 3) -> float:
    """Median seconds of one training step (render + loss + backward) of ``g`` on ``views``."""
    params = {k: v.detach().clone().requires_grad_(True) for k, v in g.tensors().items()}
    g2 = Gaussians(params["means"], params["quats"], params["log_scales"], params["logit_opacities"], params["sh"])
    times = []
    for i in range(n + 1):  # the first call compiles / warms the numba kernels
        t0 = time.perf_counter()
        loss, _ = view_loss(g2, views[i % len(views)], config)
        loss.backward()
        times.append(time.perf_counter() - t0)
    return float(np.median(times[1:]))


def budgeted_config(
    step_seconds: float,
    minutes: float,
    base: TrainConfig | None = None,
    growth: float = 2.5,
    densify_fraction: float = 0.55,
    curve_points: int = 12,
    min_iterations: int = 100,
) -> TrainConfig:
    """``base`` with iterations, schedules and ``max_seconds`` planned for ``minutes`` of training."""
    if not minutes > 0:
        raise ValueError(f"minutes must be positive, got {minutes}")
    base = base or TrainConfig()
    budget = 60.0 * minutes
    iterations = max(min_iterations, int(budget / (growth * max(step_seconds, 1e-4))))
    return replace(
        base,
        iterations=iterations,
        max_seconds=budget,
        refine_start=min(500, iterations // 15),
        refine_stop=int(densify_fraction * iterations),
        refine_every=max(10, min(100, iterations // 60)),
        sh_increase_every=max(100, iterations // 8),
        eval_every=max(1, iterations // curve_points),
    )
