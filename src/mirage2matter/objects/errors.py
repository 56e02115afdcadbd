"""The object stage's error type."""

from __future__ import annotations

from ..errors import M2MError

__all__ = ["ObjectsError"]


class ObjectsError(M2MError, ValueError):
    """Unusable input for the object stage; the message names the object / file and what to do."""
