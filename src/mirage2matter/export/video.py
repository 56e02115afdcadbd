"""Episode videos with PyAV: encode, measure what a reader will decode, and join by remuxing."""

from __future__ import annotations

from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import M2MError
from .spec import VideoOptions
from .stats import ImageStatsAccumulator


class DatasetVideoError(M2MError, ValueError):
    """A video that cannot be written or joined; the message names the file."""


def encode_video(path: Path, frames: np.ndarray, fps: int, options: VideoOptions) -> None:
    """Encode uint8 frames [T,H,W,3] as an H.264 MP4 at ``fps``, atomically (frame i at pts i/fps)."""
    import av

    with atomic_path(path) as tmp:
        with av.open(str(tmp), mode="w", format="mp4") as container:
            stream = container.add_stream(options.codec, rate=Fraction(fps))
            stream.height, stream.width = frames.shape[1:3]
            stream.pix_fmt = options.pix_fmt
            stream.options = {"crf": str(options.crf), "preset": options.preset, "threads": "1", "bf": "0",
                              "g": str(options.gop)}  # fmt: skip
            stream.thread_count = 1
            for frame in frames:
                for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)


def decoded_image_stats(path: Path) -> tuple[int, dict[str, np.ndarray]]:
    """Decode ``path`` and return (frame count, per-channel stats of the decoded frames in [0, 1]).

    Stats come from the decoded video (not the frames handed to the encoder) so that they describe
    exactly what a reader of the dataset sees, and a validator can recompute them bit for bit.
    """
    import av

    acc = ImageStatsAccumulator()
    with av.open(str(path)) as container:
        for frame in container.decode(container.streams.video[0]):
            acc.add(frame.to_ndarray(format="rgb24"))
    return acc.count, acc.result()


def concat_videos(paths: Sequence[Path], out: Path, fps: int) -> list[tuple[float, float]]:
    """Join H.264 MP4s (same encoder settings, no B-frames) into ``out`` by remuxing, no re-encode.

    Episode k's frames follow episode k-1's; returns each input's (from_timestamp, to_timestamp) in
    seconds within ``out`` (LeRobot v3's per-episode video slice), to = from + frames / fps.
    """
    import av

    if not paths:
        raise DatasetVideoError(f"{out}: no episode videos to join")
    spans: list[tuple[float, float]] = []
    with atomic_path(out) as tmp:
        with av.open(str(tmp), mode="w", format="mp4") as dst:
            out_stream = None
            extradata = None
            next_frame = 0  # frames written so far = first frame index of the next input
            for p in paths:
                with av.open(str(p)) as src:
                    in_stream = src.streams.video[0]
                    if out_stream is None:
                        out_stream = dst.add_stream_from_template(in_stream)
                        extradata = in_stream.codec_context.extradata
                    elif in_stream.codec_context.extradata != extradata:
                        raise DatasetVideoError(f"{p}: encoder parameters differ from the first episode's; "
                                                "episodes of one dataset must share one video setting")  # fmt: skip
                    tb = in_stream.time_base
                    n = 0
                    first_pts = None
                    for packet in src.demux(in_stream):
                        if packet.dts is None:  # the demuxer's flush packet
                            continue
                        if first_pts is None:
                            first_pts = packet.pts
                        # Place frame i of this episode at (next_frame + i) / fps, in the input's time base.
                        shift = round(Fraction(next_frame, fps) / tb) - first_pts
                        packet.pts += shift
                        packet.dts += shift
                        packet.stream = out_stream
                        dst.mux(packet)
                        n += 1
                    if n == 0:
                        raise DatasetVideoError(f"{p}: holds no video frames")
                spans.append((next_frame / fps, (next_frame + n) / fps))
                next_frame += n
    return spans
