"""The configuration reference (``docs/reference/configuration.md``), written from the stages' Configs.

Every setting's doc, type and default come from its stage's Config (the class docstring, read by
:func:`~..configs.field_docs`, as ``--help`` and ``m2m.yaml`` read it), so the page cannot say other than the
code. ``python -m mirage2matter.commands.reference > docs/reference/configuration.md`` writes it again;
``tests/test_docs.py`` fails when the committed page differs from :func:`configuration_reference`.
"""

from __future__ import annotations

import dataclasses
import re
import sys
import typing
from typing import Any, Literal

import yaml

from ..configs import _flag, _hints, _is_config, _unwrap_optional, field_docs, to_dict
from ..stages import STAGES
from ..stages.base import PipelineSettings
from ..stages.pipeline import PipelineConfig

__all__ = ["REGENERATE", "configuration_reference"]

REGENERATE = "python -m mirage2matter.commands.reference > docs/reference/configuration.md"

_INTRO = f"""\
# Configuration reference

<!-- Written by `{REGENERATE}` from the stages' Config docstrings; edit those, not this page. -->

Every setting of every stage, in the order `m2m init` writes them into a workspace's `m2m.yaml` (one section per
stage, nested settings as indented sections). This page is generated from the code: each row is the field's own
documentation, the same text `m2m <stage> --help` prints and `m2m.yaml` carries as a comment.

- **setting**: the key under the stage's section of `m2m.yaml` (`scene:` / `minutes: 10.0`).
- **flag**: the stage command's flag (`m2m train-scene -w ws --minutes 6`). `m2m init`, `m2m run` and `m2m demo` take
  the same flag under the stage's name (`--scene.minutes 6`). A setting marked "m2m.yaml only" has no flag.
- **default**: the value `m2m init` writes when you do not give one, as YAML.
- **type**: with the range its numbers must lie in (`[a, b]` ends included, `(a, b)` excluded; `0 or [16, 4096]`: 0
  means "not used"). Every number is checked when the settings are read (NaN and infinities never pass): a value
  outside is an error naming the setting and its range.

Paths in `m2m.yaml` are relative to the file's folder, or absolute. An unknown key, a wrong type or a missing file is
an error that names its line.
"""

_ROLE = re.compile(r":[\w:]+:`~?\.?([^`<]+?)\s*(?:<[^`]*>)?`")  # :class:`~a.B` -> B (last part below)
_CODE = re.compile(r"(``.+?``|`[^`]+`)")


def _markdown(text: str) -> str:
    """A docstring's text for a Markdown table cell: reStructuredText ``literals`` and `quotes` as code spans,
    roles as their last name, Markdown's special characters outside code escaped, pipes escaped everywhere."""
    text = _ROLE.sub(lambda m: f"`{m.group(1).split('.')[-1]}`", text)
    out = []
    for i, part in enumerate(_CODE.split(text)):
        if i % 2:  # a code span
            out.append("`" + part.strip("`").replace("|", "\\|") + "`")
        else:
            part = part.replace("\\", "\\\\")
            for ch in "*_[]|":
                part = part.replace(ch, "\\" + ch)
            out.append(part.replace("<", "&lt;").replace(">", "&gt;"))
    return "".join(out)


def _type_text(tp: Any) -> str:
    tp, optional = _unwrap_optional(tp)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        text = "one of " + ", ".join(f"`{a}`" for a in args)
    elif origin in (tuple, list) and (origin is list or (len(args) == 2 and args[1] is Ellipsis)):
        text = f"list of {_type_text(args[0])}"
    elif origin is tuple:  # fixed length, as YAML writes it
        text = "[" + ", ".join(_type_text(a) for a in args) + "]"
    elif origin is dict:
        text = f"NAME: {_type_text(args[1])} (per name)"
    elif tp is type(None):
        text = "null"
    else:
        text = {"Path": "path", "PosixPath": "path"}.get(getattr(tp, "__name__", ""), getattr(tp, "__name__", str(tp)))
    return f"{text} or null" if optional else text


def _yaml_text(value: Any) -> str:
    """A default as YAML writes it, in flow style (``[0.35, 0.62]``, ``null``)."""
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_yaml_text(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_yaml_text(v)}" for k, v in value.items()) + "}"
    return yaml.safe_dump(value, default_flow_style=True, width=1 << 16).split("\n...")[0].strip()


def _flag_text(f: dataclasses.Field, tp: Any, prefix: str) -> str:
    if f.metadata.get("flag", True) is False:
        return "m2m.yaml only"
    if f.metadata.get("positional") and not prefix:
        return f"`{f.name.upper()}` (the first argument)"
    flag = _flag(prefix, f.name)
    if _unwrap_optional(tp)[0] is bool:
        return f"`{flag}` / `{_flag(prefix, f.name, negate=True)}`"
    return f"`{flag}`"


def _rows(cls: type, values: dict[str, Any], prefix: str = "") -> list[str]:
    """One table row per field of ``cls`` (nested Configs flattened as ``outer.field``)."""
    docs, hints, rows = field_docs(cls), _hints(cls), []
    for f in dataclasses.fields(cls):
        if f.metadata.get("shared"):  # the pipeline's setting, in its own table
            continue
        tp = hints[f.name]
        inner = _unwrap_optional(tp)[0]
        if _is_config(inner) and isinstance(values[f.name], dict):
            rows.extend(_rows(inner, values[f.name], f"{prefix}{f.name}."))
            continue
        kind = _type_text(tp) + (f" in `{f.metadata['range'].text()}`" if "range" in f.metadata else "")
        cells = [f"`{prefix}{f.name}`", _flag_text(f, tp, prefix), _markdown(kind),
                 f"`{_yaml_text(values[f.name])}`".replace("|", "\\|"), _markdown(docs.get(f.name, ""))]  # fmt: skip
        rows.append("| " + " | ".join(cells) + " |")
    return rows


def configuration_reference() -> str:
    """The whole page (Markdown), from :class:`~..stages.pipeline.PipelineConfig` and the stages' Configs."""
    defaults = to_dict(PipelineConfig())
    hints = _hints(PipelineConfig)
    out = [_INTRO]
    header = ["| setting | flag | type | default | what it is |", "| --- | --- | --- | --- | --- |"]
    own = {k: defaults[k] for k in to_dict(PipelineSettings())}
    about = ("At the top of `m2m.yaml`, read by every stage that needs it (`m2m init`, `m2m run` and `m2m demo` take "
             "the same flag; a stage command's flag of that name changes it for every stage).")  # fmt: skip
    out += ["## The whole pipeline's", "", about, "", *header, *_rows(PipelineSettings, own), ""]
    for stage in STAGES:
        cls = _unwrap_optional(hints[stage.name])[0]
        line = _markdown(stage.help[0].upper() + stage.help[1:]) + "."
        if not stage.pipeline:
            line += " Not part of `m2m run`: run it on its own."
        out += [f"## {stage.name}: `m2m {stage.command}`", "", line, "",
                "| setting | flag | type | default | what it is |", "| --- | --- | --- | --- | --- |"]  # fmt: skip
        out += _rows(cls, defaults[stage.name])
        out.append("")
    return "\n".join(out).rstrip("\n") + "\n"


def main() -> None:
    sys.stdout.write(configuration_reference())


if __name__ == "__main__":
    main()
