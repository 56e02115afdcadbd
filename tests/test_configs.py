"""Config dataclasses as flags and YAML (mirage2matter.configs): one default, strict types, named fields."""

import argparse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest

from mirage2matter.configs import ConfigError, add_flags, field_docs, from_dict, from_flags, to_dict


@dataclass
class Inner:
    """inner settings.

    steps   how many steps
    rate    a rate that takes
            two lines to explain
    """

    steps: int = 10
    rate: float = 0.5


@dataclass
class Outer:
    """outer settings.

    source   the input, given as the positional argument
    names    several names
    size     width and height
    mode     one of two modes
    fast     a switch
    weights  per-name numbers
    out      an optional path
    inner    nested settings
    hidden   never on the command line
    """

    source: Path | None = field(default=None, metadata={"positional": True})
    names: tuple[str, ...] = ("a", "b")
    size: tuple[int, int] = (4, 3)
    mode: Literal["x", "y"] = "x"
    fast: bool = True
    weights: dict[str, float] = field(default_factory=dict)
    out: Path | None = None
    inner: Inner = field(default_factory=Inner)
    hidden: int = field(default=1, metadata={"flag": False})


def _parse(argv, base=None):
    p = argparse.ArgumentParser()
    add_flags(p, Outer, base=base)
    return from_flags(Outer, p.parse_args(argv), base)


def test_docs_cover_each_field_and_continuation_lines():
    assert field_docs(Inner) == {"steps": "how many steps", "rate": "a rate that takes two lines to explain"}
    assert set(field_docs(Outer)) == {f for f in Outer.__dataclass_fields__}


def test_no_flag_means_the_base_value_and_flags_change_only_what_is_given():
    assert _parse([]) == Outer()
    base = Outer(names=("q",), inner=Inner(steps=3))
    assert _parse([], base) == base
    got = _parse(["in.mp4", "--names", "c", "d", "--size", "8,6", "--mode", "y", "--no-fast", "--weights", "a=2",
                  "--weights", "b=0.5", "--inner.steps", "7", "--out", "o.json"], base)  # fmt: skip
    assert got == Outer(Path("in.mp4"), ("c", "d"), (8, 6), "y", False, {"a": 2.0, "b": 0.5}, Path("o.json"),
                        Inner(7, 0.5))  # fmt: skip


@pytest.mark.parametrize(
    "argv", [["--size", "8"], ["--inner.steps", "x"], ["--mode", "z"], ["--weights", "a"], ["--hidden", "2"]]
)
def test_bad_flags_are_usage_errors(argv, capsys):
    with pytest.raises(SystemExit):
        _parse(argv)
    assert "error:" in capsys.readouterr().err


def test_help_shows_each_fields_doc_and_default(capsys):
    p = argparse.ArgumentParser()
    add_flags(p, Outer, base=Outer(inner=Inner(steps=99)))
    text = p.format_help()
    assert "two lines to explain (default: 0.5)" in " ".join(text.split())
    assert "how many steps (default: 99)" in " ".join(text.split())


def test_yaml_mappings_are_strict_and_paths_resolve_against_the_file(tmp_path):
    cfg = from_dict(Outer, {"source": "v.mp4", "inner": {"rate": 1}, "size": [2, 2], "fast": False}, base_dir=tmp_path)
    assert cfg.source == (tmp_path / "v.mp4").resolve() and cfg.inner == Inner(10, 1.0) and cfg.size == (2, 2)
    assert to_dict(cfg, base_dir=tmp_path)["source"] == "v.mp4"
    assert from_dict(Outer, to_dict(cfg, base_dir=tmp_path), base_dir=tmp_path) == cfg
    bad = [
        ({"fast": "no"}, "fast: expected true or false"),  # a quoted "no" is not false
        ({"inner": {"steps": 2.5}}, "inner.steps: expected an integer"),
        ({"inner": {"stepz": 2}}, "unknown setting(s) stepz"),
        ({"size": [1, 2, 3]}, "size: expected 2 values"),
        ({"mode": "z"}, "mode: 'z' is not one of x, y"),
        ({"names": "a"}, "names: expected a list"),
        ({"inner": 3}, "inner: expected a mapping"),
        ({"steps": 1}, "unknown setting(s) steps"),
    ]
    for data, message in bad:
        with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
            from_dict(Outer, data)


@dataclass
class Moves:
    """moves.

    moves  from frame N on, these joints
    """

    moves: dict[int, list[float]] | None = None


def test_a_mapping_of_lists_takes_comma_separated_values_under_typed_keys(capsys):
    p = argparse.ArgumentParser()
    add_flags(p, Moves)
    got = from_flags(Moves, p.parse_args(["--moves", "360=0.1,-0.5", "--moves", "12=3"]))
    assert got.moves == {360: [0.1, -0.5], 12: [3.0]}
    assert from_dict(Moves, to_dict(got)) == got  # YAML writes the keys as text; they come back as numbers
    for bad in (["--moves", "x=1,2"], ["--moves", "3=1,y"]):
        with pytest.raises(SystemExit):
            p.parse_args(bad)
        assert "error:" in capsys.readouterr().err
