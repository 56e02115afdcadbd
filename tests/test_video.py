import hashlib

import numpy as np
import pytest

from mirage2matter.video import VideoError, read_video_frames, write_video


def _frames(n=12, h=48, w=64):
    # smooth content so H.264 reproduces it closely
    yy, xx = np.mgrid[0:h, 0:w]
    return [np.stack([(xx * 4 + i * 8) % 256, (yy * 5) % 256, np.full_like(xx, 40 * (i % 6))], -1).astype(np.uint8)
            for i in range(n)]  # fmt: skip


def test_round_trip_counts_timestamps_and_content(tmp_path):
    frames = _frames()
    path = tmp_path / "v.mp4"
    assert write_video(path, iter(frames), fps=10) == len(frames)
    decoded = list(read_video_frames(path))
    assert [i for i, _, _ in decoded] == list(range(len(frames)))
    assert np.allclose([ts for _, ts, _ in decoded], np.arange(len(frames)) / 10)
    err = np.mean(
        [np.abs(f.astype(float) - d.astype(float)).mean() for f, (_, _, d) in zip(frames, decoded, strict=True)]
    )
    assert err < 4.0  # lossy, but the same pictures
    assert len(list(read_video_frames(path, every=5))) == 3


def test_encoding_is_deterministic(tmp_path):
    a, b = tmp_path / "a.mp4", tmp_path / "b.mp4"
    write_video(a, _frames(), fps=10)
    write_video(b, _frames(), fps=10)
    assert hashlib.sha256(a.read_bytes()).digest() == hashlib.sha256(b.read_bytes()).digest()


def test_bad_input_leaves_nothing(tmp_path):
    path = tmp_path / "odd.mp4"
    with pytest.raises(VideoError, match="even"):
        write_video(path, [np.zeros((47, 64, 3), np.uint8)], fps=10)
    with pytest.raises(VideoError, match="no frames"):
        write_video(path, [], fps=10)
    with pytest.raises(VideoError, match="frame 1"):
        write_video(path, [np.zeros((48, 64, 3), np.uint8), np.zeros((50, 64, 3), np.uint8)], fps=10)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(VideoError, match="not found"):
        next(read_video_frames(tmp_path / "missing.mp4"))
    (tmp_path / "junk.mp4").write_bytes(b"not a video")
    with pytest.raises(VideoError, match="junk.mp4"):
        next(read_video_frames(tmp_path / "junk.mp4"))
