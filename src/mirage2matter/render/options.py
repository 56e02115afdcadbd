"""Bounds of the splat renderer's settings that configs check before anything heavy loads (this module imports
no torch: the stages' Configs and the command line read it)."""

from __future__ import annotations

__all__ = ["MAX_SUPERSAMPLE", "supersample_problem"]

MAX_SUPERSAMPLE = 8  # a bound on the splat layer's size: 8x a 224-px frame is already 1792 px a side


def supersample_problem(value: int) -> str | None:
    """What is wrong with a generation's ``supersample`` (1: off, up to :data:`MAX_SUPERSAMPLE`), worded for the user;
    None when valid. One wording for every command that passes it to generation."""
    if not 1 <= value <= MAX_SUPERSAMPLE:
        return f"supersample must be from 1 (off) to {MAX_SUPERSAMPLE}, got {value}"
    return None
