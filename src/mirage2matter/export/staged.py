"""A committed successful attempt as the dataset writers read it (its folder and result.json).

Its own module so that the writers (``lerobot``) and the staging area (``staging``, which calls the
writers when it consolidates) do not import each other.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["StagedEpisode"]


@dataclass
class StagedEpisode:
    """A committed successful attempt: its folder and result.json."""

    dir: Path
    result: dict[str, Any]

    @property
    def task(self) -> str:
        return self.result["task"]

    @property
    def length(self) -> int:
        return int(self.result["length"])

    @property
    def frames_path(self) -> Path:
        return self.dir / "frames.parquet"

    def video_path(self, key: str) -> Path:
        return self.dir / f"{key}.mp4"
