"""Time budgets that hold on any device: the trainer on clocks much slower and faster than this CPU (a GPU is
~50x faster per step, a loaded machine several times slower, a GPU's first steps are warm-up) uses 90-100 %
of its budget, and its schedule ends where it was set: densification stops at its fraction, the SH degree
reaches its top, the means' learning rate decays to its final value.

The clock is a stand-in: time passes only while the trainer renders, each render of N Gaussians taking
rate x (2 ms + 2 us x N) (a step slows down as densification adds Gaussians, as real steps do), so
the test is deterministic and no other process competing for the cores can move it.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

import mirage2matter.gaussians.train as train_module
from mirage2matter.gaussians.budget import COARSE_FRACTION, LR_COOLDOWN, budget_config
from mirage2matter.gaussians.render import render
from mirage2matter.gaussians.schedule import RunLength, Schedule
from mirage2matter.gaussians.synthetic import orbit_cameras, tabletop_scene
from mirage2matter.gaussians.train import TrainConfig, View, init_gaussians_from_points, scene_extent, train

W, H = 40, 30


def render_seconds(n: int) -> float:
    return 2e-3 + 2e-6 * n


class RenderClock:
    """Seconds that pass only in the trainer's renders: render number k (counting from 1, the initial
    evaluation's included) of N Gaussians takes ``rate(k, t)`` x :func:`render_seconds` (N), t being the
    clock's reading (rate 10: a machine 10x slower than the nominal one)."""

    def __init__(self, rate, monkeypatch):
        self.rate, self.now, self.renders, self.training = rate, 0.0, 0, 0.0
        # (training time before it, width, height, a training step's render?): the training time is what the
        # trainer counts against its budget, the time of its steps' renders (evaluations are extra)
        self.sizes: list[tuple[float, int, int, bool]] = []

        def timed_render(g, viewmat, K, width, height, *args, **kwargs):
            self.renders += 1
            step = len(args) > 2 and args[2] is not None  # training renders pass an info dict
            self.sizes.append((self.training, width, height, step))
            seconds = self.rate(self.renders, self.now) * render_seconds(len(g))
            self.now += seconds
            self.training += seconds if step else 0.0
            return render(g, viewmat, K, width, height, *args, **kwargs)

        monkeypatch.setattr(train_module, "render", timed_render)

    def __call__(self) -> float:
        return self.now


@pytest.fixture(scope="module")
def scene():
    gt = tabletop_scene(2000, sh_degree=1, seed=0)
    views = []
    for vm, K in orbit_cameras(8, W, H, seed=0):
        vm_t, K_t = torch.tensor(vm, dtype=torch.float32), torch.tensor(K, dtype=torch.float32)
        with torch.no_grad():
            views.append(View(render(gt, vm_t, K_t, W, H, torch.zeros(3), backend="cpu").rgb.clamp(0, 1), vm_t, K_t))
    rng = np.random.default_rng(0)
    pts = gt.means[rng.choice(len(gt), 400, replace=False)].numpy() + rng.normal(0.0, 0.02, (400, 3))
    init = init_gaussians_from_points(pts, rng.uniform(0.3, 0.7, (400, 3)), sh_degree=1)
    return views, init


# rate(k, t, budget) of each clock, and the budget in nominal steps (renders of the initial Gaussians at rate
# 1): 10x slower, 10x faster, a GPU-like warm-up (the first three steps 10x slower: the old planner timed
# them and planned 10x too few steps), a machine that gets loaded (4x slower) a third of the way in. The two
# constant rates make the same run from the trainer's side: only the budget's ratio to the steps matters.
CLOCKS = {
    "10x slower": (lambda k, t, b: 10.0, 10 * 120),
    "10x faster": (lambda k, t, b: 0.1, 0.1 * 120),
    "warm-up": (lambda k, t, b: 10.0 if k <= 4 else 1.0, 300),
    "loaded later": (lambda k, t, b: 1.0 if t < b / 3 else 4.0, 250),
}


