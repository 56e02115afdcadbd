"""3D Gaussian Splatting training (paper section 3.1, DESIGN.md section 2).

Loss L1 + lambda * (1 - SSIM) over valid pixels, Adam with the per-parameter learning rates of
3DGS (means scaled by the scene extent and decayed exponentially; optionally the others cooled down at
the end), the SH degree raised during the run, densification / pruning by gsplat's ``DefaultStrategy``
operations (pure torch, so they run on the CPU too) with a cap on the number of Gaussians, optionally a
coarse start (the views at a fraction of their resolution for the first part of the run), held-out
evaluation, and atomic checkpoints that ``train(..., resume=True)`` resumes. :class:`Trainer` is one run, a
step at a time (``step()``, ``save_checkpoint()``, ``resume()``); :func:`train` is the loop over it. A run ends at
``iterations`` steps or ``max_seconds`` of training, whichever is first, and every schedule follows the run's
progress (``schedule.py``), so a time budget holds on any device.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Protocol

import numpy as np
import torch
from torch.profiler import record_function

from ..atomic import atomic_path
from ..progress import progress_bar
from .config import TrainConfig
from .filter3d import apply_3d_filter, check_variance, max_sampling_rate
from .losses import l1, psnr, ssim
from .model import Gaussians
from .render import gpu_out_of_memory, render, resolve_backend
from .schedule import Schedule
from .sh import num_sh_bases, rgb_to_sh_dc

__all__ = [
    "TrainConfig",
    "Trainer",
    "View",
    "downsample_view",
    "init_gaussians_from_points",
    "scene_extent",
    "train",
    "view_loss",
]


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


# ---- the trainer --------------------------------------------------------------------------------
class Constraint(Protocol):
    """Where the Gaussians may be: called with (means [N,3], quats [N,4], log_scales [N,3]) every ``every`` steps and
    after the last, it returns the means and log-scales moved back into bounds (e.g. ``objects.within_mesh``)."""

    every: int

    def __call__(self, means: torch.Tensor, quats: torch.Tensor,
                 log_scales: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]: ...  # fmt: skip


def _view_order(n: int, seed: int, epoch: int) -> np.ndarray:
    """Training views visit order for one epoch; a function of (seed, epoch) so that a resumed
    run sees the same sequence as an uninterrupted one."""
    return np.random.default_rng([seed, epoch]).permutation(n)


class Trainer:
    """One 3DGS training run, a step at a time: the Gaussians as parameters, their Adam optimizers, the
    densification strategy and its statistics, the run's schedule, its training time and its curve.

    ``step()`` makes one optimisation step; ``finished`` says when the run is over (``config.iterations`` steps
    or ``config.max_seconds`` of training time); ``evaluate()`` adds a point to the curve; ``save_checkpoint`` /
    ``resume`` carry everything a step depends on, so a resumed trainer steps as the uninterrupted one would (bit
    for bit on the CPU). ``clock`` (seconds) times the steps; tests inject a slow or fast one. :func:`train` is
    the loop over it that the commands run, and ``m2m bench train`` times its steps.
    """

    def __init__(self, views_train: Sequence[View], views_eval: Sequence[View], init: Gaussians,
                 config: TrainConfig, clock: Callable[[], float] = time.perf_counter,
                 constraint: Constraint | None = None):  # fmt: skip
        if not views_train:
            raise ValueError("train needs at least one training view")
        self.length = config.run_length()  # validates iterations and max_seconds
        if not self.length.bounded:
            raise ValueError("train needs iterations > 0 or a max_seconds budget")
        if not (0 <= config.coarse_fraction <= 1 and int(config.coarse_factor) >= 1):
            raise ValueError(f"coarse_fraction must be in [0, 1] and coarse_factor >= 1, got {config.coarse_fraction} "
                             f"and {config.coarse_factor}")  # fmt: skip
        check_variance(config.filter_3d)
        if not (0 <= config.lr_cooldown <= 1 and 0 < config.lr_cooldown_ratio <= 1):
            raise ValueError(f"lr_cooldown must be in [0, 1] and lr_cooldown_ratio in (0, 1], got "
                             f"{config.lr_cooldown} and {config.lr_cooldown_ratio}")  # fmt: skip
        self.config = config
        self.views_train, self.views_eval = list(views_train), list(views_eval)
        self.clock = clock
        self.backend = resolve_backend(config.backend)
        self.device = torch.device("cuda" if self.backend == "cuda" else "cpu")
        self.extent = scene_extent(self.views_train)
        self.strategy = _make_strategy(config) if config.densify else None
        self.params = _to_params(init, config.sh_degree, self.device)
        self.optimizers = _make_optimizers(self.params, config.lr, self.extent)
        self.strategy_state = self.strategy.initialize_state(scene_scale=self.extent) if self.strategy else None
        if self.strategy:
            self.strategy.check_sanity(self.params, self.optimizers)
        self.schedule = _schedule(config, self.extent)
        self.iteration = 0  # steps done
        self.elapsed = 0.0  # training time: the steps' (evaluations and checkpoints are extra)
        self.curve: list[dict[str, Any]] = []
        self.initial: dict[str, Any] | None = None  # the evaluation before the first step
        # gsplat's split samples with torch.randn from the global generator: the run keeps its own state of it,
        # swapped in for the refinements, so that trainers (and whatever else draws) do not disturb each other
        with torch.random.fork_rng(devices=[torch.cuda.current_device()] if self.device.type == "cuda" else []):
            torch.manual_seed(config.seed)
            self._rng = self._global_rng()
        self._rates: torch.Tensor | None = None  # the 3D filter's sampling rates [N], refreshed as the Gaussians change
        self._refresh_filter()
        self._coarse: dict[int, View] = {}  # training views at 1/coarse_factor, made on first use
        # the next step is expected to take the median of the last five (robust to one step stalled by a busy
        # machine): the run stops before a step that would end past the budget
        self._recent: deque[float] = deque(maxlen=5)
        self._step_share = 1.0 / config.iterations if config.iterations else 0.0  # progress of the last step
        self._last = {"progress": 0.0, "sh_degree": 0, "means_lr": self.schedule.means_lr(0.0), "lr_scale": 1.0}
        self._warm = False
        self.constraint = constraint

    # -- where the run is
    @property
    def finished(self) -> bool:
        """The run is over: its steps are done, or the next step would end past its time budget."""
        expected = float(np.median(self._recent)) if self._recent else 0.0
        return self.length.finished(self.iteration, self.elapsed, expected)

    @property
    def progress(self) -> float:
        return self.length.fraction(self.iteration, self.elapsed)

    def gaussians(self) -> Gaussians:
        """The Gaussians now (detached, on the training device) with every SH band: the bands not yet active are
        still zero, so this renders what was trained."""
        return self._model(self.config.sh_degree).detach()

    def _model(self, degree: int) -> Gaussians:
        g = _to_gaussians(self.params, degree)
        return g if self._rates is None else apply_3d_filter(g, self._rates, self.config.filter_3d)

    def _refresh_filter(self) -> None:
        if self.config.filter_3d > 0:
            self._rates = max_sampling_rate(self.params["means"], self.views_train)

    # -- training
    def _global_rng(self) -> tuple[torch.Tensor, torch.Tensor | None]:
        return torch.get_rng_state(), torch.cuda.get_rng_state(self.device) if self.device.type == "cuda" else None

    @contextmanager
    def _own_rng(self) -> Iterator[None]:
        """The global torch generators at this run's state for the block (the run's state advanced after it)."""
        outer = self._global_rng()
        self._set_global_rng(self._rng)
        try:
            yield
        finally:
            self._rng = self._global_rng()
            self._set_global_rng(outer)

    def _set_global_rng(self, state: tuple[torch.Tensor, torch.Tensor | None]) -> None:
        torch.set_rng_state(state[0])
        if state[1] is not None and self.device.type == "cuda":
            torch.cuda.set_rng_state(state[1], self.device)

    def _start(self) -> None:
        """Before the first step: the initial evaluation (a resumed run has it), and one untimed forward +
        backward on a copy: numba compiles or loads its kernels (~35 s to compile the training step's on a busy
        2-core machine, which the first step of a 4-minute budget paid), CUDA and gsplat initialise, so the budget
        buys training steps only."""
        if self.initial is None:
            self._evaluate_initial()
        if not self._warm:
            self._warm = True
            warm = _to_gaussians(self.params, self.config.sh_degree).map(lambda t: t.detach().clone().requires_grad_())
            view_loss(warm, self.views_train[0], self.config, {}, self.backend)[0].backward()

    def step(self) -> dict[str, Any]:
        """One optimisation step on the next training view, densification included; returns its ``loss``, the
        ``gaussians`` after it, the run's ``progress`` after it, whether densification ``refined``, whether an
        ``evaluate`` is due on the schedule (the caller's: evaluations are not training time) and its ``seconds``.
        The phases are labelled for ``torch.profiler`` (``trainer.forward`` / ``backward`` / ``densify`` /
        ``adam``)."""
        self._start()
        cfg, params, schedule = self.config, self.params, self.schedule
        t0 = self.clock()
        p = self.length.fraction(self.iteration, self.elapsed)
        n_views = len(self.views_train)
        index = int(_view_order(n_views, cfg.seed, self.iteration // n_views)[self.iteration % n_views])
        view = self.views_train[index]
        if p < cfg.coarse_fraction:
            if index not in self._coarse:
                self._coarse[index] = downsample_view(view, cfg.coarse_factor)
            view = self._coarse[index]
        lr = schedule.means_lr(p)
        self.optimizers["means"].param_groups[0]["lr"] = lr
        lr_scale = schedule.lr_scale(p)
        for k, o in self.optimizers.items():
            if k != "means":
                o.param_groups[0]["lr"] = cfg.lr[k] * lr_scale
        degree = schedule.active_sh_degree(p)
        info: dict = {}
        try:
            with record_function("trainer.forward"):
                loss, _ = view_loss(self._model(degree), view, cfg, info, self.backend)
            with record_function("trainer.backward"):
                loss.backward()
        except torch.cuda.OutOfMemoryError as e:
            lower = "--max-gaussians (the densification cap) or the image size (--downscale)"
            raise gpu_out_of_memory("training", len(params["means"]), view.width, view.height, lower) from e
        refine = False
        with record_function("trainer.densify"):
            if self.strategy is not None and schedule.densifying(p):
                refine = schedule.refine_now(self.iteration + 1, p, self._step_share)
                sinfo = _strategy_info(info, view, len(params["means"]))
                if sinfo is not None:  # None: nothing was rendered (no Gaussians), so nothing to refine
                    with self._own_rng() if refine else nullcontext():
                        self.strategy.update(params, self.optimizers, self.strategy_state, sinfo, refine,
                                             self.iteration + 1)  # fmt: skip
                if refine:
                    schedule.refinements[-1] = (*schedule.refinements[-1], len(params["means"]))
        with record_function("trainer.adam"):
            for o in self.optimizers.values():
                o.step()
                o.zero_grad(set_to_none=True)
        self.iteration += 1
        if self.constraint is not None and (self.iteration % self.constraint.every == 0 or self.finished):
            with torch.no_grad():  # projected steps: the moments stay, the values go back where they may be
                means, log_scales = self.constraint(params["means"], params["quats"], params["scales"])
                params["means"].copy_(means)
                params["scales"].copy_(log_scales)
        if self._rates is not None and (refine or self.iteration % FILTER_3D_EVERY == 0):
            self._refresh_filter()  # after a refinement (added / removed Gaussians) and as the means move
        dt = self.clock() - t0
        self.elapsed += dt
        self._recent.append(dt)
        p_after = self.length.fraction(self.iteration, self.elapsed)
        self._step_share = p_after - p
        if schedule.opacity_reset_now(p, p_after):
            from gsplat.strategy.ops import reset_opa

            reset_opa(params, self.optimizers, self.strategy_state or {}, value=cfg.prune_opa * 2)
        self._last = {"progress": p, "sh_degree": degree, "means_lr": lr, "lr_scale": lr_scale}
        return {"loss": float(loss.detach()), "gaussians": len(params["means"]), "progress": p_after,
                "refined": refine, "evaluate": schedule.eval_now(p_after), "seconds": dt}  # fmt: skip

    # -- evaluation
    def _evaluate_initial(self) -> None:
        self.initial = evaluate(self._model(0).detach(), self.views_eval, self.config, self.backend)
        self.curve.append({"step": 0, "seconds": 0.0, "psnr": self.initial["psnr"], "ssim": self.initial["ssim"],
                           "gaussians": len(self.params["means"])})  # fmt: skip

    def evaluate(self) -> dict[str, Any]:
        """PSNR / SSIM of the Gaussians now on the evaluation views (module :func:`evaluate`), added to the curve."""
        m = evaluate(self.gaussians(), self.views_eval, self.config, self.backend)
        self.curve.append({"step": self.iteration, "seconds": round(self.elapsed, 3), "psnr": m["psnr"],
                           "ssim": m["ssim"], "gaussians": len(self.params["means"])})  # fmt: skip
        return m

    def metrics(self, last: dict[str, Any]) -> dict[str, Any]:
        """:func:`train`'s metrics, ``last`` being the final :meth:`evaluate`."""
        if self.initial is None:
            self._evaluate_initial()
        return {
            "psnr": last["psnr"],
            "ssim": last["ssim"],
            "views": last["views"],
            "initial": {"psnr": self.initial["psnr"], "ssim": self.initial["ssim"]},
            "curve": self.curve,
            "iterations": self.iteration,
            "gaussians": len(self.params["means"]),
            "seconds": self.elapsed,
            "backend": self.backend,
            "schedule": {
                "progress": self.progress,
                "last_step_progress": self._last["progress"],
                "sh_degree": self._last["sh_degree"],
                "means_lr": self._last["means_lr"],
                "lr_scale": self._last["lr_scale"],
                "refinements": [list(r) for r in self.schedule.refinements],
            },
        }

    # -- checkpoints
    def save_checkpoint(self, path: str | Path) -> None:
        """Everything the next step depends on, written atomically: the Gaussians, Adam's moments, the strategy's
        statistics, the step, the training time, the schedule's state, the RNG, the 3D filter's rates, the curve."""
        blob = {
            "step": self.iteration,
            "params": {k: v.detach().cpu() for k, v in self.params.items()},
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "strategy_state": self.strategy_state,
            "torch_rng": self._rng[0],
            "cuda_rng": self._rng[1],
            "elapsed": self.elapsed,
            "curve": self.curve,
            "initial": self.initial,
            "config": asdict(self.config),
            "schedule": self.schedule.state_dict(),
            "recent": list(self._recent),
            "step_share": self._step_share,
            "last": self._last,
            "filter_rates": None if self._rates is None else self._rates.cpu(),
        }
        with atomic_path(Path(path)) as tmp:
            torch.save(blob, tmp)

    def resume(self, path: str | Path) -> bool:
        """Continue from the checkpoint at ``path`` (False: there is none); the trainer's views and config must be
        the run's (the scene stage checks that with its plan)."""
        path = Path(path)
        if not path.exists():
            return False
        blob = torch.load(path, map_location=self.device, weights_only=False)
        self.params = {k: torch.nn.Parameter(v.to(self.device)) for k, v in blob["params"].items()}
        self.optimizers = _make_optimizers(self.params, self.config.lr, self.extent)
        for k, o in self.optimizers.items():
            o.load_state_dict(blob["optimizers"][k])
        self.strategy_state = blob["strategy_state"]
        self.iteration, self.elapsed, self.curve, self.initial = blob["step"], blob["elapsed"], blob["curve"], blob[
            "initial"]  # fmt: skip
        self.schedule.load_state_dict(blob["schedule"])
        self._rng = (blob["torch_rng"].cpu(), blob.get("cuda_rng"))
        if self._rng[1] is not None:
            self._rng = (self._rng[0], self._rng[1].cpu())
        # checkpoints written before these were kept: the first step's defaults, the rates recomputed
        self._recent = deque(blob.get("recent", []), maxlen=5)
        self._step_share = blob.get("step_share", self._step_share)
        self._last = blob.get("last") or {**self._last, "progress": self.progress}
        rates = blob.get("filter_rates")
        if rates is not None and self.config.filter_3d > 0:
            self._rates = rates.to(self.device)
        else:
            self._refresh_filter()
        return True


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
    constraint: Constraint | None = None,
) -> tuple[Gaussians, dict[str, Any]]:
    """Train ``init`` on ``views_train`` (a :class:`Trainer` stepped to the end); returns (trained Gaussians,
    metrics).

    metrics: ``psnr``/``ssim`` (mean over ``views_eval``), ``views`` (per view), ``initial``
    (the same before training), ``curve`` (list of {step, seconds, psnr, ssim, gaussians}; seconds
    count training time only), ``iterations``, ``gaussians``, ``seconds``, ``backend``, ``schedule``
    (where it ended: ``progress``, ``sh_degree``, ``means_lr``, ``refinements`` [(step, progress,
    Gaussians after)]). ``callback(step, stats)`` runs after every step with :meth:`Trainer.step`'s figures
    (``loss``, ``gaussians``, ...). With ``checkpoint_path`` a checkpoint is written atomically every
    ``config.checkpoint_every`` steps and at the end; ``resume=True`` continues from it when it exists.
    ``clock`` (seconds) times the steps; tests inject a slow or fast one. ``constraint``: where the Gaussians may
    be (:class:`Constraint`), applied every ``constraint.every`` steps and after the last.
    """
    trainer = Trainer(views_train, views_eval, init, config, clock, constraint)
    ckpt = Path(checkpoint_path) if checkpoint_path is not None else None
    if resume and ckpt is not None:
        trainer.resume(ckpt)
    bar = None
    if progress:
        total = config.iterations if config.max_seconds is None else None  # a time budget: no step count
        bar = progress_bar(total=total, initial=trainer.iteration, desc="train", dynamic_ncols=True)
    try:
        while not trainer.finished:
            stats = trainer.step()
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{stats['loss']:.4f}", n=stats["gaussians"], p=f"{stats['progress']:.2f}",
                                refresh=False)  # fmt: skip
            if callback is not None:
                callback(trainer.iteration, stats)
            if stats["evaluate"]:
                trainer.evaluate()
            every = config.checkpoint_every
            if ckpt is not None and every and trainer.iteration % every == 0 and not trainer.finished:
                trainer.save_checkpoint(ckpt)  # the last one follows the loop
    finally:
        if bar is not None:
            bar.close()
    last = trainer.evaluate()
    if ckpt is not None:
        trainer.save_checkpoint(ckpt)
    return trainer.gaussians().to("cpu"), trainer.metrics(last)
