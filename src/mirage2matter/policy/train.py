"""Behaviour cloning on our datasets: ``train_policy(datasets, out_dir, config, log) -> summary``.

Outputs in ``out_dir`` (each written atomically: a temporary name, then a rename):

    policy.pt        the deployable policy (EMA weights, ModelSpec, dataset meta, normalisation stats);
                     what :func:`mirage2matter.policy.load_policy` opens
    checkpoint.pt    the training state (model, EMA, optimiser, per-step losses, elapsed time)
    loss_curve.png   training loss (per step and smoothed) and validation loss
    summary.json     what was trained on, how fast, and the losses

A killed run started again with the same datasets and config resumes from ``checkpoint.pt``. Every random
draw of step i (batch, augmentation) comes from a generator seeded with (seed, i), and the optimiser, EMA
and losses are restored, so with a fixed ``steps`` the resumed run computes what the uninterrupted one would
(bit for bit on the CPU with the same thread count). A changed config or dataset starts afresh.

A ``minutes`` budget (``steps`` 0) is a time budget, not a step count planned from a few measured steps: the
learning rate decays over the elapsed fraction of the budget and training stops when it is spent, so it holds on
a loaded CPU and on a GPU alike (a plan made from steps timed in a quiet moment ran 9,976 steps of a 15-minute
budget in ~45 minutes once the host was loaded). Elapsed time is kept in the checkpoint, so a resumed run spends
only what is left.
"""

from __future__ import annotations

import copy
import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..atomic import atomic_path, atomic_write
from ..fingerprint import fingerprint
from ..progress import progress_bar
from .augment import augment, drop_cameras
from .config import CHECKPOINT_FILE, CHECKPOINT_FORMAT, POLICY_FILE, AugmentConfig, PolicyTrainConfig
from .data import Demonstrations, PolicyError, chunk_indices, load_episodes, normalization_stats
from .model import ModelSpec, VisuomotorPolicy
from .plot import plot_loss_curve, smooth
from .targets import future_tcp, robot_for

__all__ = ["CHECKPOINT_FORMAT", "PolicyTrainConfig", "PolicyTrainer", "train_policy"]


Log = Callable[[str], None]


# ---- small pure pieces ----------------------------------------------------------------------------
def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise PolicyError(f"device {name!r} asked for, but torch sees no CUDA GPU here: use device 'auto' or 'cpu'")
    return torch.device(name)


def lr_at(step: int, progress: float, cfg: PolicyTrainConfig) -> float:
    """Linear warm-up over ``warmup_steps``, times a cosine decay to 0 at ``progress`` 1 (the fraction of the run
    done: of its steps after the warm-up, or of its time budget)."""
    warm = min(1.0, (step + 1) / cfg.warmup_steps) if cfg.warmup_steps else 1.0
    return cfg.lr * warm * 0.5 * (1 + math.cos(math.pi * min(1.0, max(0.0, progress))))


def _progress(step: int, elapsed: float, total: int | None, budget_s: float | None, warmup: int) -> float:
    """The fraction of the run done: of the steps after the warm-up (a step count), or of the time budget."""
    if total:
        return max(0, step - warmup) / max(1, total - warmup)
    return elapsed / budget_s if budget_s else 1.0


