"""``--help`` of the commands: ``m2m init``'s, ``m2m run``'s and ``m2m demo``'s fit a screen with the user's own
inputs first and end saying how to see the rest; every stage's setting is listed by ``--help-all`` and by
``--help STAGE`` and still parses though the short help leaves it out; no help says a flag's default twice, prints
``%%`` or shows the docstrings' reStructuredText markup. In-process through ``main``, at a fixed terminal width."""

from __future__ import annotations

import argparse
import dataclasses
import re

import pytest

from mirage2matter.cli import build_parser, main
from mirage2matter.configs import from_flags
from mirage2matter.stages import STAGES

# the user's own inputs, in the order the short help lists them
INPUTS = {
    "init": ["--workspace", "--video", "--images", "--board", "--board-pose", "--intrinsics", "--handeye-images",
             "--handeye-poses", "--handeye-board", "--handeye-intrinsics", "--head-photo", "--objects", "--task",
             "--episodes", "--robot", "--force"],
    "run": ["--workspace", "--until", "--from"],
    "demo": ["--workspace", "--sample", "--until", "--from", "--robot"],
}  # fmt: skip
PREFIXES = "|".join(re.escape(s.name.replace("_", "-")) for s in STAGES)
STAGE_FLAG_LINE = re.compile(rf"^\s+--({PREFIXES})\.")  # a --<stage>.<field> flag's line in a help
FLAG = re.compile(r"(?<![\w.-])(--[a-z0-9-]+(?:\.[a-z0-9-]+)+)")  # a --<stage>.<field> flag anywhere


@pytest.fixture(autouse=True)
def _terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "80")  # argparse wraps to the terminal's width: an ordinary one


def _help(capsys: pytest.CaptureFixture, *argv: str) -> str:
    assert main(list(argv)) == 0
    out = capsys.readouterr()
    assert out.err == ""
    return out.out


def _fields(cls: type, prefix: str) -> list[str]:
    """The flags of ``cls``'s fields as ``--<prefix><field>`` (nested Configs' fields below theirs)."""
    flags, defaults = [], cls()
    for f in dataclasses.fields(cls):
        if f.metadata.get("flag", True) is False or f.metadata.get("shared"):  # shared: the pipeline's --robot
            continue
        value = getattr(defaults, f.name)
        if dataclasses.is_dataclass(value):
            flags += _fields(type(value), f"{prefix}{f.name}.")
        else:
            flags.append(f"--{prefix}{f.name}".replace("_", "-"))
    return flags


def _stage_flags() -> dict[str, list[str]]:
    return {s.name: _fields(s.config, f"{s.name}.") for s in STAGES}


def _option_line(text: str, flag: str) -> int:
    """The index of the help line that lists ``flag`` (its entry's first line)."""
    for i, line in enumerate(text.splitlines()):
        if re.match(rf"^ {{2}}(-\w[^,]*, )?{re.escape(flag)}\b(?![.-])", line):
            return i
    raise AssertionError(f"{flag} is not listed:\n{text}")


@pytest.mark.parametrize("command", ["init", "run", "demo"])
def test_short_help_fits_a_screen_with_the_users_inputs_first(command: str, capsys: pytest.CaptureFixture) -> None:
    text = _help(capsys, command, "--help")
    lines = text.splitlines()
    assert len(lines) < 80, f"m2m {command} --help: {len(lines)} lines"
    at = [_option_line(text, flag) for flag in INPUTS[command]]
    assert at == sorted(at), f"m2m {command} --help: the inputs out of order"
    assert at[-1] < _option_line(text, "--help")
    assert not [line for line in lines if STAGE_FLAG_LINE.match(line)]  # the stages' settings: --help STAGE
    assert "--help-all" in lines[-1], f"m2m {command} --help ends with: {lines[-1]!r}"  # how to see the rest
    if command != "run":
        assert lines[-1].split() == ["m2m", command, "--help-all", "every", "flag"]
        assert any(line.split()[:3] == ["m2m", command, "--help"] and "STAGE" in line for line in lines[-6:])