@pytest.mark.parametrize("name", list(CLOCKS))
def test_the_budget_is_used_and_the_schedule_ends_where_set(scene, name, monkeypatch):
    views, init = scene
    rate, nominal_steps = CLOCKS[name]
    budget_s = nominal_steps * render_seconds(len(init))
    base = TrainConfig(sh_degree=1, max_gaussians=1500, checkpoint_every=0, backend="cpu")
    cfg = budget_config(budget_s / 60, base, densify_fraction=0.5, curve_points=4)
    clock = RenderClock(lambda k, t: rate(k, t, budget_s), monkeypatch)
    made = []  # the trainer's optimizers, to read their learning rates at the end
    make = train_module._make_optimizers
    monkeypatch.setattr(train_module, "_make_optimizers", lambda *a: made.append(make(*a)) or made[-1])
    g, m = train(views, views[:1], init, cfg, progress=False, clock=clock)
    s = m["schedule"]
    refinements = [(r[0], round(r[1], 3), r[2]) for r in s["refinements"]]
    print(name, {"budget_s": round(budget_s, 2), "used": round(m["seconds"] / budget_s, 3), "steps": m["iterations"],
                 "refinements": refinements, "gaussians": m["gaussians"]})  # fmt: skip

    assert 0.90 <= m["seconds"] / budget_s <= 1.0
    assert m["iterations"] >= 30
    # densification refined up to its fraction and no further; the count is final from there on
    refine_p = [r[1] for r in s["refinements"]]
    assert refine_p and max(refine_p) < 0.5
    assert max(refine_p) >= 0.45  # the window's last step refines
    assert s["refinements"][-1][2] == m["gaussians"] != len(init)
    after = [c["gaussians"] for c in m["curve"] if c["seconds"] >= 0.5 * budget_s]
    assert after and set(after) == {m["gaussians"]}
    # SH at its degree, the learning rate at (the last step's share from) its final value
    assert s["sh_degree"] == 1
    lr0, lr1 = (scene_extent(views) * cfg.lr[k] for k in ("means", "means_final"))
    assert s["last_step_progress"] >= 0.9
    assert math.log(s["means_lr"] / lr1) <= 0.1 * math.log(lr0 / lr1)  # within the last tenth of its decay
    # the other rates cooled down over the last LR_COOLDOWN of the budget (p >= 0.9: 2/3 of the way or more)
    assert cfg.lr_cooldown == LR_COOLDOWN and LR_COOLDOWN >= 0.1
    ends_at = 1 - (1 - s["last_step_progress"]) / LR_COOLDOWN
    assert s["lr_scale"] == pytest.approx(cfg.lr_cooldown_ratio**ends_at) and ends_at >= 0.6
    assert {k: o.param_groups[0]["lr"] for k, o in made[-1].items()} == pytest.approx(
        {k: s["means_lr"] if k == "means" else cfg.lr[k] * s["lr_scale"] for k in made[-1]}
    )
    assert [c["step"] for c in m["curve"]][0] == 0 and len(m["curve"]) == 5  # 0, 1/4, 1/2, 3/4, the end


