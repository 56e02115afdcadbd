"""Every Config field has a range, checked when the settings are read (issue 65, "check at the door"): every number
field carries one (configs.ranged), the defaults and the bundled sample's settings lie inside, and a hostile value
(NaN, +-inf, 0, negative, huge) in any field of m2m.yaml or on the command line is accepted or refused with the
field named; never a traceback, never a NaN through."""

from __future__ import annotations

import argparse
import dataclasses
import math
import typing

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fixtures import SAMPLE
from mirage2matter.bench.render import RenderBenchConfig
from mirage2matter.bench.sim2real import Sim2RealConfig
from mirage2matter.commands.bench import datagen_config
from mirage2matter.configs import (
    ConfigError,
    Range,
    _hints,
    _is_config,
    _unwrap_optional,
    add_flags,
    check_ranges,
    from_dict,
    from_flags,
)
from mirage2matter.errors import M2MError
from mirage2matter.render.splat_world import MAX_SUPERSAMPLE
from mirage2matter.stages.base import PipelineSettings
from mirage2matter.stages.pipeline import PipelineConfig

CONFIGS = [PipelineConfig, RenderBenchConfig, Sim2RealConfig, datagen_config()]
HOSTILE = [math.nan, math.inf, -math.inf, 0, 0.0, -1, -1e300, 1e300, 10**30, 0.5]


def _leaves(cls: type, prefix: str = "") -> list[tuple[str, dataclasses.Field, typing.Any]]:
    """(dotted name, field, type) of every field that is not a nested Config."""
    out, hints = [], _hints(cls)
    for f in dataclasses.fields(cls):
        inner = _unwrap_optional(hints[f.name])[0]
        if _is_config(inner):
            out += _leaves(inner, f"{prefix}{f.name}.")
        else:
            out.append((prefix + f.name, f, hints[f.name]))
    return out


def _numeric(tp: typing.Any) -> bool:
    tp = _unwrap_optional(tp)[0]
    return tp in (int, float) or any(_numeric(a) for a in typing.get_args(tp) if a is not Ellipsis)


def _shaped(tp: typing.Any, x: typing.Any) -> typing.Any:
    """``x`` where the field's type puts numbers (a list of one, both of a pair, a mapping's value); ``x`` itself for
    other fields (a number where text, a path or a switch belongs: a wrong type)."""
    tp = _unwrap_optional(tp)[0]
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (list, tuple):
        if origin is list or args[-1] is Ellipsis:
            return [_shaped(args[0], x)]
        return [_shaped(a, x) for a in args]
    if origin is dict:
        return {"k": _shaped(args[1], x)}
    return x


def _nested(name: str, value: typing.Any) -> dict:
    for key in reversed(name.split(".")):
        value = {key: value}
    return value


FIELDS = _leaves(PipelineConfig)
_PIPELINE = {f.name for f in dataclasses.fields(PipelineSettings)}  # the pipeline's settings, at the top of m2m.yaml


def test_every_number_field_of_every_config_has_a_range():
    missing = [f"{cls.__name__}.{name}" for cls in CONFIGS for name, f, tp in _leaves(cls)
               if _numeric(tp) and not isinstance(f.metadata.get("range"), Range)]  # fmt: skip
    assert not missing, f"number fields without a range (configs.ranged): {missing}"
    assert sum(_numeric(tp) for _, _, tp in FIELDS) >= 120  # the pipeline's, all of them


def test_defaults_and_the_bundled_samples_settings_lie_inside_the_ranges():
    for cls in CONFIGS:
        check_ranges(cls())
    check_ranges(PipelineConfig.load(SAMPLE / "m2m.yaml"))
    assert Sim2RealConfig.__dataclass_fields__["supersample"].metadata["range"].hi == MAX_SUPERSAMPLE


