"""Issue 7's success rates over 50 randomised episodes per task on the sample world (slow: ~10-20 minutes)."""

import pytest

from mirage2matter.sim.tasks import evaluate, parse_task
from mirage2matter.world import load_world

RATES = {
    "grasp banana": 0.90,
    "grasp croissant": 0.90,
    "press button": 0.95,
    "push croissant --direction 0,1 --distance 0.1": 0.90,
    "pull banana --distance 0.1": 0.90,
}


@pytest.mark.slow
def test_success_rates_over_50_episodes(sim_ws):
    from mirage2matter.sim.twin import Twin, TwinOptions

    cfg = load_world(sim_ws / "world")
    twin = Twin.build(cfg, TwinOptions(render=False))
    try:
        rates = {}
        for text in RATES:
            r = evaluate(twin, parse_task(text, cfg), episodes=50, seed=1000)
            rates[text] = r["success_rate"]
    finally:
        twin.close()
    print("\nsuccess rates over 50 episodes:", rates)
    low = {t: r for t, r in rates.items() if r < RATES[t]}
    assert not low, f"below target: {low} (all: {rates})"
