"""The object stage's error type."""

from __future__ import annotations

__all__ = ["ObjectsError"]


class ObjectsError(ValueError):
    """Unusable input for the object stage; the message names the object / file and what to do."""