def split_episodes(n: int, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, val) episode indices, sorted; floor(fraction * n) held out, chosen by ``seed``."""
    n_val = int(math.floor(fraction * n)) if n > 1 else 0
    perm = np.random.default_rng([seed, 1]).permutation(n)
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def _step_generator(seed: int, step: int) -> torch.Generator:
    # One generator per (seed, step): a resumed run draws step i's batch and augmentation as the first run did.
    return torch.Generator().manual_seed(int(np.random.SeedSequence([seed, step]).generate_state(1)[0]))


class _Batches:
    """The training arrays as tensors on ``device`` plus the batch maker (normalised, chunked, augmented)."""

    def __init__(self, demos: Demonstrations, stats: dict[str, np.ndarray], chunk: int, device: torch.device,
                 aux: np.ndarray | None = None):  # fmt: skip
        self.device = device
        self.aux = None if aux is None else torch.from_numpy(np.asarray(aux, np.float32)).to(device)  # [N, D] normed
        self.cameras = demos.meta.cameras
        self.images = {c: torch.from_numpy(demos.images[c]).to(device) for c in self.cameras}  # uint8 [N,3,S,S]
        t = lambda a: torch.from_numpy(np.asarray(a, np.float32)).to(device)
        self.state = (t(demos.state) - t(stats["state_mean"])) / t(stats["state_std"])  # [N, S]
        self.action = (t(demos.action) - t(stats["action_mean"])) / t(stats["action_std"])  # [N, A]
        idx, mask = chunk_indices(demos.starts, demos.lengths, chunk)
        self.chunk_idx = torch.from_numpy(idx).to(device)  # [N, K]
        self.chunk_mask = torch.from_numpy(mask.astype(np.float32)).to(device)  # [N, K]

    def get(self, frames: torch.Tensor, aug: AugmentConfig | None, g: torch.Generator | None):
        """frames int64 [B] -> (images {cam: float [B,3,S,S]}, state [B,S], target [B,K,A], mask [B,K]);
        ``aux_of(frames)`` gives the auxiliary targets [B, D]."""
        frames = frames.to(self.device)
        images = {}
        for c in self.cameras:
            raw = self.images[c][frames]
            x = augment(raw, aug, g) if aug is not None else raw.float() / 255.0
            images[c] = x.contiguous(memory_format=torch.channels_last)
        if aug is not None:
            images = drop_cameras(images, aug.camera_dropout, g)
        idx = self.chunk_idx[frames]
        return images, self.state[frames], self.action[idx], self.chunk_mask[frames]

    def aux_of(self, frames: torch.Tensor) -> torch.Tensor | None:
        return None if self.aux is None else self.aux[frames.to(self.device)]


def masked_l1(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean |pred - target| over the real (unpadded) steps; pred/target [B,K,A], mask [B,K]."""
    err = (pred - target).abs().mean(-1)
    return (err * mask).sum() / mask.sum().clamp_min(1.0)


def step_loss(model: VisuomotorPolicy, batch: tuple, aux_target: torch.Tensor | None, aux_weight: float):
    """(total loss, action loss, auxiliary loss or None) of one batch (images, state, target, mask)."""
    images, state, target, mask = batch
    if aux_target is None or aux_weight <= 0:
        loss = masked_l1(model(images, state), target, mask)
        return loss, loss, None
    pred, aux = model(images, state, with_aux=True)
    act = masked_l1(pred, target, mask)
    aux_l1 = (aux - aux_target).abs().mean()
    return act + aux_weight * aux_l1, act, aux_l1


@torch.no_grad()
def _evaluate(model: VisuomotorPolicy, batches: _Batches, frames: np.ndarray, batch_size: int) -> float:
    model.eval()
    total, weight = 0.0, 0.0
    for i in range(0, len(frames), batch_size):
        images, state, target, mask = batches.get(torch.from_numpy(frames[i : i + batch_size]), None, None)
        err = (model(images, state) - target).abs().mean(-1)
        total += float((err * mask).sum())
        weight += float(mask.sum())
    model.train()
    return total / max(weight, 1.0)


def _ema_update(ema: VisuomotorPolicy, model: VisuomotorPolicy, decay: float, step: int) -> None:
    # warm-up of the decay so that a short run's EMA is not dominated by the random initialisation
    d = min(decay, (1 + step) / (10 + step))
    with torch.no_grad():
        for pe, pm in zip(ema.parameters(), model.parameters(), strict=True):
            pe.lerp_(pm, 1 - d)


def policy_blob(model: VisuomotorPolicy, spec: ModelSpec, demos_meta: dict, stats: dict, extra: dict) -> dict:
    """What ``policy.pt`` holds: plain types and tensors only, so it loads with ``weights_only=True``."""
    return {
        "format": CHECKPOINT_FORMAT,
        "meta": demos_meta,
        "spec": spec.to_json(),
        "stats": {k: torch.from_numpy(np.asarray(v, np.float32)) for k, v in stats.items()},
        "weights": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
        **extra,
    }


