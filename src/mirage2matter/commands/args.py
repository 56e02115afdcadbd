"""Argument types, output checks and messages shared by the commands."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import textwrap
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..configs import add_flags
from ..errors import M2MError
from ..stages import STAGES
from ..stages.base import PipelineSettings

__all__ = [
    "CliError", "Formatter", "add_settings", "backend", "check_output", "info", "int_at_least", "positive_float",
    "rgb", "show", "xyz",
]  # fmt: skip


class CliError(M2MError):
    """A bad command-line argument; printed as ``m2m: error: <message>`` with exit status 2."""


def int_at_least(lo: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text.replace("_", ""))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < lo:
            raise argparse.ArgumentTypeError(f"must be >= {lo}, got {value}")
        return value

    parse.__name__ = "integer"  # argparse names the type in "invalid <type> value" messages
    return parse


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def rgb(text: str) -> tuple[float, float, float]:
    """``R,G,B`` in 0..1, or one value for grey."""
    parts = [p.strip() for p in text.split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected R,G,B numbers in 0..1 (e.g. 1,1,1), got {text!r}") from None
    if len(values) == 1:
        values *= 3
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise argparse.ArgumentTypeError(f"expected three values in 0..1 as R,G,B (e.g. 0.5,0.5,0.5), got {text!r}")
    return values[0], values[1], values[2]


def xyz(text: str, flag: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 3:
        raise CliError(f"{flag} must be three numbers x,y,z (metres, robot-base frame), got {text!r}")
    return v  # type: ignore[return-value]


def info(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def show(path: Path) -> str:
    """A path as the user would type it: relative to the current directory when below it."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def check_output(path: Path, flag: str, suffixes: Sequence[str]) -> None:
    """Fail before any expensive work when ``path`` cannot be written."""
    if path.suffix.lower() not in suffixes:
        raise CliError(f"{flag} {path}: unsupported file type {path.suffix or '(none)'}; use {' or '.join(suffixes)}")
    parent = path.parent
    if not parent.is_dir():
        what = "is not a directory" if parent.exists() else "does not exist"
        raise CliError(f"{flag} {path}: output directory {parent} {what}; create it first (mkdir -p {parent})")
    if path.is_dir():
        raise CliError(f"{flag} {path} is a directory; give a file name")


def backend(name: str) -> str:
    """The render backend ``--backend name`` resolves to; CliError naming the flag when it cannot run here."""
    from ..gaussians.render import BackendError, resolve_backend

    try:
        return resolve_backend(name)
    except BackendError as e:
        raise CliError(f"--backend {name}: {e}") from e


# ---- the help of a command with every stage's settings as flags (m2m init, m2m demo) -------------------------------
class Formatter(argparse.HelpFormatter):
    """argparse's help, its description and epilog wrapped to the terminal (never inside a flag) except the lines
    that begin with a space (an example's command lines), which are kept as written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        out: list[str] = []
        paragraph: list[str] = []
        for line in [*text.splitlines(), ""]:
            if line.strip() and not line[0].isspace():
                paragraph.append(line.strip())
                continue
            if paragraph:
                wrap = {"initial_indent": indent, "subsequent_indent": indent, "break_on_hyphens": False}
                out += textwrap.wrap(" ".join(paragraph), width, **wrap)  # a flag stays whole
                paragraph = []
            if line.strip():
                out.append(indent + line)
        return "\n".join(out)


class _Help(argparse.Action):
    """``-h/--help [STAGE]`` and ``--help-all``: print the help (see :func:`add_settings`) and exit."""

    def __init__(self, option_strings: Sequence[str], dest: str, nargs: Any = None, **kw: Any) -> None:
        super().__init__(option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, nargs=nargs, **kw)
        self.sections: dict[str, argparse._ArgumentGroup] = {}

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string: Any = None
    ) -> None:
        if option_string == "--help-all":
            text = _format_help(parser, _own_groups(parser, self.sections) + list(self.sections.values()))
        elif values is None:
            text = _format_help(parser, _own_groups(parser, self.sections)) + _rest(parser, self.sections)
        else:
            text = _format_help(parser, [self.sections[_section(parser, self.sections, values)]], whole=False)
        parser._print_message(text, sys.stdout)
        parser.exit()


def _section(parser: argparse.ArgumentParser, sections: dict[str, Any], word: str) -> str:
    """The section ``--help WORD`` names: a stage's name (``head_view``), its flag prefix (``head-view``) or its
    command (``train-scene``); a usage error otherwise."""
    commands = {s.command: s.name for s in STAGES}
    name = commands.get(word, word.replace("-", "_"))
    if name not in sections:
        parser.error(f"argument -h/--help: no stage {word!r}; give one of {', '.join(_prefixes(sections))}")
    return name


def _prefixes(sections: dict[str, Any]) -> list[str]:
    return [name.replace("_", "-") for name in (sections or [s.name for s in STAGES])]


def _own_groups(parser: argparse.ArgumentParser, sections: dict[str, Any]) -> list[argparse._ArgumentGroup]:
    """The command's own help sections (its inputs first, its options after), without the stages'."""
    own = [g for g in parser._action_groups if g not in sections.values() and g._group_actions]
    return sorted(own, key=lambda g: g is parser._optionals)


def _format_help(parser: argparse.ArgumentParser, groups: list[argparse._ArgumentGroup], whole: bool = True) -> str:
    """``parser``'s help with only ``groups`` (and, when ``whole``, its usage, description and epilog)."""
    f = parser._get_formatter()
    if whole:
        f.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups)
        f.add_text(parser.description)
    for g in groups:
        f.start_section(g.title)
        f.add_text(g.description)
        f.add_arguments(g._group_actions)
        f.end_section()
    if whole:
        f.add_text(parser.epilog)
    return f.format_help()


