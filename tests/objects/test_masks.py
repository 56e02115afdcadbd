"""Mask providers: prompts pick the right cluster, a mask folder is read or rejected clearly, and
SAM2 runs only with the package and a local checkpoint."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from mirage2matter.geometry.camera import Camera, look_at_pose
from mirage2matter.objects import ObjectsError
from mirage2matter.objects.masks import (
    FolderMasks,
    Sam2Masks,
    Target,
    cluster_for_prompt,
    fill_holes,
    parse_prompt,
    refine_grabcut,
)
from mirage2matter.objects.support import ObjectCluster

K = np.array([[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]])


def _cams(n=8):
    return [
        Camera(K, look_at_pose([0.6 * np.cos(a), 0.6 * np.sin(a), 0.4], [0, 0, 0]), 320, 240, f"frame_{k:06d}.jpg")
        for k, a in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False))
    ]


def _cluster(name, centre):
    rng = np.random.default_rng(0)
    pts = np.asarray(centre) + rng.normal(0, 0.01, (50, 3)) * [1, 1, 0.5] + [0, 0, 0.02]
    return ObjectCluster(name, pts, pts.mean(0), 0.04)


def test_parse_prompt_and_bad_prompts():
    p = parse_prompt("banana@frame_000031.jpg:box=10,20,110,90")
    assert (p.name, p.frame, p.box) == ("banana", "frame_000031.jpg", (10.0, 20.0, 110.0, 90.0))
    q = parse_prompt("cup@frame_000031:points=5,6;7.5,8")
    assert q.points == [(5.0, 6.0), (7.5, 8.0)]
    for bad in ("banana", "banana@f:box=1,2,3", "banana@f:box=5,5,1,1", "x@f:points=1"):
        with pytest.raises(ObjectsError, match="prompt"):
            parse_prompt(bad)


def test_prompt_picks_the_cluster_it_points_at():
    cams = _cams()
    a, b = _cluster("object_0", [0.1, 0.0, 0.0]), _cluster("object_1", [-0.1, 0.05, 0.0])
    cam = cams[2]
    uv, _ = cam.project(b.centroid[None])
    (u, v) = uv[0]
    box = parse_prompt(f"cup@{cam.name}:box={u - 15},{v - 15},{u + 15},{v + 15}")
    assert cluster_for_prompt(box, cams, [a, b]) is b
    pts = parse_prompt(f"cup@frame_000002:points={u},{v}")
    assert cluster_for_prompt(pts, cams, [a, b]) is b
    empty = parse_prompt(f"cup@{cam.name}:box=0,0,5,5")
    with pytest.raises(ObjectsError, match="no object found there"):
        cluster_for_prompt(empty, cams, [a, b])
    with pytest.raises(ObjectsError, match="not in the workspace"):
        cluster_for_prompt(parse_prompt("cup@nope.jpg:box=0,0,5,5"), cams, [a, b])


def test_box_prompts_split_objects_that_touch():
    # two tins side by side, touching: one cluster on the table; a box around each in one keyframe separates them
    from mirage2matter.objects.reconstruct import ObjectsConfig, find_targets

    rng = np.random.default_rng(1)
    table = np.c_[rng.uniform(-0.3, 0.3, (2000, 2)), rng.normal(0, 0.0005, 2000)]
    tins = {"left": [-0.045, 0.0], "right": [0.045, 0.0]}
    pts = {n: np.c_[xy + rng.uniform(-0.04, 0.04, (150, 2)), rng.uniform(0.01, 0.05, 150)] for n, xy in tins.items()}
    cams = _cams()
    cloud = np.concatenate([table, *pts.values()])
    _, whole = find_targets(ObjectsConfig(), cams, cloud)
    assert len(whole) == 1 and len(whole[0].cluster.points) == 300
    cam = cams[2]  # looking along -y: left and right apart in the image
    prompts = []
    for name, p in pts.items():
        uv, _ = cam.project(p)
        (x0, y0), (x1, y1) = uv.min(0) - 2, uv.max(0) + 2
        prompts.append(f"{name}@{cam.name}:box={x0},{y0},{x1},{y1}")
    _, targets = find_targets(ObjectsConfig(prompts=prompts), cams, cloud)
    assert [t.name for t in targets] == ["left", "right"]
    for t in targets:
        assert len(t.cluster.points) >= 140 and np.all(np.sign(t.cluster.points[:, 0]) == np.sign(tins[t.name][0]))
    # a box around both leaves the cluster whole
    both = f"tins@{cam.name}:box=0,0,320,240"
    _, targets = find_targets(ObjectsConfig(prompts=[both]), cams, cloud)
    assert len(targets[0].cluster.points) == 300


def test_folder_masks(tmp_path):
    cams = _cams()
    (tmp_path / "cup").mkdir()
    for cam in cams[:7]:
        m = np.zeros((240, 320), np.uint8)
        cv2.circle(m, (160, 120), 30, 255, -1)
        cv2.imwrite(str(tmp_path / "cup" / f"{Path(cam.name).stem}.png"), m)
    res = FolderMasks(tmp_path).masks(Target("cup", None, None), cams, [None] * len(cams))
    assert res.masks[7] is None and all(m.sum() == pytest.approx(np.pi * 30**2, rel=0.05) for m in res.masks[:7])
    with pytest.raises(ObjectsError, match=r"'plate'.*not found"):
        FolderMasks(tmp_path).masks(Target("plate", None, None), cams, [])
    cv2.imwrite(str(tmp_path / "cup" / f"{Path(cams[0].name).stem}.png"), np.zeros((10, 10), np.uint8))
    with pytest.raises(ObjectsError, match=r"'cup'.*10x10"):
        FolderMasks(tmp_path).masks(Target("cup", None, None), cams, [])
    for p in (tmp_path / "cup").iterdir():
        p.unlink()
    with pytest.raises(ObjectsError, match="only 0 keyframe"):
        FolderMasks(tmp_path).masks(Target("cup", None, None), cams, [])


def test_grabcut_follows_the_edge_from_a_rough_alpha():
    img = np.full((80, 100, 3), (150, 100, 60), np.uint8)  # wood-ish
    cv2.rectangle(img, (30, 20), (70, 60), (40, 40, 40), -1)  # a dark object
    alpha = np.zeros((80, 100), np.float32)
    alpha[24:52, 34:66] = 1.0  # the core, bottom rows missing (as near the table)
    alpha[52:58, 34:66] = 0.3
    m = refine_grabcut(img, alpha)
    truth = np.zeros((80, 100), bool)
    truth[20:61, 30:71] = True
    assert (m & truth).sum() / (m | truth).sum() > 0.95
    ring = np.ones((5, 5), bool)
    ring[2, 2] = False
    assert fill_holes(ring).all()


def test_grabcut_keeps_what_the_matting_is_sure_of():
    """An object whose lower part has the table's colour: GrabCut's colour model gives it to the
    table, but the 3D matting is sure of it (alpha 0.9) and the mask keeps it."""
    rng = np.random.default_rng(0)
    img = np.clip(rng.normal((150, 100, 60), 8, (80, 100, 3)), 0, 255).astype(np.uint8)  # wood-ish
    img[20:45, 30:70] = (60, 40, 30)  # the object's dark top
    alpha = np.zeros((80, 100), np.float32)
    alpha[20:60, 30:70] = 0.9  # its lower flank (rows 45-60) looks like the table
    truth = alpha > 0.5
    m = refine_grabcut(img, alpha)
    assert m[45:60, 30:70].mean() > 0.95
    assert (m & truth).sum() / (m | truth).sum() > 0.95
    soft = refine_grabcut(
        img, np.where(truth, 0.7, 0.0).astype(np.float32) + np.pad(np.ones((25, 40)), ((20, 35), (30, 30))) * 0.2
    )
    assert soft[50:60, 30:70].mean() < 0.5  # where the matting is unsure, the image's edges win


def test_sam2_without_package_or_checkpoint_says_what_to_do(tmp_path):
    cams = _cams()
    target = Target("cup", _cluster("cup", [0, 0, 0]), None)
    with pytest.raises(ObjectsError, match="SAM2|sam2"):
        Sam2Masks(tmp_path / "missing.pt").masks(Target("cup", target.cluster, object()), cams, [])


@pytest.mark.skipif(
    importlib.util.find_spec("sam2") is None or not os.environ.get("M2M_SAM2_CHECKPOINT"),
    reason="SAM2 runs only with the sam2 package and a local checkpoint in M2M_SAM2_CHECKPOINT (nothing is downloaded)",
)
def test_sam2_masks_on_the_sample(tmp_path):
    from fixtures.ground_truth_workspace import ground_truth_workspace
    from mirage2matter.objects.reconstruct import ObjectsConfig, find_targets, load_keyframes_rgb
    from mirage2matter.workspace import Workspace

    ground_truth_workspace(tmp_path, n_keyframes=12)
    posed = Workspace(tmp_path).posed_capture(frame="base")
    cams, points = posed.cameras, posed.points
    images = load_keyframes_rgb(cams, posed.image_dir)
    _, targets = find_targets(ObjectsConfig(names=["banana"]), cams, points)
    res = Sam2Masks(Path(os.environ["M2M_SAM2_CHECKPOINT"])).masks(targets[0], cams, images)
    areas = [m.sum() for m in res.masks if m is not None]
    assert len(areas) >= 6 and min(areas) > 100


def test_grabcut_is_the_same_whatever_drew_from_opencvs_rng_before():
    """GrabCut seeds its colour models from OpenCV's global RNG; on these patchy images an unseeded
    call moved 16-124 pixels with the RNG's state."""
    alpha = np.zeros((60, 80), np.float32)
    alpha[15:45, 20:60] = 0.6
    alpha[22:38, 30:50] = 0.95
    for seed in (2, 14, 17):
        rng = np.random.default_rng(seed)
        palette = rng.integers(0, 256, (8, 3))
        img = np.kron(palette[rng.integers(0, 8, (15, 20))], np.ones((4, 4, 1)))  # 4 px patches
        img = np.clip(img + rng.normal(0, 10, img.shape), 0, 255).astype(np.uint8)
        masks = []
        for draws in (0, 5, 1000):
            cv2.randu(np.zeros((draws + 1, 1)), 0, 1)  # someone else drew from the global RNG
            masks.append(refine_grabcut(img, alpha))
        assert all(np.array_equal(masks[0], m) for m in masks[1:]), seed


