import json

import cv2
import numpy as np
import pytest

from mirage2matter.capture import CaptureConfig, CaptureError, extract_keyframes, load_keyframes, sharpness
from mirage2matter.video import write_video

H, W = 96, 128
SHARP = {3, 17, 25, 38}  # one un-blurred frame per window of 10 (40 frames, 4 keyframes)


def _texture(seed=0):
    # blocky random texture: strong corners for the flow check, survives H.264 at low crf
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (H // 4 + 40, W // 4 + 40, 3), dtype=np.uint8)
    return cv2.resize(small, (small.shape[1] * 4, small.shape[0] * 4), interpolation=cv2.INTER_NEAREST)


def _frame(tex, i, blur):
    f = np.ascontiguousarray(tex[8 : 8 + H, 2 * i : 2 * i + W])  # the camera pans 2 px a frame
    return cv2.GaussianBlur(f, (0, 0), 2.5) if blur else f


def _video(path, n=40, sharp=SHARP, static=False):
    tex = _texture()
    write_video(path, [_frame(tex, 0 if static else i, i not in sharp) for i in range(n)], fps=10, crf=8)
    return path


def _leftovers(root, keep):
    return sorted(p.name for p in root.iterdir() if p.name not in keep)


def test_sharpness_prefers_the_unblurred_frame():
    tex = _texture()
    assert sharpness(_frame(tex, 0, False)) > 3 * sharpness(_frame(tex, 0, True))


def test_picks_the_sharp_frame_of_each_window_and_writes_keyframes_json(tmp_path):
    video = _video(tmp_path / "v.mp4")
    out = tmp_path / "capture"
    recs = extract_keyframes(video, out, CaptureConfig(max_keyframes=4, min_keyframes=2))
    assert [r["frame_index"] for r in recs] == sorted(SHARP)
    meta = load_keyframes(out)
    assert meta["keyframes"] == recs and meta["source_type"] == "video" and meta["n_source_frames"] == 40
    assert (meta["width"], meta["height"]) == (W, H)
    for r in recs:
        assert r["timestamp"] == pytest.approx(r["frame_index"] / 10)
        img = cv2.imread(str(out / r["file"]))
        assert img.shape == (H, W, 3)
    assert sorted(p.name for p in out.iterdir()) == sorted([r["file"] for r in recs] + ["keyframes.json"])
    assert _leftovers(tmp_path, {"v.mp4", "capture"}) == []


@pytest.mark.parametrize("max_kf", [5, 13, 60])
def test_count_is_bounded(tmp_path, max_kf):
    recs = extract_keyframes(
        _video(tmp_path / "v.mp4"), tmp_path / "c", CaptureConfig(max_keyframes=max_kf, min_keyframes=2)
    )
    assert len(recs) == min(max_kf, 40)
    idx = [r["frame_index"] for r in recs]
    assert idx == sorted(set(idx))


def test_fixed_window_size(tmp_path):
    cfg = CaptureConfig(max_keyframes=60, min_keyframes=2, sharpness_window=10)
    recs = extract_keyframes(_video(tmp_path / "v.mp4"), tmp_path / "c", cfg)
    assert [r["frame_index"] for r in recs] == sorted(SHARP)


def test_rerun_replaces_the_folder(tmp_path):
    video, out = _video(tmp_path / "v.mp4"), tmp_path / "c"
    extract_keyframes(video, out, CaptureConfig(max_keyframes=20))
    recs = extract_keyframes(video, out, CaptureConfig(max_keyframes=4, min_keyframes=2))
    assert len(list(out.glob("*.jpg"))) == len(recs) == 4
    assert _leftovers(tmp_path, {"v.mp4", "c"}) == []


def test_image_folder(tmp_path):
    src = tmp_path / "imgs"
    src.mkdir()
    tex = _texture()
    for i in range(12):
        cv2.imwrite(str(src / f"img_{i:02d}.png"), _frame(tex, 3 * i, i % 3 != 1))
    recs = extract_keyframes(src, tmp_path / "c", CaptureConfig(max_keyframes=4, min_keyframes=2, image_format="png"))
    assert [r["file"] for r in recs] == ["img_01.png", "img_04.png", "img_07.png", "img_10.png"]
    assert all(r["timestamp"] is None for r in recs)


def test_a_fixed_cameras_image_is_always_a_keyframe(tmp_path):
    """A fixed camera's image among the orbit's (the world's head camera): blurred and beside its window's sharper
    frame, and a view of the same spot as the keyframe before it (no parallax), it is kept all the same."""
    src = tmp_path / "imgs"
    src.mkdir()
    tex = _texture()
    for i in range(12):
        cv2.imwrite(str(src / f"img_{i:02d}.png"), _frame(tex, 3 * i, i % 3 != 1))
    cv2.imwrite(str(src / "img_04b.png"), _frame(tex, 12, True))  # the fixed camera: img_04's view, blurred
    cfg = CaptureConfig(max_keyframes=4, min_keyframes=2, image_format="png")
    picked = [r["file"] for r in extract_keyframes(src, tmp_path / "c", cfg)]
    assert "img_04b.png" not in picked  # the picking alone drops it (its window's sharp frame, img_04, wins)
    recs = extract_keyframes(src, tmp_path / "c", cfg, keep=("img_04b.jpg",))  # a stem names it too
    assert [r["file"] for r in recs] == ["img_01.png", "img_04.png", "img_04b.png", "img_07.png", "img_10.png"]
    assert load_keyframes(tmp_path / "c")["dropped_low_parallax"] == []
    with pytest.raises(CaptureError, match=r"no image named 'right.jpg' \(img_00.png, img_01.png"):
        extract_keyframes(src, tmp_path / "c", cfg, keep=("right.jpg",))
    with pytest.raises(CaptureError, match="a video; right.jpg must name images of an image folder"):
        extract_keyframes(_video(tmp_path / "v.mp4"), tmp_path / "c", cfg, keep=("right.jpg",))


def test_static_camera_is_rejected_for_lack_of_parallax(tmp_path):
    video = _video(tmp_path / "v.mp4", static=True, sharp=set(range(40)))
    with pytest.raises(CaptureError, match="parallax"):
        extract_keyframes(video, tmp_path / "c", CaptureConfig(max_keyframes=10))
    assert _leftovers(tmp_path, {"v.mp4"}) == []
    # with the check off the same video gives keyframes
    recs = extract_keyframes(video, tmp_path / "c", CaptureConfig(max_keyframes=10, min_parallax_px=0))
    assert len(recs) == 10


def test_bad_inputs_give_clear_errors_and_write_nothing(tmp_path):
    out = tmp_path / "c"
    with pytest.raises(CaptureError, match="not found"):
        extract_keyframes(tmp_path / "missing.mp4", out)
    (tmp_path / "junk.mp4").write_bytes(b"not a video at all" * 100)
    with pytest.raises(CaptureError, match="junk.mp4"):
        extract_keyframes(tmp_path / "junk.mp4", out)
    (tmp_path / "notes.txt").write_text("hi")
    with pytest.raises(CaptureError, match="unsupported"):
        extract_keyframes(tmp_path / "notes.txt", out)
    with pytest.raises(CaptureError, match="fewer than min_keyframes"):
        extract_keyframes(_video(tmp_path / "short.mp4", n=5), out, CaptureConfig(min_keyframes=8))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(CaptureError, match="no images"):
        extract_keyframes(empty, out)
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    tex = _texture()
    for i in range(9):
        f = _frame(tex, i, False)
        cv2.imwrite(str(mixed / f"{i}.png"), f if i != 6 else cv2.resize(f, (W // 2, H // 2)))
    with pytest.raises(CaptureError, match="different sizes"):
        extract_keyframes(mixed, out)
    with pytest.raises(CaptureError, match="min_keyframes"):
        extract_keyframes(mixed, out, CaptureConfig(max_keyframes=2, min_keyframes=4))
    assert not out.exists()
    assert _leftovers(tmp_path, {"junk.mp4", "notes.txt", "short.mp4", "empty", "mixed"}) == []


def test_keyframes_json_is_valid_json_with_config(tmp_path):
    out = tmp_path / "c"
    extract_keyframes(_video(tmp_path / "v.mp4"), out, CaptureConfig(max_keyframes=6, min_keyframes=2))
    meta = json.loads((out / "keyframes.json").read_text())
    assert meta["config"]["max_keyframes"] == 6 and len(meta["keyframes"]) == 6
