"""Training: a tiny network overfits two episodes, a killed run resumes to the same result, outputs are whole."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

import mirage2matter.policy.train as train_mod
from fixtures.policy_datasets import tiny_config
from mirage2matter.policy import PolicyError, load_episodes, load_policy, train_policy
from mirage2matter.policy.train import PolicyTrainer


def _obs(d, i: int) -> dict:
    return {**{f"observation.images.{c}": d.images[c][i].transpose(1, 2, 0) for c in d.meta.cameras},
            "observation.state": d.state[i]}  # fmt: skip


def test_tiny_run_overfits_and_reproduces_the_demonstrations(tiny_run):
    ds, out, eps, summary = tiny_run
    assert summary["steps"] == 150
    assert summary["loss"]["last"] < 0.2 * summary["loss"]["first"], summary["loss"]
    for name in ("policy.pt", "checkpoint.pt", "loss_curve.png", "summary.json"):
        assert (out / name).is_file(), name
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]  # no temporaries left behind
    assert json.loads((out / "summary.json").read_text())["steps"] == 150

    # the policy, fed the training observations (frames as the dataset stores them), gives the demo's actions
    d = load_episodes(ds, image_size=32)
    policy = load_policy(out)
    act_std = d.action.std(0).clip(1e-2)
    errs = np.stack([np.abs(policy.predict_chunk(_obs(d, i))[0] - d.action[i]) / act_std for i in range(d.n_frames)])
    assert errs.mean() < 0.15, errs.mean(0)
    # and the executed (ensembled) actions along each episode too
    for e in range(d.n_episodes):
        policy.reset()
        got = np.stack([policy(_obs(d, i)) for i in d.frames_of([e])])
        assert got.shape == (d.lengths[e], 8) and got.dtype == np.float32
        assert (np.abs(got - d.action[d.frames_of([e])]) / act_std).mean() < 0.2


def test_resume_after_a_kill_gives_the_uninterrupted_result(make_dataset, tmp_path, monkeypatch):
    ds, _ = make_dataset(seeds=(0,), length=10)
    cfg = tiny_config(steps=24, checkpoint_every=10, eval_every=8, val_fraction=0.0, widths=(4,), keypoints=4,
                      hidden=16, batch_size=8)  # fmt: skip
    # with every random draw of a step on: camera dropout too
    cfg = dataclasses.replace(cfg, augment=dataclasses.replace(cfg.augment, camera_dropout=0.5))
    quiet = dict(log=lambda s: None, progress=False)
    whole = train_policy(ds, tmp_path / "whole", cfg, **quiet)

    # kill it in step 16 (after the checkpoint at step 10): what is left is the last checkpoint, no policy
    real, calls = train_mod.masked_l1, {"n": 0}

    def dies_at_step_16(*a):
        calls["n"] += 1
        if calls["n"] == 16:
            raise KeyboardInterrupt
        return real(*a)

    monkeypatch.setattr(train_mod, "masked_l1", dies_at_step_16)
    with pytest.raises(KeyboardInterrupt):
        train_policy(ds, tmp_path / "cut", cfg, **quiet)
    monkeypatch.setattr(train_mod, "masked_l1", real)
    left = sorted(p.name for p in (tmp_path / "cut").iterdir())
    assert left == ["checkpoint.pt"], left
    assert torch.load(tmp_path / "cut" / "checkpoint.pt", weights_only=True)["step"] == 10

    logs = []
    resumed = train_policy(ds, tmp_path / "cut", cfg, log=logs.append, progress=False)
    assert any("resuming at step 10/24" in s for s in logs), logs
    assert resumed["steps"] == whole["steps"] == 24 and resumed["resumed_from_step"] == 10
    assert resumed["loss"] == whole["loss"]  # the same batches, augmentations and optimiser state: same numbers
    a = torch.load(tmp_path / "whole" / "policy.pt", weights_only=True)["weights"]
    b = torch.load(tmp_path / "cut" / "policy.pt", weights_only=True)["weights"]
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-6, atol=1e-7)

    # a finished run started again does no more steps; a changed config starts afresh
    again = train_policy(ds, tmp_path / "cut", cfg, **quiet)
    assert again["steps"] == 24 and again["steps_per_second"] is None
    logs.clear()
    train_policy(ds, tmp_path / "cut", tiny_config(steps=5, widths=(4,), keypoints=4, hidden=16, batch_size=8),
                 log=logs.append, progress=False)  # fmt: skip
    assert any("training from scratch" in s for s in logs), logs


def test_a_resumed_policy_trainer_steps_as_the_uninterrupted_one(make_dataset, tmp_path):
    """A PolicyTrainer stepped N times and checkpointed, a new one resumed from the checkpoint and stepped M times:
    the same losses, validation curve, weights, EMA and optimiser state as one stepped N + M times; another run's
    checkpoint is refused."""
    ds, _ = make_dataset(seeds=(0, 1), length=10)
    cfg = tiny_config(steps=12, eval_every=4, val_fraction=0.5, widths=(4,), keypoints=4, hidden=16, batch_size=8)
    cfg = dataclasses.replace(cfg, augment=dataclasses.replace(cfg.augment, camera_dropout=0.5))
    quiet = lambda s: None
    n, m = 7, 5
    whole = PolicyTrainer([ds], cfg, quiet)
    while not whole.finished:
        whole.step()
    first = PolicyTrainer([ds], cfg, quiet)
    for _ in range(n):
        first.step()
    first.save_checkpoint(tmp_path / "checkpoint.pt")
    resumed = PolicyTrainer([ds], cfg, quiet)
    assert resumed.resume(tmp_path / "checkpoint.pt") and resumed.iteration == n
    for _ in range(m):
        resumed.step()
    assert resumed.finished and resumed.iteration == whole.iteration == n + m
    assert resumed.losses == whole.losses and resumed.aux_losses == whole.aux_losses
    assert resumed.val_curve == whole.val_curve and len(whole.val_curve) == 3
    for a, b in ((whole.model, resumed.model), (whole.ema, resumed.ema)):
        sa, sb = a.state_dict(), b.state_dict()
        assert all(torch.equal(sa[k], sb[k]) for k in sa)
    oa, ob = whole.opt.state_dict()["state"], resumed.opt.state_dict()["state"]
    assert all(torch.equal(oa[i][k], ob[i][k]) for i in oa for k in oa[i])

    logs: list[str] = []
    other = PolicyTrainer([ds], dataclasses.replace(cfg, lr=cfg.lr / 2), logs.append)
    assert not other.resume(tmp_path / "checkpoint.pt") and other.iteration == 0
    assert any("training from scratch" in s for s in logs), logs


@pytest.mark.parametrize("seconds_per_step", [0.1, 0.01, 0.001])
def test_minutes_budget_is_time_on_a_slow_or_fast_machine(make_dataset, tmp_path, seconds_per_step):
    """A fake clock whose steps take 10x longer or shorter: the run uses 90-100 % of its budget whatever its speed,
    and its learning-rate schedule ends where planned (at 0, when the budget is spent)."""
    ds, _ = make_dataset(seeds=(0,), length=8)
    cfg = tiny_config(steps=0, minutes=0.01, widths=(4,), keypoints=4, hidden=16, batch_size=4, eval_every=10**6,
                      checkpoint_every=10**6)  # fmt: skip
    t = {"now": 0.0}

    def clock() -> float:  # a step is the time between its start and end readings
        t["now"] += seconds_per_step
        return t["now"]

    s = train_policy(ds, tmp_path / "run", cfg, log=lambda s: None, progress=False, clock=clock)
    budget = cfg.minutes * 60
    assert 0.9 <= s["seconds"]["train"] / budget <= 1.0, s["seconds"]
    assert s["steps"] == pytest.approx(0.97 * budget / seconds_per_step, abs=2)
    assert s["final_lr"] < 1e-3 * cfg.lr and s["budget_minutes"] == cfg.minutes


def test_bad_config_and_inputs(make_dataset, tmp_path):
    ds, _ = make_dataset(seeds=(0,), length=8)
    with pytest.raises(PolicyError, match=r"chunk must be .*; lr must be > 0"):
        train_policy(ds, tmp_path / "x", tiny_config(chunk=0, lr=0.0), progress=False)
    with pytest.raises(PolicyError, match="state_noise must be >= 0"):
        train_policy(ds, tmp_path / "x", tiny_config(state_noise=-0.1), progress=False)
    aug = dataclasses.replace(tiny_config().augment, camera_dropout=1.5, hue_bands=1.0)
    with pytest.raises(PolicyError, match=r"camera_dropout must be a probability .*; augment.hue_bands must be in"):
        train_policy(ds, tmp_path / "x", tiny_config(augment=aug), progress=False)
    with pytest.raises(PolicyError, match="no datasets given"):
        train_policy([], tmp_path / "x", tiny_config(), progress=False)
    if not torch.cuda.is_available():
        with pytest.raises(PolicyError, match="no CUDA GPU"):
            train_policy(ds, tmp_path / "x", tiny_config(device="cuda"), progress=False)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_trains_and_runs_on_cuda(make_dataset, tmp_path):
    ds, _ = make_dataset(seeds=(0,), length=10)
    s = train_policy(ds, tmp_path / "gpu", tiny_config(steps=30, device="cuda"), log=lambda s: None, progress=False)
    assert s["device"].startswith("cuda") and s["loss"]["last"] < s["loss"]["first"]
    d = load_episodes(ds, image_size=32)
    policy = load_policy(tmp_path / "gpu", device="cuda")
    assert policy.device.type == "cuda" and policy(_obs(d, 0)).shape == (8,)
