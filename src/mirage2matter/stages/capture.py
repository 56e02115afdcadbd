"""Stage ``capture``: keyframes (sharpness + parallax) from a video or an image folder -> ``capture/``."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ..capture import CaptureConfig, CaptureError, extract_keyframes
from ..workspace import Workspace
from .base import Input, Log


@dataclass
class Config(CaptureConfig):
    """capture settings (besides the keyframe picking ones below).

    source   the video (mp4/mov/mkv) or folder of images to pick keyframes from
    """

    source: Path | None = field(default=None, metadata={"positional": True})

    def validate(self) -> None:
        super().validate()
        if self.source is None:
            raise CaptureError("capture: no source; give the video or image folder (`m2m capture VIDEO -w WS`)")


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    return [Input(Path(cfg.source), field="capture source")] if cfg.source is not None else []


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    picking = CaptureConfig(**{f.name: getattr(cfg, f.name) for f in fields(CaptureConfig)})
    records = extract_keyframes(cfg.source, ws.capture_dir, picking)
    return {"keyframes": len(records), "line": f"{len(records)} keyframes from {cfg.source}"}


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.keyframes_file]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.capture_dir]
