"""The task base class, the registry and the one parser of task instructions.

A task is a frozen dataclass: ``target`` (the name of an object or button in the world) plus its typed
options (fields with a default and a ``help`` text; numeric ones may carry a ``range``). ``parse_task``
turns ``"<verb> <target> [--option value ...]"`` into the registered class of that verb, reading each
option by its field's type, so a new task is one new class with ``@register_task``.

A task's success test is a :class:`SuccessMonitor` over the twin's state, updated after every control tick:
the scripted runs (``run_task``) and the Gymnasium environment (``terminated``) decide success with the same one.
"""

from __future__ import annotations

import re
import shlex
import types
import typing
from dataclasses import Field, dataclass, field, fields
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ...errors import M2MError

if TYPE_CHECKING:
    from ...world.config import WorldConfig
    from ..twin import Twin
    from .motion import Executor

__all__ = ["TASKS", "SuccessMonitor", "Task", "TaskError", "option", "parse_task", "register_task", "unit_xy"]


class TaskError(M2MError, ValueError):
    """An instruction that cannot run in this world (unknown verb, object, option)."""


class SuccessMonitor:
    """A task's success test over one episode, from the twin's state at the episode's start (its constructor)
    and after every control tick (:meth:`update`). Success is latched: once reached it stays (the episode is
    done; what the robot does after that does not undo it).

    tick_s   seconds per control tick (for tests that need a duration)
    success  whether the task has succeeded by now
    reason   why it succeeded, or (until then) why not yet, in words
    info     the task's measurements at the last update (JSON-ready numbers)
    """

    def __init__(self, tick_s: float) -> None:
        self.tick_s = float(tick_s)
        self.success = False
        self.reason = "not started"
        self.info: dict[str, Any] = {}

    def update(self, twin: Twin) -> bool:
        """Measure the state after a tick; returns :attr:`success`."""
        ok, reason = self.measure(twin)
        if not self.success:
            self.success, self.reason = bool(ok), reason
        return self.success

    def measure(self, twin: Twin) -> tuple[bool, str]:
        """(whether the state now completes the task, why / why not): the subclass' test; updates :attr:`info`."""
        raise NotImplementedError


def option(default: Any, help: str, range: tuple[float, float] | None = None, unit: str = "metres") -> Any:
    """A task option: a dataclass field with its ``--name`` help (what a value must be) and, for numbers, the
    half-open ``range`` (lo, hi] it must lie in, in ``unit`` ("" for a plain number)."""
    return field(default=default, metadata={"help": help, "range": range, "unit": unit})


@dataclass(frozen=True)
class Task:
    """A scripted manipulation task on one named ``target``; subclasses add typed options as :func:`option`
    fields and say in their docstrings what the task is, what is randomised and what counts as success."""

    verb: ClassVar[str] = ""
    target: str

    def __post_init__(self) -> None:
        if not isinstance(self.target, str) or not self.target:
            raise TaskError(f"a {self.verb} task needs a target name, got {self.target!r}")
        for f in self.option_fields():
            lim = f.metadata.get("range")
            v = getattr(self, f.name)
            if lim is not None and v is not None:
                try:
                    v = float(v)
                except (TypeError, ValueError):
                    raise TaskError(f"--{f.name} must be {f.metadata['help']}") from None
                if not (lim[0] < v <= lim[1]):
                    unit = f.metadata.get("unit", "metres")
                    raise TaskError(f"--{f.name} {v} must be in ({lim[0]:g}, {lim[1]:g}]{' ' + unit if unit else ''}")
                object.__setattr__(self, f.name, v)

    # ---- what a task defines ------------------------------------------------------------------------------
    @property
    def instruction(self) -> str:
        """The language instruction of an episode."""
        raise NotImplementedError

    def check(self, world: WorldConfig) -> None:
        """Raise :class:`TaskError` unless ``world`` has a target this task can act on (default: a free object)."""
        objects = [o.name for o in world.objects]
        if self.target not in objects:
            raise TaskError(f"no object named {self.target!r} in the world; objects: {objects}")

    def monitor(self, twin: Twin, tick_s: float) -> SuccessMonitor:
        """The success test of an episode starting from the twin's current state (ticks of ``tick_s`` s)."""
        raise NotImplementedError

    def run(self, ex: Executor) -> tuple[str, dict[str, Any]]:
        """The scripted policy from the twin's current state, tick by tick through ``ex``: (why it gave up, or ""
        when it ran to its end; its own measurements). Success is the monitor's (``ex.monitor``), not its."""
        raise NotImplementedError

    # ---- shared ---------------------------------------------------------------------------------------
    @classmethod
    def option_fields(cls) -> tuple[Field, ...]:
        return tuple(f for f in fields(cls) if f.name != "target")

    def options(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in self.option_fields()}

    @property
    def text(self) -> str:
        """The instruction in the parser's syntax (options that differ from their defaults): round-trips
        through :func:`parse_task`."""
        words = [self.verb, self.target]
        for f in self.option_fields():
            v = getattr(self, f.name)
            if v is not None and v != f.default:
                words += [f"--{f.name}", _format(v)]
        return shlex.join(words)

    def to_json(self) -> dict[str, Any]:
        opts = {k: list(v) if isinstance(v, tuple) else v for k, v in self.options().items()}
        return {"verb": self.verb, "target": self.target, **opts, "instruction": self.instruction}

    @staticmethod
    def from_json(data: dict[str, Any]) -> Task:
        """The task of :meth:`to_json`'s dict (``instruction`` is derived, not read)."""
        cls = _task_class(str(data.get("verb", "")))
        names = {f.name for f in cls.option_fields()}
        return cls(data["target"], **{k: v for k, v in data.items() if k in names})


