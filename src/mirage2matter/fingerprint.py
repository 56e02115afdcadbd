"""The one skip/resume key: a short hash of a config and of the content of the files it reads."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

__all__ = ["fingerprint"]


def _update_with_path(h: Any, path: Path) -> None:
    if path.is_file():
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    elif path.is_dir():
        for p in sorted(path.rglob("*")):
            if p.is_file() and not p.name.startswith("."):
                h.update(str(p.relative_to(path)).encode() + b"\0")
                _update_with_path(h, p)
    else:
        h.update(b"<missing>")


def fingerprint(*parts: Any) -> str:
    """A short stable hash of JSON-able ``parts`` and of the content of any ``Path`` among them (a folder:
    every file in it, hidden ones aside). Same config and same input content: same fingerprint."""
    h = hashlib.sha256()
    for p in parts:
        if isinstance(p, Path):
            _update_with_path(h, p)
        else:
            h.update(json.dumps(p, sort_keys=True, default=str).encode())
        h.update(b"\0")
    return h.hexdigest()[:16]
