"""Keyframe selection from a hand-held video or an image folder (pipeline stage ``capture``).

Frames are scored by sharpness (variance of the Laplacian on a downsized grey copy, so the score
does not depend on the input resolution) and the sequence is cut into evenly spaced windows; the
sharpest frame of each window becomes a keyframe, which bounds the count and spreads the
keyframes over the whole capture. Keyframes whose sparse optical flow to the previous kept
keyframe is below ``min_parallax_px`` add nothing for SfM (the camera stood still) and are dropped.

Videos are decoded twice (scores first, then only the chosen frames), so memory stays flat for
long phone videos. The output folder is written under a temporary name and renamed when
complete: a failed or interrupted run leaves nothing behind.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np

from ..atomic import atomic_dir
from ..configs import ranged
from ..errors import M2MError
from ..inputs import InputError, check_image_file
from ..video import VideoError, read_video_frames

__all__ = [
    "IMAGE_SUFFIXES",
    "VIDEO_SUFFIXES",
    "CaptureConfig",
    "CaptureError",
    "extract_keyframes",
    "image_files",
    "load_keyframes",
    "names_image",
    "sharpness",
]

VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
ANALYSIS_SIZE = 640  # longest side of the grey copy that sharpness and flow are measured on


class CaptureError(M2MError, ValueError):
    """Input that cannot give keyframes; the message names the source and what to do."""


@dataclass
class CaptureConfig:
    """How keyframes are picked.

    max_keyframes     upper bound on the number of keyframes
    min_keyframes     fewer usable frames than this is an error (SfM needs views)
    sharpness_window  frames per selection window; None spreads ``max_keyframes`` windows evenly
    min_parallax_px   drop a keyframe whose median flow to the previous one is below this
                      (pixels at ANALYSIS_SIZE); 0 disables the check
    image_format      "jpg" or "png" for the written keyframes
    jpeg_quality      JPEG quality (SIFT is robust to it; 95 keeps artefacts negligible)
    """

    max_keyframes: int = ranged(60, ge=1, le=10_000)
    min_keyframes: int = ranged(8, ge=1, le=10_000)
    sharpness_window: int | None = ranged(None, ge=1, le=100_000)
    min_parallax_px: float = ranged(1.0, ge=0, le=ANALYSIS_SIZE)
    image_format: Literal["jpg", "png"] = "jpg"
    jpeg_quality: int = ranged(95, ge=1, le=100)

    def validate(self) -> None:
        if self.min_keyframes < 1 or self.max_keyframes < self.min_keyframes:
            raise CaptureError(
                f"capture config: need 1 <= min_keyframes <= max_keyframes, got {self.min_keyframes}, "
                f"{self.max_keyframes}"
            )
        if self.sharpness_window is not None and self.sharpness_window < 1:
            raise CaptureError(f"capture config: sharpness_window must be >= 1, got {self.sharpness_window}")
        if self.image_format not in ("jpg", "png"):
            raise CaptureError(f"capture config: image_format must be 'jpg' or 'png', got {self.image_format!r}")
        if self.min_parallax_px < 0:
            raise CaptureError(f"capture config: min_parallax_px must be >= 0, got {self.min_parallax_px}")


# ---- measuring frames ---------------------------------------------------------------------------
def _analysis_grey(rgb: np.ndarray) -> np.ndarray:
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    h, w = grey.shape
    f = ANALYSIS_SIZE / max(h, w)
    if f < 1.0:
        grey = cv2.resize(grey, (round(w * f), round(h * f)), interpolation=cv2.INTER_AREA)
    return grey


def sharpness(rgb: np.ndarray) -> float:
    """Variance of the Laplacian of a grey copy downsized to ANALYSIS_SIZE (higher = sharper)."""
    return float(cv2.Laplacian(_analysis_grey(rgb), cv2.CV_64F).var())


def _median_flow(grey_a: np.ndarray, grey_b: np.ndarray) -> float:
    """Median sparse (Lucas-Kanade) flow in pixels from a to b; inf when nothing can be tracked,
    so that an untrackable jump counts as plenty of parallax rather than a duplicate."""
    pts = cv2.goodFeaturesToTrack(grey_a, maxCorners=400, qualityLevel=0.01, minDistance=8)
    if pts is None or len(pts) < 8:
        return float("inf")
    nxt, status, _ = cv2.calcOpticalFlowPyrLK(grey_a, grey_b, pts, None, winSize=(21, 21), maxLevel=3)
    ok = status.ravel() == 1
    if ok.sum() < 8:
        return float("inf")
    return float(np.median(np.linalg.norm((nxt - pts).reshape(-1, 2)[ok], axis=1)))


# ---- sources ------------------------------------------------------------------------------------
class _Source:
    """A sequence of RGB frames: ``scan`` yields (index, timestamp, rgb); ``frames(ids)`` re-reads some."""

    kind: str

    def scan(self) -> Iterator[tuple[int, float | None, np.ndarray]]:
        raise NotImplementedError

    def frames(self, ids: set[int]) -> Iterator[tuple[int, np.ndarray]]:
        raise NotImplementedError


class _VideoSource(_Source):
    kind = "video"

    def __init__(self, path: Path) -> None:
        self.path = path

    def _read(self) -> Iterator[tuple[int, float, np.ndarray]]:
        import av

        try:
            yield from read_video_frames(self.path)
        except VideoError as e:
            raise CaptureError(f"{e}; give a video file (mp4/mov/mkv) or a folder of images") from None
        except av.error.FFmpegError as e:  # corrupt data after a readable header
            raise CaptureError(f"{self.path}: the video cannot be decoded ({e}); re-export or re-record it") from None

    def scan(self) -> Iterator[tuple[int, float | None, np.ndarray]]:
        yield from self._read()

    def frames(self, ids: set[int]) -> Iterator[tuple[int, np.ndarray]]:
        last = max(ids)
        for i, _, rgb in self._read():
            if i in ids:
                yield i, rgb
            if i >= last:
                return


def image_files(folder: Path) -> list[Path]:
    """The images of an image-folder capture, in name order: what keyframes are picked from."""
    return sorted(p for p in Path(folder).iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def names_image(file_name: str, name: str) -> bool:
    """Whether ``name`` names the image ``file_name``: its file name, or its stem (a source's right.png is the
    keyframe right.jpg, and either name gives it)."""
    return file_name == name or Path(file_name).stem == Path(name).stem


class _FolderSource(_Source):
    kind = "images"

    def __init__(self, path: Path) -> None:
        self.path = path
        self.files = image_files(path)
        if not self.files:
            raise CaptureError(f"{path}: no images ({', '.join(IMAGE_SUFFIXES)}) in this folder")
        self.size: tuple[int, int] | None = None

    def _load(self, i: int) -> np.ndarray:
        p = self.files[i]
        try:
            check_image_file(p, "capture image")  # its size from the header, before decoding gigabytes
        except InputError as e:
            raise CaptureError(str(e)) from None
        bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if bgr is None:
            raise CaptureError(f"{p}: not a readable image; remove or replace it")
        size = (bgr.shape[1], bgr.shape[0])
        if self.size is None:
            self.size = size
        elif size != self.size:
            raise CaptureError(
                f"{self.path}: images have different sizes ({self.files[0].name} is {self.size[0]}x{self.size[1]}, "
                f"{p.name} is {size[0]}x{size[1]}); SfM assumes one camera, so resize them to one size"
            )
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)

    def scan(self) -> Iterator[tuple[int, float | None, np.ndarray]]:
        for i in range(len(self.files)):
            yield i, None, self._load(i)

    def frames(self, ids: set[int]) -> Iterator[tuple[int, np.ndarray]]:
        for i in sorted(ids):
            yield i, self._load(i)


def _open_source(source: Path) -> _Source:
    if source.is_dir():
        return _FolderSource(source)
    if not source.exists():
        raise CaptureError(f"{source}: not found; give a video file (mp4/mov/mkv) or a folder of images")
    if source.suffix.lower() not in VIDEO_SUFFIXES:
        raise CaptureError(
            f"{source}: unsupported file type {source.suffix!r}; give a video ({', '.join(VIDEO_SUFFIXES)}) "
            "or a folder of images"
        )
    return _VideoSource(source)


# ---- selection ----------------------------------------------------------------------------------
def _windows(n: int, config: CaptureConfig) -> list[range]:
    """Consecutive windows covering frames 0..n-1: fixed-size ones when ``sharpness_window`` is
    set (thinned evenly to ``max_keyframes``), else ``max_keyframes`` evenly spaced ones."""
    if config.sharpness_window is not None:
        starts = list(range(0, n, config.sharpness_window))
        wins = [range(s, min(s + config.sharpness_window, n)) for s in starts]
        if len(wins) > config.max_keyframes:
            keep = np.linspace(0, len(wins) - 1, config.max_keyframes).round().astype(int)
            wins = [wins[k] for k in keep]
        return wins
    k = min(config.max_keyframes, n)
    edges = np.linspace(0, n, k + 1).round().astype(int)
    return [range(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def _write_image(path: Path, rgb: np.ndarray, config: CaptureConfig) -> None:
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    params = [cv2.IMWRITE_JPEG_QUALITY, config.jpeg_quality] if config.image_format == "jpg" else []
    if not cv2.imwrite(str(path), bgr, params):
        raise OSError(f"cannot write keyframe {path}")


def _kept_images(src: _Source, source: Path, keep: tuple[str, ...]) -> list[int]:
    """The image folder's indices of the images ``keep`` names (a file name, or its stem); CaptureError naming one
    the folder lacks, or a video (whose frames are the moving camera's)."""
    if not keep:
        return []
    if not isinstance(src, _FolderSource):
        raise CaptureError(f"{source}: a video; {', '.join(keep)} must name images of an image folder (a fixed "
                           "camera's photo put beside the capture's images)")  # fmt: skip
    out = []
    for name in keep:
        hits = [i for i, f in enumerate(src.files) if names_image(f.name, name)]
        if len(hits) != 1:
            shown = ", ".join(f.name for f in src.files[:8]) + (", ..." if len(src.files) > 8 else "")
            raise CaptureError(f"{source}: {'no' if not hits else 'more than one'} image named {name!r} ({shown}); "
                               "put the fixed camera's image in the folder, or name it as it is there")  # fmt: skip
        out.append(hits[0])
    return out


def extract_keyframes(
    source: str | os.PathLike[str], out_dir: str | os.PathLike[str], config: CaptureConfig | None = None,
    keep: tuple[str, ...] = (),
) -> list[dict[str, Any]]:
    """Pick keyframes from a video file or an image folder and write them to ``out_dir``.

    ``keep``: images of an image folder (file names, or stems) that are keyframes whatever their sharpness or
    parallax, beside the picked ones (a fixed camera's photo among the moving camera's: its view is not one the
    orbit's parallax test applies to).

    Writes ``out_dir/<name>.jpg|png`` and ``out_dir/keyframes.json`` (source, frame size, config,
    and per keyframe: file, frame_index, timestamp in s (None for folders), sharpness), replacing
    ``out_dir`` as a whole only once everything is written. Returns the keyframe records.

    Raises CaptureError for unreadable / empty videos, folders without images or with images of
    different sizes, and fewer usable frames than ``config.min_keyframes``.
    """
    config = config or CaptureConfig()
    config.validate()
    source, out_dir = Path(source), Path(out_dir)
    src = _open_source(source)
    forced = _kept_images(src, source, tuple(keep))

    # Pass 1: score every frame (only scores are kept, so memory does not grow with the video).
    scores: list[float] = []
    timestamps: list[float | None] = []
    size: tuple[int, int] | None = None
    for i, ts, rgb in src.scan():
        if size is None:
            size = (rgb.shape[1], rgb.shape[0])
        elif (rgb.shape[1], rgb.shape[0]) != size:
            raise CaptureError(f"{source}: frame {i} changes size from {size[0]}x{size[1]}; re-encode the video")
        scores.append(sharpness(rgb))
        timestamps.append(ts)
    n = len(scores)
    if n == 0:
        raise CaptureError(f"{source}: contains no frames; record a video with the scene in view")
    if n < config.min_keyframes:
        raise CaptureError(
            f"{source}: only {n} frame(s), fewer than min_keyframes={config.min_keyframes}; SfM needs more "
            "views: capture a longer video or more images"
        )
    arr = np.asarray(scores)
    candidates = [int(w.start + np.argmax(arr[w.start : w.stop])) for w in _windows(n, config)]
    candidates = sorted(set(candidates) | set(forced))

    # Pass 2: re-read the candidates, drop those without parallax to the previous keyframe, and
    # write the rest into a temporary sibling folder, renamed onto out_dir when complete.
    with atomic_dir(out_dir) as tmp:
        ext = config.image_format
        names: dict[int, str] = {}
        kept: list[int] = []
        dropped: list[int] = []
        prev_grey: np.ndarray | None = None
        seen = 0
        for i, rgb in src.frames(set(candidates)):
            seen += 1
            if i not in forced:  # a fixed camera's image neither takes nor breaks the orbit's parallax test
                grey = _analysis_grey(rgb)
                if config.min_parallax_px > 0 and prev_grey is not None:
                    if _median_flow(prev_grey, grey) < config.min_parallax_px:
                        dropped.append(i)
                        continue
                prev_grey = grey
            kept.append(i)
            names[i] = f"frame_{i:06d}.{ext}" if isinstance(src, _VideoSource) else f"{src.files[i].stem}.{ext}"
            _write_image(tmp / names[i], rgb, config)
        if seen != len(candidates):
            raise CaptureError(f"{source}: {len(candidates) - seen} frame(s) could not be read a second time")
        if len(kept) < config.min_keyframes:
            raise CaptureError(
                f"{source}: only {len(kept)} keyframes with enough camera motion (min_keyframes="
                f"{config.min_keyframes}, {len(dropped)} dropped for parallax < {config.min_parallax_px} px); "
                "move the camera around the scene (capture more parallax) or lower min_parallax_px"
            )
        records = [
            {"file": names[i], "frame_index": i, "timestamp": timestamps[i], "sharpness": scores[i]} for i in kept
        ]
        summary = {
            "source": str(source.resolve()),
            "source_type": src.kind,
            "n_source_frames": n,
            "width": size[0],  # type: ignore[index]
            "height": size[1],  # type: ignore[index]
            "config": asdict(config),
            "dropped_low_parallax": dropped,
            "keyframes": records,
        }
        with open(tmp / "keyframes.json", "w", encoding="utf-8") as f:
            json.dump(summary, f, indent=1)
            f.write("\n")
    return records


def load_keyframes(out_dir: str | os.PathLike[str]) -> dict[str, Any]:
    """Read ``out_dir/keyframes.json`` as written by ``extract_keyframes``."""
    path = Path(out_dir) / "keyframes.json"
    if not path.is_file():
        raise CaptureError(f"{path}: not found; run the capture stage first")
    with open(path, encoding="utf-8") as f:
        return json.load(f)