def test_keyframes_and_a_mask_folder_with_a_lens_are_seen_through_its_pinhole(tmp_path):
    """A camera with a lens: `pinhole_keyframes` undistorts each keyframe to the pinhole with the same K (the object
    steps project with a pinhole) and FolderMasks(lens=...) undistorts masks drawn on the keyframes as captured, so
    a disc the lens imaged at its distorted place lands where the pinhole projects it. Pinhole cameras pass as they
    are."""
    from dataclasses import replace

    from mirage2matter.objects.reconstruct import load_keyframes_rgb, pinhole_keyframes

    lens = {"k1": -0.3, "k2": 0.05, "p1": 0.001, "p2": -0.0008, "k3": 0.0}
    plain = _cams(7)
    bent = [replace(c, distortion=lens, distortion_model="opencv") for c in plain]
    ideal = np.array([[296.0, 34.0]])  # where the pinhole images the disc's centre: far off-axis, where the lens bends
    (tmp_path / "images").mkdir()
    (tmp_path / "masks" / "cup").mkdir(parents=True)
    for cam in bent:
        (u, v) = cam.distort_pixels(ideal)[0] - 0.5  # OpenCV draws with pixel centres at integers
        assert np.hypot(u + 0.5 - ideal[0, 0], v + 0.5 - ideal[0, 1]) > 5  # the lens moves it visibly
        m = np.zeros((240, 320), np.uint8)
        cv2.circle(m, (round(16 * u), round(16 * v)), 16 * 12, 255, -1, lineType=cv2.LINE_AA, shift=4)
        cv2.imwrite(str(tmp_path / "images" / cam.name), np.repeat(m[..., None], 3, axis=2))
        cv2.imwrite(str(tmp_path / "masks" / "cup" / f"{Path(cam.name).stem}.png"), m)

    def centre(mask: np.ndarray) -> np.ndarray:
        v, u = np.nonzero(mask)
        return np.array([u.mean() + 0.5, v.mean() + 0.5])

    cams, images = pinhole_keyframes(bent, tmp_path / "images")
    assert not any(c.has_distortion for c in cams)
    for cam, pinhole, image in zip(bent, cams, images, strict=True):
        np.testing.assert_array_equal(pinhole.K, cam.K)
        np.testing.assert_array_equal(pinhole.T_world_cam, cam.T_world_cam)
        assert image.shape == (240, 320, 3) and image.dtype == np.float32
        np.testing.assert_allclose(centre(image[..., 0] > 0.5), ideal[0], atol=0.5)
    masks = FolderMasks(tmp_path / "masks", lens=bent).masks(Target("cup", None, None), cams, images).masks
    for mask in masks:
        np.testing.assert_allclose(centre(mask), ideal[0], atol=0.5)
    # without a lens: the keyframes as they are
    same_cams, same_images = pinhole_keyframes(plain, tmp_path / "images")
    assert all(a is b for a, b in zip(same_cams, plain, strict=True))
    for a, b in zip(same_images, load_keyframes_rgb(plain, tmp_path / "images"), strict=True):
        np.testing.assert_array_equal(a, b)
