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

__all__ = ["CHECKPOINT_FORMAT", "PolicyTrainConfig", "train_policy"]


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


# ---- the loop ---------------------------------------------------------------------------------------
def train_policy(
    datasets: str | Path | Sequence[str | Path],
    out_dir: str | Path,
    config: PolicyTrainConfig | None = None,
    log: Log = print,
    progress: bool = True,
    clock: Callable[[], float] = time.perf_counter,
) -> dict[str, Any]:
    """Train a visuomotor policy on one or more of our LeRobot datasets; returns the summary (also written to
    ``out_dir/summary.json``). Resumes from ``out_dir/checkpoint.pt`` when datasets and config are unchanged.
    ``clock``: the time source of the budget (a test's fake clock)."""
    cfg = config or PolicyTrainConfig()
    bad = cfg.problems()
    if bad:
        raise PolicyError("train-policy config: " + "; ".join(bad))
    dirs = [Path(datasets)] if isinstance(datasets, str | Path) else [Path(d) for d in datasets]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    device = resolve_device(cfg.device)

    t_load = time.perf_counter()
    demos = load_episodes(dirs, cfg.image_size, cfg.cameras or None, max_episodes=cfg.episodes or None)
    load_s = time.perf_counter() - t_load
    # the cadence of checkpoints does not change what is computed; everything else does
    key_cfg = {k: v for k, v in cfg.to_json().items() if k != "checkpoint_every"}
    fp = fingerprint(key_cfg, str(device), torch.get_num_threads(), *[d.resolve() for d in dirs])

    train_eps, val_eps = split_episodes(demos.n_episodes, cfg.val_fraction, cfg.seed)
    train_frames, val_frames = demos.frames_of(train_eps), demos.frames_of(val_eps)
    stats = normalization_stats(demos.state[train_frames], demos.action[train_frames])
    aux = _aux_targets(demos, train_frames, cfg, log)
    batches = _Batches(demos, stats, cfg.chunk, device, aux)
    spec = ModelSpec(demos.meta.cameras, cfg.image_size, len(demos.meta.state_names), len(demos.meta.action_names),
                     cfg.chunk, tuple(cfg.widths), cfg.keypoints, cfg.hidden,
                     0 if aux is None else int(aux.shape[1]), cfg.input_blur)  # fmt: skip

    torch.manual_seed(cfg.seed)
    model = VisuomotorPolicy(spec).to(device).to(memory_format=torch.channels_last)
    ema = copy.deepcopy(model) if cfg.ema_decay > 0 else model
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    n_params = sum(p.numel() for p in model.parameters())

    step, elapsed, losses, val_curve, aux_losses = 0, 0.0, [], [], []
    ckpt_path = out / CHECKPOINT_FILE
    total = cfg.steps or None  # a step count, or None: the time budget decides
    budget_s = None if total else cfg.minutes * 60.0 * 0.97  # 3 % for loading, the last evaluation and saving
    if ckpt_path.is_file():
        try:
            ck = torch.load(ckpt_path, map_location=device, weights_only=True)
        except Exception as e:  # a damaged checkpoint: say so and start over rather than fail forever
            log(f"train-policy: {ckpt_path} does not load ({type(e).__name__}: {e}); training from scratch")
            ck = None
        if ck is not None and ck.get("fingerprint") == fp:
            model.load_state_dict(ck["model"])
            if cfg.ema_decay > 0:
                ema.load_state_dict(ck["ema"])
            opt.load_state_dict(ck["optimizer"])
            step, elapsed = int(ck["step"]), float(ck["elapsed"])
            losses, val_curve = list(ck["losses"]), [tuple(v) for v in ck["val_curve"]]
            aux_losses = list(ck.get("aux_losses", []))
            done = f"{step}/{total}" if total else f"{step} ({elapsed / 60:.1f} of {budget_s / 60:.1f} min)"
            log(f"train-policy: resuming at step {done} from {ckpt_path}")
        elif ck is not None:
            log(f"train-policy: datasets or config changed since {ckpt_path}; training from scratch")
    if step == 0:
        # a fresh run: the outputs of an earlier, different run must not sit beside this run's checkpoints
        stale = [out / n for n in (POLICY_FILE, "summary.json", "loss_curve.png") if (out / n).is_file()]
        for f in stale:
            f.unlink()
        if stale:
            log(f"train-policy: removed the previous run's {', '.join(f.name for f in stale)} from {out}")
    length = f"{total} steps" if total else f"{cfg.minutes:g} minutes of steps"
    log(f"train-policy: {demos.n_episodes} episodes ({len(train_eps)} train, {len(val_eps)} val), "
        f"{demos.n_frames} frames from {len(dirs)} dataset(s) loaded in {load_s:.1f} s; {n_params / 1e6:.2f} M "
        f"parameters on {device}; {length} of {cfg.batch_size}")  # fmt: skip

    def checkpoint() -> None:
        _save(ckpt_path, {
            "format": CHECKPOINT_FORMAT, "fingerprint": fp, "step": step, "total_steps": total or 0, "elapsed": elapsed,
            "model": model.state_dict(), "ema": ema.state_dict() if cfg.ema_decay > 0 else {},
            "optimizer": opt.state_dict(), "losses": losses, "val_curve": [list(v) for v in val_curve],
            "aux_losses": aux_losses,
        })  # fmt: skip

    train_idx = torch.from_numpy(train_frames)
    bar = None
    if progress:
        if total:
            bar = progress_bar(total=total, initial=step, desc="train-policy", unit="step", dynamic_ncols=True)
        else:  # the budget is time: the bar counts seconds
            bar = progress_bar(total=round(budget_s), initial=round(elapsed), desc="train-policy", unit="s",
                               dynamic_ncols=True)
    run_start, run_steps = step, 0
    t_run = clock()
    try:
        model.train()
        while (step < total) if total else (elapsed < budget_s):
            t0 = clock()
            for group in opt.param_groups:
                group["lr"] = lr_at(step, _progress(step, elapsed, total, budget_s, cfg.warmup_steps), cfg)
            g = _step_generator(cfg.seed, step)
            frames = train_idx[torch.randint(len(train_idx), (cfg.batch_size,), generator=g)]
            images, state, target, mask = batches.get(frames, cfg.augment, g)
            if cfg.state_noise > 0:  # blur what the joints tell, so the network must look (see the config)
                state = state + cfg.state_noise * torch.randn(state.shape, generator=g).to(state.device)
            total_loss, loss, aux_loss = step_loss(model, (images, state, target, mask), batches.aux_of(frames),
                                                   cfg.aux_weight)  # fmt: skip
            opt.zero_grad(set_to_none=True)
            total_loss.backward()
            opt.step()
            if cfg.ema_decay > 0:
                _ema_update(ema, model, cfg.ema_decay, step)
            losses.append(float(loss.detach()))
            if aux_loss is not None:
                aux_losses.append(float(aux_loss.detach()))
            step += 1
            run_steps += 1
            if step % cfg.eval_every == 0 and len(val_frames):
                val_curve.append((step, _evaluate(ema, batches, val_frames, cfg.batch_size)))
            dt = clock() - t0
            elapsed += dt
            if bar is not None:
                bar.update(1 if total else min(round(elapsed) - bar.n, round(budget_s) - bar.n))
                bar.set_postfix(step=step, loss=f"{np.mean(losses[-20:]):.4f}", refresh=False)
            if step % cfg.checkpoint_every == 0 and ((step < total) if total else (elapsed < budget_s)):
                checkpoint()
    finally:
        if bar is not None:
            bar.close()
    run_s = clock() - t_run
    if len(val_frames) and (not val_curve or val_curve[-1][0] != step):
        val_curve.append((step, _evaluate(ema, batches, val_frames, cfg.batch_size)))
    checkpoint()

    window = max(1, min(50, len(losses) // 10))
    summary = {
        "datasets": [str(d) for d in dirs],
        "episodes": {"train": len(train_eps), "val": len(val_eps), "per_dataset": cfg.episodes or "all"},
        "frames": demos.n_frames,
        "meta": demos.meta.to_json(),
        "device": str(device),
        "threads": torch.get_num_threads(),
        "parameters": n_params,
        "steps": step,
        "budget_minutes": None if total else cfg.minutes,
        "final_lr": lr_at(step, _progress(step, elapsed, total, budget_s, cfg.warmup_steps), cfg),
        "samples_seen": step * cfg.batch_size,
        "seconds": {"load": round(load_s, 2), "train": round(elapsed, 2)},
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
    _save(out / POLICY_FILE, policy_blob(ema, spec, demos.meta.to_json(), stats, {
        "inference": {"ensemble_decay": 0.1}, "trained": {k: summary[k] for k in ("steps", "episodes", "frames")},
    }))  # fmt: skip
    if losses:
        x = np.arange(1, len(losses) + 1)
        series = [("train (per step)", x, np.asarray(losses)), ("train (smoothed)", x, smooth(losses, window))]
        if val_curve:
            series.append(("val (EMA weights)", *map(np.asarray, zip(*val_curve, strict=True))))
        plot_loss_curve(out / "loss_curve.png", series, title=f"L1 of normalised action chunks, K={cfg.chunk}")
    _write_json(out / "summary.json", summary)
    log(f"train-policy: {step} steps, loss {summary['loss']['first']:.4f} -> {summary['loss']['last']:.4f}"
        + (f", val {summary['loss']['val']:.4f}" if val_curve else "") + f"; wrote {out / POLICY_FILE}")  # fmt: skip
    return summary
