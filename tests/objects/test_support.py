"""Support plane and object clusters in a synthetic base-frame cloud."""

from __future__ import annotations

import numpy as np
import pytest

from mirage2matter.objects import ObjectsError
from mirage2matter.objects.support import find_objects, fit_support_plane, name_clusters


def _scene(seed: int = 0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A 1 x 1 m table top at z = 0 (1 mm noise), a flat sheet on it, three blobs standing on it,
    and scattered outliers off the table."""
    rng = np.random.default_rng(seed)
    table = np.c_[rng.uniform(-0.2, 0.8, (3000, 2)), rng.normal(0, 0.001, 3000)]
    sheet = np.c_[rng.uniform(0.0, 0.2, (300, 2)), 0.002 + rng.normal(0, 0.0005, 300)]
    centres = {"near": np.array([0.3, 0.1]), "middle": np.array([0.5, -0.2]), "far": np.array([0.6, 0.35])}
    blobs = {}
    for k, (name, c) in enumerate(centres.items()):
        n = 60 + 20 * k
        blobs[name] = np.c_[c + rng.normal(0, 0.015, (n, 2)), rng.uniform(0.008, 0.04, n)]
    off = np.c_[rng.uniform(2, 3, (100, 2)), rng.uniform(-1, 1, 100)]
    return np.concatenate([table, sheet, *blobs.values(), off]), centres


def test_plane_is_the_table():
    pts, _ = _scene()
    tilt = np.array([[1, 0, 0], [0, np.cos(0.1), -np.sin(0.1)], [0, np.sin(0.1), np.cos(0.1)]])
    plane = fit_support_plane(pts @ tilt.T + [0, 0, 0.05])
    assert np.degrees(np.arccos(abs(plane.normal @ (tilt @ [0, 0, 1])))) < 0.5
    assert abs(plane.height(np.array([[0.3, 0.0, 0.05]]) @ tilt.T)[0] - 0.0) < 0.01


def test_objects_found_ordered_and_named():
    pts, centres = _scene()
    plane, clusters = find_objects(pts)
    assert len(clusters) == 3  # the sheet is flat, the outliers are off the table
    dist = [np.linalg.norm(c.centroid[:2] - centres["near"]) for c in clusters]
    assert np.argmin(dist) == 0  # nearest the base first
    named = name_clusters(clusters, ["b", "a=0.6,0.35"])
    assert [c.name for c in named] == ["b", "a"]
    assert np.linalg.norm(named[1].centroid[:2] - centres["far"]) < 0.01
    assert np.linalg.norm(named[0].centroid[:2] - centres["near"]) < 0.01


def test_no_object_and_too_many_names_are_clear_errors():
    pts, _ = _scene()
    table_only = pts[pts[:, 2] < 0.005]
    with pytest.raises(ObjectsError, match="no object found"):
        find_objects(table_only)
    _, clusters = find_objects(pts)
    with pytest.raises(ObjectsError, match="'d'.*only 3 object"):
        name_clusters(clusters, ["a", "b", "c", "d"])
    with pytest.raises(ObjectsError, match="within 10 cm"):
        name_clusters(clusters, ["x=5,5"])


def test_sparse_low_specks_are_not_objects():
    # SfM noise seen on the sample: a dozen points ~1 cm above the table, nearer the base than any object
    pts, centres = _scene()
    rng = np.random.default_rng(5)
    speck = np.c_[np.array([0.05, 0.2]) + rng.normal(0, 0.02, (13, 2)), rng.uniform(0.007, 0.014, 13)]
    pole = np.c_[np.array([0.0, -0.15]) + rng.normal(0, 0.003, (13, 2)), rng.uniform(0.01, 0.06, 13)]
    _, with_speck = find_objects(np.concatenate([pts, speck]))
    assert len(with_speck) == 3 and np.linalg.norm(with_speck[0].centroid[:2] - centres["near"]) < 0.01
    _, with_pole = find_objects(np.concatenate([pts, pole]))  # as sparse, but tall: a thin object
    assert len(with_pole) == 4
    _, kept = find_objects(np.concatenate([pts, speck]), speck_fraction=0.0)
    assert len(kept) == 4  # the rule is what drops it


def test_names_pass_over_a_sparse_cluster_when_clusters_outnumber_them():
    # the UR5e sample: SfM noise scattered up to 48 mm over the wood grain, nearer the base than the objects, took the
    # first name (tall, so find_objects keeps it as a thin object could be)
    pts, centres = _scene()
    rng = np.random.default_rng(5)
    noise = np.c_[np.array([0.05, 0.1]) + rng.normal(0, 0.01, (12, 2)), np.linspace(0.007, 0.048, 12)]
    _, clusters = find_objects(np.concatenate([pts, noise]))
    assert len(clusters) == 4 and len(clusters[0].points) == 12  # the noise is nearest the base
    named = name_clusters(clusters, ["a", "b", "c"])
    off = [np.linalg.norm(c.centroid[:2] - centre) for c, centre in zip(named, centres.values(), strict=True)]
    assert max(off) < 0.01, off  # the three blobs, nearest the base first
    _, clusters = find_objects(np.concatenate([pts, noise]))
    assert len(name_clusters(clusters, ["a", "b", "c", "d"])) == 4  # as many names as clusters: every one named
    _, clusters = find_objects(np.concatenate([pts, noise]))
    named = name_clusters(clusters, ["a", "b", "c"], sparse_fraction=0.0)
    assert np.linalg.norm(named[0].centroid[:2] - [0.05, 0.1]) < 0.02  # the rule is what passes it over


def test_the_board_on_the_table_holds_the_plane_where_objects_tops_outnumber_it():
    """Flat-topped objects of one height (tins, boxes) with more points on their tops than SfM found on the table: the
    largest plane is their tops. With the board's plane (it lies on the table) the table is found, and every object
    stands on it; with no table point at all (a plain wooden table), the board's own plane is the table's."""
    rng = np.random.default_rng(3)
    table = np.c_[rng.uniform(-0.1, 0.9, 300), rng.uniform(-0.5, 0.5, 300), rng.normal(0, 0.001, 300)]
    centres = [(0.3, 0.3), (0.5, -0.2), (0.7, 0.25), (0.35, -0.35)]
    tops = [
        np.c_[np.array(c) + rng.uniform(-0.04, 0.04, (150, 2)), 0.045 + rng.normal(0, 0.0005, 150)] for c in centres
    ]
    sides = [np.c_[np.array(c) + rng.uniform(-0.04, 0.04, (40, 2)), rng.uniform(0.008, 0.045, 40)] for c in centres]
    pts = np.concatenate([table, *tops, *sides])
    board = (np.array([0.45, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))

    assert abs(fit_support_plane(pts).offset + 0.045) < 0.002  # the tops, without the board
    plane = fit_support_plane(pts, board=board)
    assert abs(plane.offset) < 0.002 and plane.normal[2] > 0.999
    _, clusters = find_objects(pts, plane=plane)
    assert len(clusters) == len(centres)

    far = np.c_[rng.uniform(2.0, 2.1, (30, 2)), rng.uniform(0.01, 0.05, 30)]  # beyond any robot's reach
    bare = np.concatenate([*tops, *sides, far])  # the table gave SfM nothing
    plane = fit_support_plane(bare, board=board)
    assert plane.offset == 0.0 and plane.normal[2] == 1.0
    _, clusters = find_objects(bare, plane=plane)
    assert len(clusters) == len(centres) and all(np.hypot(*c.centroid[:2]) < 1.2 for c in clusters)


def test_stray_points_do_not_chain_textured_objects_and_a_sparse_one_stays_whole():
    # The public real capture's case: two textured objects (SfM points ~5 mm apart on their tops) 4.4 cm apart with
    # two stray points in the gap, 2.2 cm from either side; beside them a sparse, long object (the samples' banana:
    # points 1.5-3 cm apart along 18 cm)
    rng = np.random.default_rng(3)
    table = np.c_[rng.uniform(-0.2, 0.8, (3000, 2)), rng.normal(0, 0.001, 3000)]
    top = np.c_[rng.uniform(0, 0.08, (200, 1)), rng.uniform(0, 0.06, (200, 1)), rng.normal(0.05, 0.001, 200)]
    box_a, box_b = top + [0.40, 0, 0], top[::-1] + [0.524, 0, 0]
    stray = np.array([[0.502, 0.02, 0.05], [0.502, 0.04, 0.05]])
    along = np.cumsum(np.r_[0.0, rng.uniform(0.015, 0.03, 8)])
    sparse = np.c_[0.3 + along, np.full(len(along), 0.3), np.full(len(along), 0.02)]
    sparse = np.concatenate([sparse + [0, dy, dz] for dy in (-0.004, 0.004) for dz in (0, 0.01)])
    plane, clusters = find_objects(np.concatenate([table, box_a, box_b, stray, sparse]))
    sizes = sorted(len(c.points) for c in clusters)
    assert len(clusters) == 3, sizes
    assert sizes[0] == len(sparse)  # the sparse object whole
    for box in (box_a, box_b):
        assert any(len(c.points) >= len(box) and np.linalg.norm(c.centroid[:2] - box[:, :2].mean(0)) < 0.01
                   for c in clusters)  # fmt: skip
