"""3DGS training settings (no torch here: the stages' Configs and the command line read their defaults)."""

from __future__ import annotations

from dataclasses import dataclass, field

from .schedule import RunLength

__all__ = ["FILTER_3D_VARIANCE", "TrainConfig"]

FILTER_3D_VARIANCE = 0.2  # squared training pixels (Mip-Splatting's)


def _default_lr() -> dict[str, float]:
    # 3DGS defaults; "means"/"means_final" are multiplied by the scene extent.
    return {
        "means": 1.6e-4,
        "means_final": 1.6e-6,
        "quats": 1e-3,
        "scales": 5e-3,
        "opacities": 5e-2,
        "sh0": 2.5e-3,
        "shN": 2.5e-3 / 20,
    }


@dataclass
class TrainConfig:
    """Training hyper-parameters. The run ends after ``iterations`` steps or ``max_seconds`` of training
    time, whichever comes first; the schedule fields are fractions of that run (``schedule.py``)."""

    iterations: int = 7000  # steps; 0: no step limit (``max_seconds`` ends the run)
    # training time; counts the steps only (evaluations and checkpoints are extra). The last step is
    # the last one expected to end within it, so a run uses the budget and does not overrun it.
    max_seconds: float | None = None
    lambda_dssim: float = 0.2
    sh_degree: int = 3
    sh_increase_every: float = 0.125  # fraction of the run between raises of the active SH degree
    lr: dict[str, float] = field(default_factory=_default_lr)
    densify: bool = True
    refine_start: float = 1 / 30  # densification refines from this fraction of the run ...
    refine_stop: float = 0.5  # ... up to this one (3DGS: 500 and 15000 of 30000 steps)
    refine_every: int | None = None  # steps between refinements; None: 1/60 of the run, 10..100 steps
    grow_grad2d: float = 2e-4
    prune_opa: float = 0.005
    opacity_reset_every: float = 0.0  # fraction of the run between opacity resets; 0: off (as gsplat 1.5.3's)
    # the scene's cap and checkpoint cadence: the scene stage's defaults are these (stages/scene.py reads them; m2m
    # bench train trains with them); object training passes its own
    max_gaussians: int = 200_000
    eval_points: int = 0  # evaluations spread evenly over the run; 0: only before and after training
    checkpoint_every: int = 200  # steps between the checkpoints of train(checkpoint_path=...); 0: only the last
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    backend: str = "auto"
    seed: int = 0
    # weight of the mean rendered alpha outside a view's ``alpha_mask`` (object training: no
    # background may be carried by the Gaussians); 0 leaves scene training unchanged
    lambda_alpha: float = 0.0
    # weight of mean o (1 - o) over the Gaussians' opacities o: pushes each to 0 or 1, so a surface is
    # drawn by opaque Gaussians on it rather than a haze of faint ones around an opaque core; 0 = off
    lambda_opacity: float = 0.0
    # train on views downsampled by ``coarse_factor`` for the first ``coarse_fraction`` of the run (0: off):
    # early steps fit the low frequencies, which a quarter of the pixels carry at a quarter of the cost
    coarse_fraction: float = 0.0
    coarse_factor: int = 2
    # over the last ``lr_cooldown`` of the run every learning rate but the means' (which decay all run) decays
    # exponentially to ``lr_cooldown_ratio`` of its value: the run ends on a settled model rather than on one
    # still jittering at full step size (0: off, 3DGS's constant rates)
    lr_cooldown: float = 0.0
    lr_cooldown_ratio: float = 0.1
    # Mip-Splatting's 3D smoothing filter (``filter3d``): every Gaussian trained and returned convolved with an
    # isotropic Gaussian of this variance in squared training pixels at the finest rate any view sampled it
    # (0.2 in the paper), so closer or sharper views than the training ones do not sparkle (0: off)
    filter_3d: float = 0.0

    def run_length(self) -> RunLength:
        return RunLength(self.iterations, self.max_seconds)
