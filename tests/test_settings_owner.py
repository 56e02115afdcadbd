"""A setting's default has one owner, its Config: no ``add_argument`` in ``commands/`` or ``cli.py`` writes a default
or a "(default ...)" help by hand (``configs.add_flags`` makes those flags from a Config's fields: the default and its
doc come from there, so the help cannot say other than the code).

How it fails: an ``add_argument(..., default=<literal>)`` (anything but None, False, ``argparse.SUPPRESS`` or a value
read off a Config, e.g. ``DemoConfig().workspace``) or a help text containing "(default" in those files names the file
and line; the checker is tried on such a call first, so the test cannot pass by seeing nothing."""

from __future__ import annotations

import ast
from pathlib import Path

import mirage2matter

PKG = Path(mirage2matter.__file__).parent
FILES = [PKG / "cli.py", *sorted((PKG / "commands").glob("*.py"))]


def _texts(node: ast.AST) -> list[str]:
    """The string constants of a help expression (a literal, an f-string's parts, a concatenation)."""
    return [n.value for n in ast.walk(node) if isinstance(n, ast.Constant) and isinstance(n.value, str)]


def _config_derived(node: ast.AST) -> bool:
    """``SomethingConfig.field`` / ``SomethingConfig().field`` / ``argparse.SUPPRESS``: a value the code owns once."""
    names = [n.id for n in ast.walk(node) if isinstance(n, ast.Name)]
    attrs = [n.attr for n in ast.walk(node) if isinstance(n, ast.Attribute)]
    return any(n.endswith(("Config", "Settings")) for n in names) or attrs == ["SUPPRESS"]


def hand_written_defaults(source: str, filename: str = "<source>") -> list[str]:
    """``file:line: what`` for every add_argument call of ``source`` with a hand-written default or default help."""
    found = []
    for node in ast.walk(ast.parse(source, filename)):
        call = isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
        if not (call and node.func.attr == "add_argument"):
            continue
        for kw in node.keywords:
            if kw.arg == "default":
                literal = isinstance(kw.value, ast.Constant) and kw.value.value in (None, False)
                if not literal and not _config_derived(kw.value):
                    found.append(f"{filename}:{node.lineno}: default={ast.unparse(kw.value)}")
            if kw.arg == "help" and any("(default" in t for t in _texts(kw.value)):
                found.append(f"{filename}:{node.lineno}: help says its default by hand")
    return found


def test_the_checker_finds_a_hand_written_default():
    bad = 'p.add_argument("--size", type=int, default=224, help="frame side (default 224)")\n'
    ok = ('p.add_argument("--out", default=None, help="the output")\np.add_argument("-v", action="store_true")\n'
          'p.add_argument("-w", default=DemoConfig().workspace)\n')  # fmt: skip
    assert hand_written_defaults(bad) == ["<source>:1: default=224", "<source>:1: help says its default by hand"]
    assert hand_written_defaults(ok) == []


def test_no_command_writes_an_argparse_default_by_hand():
    found = [hit for path in FILES for hit in hand_written_defaults(path.read_text(encoding="utf-8"),
                                                                  str(path.relative_to(PKG)))]  # fmt: skip
    assert not found, "defaults written by hand (give the command a Config, configs.add_flags):\n" + "\n".join(found)
