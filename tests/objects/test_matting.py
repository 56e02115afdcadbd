"""3D matting of a concave object: the bare table its arms wrap around is not the object (a banana's inside arc)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fixtures.box_scene import render_boxes
from mirage2matter.geometry.camera import Camera, look_at_pose
from mirage2matter.objects import ObjectsError
from mirage2matter.objects.masks import GeometricMasks, Target
from mirage2matter.objects.matting import MattingConfig
from mirage2matter.objects.mesh import reconstruct_mesh
from mirage2matter.objects.reconstruct import _where_it_may_be
from mirage2matter.objects.support import ObjectCluster, Plane

# a U standing on the table (metres): a bar along x and two arms along +y; the table between the arms is bare
BOXES = [
    (np.array([-0.05, -0.03, 0.0]), np.array([0.05, -0.015, 0.03])),
    (np.array([-0.05, -0.015, 0.0]), np.array([-0.035, 0.045, 0.03])),
    (np.array([0.035, -0.015, 0.0]), np.array([0.05, 0.045, 0.03])),
]
INSIDE_LO, INSIDE_HI = np.array([-0.033, -0.013]), np.array([0.033, 0.043])  # the bare table inside the U
PLANE = Plane(np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(0, bool))


def render(cam: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(image [H,W,3], the object's silhouette [H,W], the bare table inside the U [H,W]) seen by ``cam``."""
    img, hit, xy = render_boxes(cam, BOXES, (0.95, 0.85, 0.25), shading=0.12)
    inside = np.all((xy >= INSIDE_LO) & (xy <= INSIDE_HI), 1).reshape(hit.shape) & ~hit
    return img, hit, inside


