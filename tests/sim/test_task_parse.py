"""Task instructions: parsing and clear errors before any simulation (no Genesis needed)."""

import pytest

from mirage2matter.sim.tasks import TaskError, parse_task
from mirage2matter.world import load_world


def test_parse_tasks(sim_ws):
    cfg = load_world(sim_ws / "world")
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
        parse_task(text, load_world(sim_ws / "world"))


def test_tasks_round_trip_and_pickle():
    import pickle

    from mirage2matter.sim.tasks import Task

    for text in ("grasp banana", "press button", "push croissant --direction 1,1 --tolerance 0.05",
                 "pull banana --distance 0.08", "pull banana --direction -1,0"):  # fmt: skip
        task = parse_task(text)
        assert parse_task(task.text) == task
        assert Task.from_json(task.to_json()) == task
        assert pickle.loads(pickle.dumps(task)) == task  # tasks travel to worker processes as they are
    assert parse_task("push croissant").direction == (1.0, 0.0)  # push: forward unless told


def test_a_new_task_is_one_registered_class():
    from dataclasses import dataclass

    from mirage2matter.sim.tasks import TASKS, Task, option, register_task

    @register_task
    @dataclass(frozen=True)
    class WaveTask(Task):
        """Task: wave at ``target``. Success: always."""

        verb = "wave"
        height: float = option(0.1, "a number in metres", range=(0.0, 0.5))

        @property
        def instruction(self) -> str:
            return f"wave at the {self.target} {round(100 * self.height)} cm up"

    try:
        t = parse_task("wave banana --height 0.2")
        assert isinstance(t, WaveTask) and t.height == 0.2 and t.instruction == "wave at the banana 20 cm up"
        with pytest.raises(TaskError, match=r"--height 0.9 must be in \(0, 0.5\] metres"):
            parse_task("wave banana --height 0.9")
        with pytest.raises(TaskError, match=r"not allowed for 'wave' \(allowed: \['height'\]\)"):
            parse_task("wave banana --distance 0.1")
    finally:
        TASKS.pop("wave")
    with pytest.raises(TaskError, match="unknown task 'wave'"):
        parse_task("wave banana")
