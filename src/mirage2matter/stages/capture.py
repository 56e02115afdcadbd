"""Stage ``capture``: keyframes (sharpness + parallax) from a video or an image folder -> ``capture/``."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from ..capture import CaptureConfig, CaptureError, extract_keyframes
from ..workspace import Workspace
from .base import ADDED_LATER, SHARED, Input, Log


@dataclass
class Config(CaptureConfig):
    """capture settings (besides the keyframe picking ones below).

    source         the video (mp4/mov/mkv) or folder of images to pick keyframes from
    head_keyframe  a fixed camera's image in the image folder: always a keyframe, whatever its sharpness or
                   parallax (the pipeline's: the world's head camera)
    """

    source: Path | None = field(default=None, metadata={"positional": True})
    head_keyframe: str | None = field(default=None, metadata={**SHARED, **ADDED_LATER, "metavar": "IMAGE"})

    def validate(self) -> None:
        super().validate()
        if self.source is None:
            raise CaptureError("capture: no source; give the video or image folder (`m2m capture VIDEO -w WS`)")


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    return [Input(Path(cfg.source), field="capture source")] if cfg.source is not None else []


def run(ws: Workspace, cfg: Config, log: Log) -> dict[str, Any]:
    picking = CaptureConfig(**{f.name: getattr(cfg, f.name) for f in fields(CaptureConfig)})
    keep = (cfg.head_keyframe,) if cfg.head_keyframe is not None else ()  # a video refuses it, naming why
    records = extract_keyframes(cfg.source, ws.capture_dir, picking, keep=keep)
    kept = f" (with {cfg.head_keyframe}, the fixed camera's)" if keep else ""
    return {"keyframes": len(records), "line": f"{len(records)} keyframes from {cfg.source}{kept}"}


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.keyframes_file]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.capture_dir]