def _rest(parser: argparse.ArgumentParser, sections: dict[str, argparse._ArgumentGroup]) -> str:
    """The short help's last lines: how to see the flags it leaves out."""
    width = max(parser._get_formatter()._width, 60)
    count = sum(len(g._group_actions) for g in sections.values())
    more = f"{count} more flags, " if count else ""
    head = (f"every stage's settings ({more}not listed above): each field of m2m.yaml is also a flag, "
            "--<stage>.<field> VALUE (e.g. --scene.minutes 6)")  # fmt: skip
    lines = textwrap.wrap(head, width, break_on_hyphens=False)
    indent = " " * 26
    one, every = f"  {parser.prog} --help STAGE", f"  {parser.prog} --help-all"
    stages = f"one stage's; STAGE: {', '.join(_prefixes(sections))}"
    lines += textwrap.wrap(stages, width, initial_indent=f"{one:<26}", subsequent_indent=indent,
                           break_on_hyphens=False)  # fmt: skip
    lines.append(f"{every:<26}every flag")
    return "\n" + "\n".join(lines) + "\n"


def add_settings(parser: argparse.ArgumentParser, full: bool, base: Any = None) -> None:
    """The pipeline's own settings (``--robot``) and every stage's as ``--<stage>.<field>`` flags (the stages' when
    ``full``: this imports every stage's
    libraries; ``base``: the PipelineConfig whose values ``--help`` shows, default the Configs' defaults), and the
    help flags of a command that has them all. Call it on a parser made with ``add_help=False``, after its own
    flags: its usage line shows those, and the stages' flags as one ``[--<stage>.<field> VALUE]``.

    - ``--help``: the command's own flags, then how to see the rest (the stages' flags are not listed);
    - ``--help STAGE``: that stage's flags (``STAGE``: its m2m.yaml section, flag prefix or command);
    - ``--help-all``: every flag.

    The stages' flags parse the same whichever help lists them.
    """
    pipeline = {f.name for f in dataclasses.fields(PipelineSettings)}  # the whole pipeline's settings (the robot)
    add_flags(parser, PipelineSettings, base=base, skip={a.dest for a in parser._actions})  # unless listed already
    short = "show this help; --help STAGE: that stage's settings instead (e.g. --help scene)"
    helps = [
        parser.add_argument("-h", "--help", action=_Help, nargs="?", metavar="STAGE", help=short),
        parser.add_argument("--help-all", action=_Help, nargs=0, help="show every flag, each stage's settings too"),
    ]
    # the usage line, made before the stages' flags are added (they would make it a page long)
    stages = argparse.Action(["--<stage>.<field>"], dest="settings", metavar="VALUE")
    f = parser._get_formatter()
    f.add_usage(None, [*parser._actions, stages], parser._mutually_exclusive_groups)
    parser.usage = f.format_help().strip("\n").removeprefix("usage: ")
    if full:
        from ..stages.pipeline import PipelineConfig

        sections = add_flags(parser, PipelineConfig, base=base, sections=True, skip=pipeline)
        for action in helps:
            action.sections = sections  # type: ignore[attr-defined]