def _read_or_refuse(name: str, tp: typing.Any, x: typing.Any) -> None:
    """``x`` in the field ``name`` of an m2m.yaml: refused naming the field, or accepted (finite) and then the stage's
    own check passes or refuses it as an expected error."""
    try:
        cfg = from_dict(PipelineConfig, _nested(name, _shaped(tp, x)))
    except ConfigError as e:
        # a section's field that is the pipeline's (head_photo_joints) may be read at the top: named so
        names = [name, *[n for n in name.split(".")[-1:] if "." in name and n in _PIPELINE]]
        assert e.field is not None and any(e.field.startswith(n) and n in str(e) for n in names), (name, x, str(e))
        return
    assert not (isinstance(x, float) and not math.isfinite(x)), f"{name}: {x} accepted"
    section = getattr(cfg, name.split(".")[0])
    section = section if dataclasses.is_dataclass(section) else cfg  # the pipeline's own setting
    check_ranges(section)
    try:
        section.validate() if hasattr(section, "validate") else None
    except M2MError:
        pass


def test_every_field_takes_or_refuses_every_hostile_value_by_name():
    for name, _, tp in FIELDS:
        for x in HOSTILE:
            _read_or_refuse(name, tp, x)


def test_a_refusal_says_the_range():
    with pytest.raises(ConfigError, match=r"capture\.jpeg_quality: 500 is out of range; allowed: an integer in "
                                          r"\[1, 100\]") as e:  # fmt: skip
        from_dict(PipelineConfig, {"capture": {"jpeg_quality": 500}})
    assert e.value.field == "capture.jpeg_quality"
    with pytest.raises(ConfigError, match=r"capture\.min_parallax_px: nan is not a finite number; allowed: a number "
                                          r"in \[0, 640\]"):  # fmt: skip
        from_dict(PipelineConfig, {"capture": {"min_parallax_px": math.nan}})
    with pytest.raises(ConfigError, match=r"world\.randomize\.x: \[0\.6, 0\.3\] has its first value above"):
        from_dict(PipelineConfig, {"world": {"randomize": {"x": [0.6, 0.3]}}})
    with pytest.raises(ConfigError, match=r"eval_policy\.size: 8 is out of range; allowed: an integer in 0 or "
                                          r"\[16, 4096\]"):  # fmt: skip
        from_dict(PipelineConfig, {"eval_policy": {"size": 8}})
    assert from_dict(PipelineConfig, {"eval_policy": {"size": 0}}).eval_policy.size == 0


@pytest.fixture(scope="module")
def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(exit_on_error=False)
    add_flags(p, PipelineConfig)
    return p


def _flag_words(name: str, tp: typing.Any, x: typing.Any) -> list[str]:
    flag = "--" + name.replace("_", "-")
    tp = _unwrap_optional(tp)[0]
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is bool:
        return [flag]
    if origin is dict:
        return [f"{flag}=k={x}"]
    if origin is tuple and args[-1] is not Ellipsis:
        return [f"{flag}={','.join([str(x)] * len(args))}"]
    return [f"{flag}={x}"]  # one word: "-1e+16" after a flag of its own would read as an option


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([f for f in FIELDS if _numeric(f[2])]),
       st.one_of(st.sampled_from(HOSTILE), st.floats(), st.integers(), st.integers(-(2**70), 2**70)))  # fmt: skip
def test_a_hostile_number_on_the_command_line_or_in_the_file_is_taken_or_refused_by_name(parser, field, x):
    name, f, tp = field
    _read_or_refuse(name, tp, x)
    if f.metadata.get("flag", True) is False or ("." in name and f.metadata.get("shared")):  # m2m.yaml only, or
        return  # the pipeline's setting (its flag: the top-level one's)
    words = _flag_words(name, tp, x)
    try:
        cfg = from_flags(PipelineConfig, parser.parse_args(words))
    except argparse.ArgumentError as e:  # not a number of the field's type: argparse's usage error (exit 2)
        assert words[0].split("=")[0] in str(e)
        return
    except ConfigError as e:
        assert words[0].split("=")[0] in str(e) and e.field == name, (words, str(e))
        return
    assert not (isinstance(x, float) and not math.isfinite(x)), f"{words} accepted"
    check_ranges(cfg)
