"""Scripted tasks with language instructions on a :class:`~mirage2matter.sim.twin.Twin`.

Each task is a registered class (``@register_task``): its verb, typed options, instruction, target check,
scripted policy and success test; ``parse_task`` turns an instruction string into one, once, at the border.

- ``grasp <object>`` (:class:`GraspTask`): top-down antipodal grasp, lift, hold.
- ``press <button>`` (:class:`PressTask`): press a press button past its threshold.
- ``push <object> --direction dx,dy --distance d [--tolerance t]`` (:class:`PushTask`) and ``pull ...``
  (:class:`PullTask`, towards the robot base by default): slide it with the closed fingers.

``run_task`` records a :class:`StepRecord` at ``control_hz`` and calls ``on_step`` with it (the twin is then
in that record's state, so a caller can render). Actions are the arm's joint targets 0.1 s ahead [n_arm] and the
finger target (m per finger: the robot's ``gripper_open`` .. ``gripper_closed``) [1].
"""

from .base import TASKS, Task, TaskError, option, parse_task, register_task
from .grasp import GraspTask, grasp_candidates
from .motion import Executor, StepRecord, topdown
from .press import PressTask
from .push import PullTask, PushTask
from .run import TaskResult, evaluate, run_task

__all__ = [
    "TASKS",
    "Executor",
    "GraspTask",
    "PressTask",
    "PullTask",
    "PushTask",
    "StepRecord",
    "Task",
    "TaskError",
    "TaskResult",
    "evaluate",
    "grasp_candidates",
    "option",
    "parse_task",
    "register_task",
    "run_task",
    "topdown",
]
