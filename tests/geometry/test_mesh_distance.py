"""Point-to-mesh distance (`geometry/mesh_distance.py`) against a brute-force check over every triangle."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from mirage2matter.geometry.mesh_distance import point_mesh_distance, point_mesh_nearest


def _segment(p, a, b):
    ab = b - a
    t = np.clip(((p - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=-1)


def brute_force(p: np.ndarray, tris: np.ndarray) -> float:
    """Distance from p [3] to the nearest of tris [T,3,3]: the plane's where the foot lies inside, else the edges'."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    dn = ((p - a) * n).sum(-1)
    foot = p - dn[:, None] * n
    sides = np.stack([(np.cross(v - u, foot - u) * n).sum(-1) for u, v in ((a, b), (b, c), (c, a))])
    inside = (sides >= 0).all(0) | (sides <= 0).all(0)
    edges = np.minimum(np.minimum(_segment(p, a, b), _segment(p, b, c)), _segment(p, c, a))
    return float(np.where(inside, np.abs(dn), edges).min())


def test_one_triangle_every_region():
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    pts = np.array([
        [0.2, 0.2, 0.5],  # above the face
        [-1, -1, 0.0],  # vertex a
        [2, -0.5, 1.0],  # vertex b
        [-0.2, 2, -1.0],  # vertex c
        [0.5, -1, 0.0],  # edge ab
        [-1, 0.5, 2.0],  # edge ac
        [1, 1, 0.0],  # edge bc
    ])  # fmt: skip
    want = [0.5, np.sqrt(2), np.sqrt(1 + 0.25 + 1), np.sqrt(0.04 + 1 + 1), 1.0, np.sqrt(1 + 4), np.sqrt(0.5)]
    np.testing.assert_allclose(point_mesh_distance(pts, tri, [[0, 1, 2]]), want, rtol=1e-12)


@pytest.mark.parametrize("k", [1, 16])
def test_a_mesh_near_and_far_is_exact(k):
    rng = np.random.default_rng(0)
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    mesh.vertices *= [1.0, 0.6, 1.4]  # triangles of many sizes and shapes
    mesh.vertices += rng.normal(0, 0.002, mesh.vertices.shape)
    near = trimesh.sample.sample_surface(mesh, 300, seed=1)[0] + rng.normal(0, 0.004, (300, 3))
    pts = np.r_[near, rng.uniform(-0.3, 0.3, (60, 3))]  # and far away, where the k nearest prove nothing
    got = point_mesh_distance(pts, mesh.vertices, mesh.faces, k=k)
    tris = mesh.vertices[mesh.faces]
    np.testing.assert_allclose(got, [brute_force(p, tris) for p in pts], rtol=1e-9, atol=1e-12)
    dist, tri = point_mesh_nearest(pts, mesh.vertices, mesh.faces, k=k)  # the triangle named is that nearest one
    np.testing.assert_array_equal(dist, got)
    np.testing.assert_allclose([brute_force(p, tris[[t]]) for p, t in zip(pts, tri, strict=True)], got, rtol=1e-9)


def test_no_points_and_no_triangles():
    assert point_mesh_distance(np.zeros((0, 3)), np.eye(3), [[0, 1, 2]]).shape == (0,)
    with pytest.raises(ValueError, match="no triangles"):
        point_mesh_distance(np.zeros((2, 3)), np.zeros((0, 3)), np.zeros((0, 3), int))
