"""Task instructions: parsing and clear errors before any simulation (no Genesis needed)."""

import pytest

from mirage2matter.sim.tasks import TaskError, parse_task
from mirage2matter.world import load_world


def test_parse_tasks(sim_ws):
    cfg = load_world(sim_ws)
    g = parse_task("grasp banana", cfg)
    assert (g.verb, g.target, g.instruction) == ("grasp", "banana", "pick up the banana")
    p = parse_task("push croissant --direction 0,1 --distance 0.1", cfg)
    assert p.direction == (0.0, 1.0) and p.distance == 0.1
    assert p.instruction == "push the croissant 10 cm left"
    pull = parse_task("pull the banana --distance 0.08", cfg)
    assert pull.direction is None and pull.instruction == "pull the banana 8 cm towards the robot"
    assert parse_task("press button", cfg).instruction == "press the button"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("lift banana", "unknown task 'lift'"),
        ("grasp kiwi", "no object named 'kiwi'"),
        ("press banana", "no press button named 'banana'"),
        ("grasp button", "no object named 'button'"),
        ("push croissant --direction 0,0", "--direction"),
        ("push croissant --distance far", "--distance must be a number"),
        ("grasp banana --force 3", "not allowed"),
        ("grasp", "expected '<verb> <object>"),
    ],
)
def test_bad_tasks(sim_ws, text, message):
    with pytest.raises(TaskError, match=message):
        parse_task(text, load_world(sim_ws))
