"""The bare-table background behind an object, from the other keyframes through the support plane."""

from __future__ import annotations

import numpy as np

from fixtures.box_scene import render_boxes
from mirage2matter.geometry.camera import Camera, look_at_pose
from mirage2matter.objects.background import table_background
from mirage2matter.objects.support import Plane
from mirage2matter.objects.views import proxy_mask

BOX_LO, BOX_HI = np.array([-0.06, -0.015, 0.0]), np.array([0.06, 0.015, 0.04])  # the object, metres
PLANE = Plane(np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(0, bool))


def table_colour(xy: np.ndarray) -> np.ndarray:
    """A wood-like texture [N,3] of the table at plane points xy [N,2]."""
    g = 0.5 + 0.25 * np.sin(60 * xy[:, 0] + 10 * np.sin(20 * xy[:, 1])) + 0.1 * np.sin(120 * xy[:, 1])
    return np.stack([g, 0.8 * g, 0.5 * g], -1)


def render(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """(image [H,W,3] of the table and a uniformly coloured box, the table point [H,W,2] behind each pixel)."""
    img, _, xy = render_boxes(cam, [(BOX_LO, BOX_HI)], (0.2, 0.3, 0.9), table=table_colour)
    return img, xy.reshape(cam.height, cam.width, 2)


def test_keyframes_that_look_through_the_object_do_not_vote():
    K = np.array([[200.0, 0, 80], [0, 200.0, 60], [0, 0, 1]])
    cams = []
    for k in range(16):  # a low orbit: beside the box's foot most keyframes look across the box
        a = 2 * np.pi * k / 16
        eye = np.array([0.35 * np.cos(a), 0.35 * np.sin(a), 0.12])
        cams.append(Camera(K, look_at_pose(eye, np.zeros(3)), 160, 120, f"c{k}"))
    rendered = [render(c) for c in cams]
    images = [r[0] for r in rendered]
    lo, hi = BOX_LO - 0.001, BOX_HI + 0.001  # a proxy 1 mm around the box, on the table
    proxy = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (0.0, hi[2])])
    hidden = [proxy_mask(c, proxy) for c in cams]

    for i in (0, 3):
        roi = (0, 0, 160, 120)
        plain = table_background(i, cams, images, roi, PLANE)
        aware = table_background(i, cams, images, roi, PLANE, hidden=hidden)
        xy = rendered[i][1]  # the table point behind each pixel (behind the box too)
        truth = table_colour(xy.reshape(-1, 2)).reshape(xy.shape[:2] + (3,))
        gap = np.maximum(np.maximum(BOX_LO[:2] - xy, xy - BOX_HI[:2]), 0).max(-1)  # to the box's foot
        ring = (gap > 0.003) & (gap < 0.006)
        assert ring.sum() > 50
        wrong_plain = np.mean(np.abs(plain - truth).max(-1)[ring] > 0.05)
        wrong_aware = np.mean(np.abs(aware - truth).max(-1)[ring] > 0.05)
        assert wrong_plain > 0.25, wrong_plain  # a plain median shows the box there
        assert wrong_aware < 0.08, wrong_aware
        far = (gap > 0.06) & np.isfinite(plain[..., 0])  # away from the object both are the table
        assert np.isfinite(aware[far]).all() and np.abs(aware - truth).max(-1)[far].mean() < 0.02


def test_the_median_of_the_votes_is_numpys_nanmedian():
    from mirage2matter.objects.background import _nanmedian_first_axis

    rng = np.random.default_rng(0)
    votes = rng.random((9, 500, 3)).astype(np.float32)
    votes[rng.random(votes.shape) < 0.4] = np.nan
    votes[:, :3] = np.nan  # columns nobody votes for
    votes[:-2, 3:6] = np.nan  # even counts
    votes[:-1, 6:9] = np.nan  # one vote
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # numpy warns on the all-NaN columns
        want = np.nanmedian(votes, axis=0)
    got = _nanmedian_first_axis(votes)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, want)  # NaN where nobody votes, the very same numbers elsewhere
