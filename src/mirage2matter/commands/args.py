"""Argument types, output checks and messages shared by the commands."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from ..errors import M2MError

__all__ = ["CliError", "backend", "check_output", "info", "int_at_least", "positive_float", "rgb", "show", "xyz"]


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
