"""A 3DGS training run that fits a wall-clock budget: the one configuration ``m2m train-scene --minutes``
and ``m2m bench train --minutes`` both train with (one code path, so the benchmark times what users run).

Nothing is planned from a measured step: the run ends when its training time is spent, and its schedules
(densification, SH degree, learning-rate decay, evaluations) are fractions of the budget
(``schedule.py``), so the same minutes fit a 2-core CPU, a GPU or a loaded machine.
"""

from __future__ import annotations

from dataclasses import replace

from .train import TrainConfig

__all__ = ["COARSE_FRACTION", "DENSIFY_FRACTION", "LR_COOLDOWN", "budget_config"]

# Densify for this fraction of the training time. The planner this replaces densified for 55 % of its
# planned steps, which was 40-45 % of the time (steps get ~2.5x slower as densification adds Gaussians);
# on fox, 4 minutes (CPU, 1/4 resolution): see the commit that set it for the measurements.
DENSIFY_FRACTION = 0.45
# Train on half-resolution views for this fraction of the time (DashGaussian's observation: early steps fit
# low frequencies, which a quarter of the pixels carry; at the start, when the few initial Gaussians are
# large, a quarter of the pixels is close to a quarter of the step). On fox, 4 minutes (CPU, 1/4 resolution):
# 28.8 dB without it, 31.7 / 32.1 / 31.6 dB with 0.2 / 0.3 / 0.5 (one run each; 0.3 over three: 31.0-32.1).
COARSE_FRACTION = 0.3
# Cool the other learning rates (opacity, scales, rotations, colours) down to a tenth over this last fraction
# of the time, as the means' decay all run: at constant rates the held-out PSNR of fox's 15-minute runs
# jittered by 0.1-0.3 dB between the last evaluations, and a run ended wherever the jitter left it. On fox,
# 15 minutes (CPU, 1/4 resolution, three runs each): 33.70 / 33.87 / 33.97 dB without, 34.03 / 34.19 / 34.29 with.
LR_COOLDOWN = 0.3


def budget_config(
    minutes: float,
    base: TrainConfig | None = None,
    densify_fraction: float = DENSIFY_FRACTION,
    curve_points: int = 12,
    coarse_fraction: float = COARSE_FRACTION,
    lr_cooldown: float = LR_COOLDOWN,
) -> TrainConfig:
    """``base`` set to train for ``minutes`` of training time: no step limit, views at half resolution for the
    first ``coarse_fraction`` of the time, densification from 1/15 to ``densify_fraction`` of it, SH raised every
    1/8, the learning rates cooled down over the last ``lr_cooldown``, ``curve_points`` evaluations along the
    way."""
    if not minutes > 0:
        raise ValueError(f"minutes must be positive, got {minutes}")
    if not 0 < densify_fraction <= 1:
        raise ValueError(f"densify_fraction must be in (0, 1], got {densify_fraction}")
    if not 0 <= coarse_fraction < 1:
        raise ValueError(f"coarse_fraction must be in [0, 1), got {coarse_fraction}")
    base = base or TrainConfig()
    return replace(
        base,
        iterations=0,
        max_seconds=60.0 * minutes,
        refine_start=min(1 / 15, densify_fraction / 2),
        refine_stop=densify_fraction,
        refine_every=None,
        sh_increase_every=0.125,
        eval_points=curve_points,
        coarse_fraction=coarse_fraction,
        coarse_factor=2,
        lr_cooldown=lr_cooldown,
    )