def test_a_budget_run_trains_coarse_then_fine(scene, monkeypatch):
    """budget_config trains on half-resolution views for its first COARSE_FRACTION of the time, then on the
    views themselves; evaluations are always at full resolution."""
    views, init = scene
    budget_s = 120 * render_seconds(len(init))
    cfg = budget_config(budget_s / 60, TrainConfig(sh_degree=1, max_gaussians=1500, checkpoint_every=0, backend="cpu"),
                        densify_fraction=0.5, curve_points=4)  # fmt: skip
    assert (cfg.coarse_fraction, cfg.coarse_factor) == (COARSE_FRACTION, 2)
    clock = RenderClock(lambda k, t: 1.0, monkeypatch)
    train(views, views[:1], init, cfg, progress=False, clock=clock)
    warm_up, *steps = [(t, (w, h)) for t, w, h, training in clock.sizes if training]
    # the untimed warm-up render (full size, before the run) is on the clock but not on the budget
    steps = [((t - render_seconds(len(init))) / budget_s, size) for t, size in steps]
    assert warm_up == (0.0, (W, H))
    coarse = [p for p, size in steps if size == (W // 2, H // 2)]
    fine = [p for p, size in steps if size == (W, H)]
    assert len(coarse) + len(fine) == len(steps) and coarse and fine
    assert max(coarse) < COARSE_FRACTION <= min(fine) and max(coarse) > COARSE_FRACTION - 0.05
    assert {(w, h) for _, w, h, training in clock.sizes if not training} == {(W, H)}
    no_coarse = budget_config(1.0, coarse_fraction=0.0)
    assert no_coarse.coarse_fraction == 0.0
    with pytest.raises(ValueError, match="coarse_fraction"):
        budget_config(1.0, coarse_fraction=1.0)
    with pytest.raises(ValueError, match="coarse_factor >= 1"):
        train(views, views[:1], init, replace(cfg, coarse_factor=0), progress=False)


def test_bad_cooldown_values_are_clear_errors(scene):
    views, init = scene
    cfg = budget_config(0.01, TrainConfig(sh_degree=1, checkpoint_every=0, backend="cpu"))
    for bad in ({"lr_cooldown": 1.5}, {"lr_cooldown": -0.1}, {"lr_cooldown_ratio": 0.0}, {"lr_cooldown_ratio": 2.0}):
        with pytest.raises(ValueError, match="lr_cooldown"):
            train(views, views[:1], init, replace(cfg, **bad), progress=False)


def test_a_resumed_budget_run_continues_the_same_schedule(scene, tmp_path, monkeypatch):
    """Killed after a checkpoint, resumed: the training time spent and the schedule's state come back, so the
    two parts together use the budget once and refine as one run."""
    views, init = scene
    budget_s = 120 * render_seconds(len(init))
    cfg = budget_config(budget_s / 60, TrainConfig(sh_degree=1, max_gaussians=1500, checkpoint_every=20,
                                                   backend="cpu"), densify_fraction=0.5, curve_points=4)  # fmt: skip

    class Killed(Exception):
        pass

    def kill_at_30(step, stats):
        if step == 30:
            raise Killed

    ckpt = tmp_path / "ckpt.pt"
    with pytest.raises(Killed):
        train(views, views[:1], init, cfg, progress=False, checkpoint_path=ckpt,
              clock=RenderClock(lambda k, t: 1.0, monkeypatch), callback=kill_at_30)  # fmt: skip
    saved = torch.load(ckpt, weights_only=False)
    assert saved["step"] == 20 and 0 < saved["elapsed"] < budget_s
    g, m = train(views, views[:1], init, cfg, progress=False, checkpoint_path=ckpt, resume=True,
                 clock=RenderClock(lambda k, t: 1.0, monkeypatch))  # fmt: skip
    assert 0.90 <= m["seconds"] / budget_s <= 1.0
    refinements = m["schedule"]["refinements"]
    assert [r for r in refinements if r[0] <= 20] == [list(r) for r in saved["schedule"]["refinements"]]
    assert max(r[1] for r in refinements) < 0.5 and m["schedule"]["sh_degree"] == 1


# ---- the schedule and the run length on their own ------------------------------------------------------
def test_run_length_progress_and_end():
    both = RunLength(iterations=100, seconds=10.0)
    assert both.fraction(50, 2.0) == 0.5 and both.fraction(10, 8.0) == 0.8 and both.fraction(200, 0) == 1.0
    assert both.finished(100, 0.0) and both.finished(5, 9.5, next_step_seconds=0.6)
    assert not both.finished(5, 9.5, next_step_seconds=0.4)
    assert not RunLength(iterations=0, seconds=None).bounded
    with pytest.raises(ValueError, match="max_seconds"):
        RunLength(seconds=0.0)
    with pytest.raises(ValueError, match="train needs iterations > 0 or a max_seconds"):
        train([View(torch.zeros(H, W, 3), torch.eye(4), torch.eye(3))], [], None, TrainConfig(iterations=0))


def test_schedule_by_progress():
    s = Schedule(sh_degree=3, sh_increase_every=0.125, refine_start=0.05, refine_stop=0.5, refine_every=None,
                 opacity_reset_every=0.2, eval_points=4, lr0=1e-3, lr1=1e-5)  # fmt: skip
    assert [s.active_sh_degree(p) for p in (0.0, 0.124, 0.125, 0.3, 0.375, 0.99)] == [0, 0, 1, 2, 3, 3]
    assert s.means_lr(0.0) == pytest.approx(1e-3) and s.means_lr(0.5) == pytest.approx(1e-4)
    assert s.means_lr(1.0) == pytest.approx(1e-5)
    assert s.lr_scale(0.99) == 1.0  # no cool-down unless asked
    cool = replace(s, cooldown=0.2, cooldown_ratio=0.01)
    assert [cool.lr_scale(p) for p in (0.0, 0.8, 0.9, 1.0)] == pytest.approx([1.0, 1.0, 0.1, 0.01])
    # 1000 steps: refinements every 1/60 of the run (17 steps) within [0.05, 0.5)
    steps = [k for k in range(1, 1001) if s.refine_now(k, (k - 1) / 1000)]
    assert steps[0] >= 51 and steps[-1] <= 500 and len(steps) == pytest.approx(0.45 * 60, abs=2)
    assert all(17 <= b - a <= 18 for a, b in zip(steps, steps[1:], strict=False))
    # 100 steps: 1/60 of the run is under 2 steps; at least 10 apart
    s2 = Schedule(1, 0.5, 0.0, 0.5, None, 0.0, 0, 1e-3, 1e-5)
    steps = [k for k in range(1, 101) if s2.refine_now(k, (k - 1) / 100)]
    assert steps == [10, 20, 30, 40, 50]
    # 100000 steps (a GPU): at most 100 apart
    s3 = Schedule(1, 0.5, 0.0, 0.5, None, 0.0, 0, 1e-3, 1e-5)
    steps = [k for k in range(1, 20001) if s3.refine_now(k, (k - 1) / 100000)]
    assert steps[:3] == [100, 200, 300]
    evals = [s.eval_now(p) for p in (0.1, 0.25, 0.3, 0.5, 0.74, 0.75, 1.0)]
    assert evals == [False, True, False, True, False, True, False]
    assert s.opacity_reset_now(0.19, 0.21) and not s.opacity_reset_now(0.21, 0.3)
    assert not s.opacity_reset_now(0.59, 0.61)  # past the densification window
    state = s.state_dict()
    t = Schedule(3, 0.125, 0.05, 0.5, None, 0.2, 4, 1e-3, 1e-5)
    t.load_state_dict(state)
    assert t.state_dict() == state
