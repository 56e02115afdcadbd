"""Reading our LeRobot datasets for training: frames, chunks, statistics, and datasets that do not belong."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from fixtures.policy_datasets import spec_for
from mirage2matter.policy import AugmentConfig, PolicyError, chunk_indices, load_episodes, normalization_stats
from mirage2matter.policy.augment import augment, drop_cameras
from mirage2matter.policy.data import MIN_STD, resize_area


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return 10 * np.log10(255.0**2 / max(mse, 1e-12))


@pytest.mark.parametrize("fmt", ["lerobot-v3.0", "lerobot-v2.1"])
def test_load_episodes_reads_our_format(make_dataset, fmt):
    root, eps = make_dataset(seeds=(0, 1, 2), fmt=fmt)
    d = load_episodes(root, image_size=24)
    assert d.meta.cameras == ("head", "wrist") and d.meta.fps == 10
    assert d.meta.state_names == spec_for().state_names and d.meta.action_names == spec_for().action_names
    assert d.n_episodes == 3 and list(d.lengths) == [e.length for e in eps]
    assert list(d.starts) == [0, eps[0].length, eps[0].length + eps[1].length]
    np.testing.assert_array_equal(d.state, np.concatenate([e.state for e in eps]))  # exact, float32 parquet
    np.testing.assert_array_equal(d.action, np.concatenate([e.action for e in eps]))
    assert d.images["head"].shape == (d.n_frames, 3, 24, 24) and d.images["head"].dtype == np.uint8
    # each frame is its own episode frame (after H.264 and the same area resize), not a neighbour's
    for e, ep in enumerate(eps):
        for i in range(ep.length):
            got = d.images["head"][d.starts[e] + i].transpose(1, 2, 0)
            want = resize_area(ep.images["head"][i], 24)
            assert _psnr(got, want) > 30, (e, i)
            if i:
                assert _psnr(got, want) > _psnr(got, resize_area(ep.images["head"][i - 1], 24)), (e, i)
    assert d.tasks == ["grasp banana"] * 3 and [s[1] for s in d.sources] == [0, 1, 2]


def test_several_datasets_and_camera_choice(make_dataset):
    a, eps_a = make_dataset("a", seeds=(0,))
    b, eps_b = make_dataset("b", seeds=(5, 6), fmt="lerobot-v2.1")
    d = load_episodes([a, b], image_size=16, cameras=["wrist"])
    assert d.meta.cameras == ("wrist",) and set(d.images) == {"wrist"}
    assert d.n_episodes == 3 and [s[0] for s in d.sources] == [str(a), str(b), str(b)]
    np.testing.assert_array_equal(d.state, np.concatenate([e.state for e in eps_a + eps_b]))


def test_datasets_of_another_robot_rate_or_layout_are_refused(make_dataset):
    a, _ = make_dataset("a", seeds=(0,))
    fast, _ = make_dataset("fast", seeds=(1,), spec=spec_for(fps=20))
    other, _ = make_dataset("other", seeds=(2,), spec=spec_for(robot_type="ur5e"))
    with pytest.raises(PolicyError, match=r"fast/meta/info.json: fps 20 differs from 10"):
        load_episodes([a, fast], 16)
    with pytest.raises(PolicyError, match=r"other/meta/info.json: robot_type 'ur5e'"):
        load_episodes([a, other], 16)
    info = json.loads((a / "meta" / "info.json").read_text())
    info["features"]["action"]["names"] = ["x"] * 8
    (other / "meta" / "info.json").write_text(json.dumps(info))
    with pytest.raises(PolicyError, match="action names"):
        load_episodes([a, other], 16)
    with pytest.raises(PolicyError, match="no video feature for camera"):
        load_episodes(a, 16, cameras=["side"])
    with pytest.raises(PolicyError, match="not a LeRobot dataset"):
        load_episodes(a / "meta", 16)
    with pytest.raises(PolicyError, match="image_size"):
        load_episodes(a, 3)
    (a / "videos" / "observation.images.head" / "chunk-000" / "file-000.mp4").write_bytes(b"not a video")
    with pytest.raises(PolicyError, match="file-000.mp4.*re-export"):
        load_episodes(a, 16)
    (fast / "data" / "chunk-000" / "file-000.parquet").unlink()
    with pytest.raises(PolicyError, match=r"file-000.parquet not found: the dataset is incomplete"):
        load_episodes(fast, 16)


def test_chunk_indices_pad_with_the_last_action():
    idx, mask = chunk_indices(np.array([0, 3]), np.array([3, 2]), 4)
    np.testing.assert_array_equal(idx, [[0, 1, 2, 2], [1, 2, 2, 2], [2, 2, 2, 2], [3, 4, 4, 4], [4, 4, 4, 4]])
    np.testing.assert_array_equal(mask.sum(1), [3, 2, 1, 2, 1])
    assert mask[:, 0].all()  # the current step is always real


def test_normalization_stats():
    rng = np.random.default_rng(0)
    state = rng.normal(2.0, 3.0, (500, 9)).astype(np.float32)
    action = rng.normal(-1.0, 0.5, (500, 8)).astype(np.float32)
    action[:, 7] = 0.0  # a gripper that never moves (press button)
    st = normalization_stats(state, action)
    np.testing.assert_allclose(st["state_mean"], state.mean(0), rtol=1e-5)
    np.testing.assert_allclose(st["state_std"], state.std(0), rtol=1e-4)
    np.testing.assert_allclose(st["action_std"][:7], action[:, :7].std(0), rtol=1e-4)
    assert st["action_std"][7] == np.float32(MIN_STD) and st["action_mean"][7] == 0.0
    assert all(v.dtype == np.float32 for v in st.values())


def _only(**on: float) -> AugmentConfig:
    """Every random change off but those named."""
    return AugmentConfig(**{f.name: on.get(f.name, 0) for f in dataclasses.fields(AugmentConfig)})


def test_resize_area_and_augment_shapes():
    im = np.zeros((48, 64, 3), np.uint8)
    im[:, 32:] = 200
    out = resize_area(im, 16)
    assert out.shape == (16, 16, 3) and out[:, :7].max() == 0 and out[:, 9:].min() == 200
    with pytest.raises(PolicyError, match="uint8"):
        resize_area(im.astype(np.float32), 16)
    x = torch.randint(0, 256, (5, 3, 16, 16), dtype=torch.uint8)
    a1 = augment(x, AugmentConfig(), torch.Generator().manual_seed(3))
    a2 = augment(x, AugmentConfig(), torch.Generator().manual_seed(3))
    assert a1.shape == (5, 3, 16, 16) and torch.equal(a1, a2) and 0 <= a1.min() and a1.max() <= 1
    off = _only()
    torch.testing.assert_close(augment(x, off, torch.Generator()), x.float() / 255, atol=1e-5, rtol=0)


def test_augment_softens_or_sharpens_focus():
    # a fine checker of mid greys (no clipping): a blur lowers its contrast, an unsharp mask raises it
    checker = (np.indices((16, 16)).sum(0) % 2).astype(np.float32)
    x = torch.from_numpy(0.4 + 0.2 * checker).expand(8, 3, 16, 16).clone()
    soft = augment(x, _only(blur=1.0, sharpen=0.0), torch.Generator().manual_seed(0))
    sharp = augment(x, _only(blur=0.0, sharpen=1.0), torch.Generator().manual_seed(0))
    spread = lambda t: t[:, :, 4:12, 4:12].std(dim=(1, 2, 3))  # noqa: E731
    assert (spread(soft) < spread(x)).all() and (spread(sharp) > spread(x)).all()
    assert torch.allclose(soft.mean(), x.mean(), atol=1e-3) and torch.allclose(sharp.mean(), x.mean(), atol=1e-3)


def test_randconv_remaps_textures_but_keeps_each_channels_level():
    # a vertical edge: a random 3x3 filter changes the texture, the rescaling keeps each channel's mean and spread
    x = torch.zeros(16, 3, 24, 24)
    x[..., 12:] = 0.8
    x[:, 1] *= 0.5
    a = augment(x, _only(randconv=1.0), torch.Generator().manual_seed(0))
    b = augment(x, _only(randconv=1.0), torch.Generator().manual_seed(0))
    assert torch.equal(a, b), "the generator alone decides the draw (resumed runs draw the same)"
    changed = (a - x).abs().amax(dim=(1, 2, 3)) > 0.05
    assert changed.float().mean() > 0.5
    # the mean of each channel before clamping is the input's; clamping moves it little for mid-range images
    torch.testing.assert_close(a.mean(dim=(2, 3)), x.mean(dim=(2, 3)), atol=0.08, rtol=0)
    none = augment(x, _only(randconv=0.0), torch.Generator().manual_seed(0))
    torch.testing.assert_close(none, x)
    grey = augment(x, _only(grayscale=1.0), torch.Generator().manual_seed(0))
    assert torch.equal(grey[:, 0], grey[:, 1]) and torch.equal(grey[:, 1], grey[:, 2])
    torch.testing.assert_close(grey[:, 0], 0.299 * x[:, 0] + 0.587 * x[:, 1] + 0.114 * x[:, 2])


def test_hue_band_gains_change_colours_of_different_hues_independently_and_leave_greys():
    x = torch.zeros(64, 3, 4, 12)
    x[..., 0:4] = torch.tensor([0.9, 0.8, 0.2]).view(1, 3, 1, 1)  # banana yellow
    x[..., 4:8] = torch.tensor([0.55, 0.35, 0.2]).view(1, 3, 1, 1)  # table brown
    x[..., 8:12] = 0.6  # grey
    y = augment(x, _only(hue_bands=0.4), torch.Generator().manual_seed(0))
    assert torch.equal(y, augment(x, _only(hue_bands=0.4), torch.Generator().manual_seed(0)))
    torch.testing.assert_close(y[..., 8:], x[..., 8:], atol=1e-5, rtol=0)  # no hue, no change
    luma = lambda im: (0.299 * im[:, 0] + 0.587 * im[:, 1] + 0.114 * im[:, 2]).mean(dim=(1, 2))
    ratio_yellow = luma(y[..., 0:4]) / luma(x[..., 0:4])
    ratio_brown = luma(y[..., 4:8]) / luma(x[..., 4:8])
    assert ratio_yellow.std() > 0.1 and ratio_brown.std() > 0.1  # each changes from image to image ...
    assert abs(np.corrcoef(ratio_yellow.numpy(), ratio_brown.numpy())[0, 1]) < 0.5  # ... and not together
    assert ((y[..., 0:8] - x[..., 0:8]).abs().amax(dim=(1, 2, 3)) < 0.45).all()  # within the range's reach
    torch.testing.assert_close(augment(x, _only(hue_bands=0.0), torch.Generator().manual_seed(0)), x)


def test_camera_dropout_blanks_at_most_one_camera_per_sample_at_its_rate():
    b = 4000
    images = {"head": torch.rand(b, 3, 4, 4), "wrist": torch.rand(b, 3, 4, 4)}
    out = drop_cameras(images, 0.4, torch.Generator().manual_seed(0))
    again = drop_cameras(images, 0.4, torch.Generator().manual_seed(0))
    assert all(torch.equal(out[c], again[c]) for c in images), "the generator alone decides the draw"
    blank = {c: (out[c] == 0.5).flatten(1).all(1) for c in images}
    kept = {c: torch.equal(out[c][~blank[c]], images[c][~blank[c]]) for c in images}
    assert all(kept.values()), "a camera not blanked is untouched"
    assert not (blank["head"] & blank["wrist"]).any(), "never both views of one sample"
    for c in images:  # each camera blanked in about p / 2 of the samples
        assert abs(blank[c].float().mean().item() - 0.2) < 0.03, (c, blank[c].float().mean())
    none = drop_cameras(images, 0.0, torch.Generator().manual_seed(0))
    assert all(torch.equal(none[c], images[c]) for c in images)
    g = torch.Generator().manual_seed(0)
    alone = drop_cameras({"head": images["head"]}, 1.0, g)
    assert torch.equal(alone["head"], images["head"]), "a lone camera is never blanked"
    assert torch.equal(g.get_state(), torch.Generator().manual_seed(0).get_state()), "and nothing is drawn"


def test_input_blur_hides_detail_finer_than_it_and_keeps_the_weights_layout():
    from mirage2matter.policy.model import Encoder, ModelSpec, VisuomotorPolicy

    torch.manual_seed(0)
    sharp, soft = Encoder((8, 16), 4), Encoder((8, 16), 4, input_blur=2.0)
    soft.load_state_dict(sharp.state_dict())  # same weights: only the fixed low-pass differs
    # a smooth scene, and the same scene with a 1-px checker on it (detail no reconstruction renders)
    smooth = 0.3 + 0.4 * torch.nn.functional.interpolate(torch.rand(1, 3, 6, 6), size=(48, 48), mode="bicubic",
                                                         align_corners=False).clamp(0, 1)  # fmt: skip
    checker = smooth + 0.2 * ((torch.arange(48)[:, None] + torch.arange(48)[None]) % 2).float() - 0.1
    moved = lambda enc: (enc(checker) - enc(smooth)).abs().max().item()  # noqa: E731
    assert moved(soft) < 0.1 * moved(sharp)
    a = VisuomotorPolicy(ModelSpec(("head",), 32, 9, 8, 4))
    b = VisuomotorPolicy(ModelSpec(("head",), 32, 9, 8, 4, input_blur=1.5))
    assert a.state_dict().keys() == b.state_dict().keys(), "a checkpoint's weights do not depend on the blur"