@pytest.mark.parametrize("command", ["init", "demo"])
def test_help_all_lists_every_stages_fields_after_the_inputs(command: str, capsys: pytest.CaptureFixture) -> None:
    text = _help(capsys, command, "--help-all")
    listed = set(FLAG.findall(text))
    expected = [flag for flags in _stage_flags().values() for flag in flags]
    assert len(expected) > 150
    assert not [flag for flag in expected if flag not in listed]
    first = min(i for i, line in enumerate(text.splitlines()) if STAGE_FLAG_LINE.match(line))
    assert max(_option_line(text, flag) for flag in INPUTS[command]) < first


def test_help_stage_lists_that_stages_fields(capsys: pytest.CaptureFixture) -> None:
    flags = _stage_flags()
    for i, stage in enumerate(STAGES):
        word = (stage.name, stage.name.replace("_", "-"), stage.command)[i % 3]  # any of its names
        text = _help(capsys, "init", "--help", word)
        listed = set(FLAG.findall(text))
        assert set(flags[stage.name]) <= listed, f"--help {word}"
        assert all(f.startswith(f"--{stage.name.replace('_', '-')}.") for f in listed), f"--help {word}"
        assert text.startswith(f"{stage.name} settings (--") and text.count(" settings (--") == 1
    assert main(["init", "--help", "nope"]) == 2
    err = capsys.readouterr().err
    assert "no stage 'nope'" in err and "head-view" in err and len(err.splitlines()) < 12  # a short usage


def test_every_stage_flag_parses_as_before_though_not_listed(tmp_path, capsys: pytest.CaptureFixture) -> None:
    from mirage2matter.stages.pipeline import PipelineConfig

    parser = build_parser("init")
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    options = {o for a in sub.choices["init"]._actions for o in a.option_strings}
    assert not [flag for flags in _stage_flags().values() for flag in flags if flag not in options]
    given = ["--scene.minutes", "3", "--align.icp", "--objects.names", "a", "b", "--objects.matting.iterations", "7",
             "--capture.max-keyframes", "1_000"]  # fmt: skip
    args = parser.parse_args(["init", "-w", str(tmp_path), *given])
    cfg = from_flags(PipelineConfig, args)
    assert cfg.scene.minutes == 3.0 and cfg.align.icp is True and list(cfg.objects.names) == ["a", "b"]
    assert cfg.objects.matting.iterations == 7 and cfg.capture.max_keyframes == 1000
    assert cfg.sfm == PipelineConfig().sfm  # absent flags change nothing
    assert main(["init", "-w", str(tmp_path), "--scene.minutes", "soon"]) == 2
    err = capsys.readouterr().err
    assert "--scene.minutes" in err and "expected a number" in err and len(err.splitlines()) < 12


def _entries(text: str) -> list[str]:
    """A help's flag entries, each with its wrapped lines joined (an entry starts with a line "  -...")."""
    entries: list[list[str]] = []
    current: list[str] | None = None
    for line in text.splitlines():
        if re.match(r"^ {2}-", line):
            current = [line.strip()]
            entries.append(current)
        elif current is not None and line.startswith(" " * 8) and line.strip():
            current.append(line.strip())
        else:
            current = None
    return [" ".join(e) for e in entries]


def test_no_help_says_a_default_twice_or_shows_escapes_or_markup(capsys: pytest.CaptureFixture) -> None:
    sub = next(a for a in build_parser(None)._actions if isinstance(a, argparse._SubParsersAction))
    helps = {name: _help(capsys, name, "--help") for name in sub.choices}
    helps |= {f"{name} --help-all": _help(capsys, name, "--help-all") for name in ("init", "demo")}
    assert len(helps) > 20
    for name, text in helps.items():
        flat = " ".join(text.split())
        for bad in ("%%", "``", ":class:", ":func:", ":meth:"):
            assert bad not in flat, f"m2m {name} --help shows {bad!r}"
        for entry in _entries(text):
            says = re.findall(r"\(default\b|\bdefault:", entry, re.IGNORECASE)  # "(default: X)", "default: X"
            assert len(says) <= 1, f"m2m {name} --help says the default twice: {entry}"
