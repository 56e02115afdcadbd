"""Scripted tasks with language instructions on a :class:`~mirage2matter.sim.twin.Twin`.

Each task is a registered class (``@register_task``): its verb, typed options, instruction, target check,
scripted policy and success test; ``parse_task`` turns an instruction string into one, once, at the border.

- ``grasp <object>`` (:class:`GraspTask`): top-down antipodal grasp, lift, hold.
- ``press <button>`` (:class:`PressTask`): press a press button past its threshold.
- ``push <object> --direction dx,dy --distance d [--tolerance t]`` (:class:`PushTask`) and ``pull ...``
  (:class:`PullTask`, towards the robot base by default): slide it with the closed fingers.

``run_task`` runs a script as control ticks at ``control_hz``: each tick's action [n_arm + 1] (the arm's joint
targets at the tick's end, the gripper target in m per finger: the robot's ``gripper_open`` .. ``gripper_closed``)
goes through ``Twin.act``, the one control function the Gymnasium environment steps through too, and is recorded
as a :class:`StepRecord` with the state at the tick's start; ``on_step`` gets it before the tick runs (the twin
is then in that record's state, so a caller can render). Success is each task's :class:`SuccessMonitor`,
updated after every tick.
"""

from .base import TASKS, SuccessMonitor, Task, TaskError, option, parse_task, register_task
from .grasp import GraspTask, LiftMonitor, grasp_candidates
from .motion import Executor, StepRecord, steps_per_tick, topdown
from .press import PressMonitor, PressTask
from .push import PullTask, PushTask, SlideMonitor
from .run import TaskResult, evaluate, run_task

__all__ = [
    "TASKS",
    "Executor",
    "GraspTask",
    "LiftMonitor",
    "PressMonitor",
    "PressTask",
    "PullTask",
    "PushTask",
    "SlideMonitor",
    "StepRecord",
    "SuccessMonitor",
    "Task",
    "TaskError",
    "TaskResult",
    "evaluate",
    "grasp_candidates",
    "option",
    "parse_task",
    "register_task",
    "run_task",
    "steps_per_tick",
    "topdown",
]