def _save(path: Path, blob: dict) -> None:
    with atomic_path(path) as tmp:
        torch.save(blob, tmp)


def _write_json(path: Path, obj: Any) -> None:
    with atomic_write(path, "w", encoding="utf-8") as f:
        json.dump(obj, f, indent=2)


def _aux_targets(demos: Demonstrations, train_frames: np.ndarray, cfg: PolicyTrainConfig, log: Log):
    """The auxiliary targets [N, 3 H] normalised by their training frames' mean and std, or None (none asked for,
    or a robot we have no model of: the policy then trains on actions alone, and says so)."""
    if cfg.aux_weight <= 0 or not cfg.aux_horizons:
        return None
    spec = robot_for(demos.meta.robot_type)
    if spec is None:
        log(f"train-policy: no robot model for robot_type {demos.meta.robot_type!r}; training without the auxiliary "
            "target (it needs the arm's kinematics)")  # fmt: skip
        return None
    aux = future_tcp(demos, cfg.aux_horizons, spec)
    mean, std = aux[train_frames].mean(0), np.maximum(aux[train_frames].std(0), 1e-3)
    return (aux - mean) / std


# ---- the trainer ------------------------------------------------------------------------------------
class PolicyTrainer:
    """One behaviour-cloning run, a step at a time: the datasets in memory (split, normalised, chunked), the
    network, its EMA, AdamW, the per-step losses and the validation curve.

    ``step()`` makes one optimisation step (and the validation the schedule asks for); ``finished`` says when the run
    is over (``config.steps``, or ``config.minutes`` of training time); ``save_checkpoint`` / ``resume`` carry the
    training state, and step i's random draws come from a generator seeded with (seed, i), so a resumed trainer
    steps as the uninterrupted one would (bit for bit on the CPU with the same thread count). ``clock``: the time
    source of the budget (a test's fake clock). :func:`train_policy` is the loop over it.
    """

    def __init__(self, datasets: Sequence[Path], config: PolicyTrainConfig, log: Log = print,
                 clock: Callable[[], float] = time.perf_counter):  # fmt: skip
        cfg = config
        bad = cfg.problems()
        if bad:
            raise PolicyError("train-policy config: " + "; ".join(bad))
        self.config, self.dirs, self.log, self.clock = cfg, [Path(d) for d in datasets], log, clock
        self.device = resolve_device(cfg.device)
        t_load = time.perf_counter()
        self.demos = demos = load_episodes(self.dirs, cfg.image_size, cfg.cameras or None,
                                           max_episodes=cfg.episodes or None)  # fmt: skip
        self.load_seconds = time.perf_counter() - t_load
        # the cadence of checkpoints does not change what is computed; everything else does
        key_cfg = {k: v for k, v in cfg.to_json().items() if k != "checkpoint_every"}
        self.fingerprint = fingerprint(key_cfg, str(self.device), torch.get_num_threads(),
                                       *[d.resolve() for d in self.dirs])  # fmt: skip

        self.train_episodes, self.val_episodes = split_episodes(demos.n_episodes, cfg.val_fraction, cfg.seed)
        train_frames, self.val_frames = demos.frames_of(self.train_episodes), demos.frames_of(self.val_episodes)
        self.stats = normalization_stats(demos.state[train_frames], demos.action[train_frames])
        aux = _aux_targets(demos, train_frames, cfg, log)
        self.batches = _Batches(demos, self.stats, cfg.chunk, self.device, aux)
        self.spec = ModelSpec(demos.meta.cameras, cfg.image_size, len(demos.meta.state_names),
                              len(demos.meta.action_names), cfg.chunk, tuple(cfg.widths), cfg.keypoints, cfg.hidden,
                              0 if aux is None else int(aux.shape[1]), cfg.input_blur)  # fmt: skip

        torch.manual_seed(cfg.seed)
        self.model = VisuomotorPolicy(self.spec).to(self.device).to(memory_format=torch.channels_last)
        self.ema = copy.deepcopy(self.model) if cfg.ema_decay > 0 else self.model
        self.opt = torch.optim.AdamW(self.model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        self.n_parameters = sum(p.numel() for p in self.model.parameters())
        self.model.train()

        self.iteration, self.elapsed = 0, 0.0
        self.losses: list[float] = []
        self.aux_losses: list[float] = []
        self.val_curve: list[tuple[int, float]] = []
        self.total_steps = cfg.steps or None  # a step count, or None: the time budget decides
        # 3 % of the minutes for loading, the last evaluation and saving
        self.budget_s = None if self.total_steps else cfg.minutes * 60.0 * 0.97
        self._train_idx = torch.from_numpy(train_frames)

    @property
    def finished(self) -> bool:
        if self.total_steps:
            return self.iteration >= self.total_steps
        return self.elapsed >= self.budget_s

    def lr(self) -> float:
        """The learning rate of the next step."""
        progress = _progress(self.iteration, self.elapsed, self.total_steps, self.budget_s, self.config.warmup_steps)
        return lr_at(self.iteration, progress, self.config)

    def step(self) -> dict[str, Any]:
        """One optimisation step on a batch of step ``iteration``'s draw, the EMA updated; the validation loss when
        it is due (every ``eval_every`` steps). Returns the step's ``loss`` (actions), ``aux_loss`` (or None),
        ``lr``, ``val`` (or None) and ``seconds`` (validation included: it is training time)."""
        cfg = self.config
        t0 = self.clock()
        lr = self.lr()
        for group in self.opt.param_groups:
            group["lr"] = lr
        g = _step_generator(cfg.seed, self.iteration)
        frames = self._train_idx[torch.randint(len(self._train_idx), (cfg.batch_size,), generator=g)]
        images, state, target, mask = self.batches.get(frames, cfg.augment, g)
        if cfg.state_noise > 0:  # blur what the joints tell, so the network must look (see the config)
            state = state + cfg.state_noise * torch.randn(state.shape, generator=g).to(state.device)
        total_loss, loss, aux_loss = step_loss(self.model, (images, state, target, mask), self.batches.aux_of(frames),
                                               cfg.aux_weight)  # fmt: skip
        self.opt.zero_grad(set_to_none=True)
        total_loss.backward()
        self.opt.step()
        if cfg.ema_decay > 0:
            _ema_update(self.ema, self.model, cfg.ema_decay, self.iteration)
        self.losses.append(float(loss.detach()))
        if aux_loss is not None:
            self.aux_losses.append(float(aux_loss.detach()))
        self.iteration += 1
        val = None
        if self.iteration % cfg.eval_every == 0 and len(self.val_frames):
            val = self.validate()
        dt = self.clock() - t0
        self.elapsed += dt
        return {"loss": self.losses[-1], "aux_loss": self.aux_losses[-1] if aux_loss is not None else None, "lr": lr,
                "val": val, "seconds": dt}  # fmt: skip

    def validate(self) -> float:
        """The EMA weights' validation loss now, added to the curve (NaN without validation episodes)."""
        if not len(self.val_frames):
            return math.nan
        val = _evaluate(self.ema, self.batches, self.val_frames, self.config.batch_size)
        self.val_curve.append((self.iteration, val))
        return val

    # -- checkpoints
    def save_checkpoint(self, path: str | Path) -> None:
        """The training state (model, EMA, optimiser, step, training time, losses), written atomically."""
        _save(Path(path), {
            "format": CHECKPOINT_FORMAT, "fingerprint": self.fingerprint, "step": self.iteration,
            "total_steps": self.total_steps or 0, "elapsed": self.elapsed, "model": self.model.state_dict(),
            "ema": self.ema.state_dict() if self.config.ema_decay > 0 else {}, "optimizer": self.opt.state_dict(),
            "losses": self.losses, "val_curve": [list(v) for v in self.val_curve], "aux_losses": self.aux_losses,
        })  # fmt: skip

    def resume(self, path: str | Path) -> bool:
        """Continue from the checkpoint at ``path`` when it is this run's (same datasets, config, device and thread
        count); False, and a word in the log when it is damaged or another run's (training starts afresh)."""
        path = Path(path)
        if not path.is_file():
            return False
        try:
            ck = torch.load(path, map_location=self.device, weights_only=True)
        except Exception as e:  # a damaged checkpoint: say so and start over rather than fail forever
            self.log(f"train-policy: {path} does not load ({type(e).__name__}: {e}); training from scratch")
            return False
        if ck.get("fingerprint") != self.fingerprint:
            self.log(f"train-policy: datasets or config changed since {path}; training from scratch")
            return False
        self.model.load_state_dict(ck["model"])
        if self.config.ema_decay > 0:
            self.ema.load_state_dict(ck["ema"])
        self.opt.load_state_dict(ck["optimizer"])
        self.iteration, self.elapsed = int(ck["step"]), float(ck["elapsed"])
        self.losses, self.val_curve = list(ck["losses"]), [tuple(v) for v in ck["val_curve"]]
        self.aux_losses = list(ck.get("aux_losses", []))
        total, budget_s = self.total_steps, self.budget_s
        done = f"{self.iteration}/{total}" if total else f"{self.iteration} ({self.elapsed / 60:.1f} of " \
            f"{budget_s / 60:.1f} min)"  # fmt: skip
        self.log(f"train-policy: resuming at step {done} from {path}")
        return True

    # -- results
    def policy(self, summary: dict[str, Any]) -> dict[str, Any]:
        """What ``policy.pt`` holds: the EMA weights, the model spec, the datasets' meta and normalisation."""
        trained = {k: summary[k] for k in ("steps", "episodes", "frames")}
        extra = {"inference": {"ensemble_decay": 0.1}, "trained": trained,
                 "frame_sizes": {c: list(s) if s else None for c, s in self.demos.frame_sizes.items()}}
        return policy_blob(self.ema, self.spec, self.demos.meta.to_json(), self.stats, extra)

    def summary(self, run_start: int, run_steps: int, run_s: float) -> dict[str, Any]:
        """summary.json: what was trained on, how fast (``run_steps`` steps in ``run_s`` seconds this session, from
        step ``run_start``), and the losses."""
        cfg, losses, aux_losses, val_curve = self.config, self.losses, self.aux_losses, self.val_curve
        step = self.iteration
        window = max(1, min(50, len(losses) // 10))
        return {
            "datasets": [str(d) for d in self.dirs],
            "episodes": {
                "train": len(self.train_episodes),
                "val": len(self.val_episodes),
                "per_dataset": cfg.episodes or "all",
            },
            "frames": self.demos.n_frames,
            "meta": self.demos.meta.to_json(),
            "device": str(self.device),
            "threads": torch.get_num_threads(),
            "parameters": self.n_parameters,
            "steps": step,
            "budget_minutes": None if self.total_steps else cfg.minutes,
            "final_lr": self.lr(),
            "samples_seen": step * cfg.batch_size,
            "seconds": {"load": round(self.load_seconds, 2), "train": round(self.elapsed, 2)},
            "steps_per_second": round(run_steps / run_s, 3) if run_steps and run_s > 0 else None,
            "samples_per_second": round(run_steps * cfg.batch_size / run_s, 1) if run_steps and run_s > 0 else None,
            "resumed_from_step": run_start or None,
            "loss": {
                "first": float(np.mean(losses[:window])) if losses else None,
                "last": float(np.mean(losses[-window:])) if losses else None,
                "val": val_curve[-1][1] if val_curve else None,
                "units": "mean |a - a_demo| in dataset-std units (normalised actions), unpadded chunk steps",
                "aux_first": float(np.mean(aux_losses[:window])) if aux_losses else None,
                "aux_last": float(np.mean(aux_losses[-window:])) if aux_losses else None,
            },
            "val_curve": [[s, round(v, 6)] for s, v in val_curve],
            "config": cfg.to_json(),
            "files": {"policy": POLICY_FILE, "checkpoint": CHECKPOINT_FILE, "loss_curve": "loss_curve.png"},
        }


# ---- the loop ---------------------------------------------------------------------------------------
def train_policy(
    datasets: str | Path | Sequence[str | Path],
    out_dir: str | Path,
    config: PolicyTrainConfig | None = None,
    log: Log = print,
    progress: bool = True,
    clock: Callable[[], float] = time.perf_counter,
) -> dict[str, Any]:
    """Train a visuomotor policy on one or more of our LeRobot datasets (a :class:`PolicyTrainer` stepped to the
    end); returns the summary (also written to ``out_dir/summary.json``). Resumes from ``out_dir/checkpoint.pt``
    when datasets and config are unchanged. ``clock``: the time source of the budget (a test's fake clock)."""
    cfg = config or PolicyTrainConfig()
    dirs = [Path(datasets)] if isinstance(datasets, str | Path) else [Path(d) for d in datasets]
    trainer = PolicyTrainer(dirs, cfg, log, clock)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ckpt_path = out / CHECKPOINT_FILE
    if not trainer.resume(ckpt_path):
        # a fresh run: the outputs of an earlier, different run must not sit beside this run's checkpoints
        stale = [out / n for n in (POLICY_FILE, "summary.json", "loss_curve.png") if (out / n).is_file()]
        for f in stale:
            f.unlink()
        if stale:
            log(f"train-policy: removed the previous run's {', '.join(f.name for f in stale)} from {out}")
    total, budget_s = trainer.total_steps, trainer.budget_s
    length = f"{total} steps" if total else f"{cfg.minutes:g} minutes of steps"
    log(f"train-policy: {trainer.demos.n_episodes} episodes ({len(trainer.train_episodes)} train, "
        f"{len(trainer.val_episodes)} val), {trainer.demos.n_frames} frames from {len(dirs)} dataset(s) loaded in "
        f"{trainer.load_seconds:.1f} s; {trainer.n_parameters / 1e6:.2f} M parameters on {trainer.device}; {length} of "
        f"{cfg.batch_size}")  # fmt: skip

    bar = None
    if progress:
        if total:
            bar = progress_bar(total=total, initial=trainer.iteration, desc="train-policy", unit="step",
                               dynamic_ncols=True)  # fmt: skip
        else:  # the budget is time: the bar counts seconds
            bar = progress_bar(total=round(budget_s), initial=round(trainer.elapsed), desc="train-policy", unit="s",
                               dynamic_ncols=True)  # fmt: skip
    run_start, run_steps = trainer.iteration, 0
    t_run = clock()
    try:
        while not trainer.finished:
            trainer.step()
            run_steps += 1
            if bar is not None:
                bar.update(1 if total else min(round(trainer.elapsed) - bar.n, round(budget_s) - bar.n))
                bar.set_postfix(step=trainer.iteration, loss=f"{np.mean(trainer.losses[-20:]):.4f}", refresh=False)
            if trainer.iteration % cfg.checkpoint_every == 0 and not trainer.finished:
                trainer.save_checkpoint(ckpt_path)  # the last one follows the loop
    finally:
        if bar is not None:
            bar.close()
    run_s = clock() - t_run
    if not trainer.val_curve or trainer.val_curve[-1][0] != trainer.iteration:
        trainer.validate()
    trainer.save_checkpoint(ckpt_path)

    summary = trainer.summary(run_start, run_steps, run_s)
    _save(out / POLICY_FILE, trainer.policy(summary))
    losses, val_curve = trainer.losses, trainer.val_curve
    if losses:
        window = max(1, min(50, len(losses) // 10))
        x = np.arange(1, len(losses) + 1)
        series = [("train (per step)", x, np.asarray(losses)), ("train (smoothed)", x, smooth(losses, window))]
        if val_curve:
            series.append(("val (EMA weights)", *map(np.asarray, zip(*val_curve, strict=True))))
        plot_loss_curve(out / "loss_curve.png", series, title=f"L1 of normalised action chunks, K={cfg.chunk}")
    _write_json(out / "summary.json", summary)
    log(f"train-policy: {trainer.iteration} steps, loss {summary['loss']['first']:.4f} -> "
        f"{summary['loss']['last']:.4f}" + (f", val {summary['loss']['val']:.4f}" if val_curve else "")
        + f"; wrote {out / POLICY_FILE}")  # fmt: skip
    return summary