TASKS: dict[str, type[Task]] = {}


def register_task(cls: type[Task]) -> type[Task]:
    """Class decorator: make ``cls`` (a frozen dataclass subclass of :class:`Task`) the task of ``cls.verb``."""
    if not (isinstance(cls, type) and issubclass(cls, Task)) or not cls.verb or not re.fullmatch(r"[a-z]+", cls.verb):
        raise TypeError(f"{cls!r}: a task is a Task subclass with a lower-case verb")
    if cls.verb in TASKS and TASKS[cls.verb] is not cls:
        raise ValueError(f"task verb {cls.verb!r} is registered twice ({TASKS[cls.verb].__name__}, {cls.__name__})")
    TASKS[cls.verb] = cls
    return cls


def _task_class(verb: str) -> type[Task]:
    try:
        return TASKS[verb]
    except KeyError:
        raise TaskError(f"unknown task {verb!r}; known tasks: {', '.join(TASKS)}") from None


def _format(v: Any) -> str:
    if isinstance(v, tuple | list):
        return ",".join(_format(x) for x in v)
    if isinstance(v, float):
        short = f"{v:g}"
        return short if float(short) == v else repr(v)
    return str(v)


def _value(cls: type[Task], f: Field, raw: str) -> Any:
    """``raw`` as the option's type: a number, or a tuple of numbers written 'a,b'."""
    hint = typing.get_type_hints(cls)[f.name]
    if typing.get_origin(hint) in (typing.Union, types.UnionType):  # X | None
        hint = next(a for a in typing.get_args(hint) if a is not type(None))
    try:
        if hint is float or hint is int:
            return hint(raw)
        if typing.get_origin(hint) is tuple:
            return tuple(float(v) for v in re.split(r"[,\s]+", raw.strip()) if v)
        return raw
    except ValueError:
        raise TaskError(f"--{f.name} must be {f.metadata.get('help', 'a valid value')}") from None


def parse_task(text: str, world: WorldConfig | None = None) -> Task:
    """Parse ``"grasp banana"``, ``"press button"``, ``"push croissant --direction 0,1 --distance 0.1"``,
    ``"pull croissant --distance 0.08 [--direction -1,0] [--tolerance 0.02]"`` into the registered task of the
    verb; with ``world``, check the target exists and suits the verb. Raises :class:`TaskError` naming what was
    wrong."""
    try:
        words = shlex.split(text.strip())
    except ValueError as e:
        raise TaskError(f"cannot parse task {text!r}: {e}") from None
    if len(words) < 2:
        raise TaskError(f"task {text!r}: expected '<verb> <object> [options]' with verb one of {tuple(TASKS)}")
    verb, target, rest = words[0].lower(), words[1], words[2:]
    if verb not in TASKS:
        raise TaskError(f"unknown task {verb!r} in {text!r}; known tasks: {', '.join(TASKS)}")
    cls = TASKS[verb]
    if target.lower() == "the" and rest:
        target, rest = rest[0], rest[1:]
    opts: dict[str, str] = {}
    i = 0
    while i < len(rest):
        key = rest[i]
        if not key.startswith("--") or i + 1 >= len(rest):
            raise TaskError(f"task {text!r}: expected '--option value' pairs after the object, got {rest[i:]}")
        opts[key[2:]] = rest[i + 1]
        i += 2
    by_name = {f.name: f for f in cls.option_fields()}
    unknown = set(opts) - set(by_name)
    if unknown:
        raise TaskError(
            f"task {text!r}: option(s) {sorted(unknown)} not allowed for {verb!r} (allowed: {sorted(by_name)})"
        )
    try:
        task = cls(target, **{k: _value(cls, by_name[k], v) for k, v in opts.items()})
        if world is not None:
            task.check(world)
    except TaskError as e:
        raise TaskError(f"task {text!r}: {e}") from None
    return task


def unit_xy(v: Any, name: str, help: str) -> tuple[float, float] | None:
    """A direction option as a unit xy tuple (None stays None); :class:`TaskError` "--name must be help"."""
    if v is None:
        return None
    try:
        d = np.asarray(v, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        d = np.zeros(0)
    n = np.linalg.norm(d) if d.shape == (2,) else 0.0
    if n < 1e-9:
        raise TaskError(f"--{name} must be {help}")
    # a unit vector stays as it is, so that to_json / text round-trip exactly
    return tuple((d / n if abs(n - 1.0) > 1e-12 else d).tolist())
