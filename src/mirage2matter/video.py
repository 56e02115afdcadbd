"""Video files with PyAV (bundled FFmpeg): H.264 writing and frame reading."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from fractions import Fraction
from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .errors import M2MError


class VideoError(M2MError, ValueError):
    """A video that cannot be read or written; the message names the file."""


def write_video(
    path: str | Path,
    frames: Iterable[np.ndarray],
    fps: float,
    crf: int = 20,
    preset: str = "medium",
    threads: int = 1,
) -> int:
    """Encode uint8 frames [H,W,3] (RGB, even H and W) as H.264 yuv420p MP4, atomically.

    ``threads=1`` keeps the bitstream identical run to run (x264 output depends on its threading).
    Returns the number of frames written.
    """
    import av

    path = Path(path)
    n = 0
    with atomic_path(path) as tmp:
        with av.open(str(tmp), mode="w", format="mp4") as container:
            stream = None
            for frame in frames:
                if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
                    raise VideoError(f"{path}: frames must be uint8 [H,W,3], got {frame.dtype} {frame.shape}")
                if stream is None:
                    h, w = frame.shape[:2]
                    if h % 2 or w % 2:
                        raise VideoError(f"{path}: H.264 yuv420p needs even width and height, got {w}x{h}")
                    stream = container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
                    stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
                    stream.options = {"crf": str(crf), "preset": preset, "threads": str(threads)}
                    stream.thread_count = threads
                elif frame.shape[:2] != (stream.height, stream.width):
                    raise VideoError(f"{path}: frame {n} is {frame.shape[1]}x{frame.shape[0]}, the video is "
                                     f"{stream.width}x{stream.height}")  # fmt: skip
                for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                    container.mux(packet)
                n += 1
            if stream is None:
                raise VideoError(f"{path}: no frames to write")
            for packet in stream.encode():
                container.mux(packet)
    return n


def read_video_frames(path: str | Path, every: int = 1) -> Iterator[tuple[int, float, np.ndarray]]:
    """Yield (index, timestamp s, uint8 [H,W,3] RGB) for every ``every``-th frame of a video file."""
    import av

    path = Path(path)
    if not path.is_file():
        raise VideoError(f"video {path} not found")
    try:
        container = av.open(str(path))
    except av.error.FFmpegError as exc:
        raise VideoError(f"{path}: not a readable video ({exc})") from None
    with container:
        if not container.streams.video:
            raise VideoError(f"{path}: has no video stream")
        stream = container.streams.video[0]
        expected, n = int(stream.frames or 0), 0
        try:
            for i, frame in enumerate(container.decode(stream)):
                n = i + 1
                if i % every == 0:
                    rate = float(stream.average_rate)
                    ts = float(frame.pts * stream.time_base) if frame.pts is not None else i / rate
                    yield i, ts, frame.to_ndarray(format="rgb24")
        except av.error.FFmpegError as exc:
            raise VideoError(f"{path}: decoding failed at frame {n} ({exc}); the file is damaged from there: "
                             "re-export or re-record it") from None  # fmt: skip
        # FFmpeg skips undecodable data without an error: a damaged file ends early
        if expected and n < expected:
            raise VideoError(f"{path}: only {n} of its {expected} frames decode (decoding stopped after frame {n}); "
                             "the file is damaged there: re-export or re-record it")  # fmt: skip
