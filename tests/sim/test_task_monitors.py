"""The tasks' per-tick success tests (``Task.monitor``) on scripted states: what counts, when, and that success is
latched. No simulator: a stand-in twin reports the poses."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from mirage2matter.sim.tasks import LiftMonitor, PressMonitor


class _Twin:
    def __init__(self) -> None:
        self.z = 0.02
        self.travel = 0.0
        self.bodies = {"button": SimpleNamespace(cfg=SimpleNamespace(threshold=0.006))}

    def object_poses(self) -> dict[str, np.ndarray]:
        T = np.eye(4)
        T[2, 3] = self.z
        return {"banana": T}

    def button_travel(self, name: str) -> float:
        return self.travel


def test_lift_needs_five_cm_for_the_whole_hold():
    tw = _Twin()
    m = LiftMonitor(tw, "banana", tick_s=0.1)
    heights = [0.03, 0.06] + [0.08] * 8 + [0.06]  # 6 cm up from the 3rd tick to the 10th: 0.7 s, not 1 s
    for z in heights:
        tw.z = z
        assert not m.update(tw)
    assert "held >= 5 cm up for only 0.7 s" in m.reason
    tw.z = 0.05  # 3 cm over the start: the run of lifted ticks breaks, the clock restarts
    assert not m.update(tw)
    tw.z = 0.09
    for _ in range(10):
        assert not m.update(tw)
    assert m.update(tw) and m.reason.startswith("banana lifted 7.0 cm and held 1 s")
    tw.z = 0.02  # dropped afterwards: success stays (the episode is done)
    assert m.update(tw) and m.info["lift_m"] == 0.0 and m.info["max_lift_m"] > 0.069


def test_lift_that_never_rises_says_so():
    tw = _Twin()
    m = LiftMonitor(tw, "banana", tick_s=0.1)
    tw.z = 0.035
    assert not m.update(tw) and m.reason == "banana rose only 1.5 cm (needs 5 cm)"


def test_press_counts_the_travel_at_a_tick():
    tw = _Twin()
    m = PressMonitor(tw, "button", tick_s=0.1)
    tw.travel = 0.004
    assert not m.update(tw) and "pressed only 4.0 mm" in m.reason
    tw.travel = 0.0061
    assert m.update(tw) and m.info["max_travel_m"] == 0.0061
    tw.travel = 0.0
    assert m.update(tw) and m.info["travel_m"] == 0.0
