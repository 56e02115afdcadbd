"""Typed config dataclasses as command-line flags and as YAML: a default lives once, in its Config.

Every stage's Config is a dataclass whose fields carry the defaults and whose class docstring documents
each field on a line of its own (``name   what it is``, continuation lines indented further). From that:

- :func:`add_flags` adds one ``--field-name`` flag per field (nested dataclasses as ``--outer.field``, optionally
  one help section per nested dataclass) with the field's doc (reStructuredText markup stripped) and default in
  ``--help`` (once: not when the doc already says it); the flags default to *absent*, so :func:`from_flags` starts
  from a base config (the Config's defaults, or the workspace's ``m2m.yaml``) and changes only what was
  given. ``m2m <stage>``, ``m2m init``, ``m2m demo`` and ``m2m run`` therefore cannot drift apart.
- :func:`from_dict` / :func:`to_dict` read and write the same fields as YAML-ready mappings: unknown keys
  and wrong types are errors naming the field (``ConfigError.field``, so a file reader can add the line;
  ``"no"`` is not a bool), paths are resolved against the file's folder and written relative to it (when
  below it; else absolute).
- :func:`to_yaml` writes a Config as YAML text with each field's doc as a comment above it (``m2m.yaml``).

Supported field types: bool, int, float, str, Path, ``X | None``, ``Literal[...]``, ``tuple[T, ...]`` /
``list[T]`` (several values), fixed tuples ``tuple[T, T]`` (``a,b``), ``dict[str, T]`` (``NAME=VALUE``,
repeatable) and nested dataclasses. Field metadata: ``{"positional": True}`` makes a field the command's
optional positional argument; ``{"flag": False}`` keeps an internal field off the command line; ``{"flags": ("-w",
"--workspace")}`` names its flag otherwise, ``{"metavar": "PX"}`` its value, ``{"parse": fn}`` reads the flag's word
(an argparse type); ``{"shared": True}`` marks a stage's field that is the whole pipeline's (``stages.base.SHARED``:
m2m.yaml holds it once, at the top, and its section no flag of its own); ``{"output": True}``
marks a path the stage writes (a pipeline run checks every other path exists before it starts); ``{"range":
Range(...)}`` (:func:`ranged`) the numbers a field may hold.

Every number read (from YAML or a flag) is checked at once: a float is finite (NaN and infinities never pass, whatever
the field), and a field with a :class:`Range` holds only numbers inside it (each number of a list, pair or mapping);
the ConfigError names the field and the range. :func:`check_ranges` checks a whole Config (its defaults, one built in
code) the same way.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import functools
import inspect
import math
import re
import textwrap
import types
import typing
from collections.abc import Collection
from pathlib import Path
from typing import Any, Literal, Union

import yaml

from .errors import M2MError

__all__ = ["ConfigError", "Range", "add_flags", "check_ranges", "field_docs", "from_dict", "from_flags", "range_errors",
           "ranged", "to_dict", "to_yaml"]

_DOC_LINE = re.compile(r"^(\w+)\s{2,}(\S.*)$")


class ConfigError(M2MError, ValueError):
    """A config value of the wrong type or an unknown key; the message names the field.

    field   the dotted field it is about (``scene.minutes``, ``objects.names[2]``), so a reader of a file can
            add the line it is on; None when the message is about no one field
    """

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


# ---- ranges ---------------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Range:
    """The numbers a field may hold (each number of a list, pair or mapping field).

    lo, hi      the bounds (None: none on that side)
    lo_open     lo itself excluded (``gt``); hi_open likewise (``lt``)
    off         one more value outside the bounds that means "not used" (``0: none`` in the field's doc)
    ordered     a (lo, hi) pair: the first no larger than the second
    """

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    off: float | None = None
    ordered: bool = False

    def text(self) -> str:
        """The range as the reference and the messages write it: ``[1, 100]``, ``(0, 10080]``, ``0 or [16, 4096]``."""
        if self.lo is None and self.hi is None:
            body = "finite"
        else:
            left = "(" if self.lo_open or self.lo is None else "["
            right = ")" if self.hi_open or self.hi is None else "]"
            body = f"{left}{_num(self.lo, '-inf')}, {_num(self.hi, 'inf')}{right}"
        if self.off is not None:
            body = f"{_num(self.off, '')} or {body}"
        return body + (", first <= second" if self.ordered else "")

    def holds(self, x: float) -> bool:
        if self.off is not None and x == self.off:
            return True
        above = self.lo is None or (x > self.lo if self.lo_open else x >= self.lo)
        below = self.hi is None or (x < self.hi if self.hi_open else x <= self.hi)
        return above and below


def _num(x: float | None, none: str) -> str:
    return none if x is None else (f"{x:g}" if isinstance(x, float) else str(x))


def ranged(default: Any = dataclasses.MISSING, *, ge: float | None = None, gt: float | None = None,
           le: float | None = None, lt: float | None = None, off: float | None = None, ordered: bool = False,
           metadata: dict | None = None, **kw: Any) -> Any:  # fmt: skip
    """A dataclass field (``dataclasses.field``) whose numbers must lie within ``ge``/``gt`` .. ``le``/``lt`` (or be
    ``off``); checked whenever the Config is read (:func:`from_dict`, :func:`from_flags`) or :func:`check_ranges`."""
    rng = Range(gt if gt is not None else ge, lt if lt is not None else le, gt is not None, lt is not None, off,
                ordered)  # fmt: skip
    return dataclasses.field(default=default, metadata={**(metadata or {}), "range": rng}, **kw)


def _numbers(value: Any, where: str):
    """(where, number) of every number in ``value`` (a scalar, or lists / tuples / mappings of them); bools are not."""
    if isinstance(value, bool):
        return
    if isinstance(value, int | float):
        yield where, value
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            yield from _numbers(v, f"{where}[{i}]")
    elif isinstance(value, dict):
        for k, v in value.items():
            yield from _numbers(v, f"{where}.{k}")


def check_value(f: dataclasses.Field, value: Any, where: str, field: str | None = None) -> None:
    """ConfigError naming ``where`` (the dotted ``field`` for a reader to find the line) unless every number in
    ``value`` is finite and inside the field's :class:`Range`."""
    rng: Range = f.metadata.get("range") or Range()
    for at, x in _numbers(value, where):
        allowed = f"allowed: {'an integer' if isinstance(x, int) else 'a number'} in {rng.text()}"
        if isinstance(x, float) and not math.isfinite(x):
            raise ConfigError(f"{at}: {x} is not a finite number; {allowed}", field or where)
        if not rng.holds(x):
            raise ConfigError(f"{at}: {x!r} is out of range; {allowed}", field or where)
    if rng.ordered and isinstance(value, tuple | list) and len(value) == 2 and value[0] > value[1]:
        raise ConfigError(f"{where}: {list(value)} has its first value above its second; give lo,hi", field or where)


def range_errors(cfg: Any, prefix: str = "") -> list[ConfigError]:
    """A ConfigError per field of the Config ``cfg`` (nested Configs too) holding a number that is not finite or
    outside the field's range, each naming the dotted field (``prefix`` before it, e.g. the stage's section)."""
    out = []
    for f in dataclasses.fields(cfg):
        value, name = getattr(cfg, f.name), f"{prefix}.{f.name}" if prefix else f.name
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            out += range_errors(value, name)
            continue
        try:
            check_value(f, value, name)
        except ConfigError as e:
            out.append(e)
    return out


def check_ranges(cfg: Any, prefix: str = "") -> None:
    """:func:`range_errors`' first, raised."""
    errors = range_errors(cfg, prefix)
    if errors:
        raise errors[0]


# ---- field documentation and types ------------------------------------------------------------------
def field_docs(cls: type) -> dict[str, str]:
    """{field: doc} from the class docstrings (a subclass's docs win over its bases')."""
    names = {f.name for f in dataclasses.fields(cls)}
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        doc = klass.__dict__.get("__doc__")
        if not doc or not dataclasses.is_dataclass(klass):
            continue
        current = None
        for raw in inspect.cleandoc(doc).splitlines():
            m = _DOC_LINE.match(raw)
            if m and m.group(1) in names:
                current = m.group(1)
                docs[current] = m.group(2).strip()
            elif current and raw.startswith(" ") and raw.strip():
                docs[current] += " " + raw.strip()
            else:
                current = None
    return docs


def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _unwrap_optional(tp: Any) -> tuple[Any, bool]:
    if typing.get_origin(tp) in (Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0], True
    return tp, False


def _scalar(tp: Any, value: Any, where: str) -> Any:
    """``value`` (from YAML or a command-line word) as a ``tp``; ConfigError naming ``where`` otherwise."""
    if typing.get_origin(tp) is Literal:
        choices = typing.get_args(tp)
        if value not in choices:
            raise ConfigError(f"{where}: {value!r} is not one of {', '.join(map(str, choices))}", where)
        return value
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: expected true or false, got {value!r}", where)
    if tp is int:
        if isinstance(value, str):
            try:
                return int(value.replace("_", ""))
            except ValueError:
                pass
        elif isinstance(value, int) and not isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: expected an integer, got {value!r}", where)
    if tp is float:
        if isinstance(value, str):
            try:
                return float(value)
            except ValueError:
                pass
        elif isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
        raise ConfigError(f"{where}: expected a number, got {value!r}", where)
    if tp is str:
        if isinstance(value, str):
            return value
        raise ConfigError(f"{where}: expected text, got {value!r}", where)
    if tp is Path:
        if isinstance(value, str | Path) and str(value):
            return Path(value)
        raise ConfigError(f"{where}: expected a path, got {value!r}", where)
    raise TypeError(f"{where}: unsupported config field type {tp!r}")


def _is_config(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _coerce(tp: Any, value: Any, where: str) -> Any:
    """A YAML value (or parsed flag) of field type ``tp``."""
    tp, optional = _unwrap_optional(tp)
    if value is None:
        if optional:
            return None
        raise ConfigError(f"{where}: a value is required (null given)", where)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (tuple, list):
        if isinstance(value, str) or not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {value!r}", where)
        if origin is tuple and not (len(args) == 2 and args[1] is Ellipsis):
            if len(value) != len(args):
                raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}", where)
            return tuple(_coerce(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value, strict=True)))
        items = [_coerce(args[0], v, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {value!r}", where)
        return {_scalar(args[0], k, where): _coerce(args[1], v, f"{where}.{k}") for k, v in value.items()}
    return _scalar(tp, value, where)


# ---- YAML-ready mappings ---------------------------------------------------------------------------------
def from_dict(cls: type, data: Any, where: str = "", base_dir: Path | None = None, base: Any = None) -> Any:
    """A ``cls`` from a mapping (e.g. one section of ``m2m.yaml``): ``base`` (default ``cls()``) with the
    given keys replaced. Relative paths resolve against ``base_dir``. ConfigError names the field."""
    base = cls() if base is None else base
    if data is None:
        return base
    if not isinstance(data, dict):
        raise ConfigError(f"{where or cls.__name__}: expected a mapping of settings, got {type(data).__name__}",
                          where or None)  # fmt: skip
    if hasattr(cls, "upgrade"):  # settings an earlier version wrote, in their current form
        data = cls.upgrade(dict(data))
    hints = _hints(cls)
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [k for k in data if k not in known]
    if unknown:
        first = str(unknown[0])
        close = difflib.get_close_matches(first, list(known), n=1)
        hint = f"; did you mean {close[0]}?" if close else ""
        raise ConfigError(
            f"{where + ': ' if where else ''}unknown setting(s) {', '.join(map(str, unknown))}{hint} (known: "
            f"{', '.join(known)})",
            f"{where}.{first}" if where else first,
        )
    changes = {}
    for key, value in data.items():
        field_where = f"{where}.{key}" if where else key
        tp = hints[key]
        inner, _ = _unwrap_optional(tp)
        if _is_config(inner):
            changes[key] = from_dict(inner, value, field_where, base_dir, getattr(base, key))
            continue
        v = _coerce(tp, value, field_where)
        check_value(known[key], v, field_where)
        changes[key] = _resolve_paths(v, base_dir)
    return dataclasses.replace(base, **changes)


def _resolve_paths(value: Any, base_dir: Path | None) -> Any:
    if base_dir is None:
        return value
    if isinstance(value, Path):
        return value if value.is_absolute() else (base_dir / value).resolve()
    if isinstance(value, tuple | list):
        return type(value)(_resolve_paths(v, base_dir) for v in value)
    if isinstance(value, dict):
        return {k: _resolve_paths(v, base_dir) for k, v in value.items()}
    return value


def to_dict(cfg: Any, base_dir: Path | None = None) -> dict[str, Any]:
    """A YAML-ready mapping of ``cfg`` (tuples as lists). With ``base_dir`` (the folder of the file it goes
    to) a path is written relative to it when below it, else absolute: a relative path given on the command
    line means the current folder, which a reader of the file does not know."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, Path):
            if base_dir is not None:
                try:
                    return str(v.resolve().relative_to(base_dir.resolve()))
                except ValueError:
                    return str(v.resolve())
            return str(v)
        if isinstance(v, tuple | list):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {str(k): plain(x) for k, x in v.items()}
        return v

    return plain(cfg)


def fingerprinted(cfg: Any) -> dict[str, Any]:
    """:func:`to_dict` of ``cfg`` as fingerprints see it: without top-level fields whose metadata is
    ``{"fingerprint": "when_set"}`` (``stages.base.ADDED_LATER``) while at their default, and never with those whose
    metadata is ``{"fingerprint": "never"}`` (how a stage runs, not what it makes: ``objects.workers``)."""
    d = to_dict(cfg)
    for f in dataclasses.fields(cfg):
        when = f.metadata.get("fingerprint")
        if when == "never" or (when == "when_set" and getattr(cfg, f.name) == f.default):
            d.pop(f.name)
    return d


def to_yaml(cfg: Any, base_dir: Path | None = None, header: str = "", notes: dict[str, str] | None = None) -> str:
    """``cfg`` as YAML text that :func:`from_dict` reads back to ``cfg``: every field, each under its doc (from
    the class docstrings) as a comment; nested Configs as indented sections. ``header``: comment lines on top;
    ``notes``: {top-level field: a comment line above its section}. Paths as :func:`to_dict` writes them."""
    out = [line.rstrip() for line in header.splitlines()]

    def comment(text: str, pad: str) -> list[str]:
        return [pad + "# " + line for line in textwrap.wrap(text, max(40, 116 - len(pad)), break_on_hyphens=False)]

    def emit(cls: type, values: dict[str, Any], pad: str) -> None:
        docs, hints = field_docs(cls), _hints(cls)
        for f in dataclasses.fields(cls):
            if pad and f.metadata.get("shared"):  # the whole pipeline's: written once, at the top
                continue
            value, (tp, _) = values[f.name], _unwrap_optional(hints[f.name])
            section = _is_config(tp) and isinstance(value, dict)
            if not pad and (section or notes):
                out.append("")
            if not pad and notes and f.name in notes:
                out.extend(comment(notes[f.name], pad))
            if f.name in docs:
                out.extend(comment(docs[f.name], pad))
            if section:
                out.append(f"{pad}{f.name}:")
                emit(tp, value, pad + "  ")
            else:
                out.extend(pad + line for line in _yaml_value(f.name, value).splitlines())

    emit(type(cfg), to_dict(cfg, base_dir), "")
    return "\n".join(out).lstrip("\n") + "\n"


def _yaml_value(name: str, value: Any) -> str:
    """``name: value`` as YAML: a list of texts one item per line, other lists and mappings of numbers in flow
    style (``[0.0, 1.0]``), no line folded."""
    texts = isinstance(value, list) and value and all(isinstance(v, str) for v in value)
    flow = None if isinstance(value, list | dict) and not texts else False  # None: innermost collections in flow
    return yaml.dump({name: value}, Dumper=_dumper(), sort_keys=False, default_flow_style=flow, width=1 << 16,
                     allow_unicode=True)  # fmt: skip


@functools.cache
def _dumper() -> type:
    """PyYAML's safe dumper, with a list's items indented under its key."""
    class Dumper(yaml.SafeDumper):
        def increase_indent(self, flow: bool = False, indentless: bool = False) -> Any:
            return super().increase_indent(flow, False)

    return Dumper


# ---- command-line flags ---------------------------------------------------------------------------------
def _flag(prefix: str, name: str, negate: bool = False) -> str:
    """``--outer.field-name`` (``--outer.no-field-name`` when ``negate``)."""
    return "--" + prefix.replace("_", "-") + ("no-" if negate else "") + name.replace("_", "-")


class _Switch(argparse.Action):
    """``--x.flag`` / ``--x.no-flag`` for a bool field (argparse's BooleanOptionalAction would say --no-x.flag)."""

    def __init__(self, option_strings, dest, negative: str = "", **kw):
        super().__init__([*option_strings, negative], dest, nargs=0, **kw)
        self.negative = negative

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, option_string != self.negative)

    def format_usage(self) -> str:
        return " | ".join(self.option_strings)


def _word_parser(tp: Any, where: str):
    def parse(text: str) -> Any:
        try:
            return _scalar(tp, text, where)
        except ConfigError as e:
            raise argparse.ArgumentTypeError(str(e).split(": ", 1)[-1]) from None

    parse.__name__ = getattr(tp, "__name__", "value")
    return parse


def _fixed_tuple_parser(args: tuple, where: str):
    def parse(text: str) -> tuple:
        parts = [p.strip() for p in text.split(",")]
        if len(parts) != len(args):
            raise argparse.ArgumentTypeError(f"expected {len(args)} comma-separated values, got {text!r}")
        try:
            return tuple(_scalar(a, p, where) for a, p in zip(args, parts, strict=True))
        except ConfigError as e:
            raise argparse.ArgumentTypeError(str(e).split(": ", 1)[-1]) from None

    parse.__name__ = "values"
    return parse


def _key_value_parser(key_tp: Any, tp: Any, where: str):
    """NAME=VALUE; a list value is comma-separated (``360=0.1,0.2``)."""
    many = typing.get_origin(tp) in (list, tuple)

    def parse(text: str) -> tuple[Any, Any]:
        name, sep, value = text.partition("=")
        if not sep or not name or not value:
            raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
        try:
            return _scalar(key_tp, name, where), (_coerce(tp, value.split(","), where) if many else
                                                  _scalar(tp, value, where))  # fmt: skip
        except ConfigError as e:
            raise argparse.ArgumentTypeError(str(e).split(": ", 1)[-1]) from None

    parse.__name__ = "NAME=VALUE"
    return parse


_ROLE = re.compile(r":[\w:]+:`([^`]+)`")  # :class:`~a.B`, :func:`.f`, :meth:`title <target>`
_LITERAL = re.compile(r"``(.+?)``")
_SAYS_DEFAULT = re.compile(r"\bdefault\b", re.IGNORECASE)


def _plain(text: str) -> str:
    """A docstring's text for ``--help``: reStructuredText roles as their name (``:class:`~a.b.C``` -> C), a
    literal as itself (a phrase of several words in single backquotes, as the hand-written help quotes commands)."""

    def role(m: re.Match) -> str:
        target = m.group(1).strip()
        if "<" in target:  # :role:`title <target>`
            return target.split("<")[0].strip()
        return target.split(".")[-1] if target.startswith("~") else target.lstrip(".")

    text = _ROLE.sub(role, text)
    return _LITERAL.sub(lambda m: f"`{m.group(1)}`" if " " in m.group(1) else m.group(1), text)


def _help_text(doc: str, value: Any, own_default: Any) -> str:
    """A flag's help: its doc and default, the default said once. A doc that speaks of the default (``(default: the
    joints file's)``, ``Off by default``) already explains the field's own; only a base's other value is added."""
    doc, shown = _plain(doc), _default_text(value)
    if not _SAYS_DEFAULT.search(doc):
        return f"{doc} (default: {shown})".strip()
    if shown == "none" or value == own_default:
        return doc
    return f"{doc} (here: {shown})"


def _default_text(value: Any) -> str:
    if isinstance(value, tuple | list):
        return " ".join(map(str, value)) if value else "none"
    if isinstance(value, dict):
        return ", ".join(f"{k}={v}" for k, v in value.items()) or "none"
    return "none" if value is None else str(value)


def add_flags(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    cls: type,
    prefix: str = "",
    base: Any = None,
    sections: bool = False,
    skip: Collection[str] = (),
) -> dict[str, argparse._ArgumentGroup]:
    """One flag per field of ``cls`` (recursively), documented from the docstring; ``base`` supplies the
    defaults shown in ``--help`` (default: ``cls()``). With ``sections`` each nested Config field of ``cls`` gets
    a help section (argument group) of its own, described by its doc; returns them, {field: group}. ``skip``:
    fields (top-level) that get no flag here (a command that adds them itself). A nested Config's field marked
    ``{"shared": True}`` is the enclosing Config's own field of that name and gets no flag of its own."""
    base = cls() if base is None else base
    own = cls()  # the defaults the docs describe
    docs, hints = field_docs(cls), _hints(cls)
    groups: dict[str, argparse._ArgumentGroup] = {}
    for f in dataclasses.fields(cls):
        if f.metadata.get("flag", True) is False or f.name in skip or (prefix and f.metadata.get("shared")):
            continue
        tp, _ = _unwrap_optional(hints[f.name])
        default = getattr(base, f.name)
        if _is_config(tp):
            target = parser
            if sections:
                title = f"{f.name} settings (--{(prefix + f.name).replace('_', '-')}.*)"
                doc = _plain(docs.get(f.name, "")) or None
                target = groups[f.name] = parser.add_argument_group(title, doc)
            add_flags(target, tp, f"{prefix}{f.name}.", default)
            continue
        dest, where = prefix + f.name, _flag(prefix, f.name)
        help_text = _help_text(docs.get(f.name, ""), default, getattr(own, f.name))
        kw: dict[str, Any] = {"dest": dest, "default": argparse.SUPPRESS, "help": help_text.replace("%", "%%")}
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if f.metadata.get("parse"):  # the flag's own reading of its word (``R,G,B`` or one grey value)
            kw.update(type=f.metadata["parse"], metavar=f.name.upper())
        elif tp is bool:
            kw.update(action=_Switch, negative=_flag(prefix, f.name, negate=True))
        elif typing.get_origin(tp) is Literal:
            kw["choices"] = typing.get_args(tp)
        elif origin in (tuple, list) and (origin is list or (len(args) == 2 and args[1] is Ellipsis)):
            kw.update(nargs="*", type=_word_parser(args[0], where), metavar=f.name.upper().rstrip("S") or "V")
        elif origin is tuple:
            kw.update(type=_fixed_tuple_parser(args, where), metavar=",".join("V" * len(args)))
        elif origin is dict:
            kw.update(action="append", type=_key_value_parser(args[0], args[1], where), metavar="NAME=VALUE")
        else:
            kw.update(type=_word_parser(tp, where), metavar=f.name.upper())
        if "metavar" in f.metadata:
            kw["metavar"] = f.metadata["metavar"]
        if f.metadata.get("positional") and not prefix:
            # absent -> None (argparse stores its SUPPRESS marker for an optional positional); from_flags skips it
            kw.update(default=None, nargs="?")
            parser.add_argument(dest, **{k: v for k, v in kw.items() if k not in ("metavar", "dest")})
        else:
            parser.add_argument(*f.metadata.get("flags", (where,)), **kw)
    return groups


def from_flags(cls: type, ns: argparse.Namespace, base: Any = None, prefix: str = "", check: bool = True) -> Any:
    """``base`` (default ``cls()``) with the fields given on the command line replaced; each number checked (finite,
    in its range) unless ``check`` is False (a caller listing every problem at once, :func:`range_errors`)."""
    base = cls() if base is None else base
    hints = _hints(cls)
    changes = {}
    for f in dataclasses.fields(cls):
        tp, _ = _unwrap_optional(hints[f.name])
        if _is_config(tp):
            changes[f.name] = from_flags(tp, ns, getattr(base, f.name), f"{prefix}{f.name}.", check)
            continue
        dest = prefix + f.name
        if not hasattr(ns, dest) or (f.metadata.get("positional") and not prefix and getattr(ns, dest) is None):
            continue
        value = getattr(ns, dest)
        origin = typing.get_origin(tp)
        if origin is dict:
            value = dict(value)
        elif origin is tuple and isinstance(value, list):
            value = tuple(value)
        if check:  # NaN, inf and out-of-range numbers, as YAML's
            check_value(f, value, _flag(prefix, f.name), dest)
        changes[f.name] = value
    return dataclasses.replace(base, **changes)
