"""A look at a dataset without a LeRobot viewer: preview.mp4 (the first episodes, cameras side by
side) and a contact-sheet PNG (first / middle / last frame of each, one row per episode)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..export.spec import DatasetSpec
from ..export.staging import StagedEpisode
from ..export.video import encode_video


def _frames(path: Path) -> np.ndarray:
    import av

    with av.open(str(path)) as c:
        return np.stack([f.to_ndarray(format="rgb24") for f in c.decode(c.streams.video[0])])


def _side_by_side(ep: StagedEpisode, spec: DatasetSpec) -> np.ndarray:
    """[T, H, sum W, 3]: the episode's cameras next to each other (padded to the tallest)."""
    views = [_frames(ep.video_path(k)) for k in spec.video_keys]
    h = max(v.shape[1] for v in views)
    views = [np.pad(v, ((0, 0), (0, h - v.shape[1]), (0, 0), (0, 0))) for v in views]
    return np.concatenate(views, axis=2)


def write_preview(out_dir: Path, episodes: list[StagedEpisode], spec: DatasetSpec, n: int = 4) -> list[Path]:
    """Write ``preview.mp4`` and ``contact_sheet.png`` of the first ``n`` episodes into ``out_dir``."""
    from PIL import Image

    clips = [_side_by_side(ep, spec) for ep in episodes[:n]]
    if not clips:
        return []
    video = np.concatenate(clips)
    if video.shape[1] % 2 or video.shape[2] % 2:
        video = video[:, : video.shape[1] // 2 * 2, : video.shape[2] // 2 * 2]
    preview = out_dir / "preview.mp4"
    encode_video(preview, video, spec.fps, spec.video)
    rows = []
    for clip in clips:
        t = len(clip)
        rows.append(np.concatenate([clip[0], clip[t // 2], clip[-1]], axis=1))
    sheet = np.concatenate(rows, axis=0)
    png = out_dir / "contact_sheet.png"
    with atomic_path(png) as tmp:
        Image.fromarray(sheet).save(tmp)
    return [preview, png]
