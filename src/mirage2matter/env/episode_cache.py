"""Recorded episodes cached one per file, ``<folder>/<prefix>_<seed>.npz`` (written atomically): what
``bench policy-gap`` (expert pairs) and ``bench splats`` (splat streams) record once and read back."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_write

__all__ = ["load_or_record_episodes"]


def load_or_record_episodes(folder: Path, prefix: str, seeds: Sequence[int],
                            record: Callable[[list[int]], Iterable[dict[str, Any]]],
                            log: Callable[[str], None], what: str) -> list[dict[str, Any]]:  # fmt: skip
    """The episodes of ``seeds``: those not cached yet recorded by ``record(missing seeds)`` (each a dict of arrays
    with its ``seed``) and written, then every one read back (0-d arrays as Python scalars), so a first call and a
    cached one return the same thing. ``what`` names the recording in the log line."""
    folder.mkdir(parents=True, exist_ok=True)
    path = lambda s: folder / f"{prefix}_{s}.npz"
    missing = [s for s in seeds if not path(s).is_file()]
    if missing:
        log(f"recording {len(missing)} {what} -> {folder}")
        for ep in record(missing):
            with atomic_write(path(ep["seed"])) as f:
                np.savez_compressed(f, **ep)
    out = []
    for s in seeds:
        with np.load(path(s)) as z:
            out.append({k: (z[k].item() if z[k].ndim == 0 else z[k]) for k in z.files})
    return out
