"""3D Gaussian Splatting training (paper section 3.1, DESIGN.md section 2).

Loss L1 + lambda * (1 - SSIM) over valid pixels, Adam with the per-parameter learning rates of
3DGS (means scaled by the scene extent and decayed exponentially; optionally the others cooled down at
the end), the SH degree raised during the run, densification / pruning by gsplat's ``DefaultStrategy``
operations (pure torch, so they run on the CPU too) with a cap on the number of Gaussians, optionally a
coarse start (the views at a fraction of their resolution for the first part of the run), held-out
evaluation, and atomic checkpoints that ``train(..., resume=True)`` resumes. A run ends at ``iterations``
steps or ``max_seconds`` of training, whichever is first, and every schedule follows the run's progress
(``schedule.py``), so a time budget holds on any device.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import torch

from ..atomic import atomic_path
from ..progress import progress_bar
from .filter3d import apply_3d_filter, check_variance, max_sampling_rate
from .losses import l1, psnr, ssim
from .model import Gaussians
from .render import gpu_out_of_memory, render, resolve_backend
from .schedule import RunLength, Schedule
from .sh import num_sh_bases, rgb_to_sh_dc

__all__ = [
    "TrainConfig",
    "View",
    "downsample_view",
    "init_gaussians_from_points",
    "scene_extent",
    "train",
    "view_loss",
]


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
    max_gaussians: int = 1_000_000
    eval_points: int = 0  # evaluations spread evenly over the run; 0: only before and after training
    checkpoint_every: int = 1000
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


@dataclass
class View:
    """One training / evaluation photo: image [H,W,3] float in [0,1], viewmat [4,4] world-to-camera
    (OpenCV axes), K [3,3] (pixel centres at +0.5), optional mask [H,W] bool of valid pixels.

    Optional, for object training: ``background`` [H,W,3] is composited behind the render instead
    of ``TrainConfig.background`` (e.g. the table seen from other views), and ``alpha_mask`` [H,W]
    bool marks where rendered alpha may be non-zero (``TrainConfig.lambda_alpha`` penalises it
    elsewhere)."""

    image: torch.Tensor
    viewmat: torch.Tensor
    K: torch.Tensor
    mask: torch.Tensor | None = None
    name: str = ""
    background: torch.Tensor | None = None
    alpha_mask: torch.Tensor | None = None

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def height(self) -> int:
        return int(self.image.shape[0])


def downsample_view(view: View, factor: int) -> View:
    """``view`` at 1/``factor`` resolution: images area-averaged over factor x factor blocks (cropped to a
    multiple of it, so pixel edges stay put), K scaled by 1/factor, a pixel valid only where its whole
    block is, and allowed alpha wherever any of its block is."""
    f = int(factor)
    if f == 1:
        return view
    h, w = view.height // f, view.width // f
    if h < 1 or w < 1:
        raise ValueError(f"factor {f} leaves no pixels of a {view.width}x{view.height} view")

    def pool(img: torch.Tensor | None, how: str) -> torch.Tensor | None:
        if img is None:
            return None
        x = img[: h * f, : w * f]
        x = x.reshape(h, f, w, f, *x.shape[2:])
        if how == "mean":
            return x.float().mean(dim=(1, 3)).to(img.dtype)
        return x.all(dim=3).all(dim=1) if how == "all" else x.any(dim=3).any(dim=1)

    K = torch.as_tensor(view.K).clone()
    K[:2] = K[:2] / f
    return View(pool(view.image, "mean"), view.viewmat, K, pool(view.mask, "all"), view.name,
                pool(view.background, "mean"), pool(view.alpha_mask, "any"))  # fmt: skip


def scene_extent(views: Sequence[View]) -> float:
    """3DGS's "cameras extent": 1.1 x the largest distance of a camera centre from their mean."""
    centres = []
    for v in views:
        vm = torch.as_tensor(v.viewmat, dtype=torch.float64).cpu()
        centres.append(-vm[:3, :3].T @ vm[:3, 3])
    c = torch.stack(centres)
    radius = float((c - c.mean(0)).norm(dim=1).max()) if len(centres) > 1 else 0.0
    return 1.1 * max(radius, 1e-2)


