"""One base for every expected failure (DESIGN.md section 4).

An :class:`M2MError` is bad input or a missing prerequisite the user can act on: its message names the
file, field or stage and says what to do. The command line catches it once (``m2m: error: ...``, exit
status 2; ``m2m --debug`` keeps the traceback); anything else escaping a command is a bug. Each library
keeps its own subclass (``SfMError``, ``WorldConfigError``, ...), most also deriving from ``ValueError`` or
``RuntimeError`` as before, so callers that catch those keep working.

This module imports nothing, so every layer (``geometry`` included) may use it.
"""

from __future__ import annotations

__all__ = ["EpisodeStalled", "M2MError"]


class M2MError(Exception):
    """An expected failure; the message says what was wrong and what to do."""


class EpisodeStalled(M2MError, RuntimeError):
    """An environment that cannot go on with the episode it is in (a renderer that stalls at one state, its retries
    included); the next ``reset`` starts afresh. A closed-loop evaluation counts that episode as a failure cut short
    (``evaluation.run_episode``) and goes on with the next."""
