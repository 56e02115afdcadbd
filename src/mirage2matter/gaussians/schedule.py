"""A 3DGS training run's schedule, driven by how far the run is rather than by a planned step count.

A run ends at ``iterations`` steps or at ``max_seconds`` of training time, whichever comes first; its
progress ``p`` in [0, 1] is the larger of ``step / iterations`` and ``elapsed / max_seconds``. Every
schedule is a function of ``p``: the means' learning-rate decay, the SH degree, the densification window
(and its pruning), the opacity resets and the evaluations. So a time-budgeted run keeps its shape on any
device and under any load: on a GPU the same minutes hold ~50x the steps of a 2-core CPU, and a machine
that slows down halfway just gets fewer steps in the second half. (The planner this replaces timed three
steps after one warm-up and fixed the step count: on an H100 it measured CUDA warm-up, 0.11 s instead of
0.016 s per step, planned 343 steps and trained 5.4 s of a 120 s budget.)

Densification refines every 1/60 of the run (3DGS: every 100 of 30000 steps in its first half), but
never sooner than 10 steps after the last refinement (the screen-space gradients it averages need a few
views) and never later than 100 (3DGS's cadence): in steps, 1/60 of the run is read off the running step
rate, so it adapts as densification makes steps slower.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["RunLength", "Schedule"]

REFINE_FRACTION = 1.0 / 60.0  # of the run between densification refinements
REFINE_MIN_STEPS = 10
REFINE_MAX_STEPS = 100


@dataclass(frozen=True)
class RunLength:
    """When a run ends: ``iterations`` steps (0: no step limit) or ``seconds`` of training time (None: no
    time limit), whichever comes first."""

    iterations: int = 0
    seconds: float | None = None

    def __post_init__(self) -> None:
        if self.iterations < 0:
            raise ValueError(f"iterations must be >= 0, got {self.iterations}")
        if self.seconds is not None and not self.seconds > 0:
            raise ValueError(f"max_seconds must be positive (or None), got {self.seconds}")

    @property
    def bounded(self) -> bool:
        return self.iterations > 0 or self.seconds is not None

    def fraction(self, step: int, elapsed: float) -> float:
        """Progress in [0, 1] after ``step`` steps and ``elapsed`` seconds of training."""
        p = 0.0
        if self.iterations > 0:
            p = step / self.iterations
        if self.seconds is not None:
            p = max(p, elapsed / self.seconds)
        return min(max(p, 0.0), 1.0)

    def finished(self, step: int, elapsed: float, next_step_seconds: float = 0.0) -> bool:
        """True when no further step fits: the step limit is reached, or the next step (expected to take
        ``next_step_seconds``) would end past the time budget."""
        if self.iterations > 0 and step >= self.iterations:
            return True
        return self.seconds is not None and elapsed + next_step_seconds > self.seconds


@dataclass
class Schedule:
    """The schedules of one run as fractions of it; ``state_dict`` / ``load_state_dict`` carry what a
    resumed run needs to continue the same schedule (the last refinement, the evaluations made).

    sh_degree / sh_increase_every: the active SH degree rises by one every ``sh_increase_every`` of the run
    refine_start / refine_stop: densification (growth and pruning) refines only within this window
    refine_every: steps between refinements, or None for 1/60 of the run (10..100 steps)
    opacity_reset_every: fraction of the run between opacity resets within the window (0: off)
    eval_points: evaluations spread evenly over the run (0: only before and after)
    lr0 / lr1: the means' learning rate at the start and the end (exponential decay in between)
    cooldown / cooldown_ratio: over the last ``cooldown`` of the run the other parameters' learning rates
    decay exponentially to ``cooldown_ratio`` of theirs (0: constant, as in 3DGS)
    """

    sh_degree: int
    sh_increase_every: float
    refine_start: float
    refine_stop: float
    refine_every: int | None
    opacity_reset_every: float
    eval_points: int
    lr0: float
    lr1: float
    cooldown: float = 0.0
    cooldown_ratio: float = 0.1
    last_refine_step: int = 0
    last_refine_p: float = 0.0
    evals_done: int = 0
    refinements: list[tuple[int, float]] = field(default_factory=list)  # (step, p) of each refinement

    def means_lr(self, p: float) -> float:
        return math.exp((1 - p) * math.log(self.lr0) + p * math.log(self.lr1))

    def lr_scale(self, p: float) -> float:
        """The factor on every learning rate but the means' at progress ``p``: 1 until the cool-down."""
        if self.cooldown <= 0 or p <= 1 - self.cooldown:
            return 1.0
        return math.exp(min(1.0, (p - (1 - self.cooldown)) / self.cooldown) * math.log(self.cooldown_ratio))

    def active_sh_degree(self, p: float) -> int:
        if self.sh_increase_every <= 0:
            return self.sh_degree
        return min(int(p / self.sh_increase_every + 1e-9), self.sh_degree)

    def densifying(self, p: float) -> bool:
        """Screen-space gradient statistics are gathered up to the end of the window."""
        return p < self.refine_stop

    def refine_now(self, step: int, p: float, step_share: float = 0.0) -> bool:
        """Whether to refine after step number ``step`` (counting from 1) that started at progress ``p``;
        records it. ``step_share``: the progress one step is expected to make (the last step's), so that
        the window's last step refines too (densification then ends at ``refine_stop``, not up to 10 steps
        before it)."""
        if not self.refine_start <= p < self.refine_stop:
            return False
        since = step - self.last_refine_step
        if self.refine_every is not None:
            due = since >= self.refine_every
        else:
            due = (p - self.last_refine_p >= REFINE_FRACTION and since >= REFINE_MIN_STEPS) or since >= REFINE_MAX_STEPS
        due = due or (p + step_share >= self.refine_stop and since > 1)  # the window's last step
        if due:
            self.last_refine_step, self.last_refine_p = step, p
            self.refinements.append((step, p))
        return due

    def opacity_reset_now(self, p_before: float, p: float) -> bool:
        """True when a multiple of ``opacity_reset_every`` was crossed within the densification window."""
        k = self.opacity_reset_every
        if k <= 0 or p >= self.refine_stop:
            return False
        return math.floor(p / k + 1e-9) > math.floor(p_before / k + 1e-9)

    def eval_now(self, p: float) -> bool:
        """Whether an evaluation is due at progress ``p`` < 1 (the final one is the caller's); records it."""
        if self.eval_points <= 0 or p >= 1.0:
            return False
        due = int(p * self.eval_points + 1e-9)
        if due > self.evals_done:
            self.evals_done = due
            return True
        return False

    def state_dict(self) -> dict:
        return {
            "last_refine_step": self.last_refine_step,
            "last_refine_p": self.last_refine_p,
            "evals_done": self.evals_done,
            "refinements": list(self.refinements),
        }

    def load_state_dict(self, state: dict) -> None:
        self.last_refine_step = int(state["last_refine_step"])
        self.last_refine_p = float(state["last_refine_p"])
        self.evals_done = int(state["evals_done"])
        self.refinements = [tuple(r) for r in state["refinements"]]