def init_gaussians_from_points(
    points: torch.Tensor | np.ndarray, colors: torch.Tensor | np.ndarray, sh_degree: int = 3
) -> Gaussians:
    """Initial Gaussians at ``points`` [M,3] with ``colors`` [M,3] in 0..1: isotropic, scale = mean
    distance to the 3 nearest neighbours, identity rotation, opacity 0.1, higher SH bands zero."""
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64)
    cols = np.asarray(colors, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or cols.shape != pts.shape or len(pts) < 2:
        raise ValueError(f"need points [M,3] (M >= 2) and colors of the same shape, got {pts.shape} and {cols.shape}")
    k = min(4, len(pts))
    d, _ = cKDTree(pts).query(pts, k=k)  # the first neighbour is the point itself
    dist = np.maximum(d[:, 1:].mean(axis=1), 1e-7)
    m = len(pts)
    means = torch.as_tensor(pts, dtype=torch.float32)
    quats = torch.zeros(m, 4)
    quats[:, 0] = 1.0
    log_scales = torch.as_tensor(np.log(dist), dtype=torch.float32)[:, None].repeat(1, 3)
    logit_op = torch.full((m,), math.log(0.1 / 0.9))
    sh = torch.zeros(m, num_sh_bases(sh_degree), 3)
    sh[:, 0] = rgb_to_sh_dc(torch.as_tensor(cols, dtype=torch.float32).clamp(0, 1))
    return Gaussians(means, quats, log_scales, logit_op, sh)


# ---- parameters <-> Gaussians -------------------------------------------------------------------
FILTER_3D_EVERY = 100  # steps between recomputations of the 3D filter's sampling rates (and after refinements)

# gsplat's strategy wants a flat dict of parameters with "means", "scales", "quats", "opacities";
# we keep log scales and logit opacities under those names (as gsplat's own trainer does) and
# split SH into DC and rest because they have different learning rates.
_PARAM_NAMES = ("means", "quats", "scales", "opacities", "sh0", "shN")


def _to_params(g: Gaussians, sh_degree: int, device: torch.device) -> dict[str, torch.nn.Parameter]:
    g = g.with_sh_degree(sh_degree).to(device, torch.float32)
    raw = {
        "means": g.means,
        "quats": g.quats,
        "scales": g.log_scales,
        "opacities": g.logit_opacities,
        "sh0": g.sh[:, :1],
        "shN": g.sh[:, 1:],
    }
    return {k: torch.nn.Parameter(v.detach().clone().contiguous()) for k, v in raw.items()}


def _to_gaussians(params: dict[str, torch.Tensor], degree: int) -> Gaussians:
    """The model seen by the renderer, with only the first ``degree`` SH bands active."""
    k = num_sh_bases(degree)
    sh = params["sh0"] if k == 1 else torch.cat([params["sh0"], params["shN"][:, : k - 1]], dim=1)
    return Gaussians(params["means"], params["quats"], params["scales"], params["opacities"], sh)


def _make_optimizers(
    params: dict[str, torch.nn.Parameter], lr: dict[str, float], extent: float
) -> dict[str, torch.optim.Optimizer]:
    opts = {}
    for k, p in params.items():
        rate = lr[k] * (extent if k == "means" else 1.0)
        # eps 1e-15 as in 3DGS: gradients of far-away Gaussians are tiny and must still move them. fused:
        # one kernel per tensor; on 2 CPU cores, Adam over 150k Gaussians took 46-66 ms instead of 440-680 ms
        # with the default (foreach) implementation, the same update
        opts[k] = torch.optim.Adam([{"params": [p], "lr": rate, "name": k}], eps=1e-15, fused=True)
    return opts


def _schedule(config: TrainConfig, extent: float) -> Schedule:
    return Schedule(
        sh_degree=config.sh_degree,
        sh_increase_every=config.sh_increase_every,
        refine_start=config.refine_start,
        refine_stop=config.refine_stop,
        refine_every=config.refine_every,
        opacity_reset_every=config.opacity_reset_every,
        eval_points=config.eval_points,
        lr0=config.lr["means"] * extent,
        lr1=config.lr["means_final"] * extent,
        cooldown=config.lr_cooldown,
        cooldown_ratio=config.lr_cooldown_ratio,
    )


# ---- densification ------------------------------------------------------------------------------
def _make_strategy(config: TrainConfig):
    from gsplat.strategy import DefaultStrategy

    @dataclass
    class CappedStrategy(DefaultStrategy):
        """gsplat's DefaultStrategy growth and pruning, refined when the run's schedule says (not at
        gsplat's fixed steps), that never grows past ``max_gaussians``: when more Gaussians qualify
        than there is room for, only the ones with the largest screen-space gradient grow (each
        clone or split adds exactly one)."""

        max_gaussians: int = 1_000_000

        def update(self, params, optimizers, state, info: dict, refine: bool, step: int) -> None:
            """Accumulate this step's screen-space gradients; with ``refine``, grow, prune and restart
            the statistics (what ``step_post_backward`` does at its refinement steps)."""
            self._update_state(params, state, info, packed=False)
            if not refine:
                return
            self._grow_gs(params, optimizers, state, step)
            self._prune_gs(params, optimizers, state, step)
            state["grad2d"].zero_()
            state["count"].zero_()
            if self.refine_scale2d_stop_iter > 0:
                state["radii"].zero_()

        def _update_state(self, params, state, info, packed=False):
            # gsplat's, for one camera and packed=False, without its gather / index_add round trip: the
            # same sums (|grad2d| in normalised screen units, visible-view counts) at ~1/5 of the time
            if packed or self.absgrad or self.refine_scale2d_stop_iter > 0:  # not our configuration
                return super()._update_state(params, state, info, packed)
            grads = info[self.key_for_gradient].grad[0]  # [N,2]
            visible = (info["radii"][0] > 0).all(dim=-1)
            scale = grads.new_tensor([info["width"] / 2.0, info["height"] / 2.0])
            norm = torch.where(visible, (grads * scale).norm(dim=-1), 0.0)
            if state["grad2d"] is None:
                state["grad2d"] = torch.zeros_like(norm)
            if state["count"] is None:
                state["count"] = torch.zeros_like(norm)
            state["grad2d"] += norm
            state["count"] += visible

        def _grow_gs(self, params, optimizers, state, step):
            room = self.max_gaussians - len(params["means"])
            if room <= 0:
                return 0, 0
            grads = state["grad2d"] / state["count"].clamp_min(1)
            base = self.grow_grad2d
            if int((grads > base).sum()) > room:
                self.grow_grad2d = max(base, float(torch.topk(grads, room + 1).values[-1]))
            try:
                return super()._grow_gs(params, optimizers, state, step)
            finally:
                self.grow_grad2d = base

    return CappedStrategy(
        prune_opa=config.prune_opa,
        grow_grad2d=config.grow_grad2d,
        # In 1.5.3 this only gates pruning of Gaussians larger than 0.1 x extent (its reset never
        # fires). 3DGS starts that at step 3000 of 30000; in short runs from sparse points it
        # deletes the walls and floor before densification has replaced them, so it is off here.
        reset_every=2**62,
        max_gaussians=config.max_gaussians,
    )


def _strategy_info(info: dict, view: View, n: int) -> dict | None:
    """Adapt our renderer's ``info`` (mean2d [N,2] or gsplat's [1,N,2], radius [N,2]) to what
    gsplat's strategy reads after backward: ``means2d.grad`` [1,N,2], ``radii`` [1,N,2]."""
    m2d = info.get("mean2d")
    if m2d is None or m2d.grad is None:
        return None
    return {
        "means2d": SimpleNamespace(grad=m2d.grad.reshape(1, n, 2)),
        "radii": info["radius"].reshape(1, n, 2),
        "width": view.width,
        "height": view.height,
        "n_cameras": 1,
        "gaussian_ids": None,
    }


# ---- loss and evaluation ------------------------------------------------------------------------
def view_loss(
    g: Gaussians, view: View, config: TrainConfig, info: dict | None = None, backend: str | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(loss, rendered rgb [H,W,3]) of ``g`` against ``view``: (1-l) L1 + l (1 - SSIM) over the
    view's valid pixels (pixels outside the mask affect neither the loss nor its gradient)."""
    dev = g.means.device
    out, rgb = _render_view(g, view, config, info, backend)
    gt = view.image.to(dev)
    mask = None if view.mask is None else view.mask.to(dev)
    lam = config.lambda_dssim
    loss = (1 - lam) * l1(rgb, gt, mask)
    if lam > 0:
        loss = loss + lam * (1 - ssim(rgb, gt, mask=mask))
    if config.lambda_alpha > 0 and view.alpha_mask is not None:
        outside = ~view.alpha_mask.to(dev)
        if bool(outside.any()):
            loss = loss + config.lambda_alpha * out.alpha[outside].mean()
    if config.lambda_opacity > 0:
        o = torch.sigmoid(g.logit_opacities)
        loss = loss + config.lambda_opacity * (o * (1 - o)).mean()
    return loss, rgb


def _render_view(g: Gaussians, view: View, config: TrainConfig, info: dict | None = None, backend: str | None = None):
    """(render output, rgb [H,W,3]) with the view's own background image when it has one."""
    dev = g.means.device
    bg = torch.tensor(config.background, dtype=torch.float32, device=dev)
    if view.background is not None:
        bg = torch.zeros(3, device=dev)
    out = render(g, view.viewmat, view.K, view.width, view.height, bg, backend or config.backend, info)
    rgb = out.rgb
    if view.background is not None:
        rgb = rgb + (1 - out.alpha)[..., None] * view.background.to(dev)
    return out, rgb


@torch.no_grad()
def evaluate(g: Gaussians, views: Sequence[View], config: TrainConfig, backend: str | None = None) -> dict[str, Any]:
    """Mean PSNR / SSIM over ``views`` (valid pixels only) and the per-view values."""
    per_view = []
    for v in views:
        rgb = _render_view(g, v, config, None, backend)[1].clamp(0, 1)
        gt = v.image.to(rgb.device)
        mask = None if v.mask is None else v.mask.to(rgb.device)
        per_view.append({"name": v.name, "psnr": float(psnr(rgb, gt, mask)), "ssim": float(ssim(rgb, gt, mask=mask))})
    if not per_view:
        return {"psnr": math.nan, "ssim": math.nan, "views": []}
    return {
        "psnr": float(np.mean([p["psnr"] for p in per_view])),
        "ssim": float(np.mean([p["ssim"] for p in per_view])),
        "views": per_view,
    }


# ---- checkpoints --------------------------------------------------------------------------------
def _save_checkpoint(path: Path, params, optimizers, strategy_state, step: int, extra: dict) -> None:
    blob = {
        "step": step,
        "params": {k: v.detach().cpu() for k, v in params.items()},
        "optimizers": {k: o.state_dict() for k, o in optimizers.items()},
        "strategy_state": strategy_state,
        "torch_rng": torch.get_rng_state(),
        **extra,
    }
    with atomic_path(path) as tmp:
        torch.save(blob, tmp)


def _view_order(n: int, seed: int, epoch: int) -> np.ndarray:
    """Training views visit order for one epoch; a function of (seed, epoch) so that a resumed
    run sees the same sequence as an uninterrupted one."""
    return np.random.default_rng([seed, epoch]).permutation(n)


# ---- the loop -----------------------------------------------------------------------------------
def train(
    views_train: Sequence[View],
    views_eval: Sequence[View],
    init: Gaussians,
    config: TrainConfig,
    callback: Callable[[int, dict[str, Any]], None] | None = None,
    progress: bool = True,
    checkpoint_path: str | Path | None = None,
    resume: bool = False,
    clock: Callable[[], float] = time.perf_counter,
) -> tuple[Gaussians, dict[str, Any]]:
    """Train ``init`` on ``views_train``; returns (trained Gaussians, metrics).

    metrics: ``psnr``/``ssim`` (mean over ``views_eval``), ``views`` (per view), ``initial``
    (the same before training), ``curve`` (list of {step, seconds, psnr, ssim, gaussians}; seconds
    count training time only), ``iterations``, ``gaussians``, ``seconds``, ``backend``, ``schedule``
    (where it ended: ``progress``, ``sh_degree``, ``means_lr``, ``refinements`` [(step, progress,
    Gaussians after)]). ``callback(step, {"loss", "gaussians"})`` runs after every step. With
    ``checkpoint_path`` a checkpoint is written atomically every ``config.checkpoint_every`` steps and at
    the end; ``resume=True`` continues from it when it exists (Gaussians, Adam moments, strategy state,
    step, training time, schedule state, RNG and the curve so far). ``clock`` (seconds) times the steps;
    tests inject a slow or fast one.
    """
    if not views_train:
        raise ValueError("train needs at least one training view")
    length = config.run_length()  # validates iterations and max_seconds
    if not length.bounded:
        raise ValueError("train needs iterations > 0 or a max_seconds budget")
    if not (0 <= config.coarse_fraction <= 1 and int(config.coarse_factor) >= 1):
        raise ValueError(f"coarse_fraction must be in [0, 1] and coarse_factor >= 1, got {config.coarse_fraction} "
                         f"and {config.coarse_factor}")  # fmt: skip
    check_variance(config.filter_3d)
    if not (0 <= config.lr_cooldown <= 1 and 0 < config.lr_cooldown_ratio <= 1):
        raise ValueError(f"lr_cooldown must be in [0, 1] and lr_cooldown_ratio in (0, 1], got {config.lr_cooldown} "
                         f"and {config.lr_cooldown_ratio}")  # fmt: skip
    backend = resolve_backend(config.backend)
    device = torch.device("cuda" if backend == "cuda" else "cpu")
    extent = scene_extent(views_train)
    ckpt = Path(checkpoint_path) if checkpoint_path is not None else None

    strategy = _make_strategy(config) if config.densify else None
    params = _to_params(init, config.sh_degree, device)
    optimizers = _make_optimizers(params, config.lr, extent)
    strategy_state = strategy.initialize_state(scene_scale=extent) if strategy else None
    if strategy:
        strategy.check_sanity(params, optimizers)
    schedule = _schedule(config, extent)
    step, elapsed, curve, initial = 0, 0.0, [], None
    torch.manual_seed(config.seed)  # gsplat's split samples with torch.randn

    if resume and ckpt is not None and ckpt.exists():
        blob = torch.load(ckpt, map_location=device, weights_only=False)
        params = {k: torch.nn.Parameter(v.to(device)) for k, v in blob["params"].items()}
        optimizers = _make_optimizers(params, config.lr, extent)
        for k, o in optimizers.items():
            o.load_state_dict(blob["optimizers"][k])
        strategy_state = blob["strategy_state"]
        step, elapsed, curve, initial = blob["step"], blob["elapsed"], blob["curve"], blob["initial"]
        schedule.load_state_dict(blob["schedule"])
        torch.set_rng_state(blob["torch_rng"])

    nu: torch.Tensor | None = None  # the 3D filter's sampling rates [N], recomputed as the Gaussians change

    def refresh_filter() -> None:
        nonlocal nu
        if config.filter_3d > 0:
            nu = max_sampling_rate(params["means"], views_train)

    def model(degree: int) -> Gaussians:
        g = _to_gaussians(params, degree)
        return g if nu is None else apply_3d_filter(g, nu, config.filter_3d)

    def g_now(degree: int | None = None) -> Gaussians:
        return model(config.sh_degree if degree is None else degree)

    refresh_filter()

    def checkpoint(at: int) -> None:
        if ckpt is not None:
            extra = {"elapsed": elapsed, "curve": curve, "initial": initial, "config": asdict(config),
                     "schedule": schedule.state_dict()}  # fmt: skip
            _save_checkpoint(ckpt, params, optimizers, strategy_state, at, extra)

    def record(at: int) -> dict[str, Any]:
        # bands not yet active are still zero, so the full-degree model renders what was trained
        m = evaluate(g_now().detach(), views_eval, config, backend)
        curve.append(
            {
                "step": at,
                "seconds": round(elapsed, 3),
                "psnr": m["psnr"],
                "ssim": m["ssim"],
                "gaussians": len(params["means"]),
            }
        )
        return m

    if initial is None:
        initial = evaluate(g_now(0).detach(), views_eval, config, backend)
        curve.append(
            {
                "step": 0,
                "seconds": 0.0,
                "psnr": initial["psnr"],
                "ssim": initial["ssim"],
                "gaussians": len(params["means"]),
            }
        )

    if not length.finished(step, elapsed):
        # one untimed forward + backward on a copy: numba compiles or loads its kernels (~35 s to compile
        # the training step's on a busy 2-core machine, which the first step of a 4-minute budget paid),
        # CUDA and gsplat initialise, so the budget buys training steps only
        warm = _to_gaussians(params, config.sh_degree).map(lambda t: t.detach().clone().requires_grad_(True))
        view_loss(warm, views_train[0], config, {}, backend)[0].backward()

    bar = None
    if progress:
        total = config.iterations if config.max_seconds is None else None  # a time budget: no step count
        bar = progress_bar(total=total, initial=step, desc="train", dynamic_ncols=True)
    n_views = len(views_train)
    coarse: dict[int, View] = {}  # training views at 1/coarse_factor, made on first use
    # the next step is expected to take the median of the last five (robust to one step stalled by a
    # busy machine): the run stops before a step that would end past the budget
    recent: deque[float] = deque(maxlen=5)
    p, lr, lr_scale, degree = length.fraction(step, elapsed), schedule.means_lr(0.0), 1.0, 0
    step_share = 1.0 / config.iterations if config.iterations else 0.0  # progress of one step (the last one's)
    try:
        while not length.finished(step, elapsed, float(np.median(recent)) if recent else 0.0):
            t0 = clock()
            p = length.fraction(step, elapsed)
            index = int(_view_order(n_views, config.seed, step // n_views)[step % n_views])
            view = views_train[index]
            if p < config.coarse_fraction:
                if index not in coarse:
                    coarse[index] = downsample_view(view, config.coarse_factor)
                view = coarse[index]
            lr = schedule.means_lr(p)
            optimizers["means"].param_groups[0]["lr"] = lr
            lr_scale = schedule.lr_scale(p)
            for k, o in optimizers.items():
                if k != "means":
                    o.param_groups[0]["lr"] = config.lr[k] * lr_scale
            degree = schedule.active_sh_degree(p)
            info: dict = {}
            try:
                loss, _ = view_loss(model(degree), view, config, info, backend)
                loss.backward()
            except torch.cuda.OutOfMemoryError as e:
                lower = "--max-gaussians (the densification cap) or the image size (--downscale)"
                raise gpu_out_of_memory("training", len(params["means"]), view.width, view.height, lower) from e
            refine = False
            if strategy is not None and schedule.densifying(p):
                refine = schedule.refine_now(step + 1, p, step_share)
                sinfo = _strategy_info(info, view, len(params["means"]))
                if sinfo is not None:  # None: nothing was rendered (no Gaussians), so nothing to refine
                    strategy.update(params, optimizers, strategy_state, sinfo, refine, step + 1)
                if refine:
                    schedule.refinements[-1] = (*schedule.refinements[-1], len(params["means"]))
            for o in optimizers.values():
                o.step()
                o.zero_grad(set_to_none=True)
            step += 1
            if nu is not None and (refine or step % FILTER_3D_EVERY == 0):
                refresh_filter()  # after a refinement (added / removed Gaussians) and as the means move
            dt = clock() - t0
            elapsed += dt
            recent.append(dt)
            p_after = length.fraction(step, elapsed)
            step_share = p_after - p
            if schedule.opacity_reset_now(p, p_after):
                from gsplat.strategy.ops import reset_opa

                reset_opa(params, optimizers, strategy_state or {}, value=config.prune_opa * 2)
            stats = {"loss": float(loss.detach()), "gaussians": len(params["means"])}
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{stats['loss']:.4f}", n=stats["gaussians"], p=f"{p_after:.2f}", refresh=False)
            if callback is not None:
                callback(step, stats)
            if schedule.eval_now(p_after):
                record(step)
            if config.checkpoint_every and step % config.checkpoint_every == 0 and not length.finished(step, elapsed):
                checkpoint(step)
    finally:
        if bar is not None:
            bar.close()

    last = record(step)
    checkpoint(step)
    final = g_now().detach()
    metrics = {
        "psnr": last["psnr"],
        "ssim": last["ssim"],
        "views": last["views"],
        "initial": {"psnr": initial["psnr"], "ssim": initial["ssim"]},
        "curve": curve,
        "iterations": step,
        "gaussians": len(final),
        "seconds": elapsed,
        "backend": backend,
        "schedule": {
            "progress": length.fraction(step, elapsed),
            "last_step_progress": p,
            "sh_degree": degree,
            "means_lr": lr,
            "lr_scale": lr_scale,
            "refinements": [list(r) for r in schedule.refinements],
        },
    }
    return final.to("cpu"), metrics