def surface_points(n: int, seed: int = 0) -> np.ndarray:
    """SfM-like points [n,3] on the U's top and outer faces, with 1.5 mm of noise."""
    rng = np.random.default_rng(seed)
    pts = []
    for lo, hi in BOXES:
        p = rng.uniform(lo, hi, (n // len(BOXES), 3))
        axis = rng.integers(0, 3, len(p))
        p[np.arange(len(p)), axis] = np.where(rng.random(len(p)) < 0.5, lo[axis], hi[axis])
        pts.append(p[p[:, 2] > 0.006])
    return np.concatenate(pts) + rng.normal(0, 0.0015, (sum(len(p) for p in pts), 3))


@pytest.fixture(scope="module")
def scene():
    K = np.array([[220.0, 0, 80], [0, 220.0, 60], [0, 0, 1]])
    cams = []
    for k in range(24):
        a = 2 * np.pi * k / 24
        eye = np.array([0.3 * np.cos(a), 0.3 * np.sin(a), 0.22 + 0.04 * np.sin(3 * a)])
        cams.append(Camera(K, look_at_pose(eye, np.array([0.0, 0.0, 0.01])), 160, 120, f"c{k:02d}"))
    rendered = [render(c) for c in cams]
    pts = surface_points(240)
    cluster = ObjectCluster("u", pts, pts.mean(0), float(pts[:, 2].max()))
    return cams, rendered, Target("u", cluster, PLANE)


def _run(scene, **options):
    cams, rendered, target = scene
    provider = GeometricMasks(MattingConfig(iterations=600, init_gaussians=8000, max_gaussians=20000, **options))
    result = provider.masks(target, cams, [r[0] for r in rendered])
    ious, claimed, bare = [], 0, 0
    for m, (_, truth, inside) in zip(result.masks, rendered, strict=True):
        assert m is not None
        ious.append((m & truth).sum() / (m | truth).sum())
        inside = inside & ~(cv2.dilate(truth.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0)  # 2 px off its edge
        claimed, bare = claimed + (m & inside).sum(), bare + inside.sum()
    return float(np.median(ious)), claimed / bare


def test_the_table_inside_a_concave_object_is_not_the_object(scene):
    iou, claimed = _run(scene)
    one_pass_iou, one_pass_claimed = _run(scene, passes=1, floor=0.0)
    # measured: IoU 0.956 (one pass, no floor: 0.893); the bare table inside the U masked 14 % (21 %): what is left
    # is the strip along the bar's inner wall, which only the keyframes looking into the U see
    assert one_pass_iou < 0.92 and one_pass_claimed > 0.18, "the test bed no longer shows the problem"
    assert iou > 0.94, f"IoU {iou:.3f} with the true silhouettes (median over 24 keyframes)"
    assert claimed < 0.75 * one_pass_claimed, f"{claimed:.2f} of the bare table inside the U masked as the object"


@pytest.mark.parametrize("options", [{"passes": 0}, {"hidden_margin_px": -1}])
def test_bad_matting_settings_are_named(scene, options):
    cams, rendered, target = scene
    with pytest.raises(ObjectsError, match="objects.matting: passes must be >= 1"):
        GeometricMasks(MattingConfig(**options)).masks(target, cams, [r[0] for r in rendered])


def _barred(scene) -> tuple[list[int], list[np.ndarray], list[np.ndarray]]:
    """A dark bar (the robot's arm) in front of the U in every third keyframe: (those keyframes, the images, the bar
    [H,W] per keyframe)."""
    cams, rendered, _ = scene
    occluded = list(range(0, 24, 3))
    images, bars = [], []
    for k, (img, _, _) in enumerate(rendered):
        bar = np.zeros(img.shape[:2], bool)
        if k in occluded:
            bar[:, 66:94] = True  # 28 px down the middle of a 160 px view: across the U
        images.append(np.where(bar[..., None], np.float32(0.12), img))
        bars.append(bar)
    return occluded, images, bars


def test_the_robot_in_front_of_the_object_is_unknown_not_the_object(scene):
    """Given as ``unknown``, the bar's pixels are evidence for neither the object nor the table: the masks in those
    keyframes are the U's silhouette, seen through the bar from the other keyframes, and claim little of the bar
    beside it (before, such keyframes were left out whole; measured: IoU 0.878, 3.8 % of the bar beside the U)."""
    cams, rendered, target = scene
    occluded, images, bars = _barred(scene)
    t = Target("u", target.cluster, PLANE, unknown=tuple(b if b.any() else None for b in bars))
    masks = GeometricMasks(MattingConfig(iterations=600, init_gaussians=8000, max_gaussians=20000)).masks(
        t, cams, images).masks
    ious, beside, bar_px = [], 0, 0
    for k in occluded:
        truth = rendered[k][1]
        ious.append((masks[k] & truth).sum() / (masks[k] | truth).sum())
        off = bars[k] & ~(cv2.dilate(truth.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0)
        beside, bar_px = beside + (masks[k] & off).sum(), bar_px + off.sum()
    iou = float(np.median(ious))
    assert iou > 0.85, f"IoU {iou:.3f} with the true silhouettes where the bar stands (median over {len(occluded)})"
    assert beside / bar_px < 0.08, f"{beside / bar_px:.3f} of the bar beside the U masked as the object"


def test_the_carving_cuts_nothing_where_the_robot_stands(scene):
    """The stage keeps an object's mask less the robot's pixels; carved from those alone, a third of the keyframes
    would cut away what stands behind the bar. Grown back by the unknown pixels, the hull keeps it."""
    cams, rendered, target = scene
    _, _, bars = _barred(scene)
    seen = [truth & ~bar for (_, truth, _), bar in zip(rendered, bars, strict=True)]
    t = Target("u", target.cluster, PLANE, unknown=tuple(b if b.any() else None for b in bars))
    true_volume = sum(float(np.prod(hi - lo)) for lo, hi in BOXES)
    cut = reconstruct_mesh(target.cluster, PLANE, cams, seen, voxel=0.002).volume
    kept = reconstruct_mesh(target.cluster, PLANE, cams, _where_it_may_be(seen, t), voxel=0.002).volume
    full = reconstruct_mesh(target.cluster, PLANE, cams, [r[1] for r in rendered], voxel=0.002).volume
    # measured: carved from the masks less the bar 0.067 of the unbarred hull, grown back 1.029
    assert cut < 0.8 * full, f"the test bed no longer shows the problem ({cut / full:.2f} of the hull kept)"
    assert abs(kept / full - 1) < 0.05, f"{kept / full:.3f} of the unbarred hull ({full / true_volume:.2f} of the U)"


def test_an_object_the_robot_covers_everywhere_is_a_clear_error(scene):
    cams, rendered, target = scene
    everywhere = tuple(np.ones(r[0].shape[:2], bool) for r in rendered)
    t = Target("u", target.cluster, PLANE, unknown=everywhere)
    with pytest.raises(ObjectsError, match="'u': only 0 keyframe.*beside the robot"):
        GeometricMasks(MattingConfig(iterations=10)).masks(t, cams, [r[0] for r in rendered])
