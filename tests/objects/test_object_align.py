"""3DGS <-> mesh alignment: a user mesh at the wrong scale and orientation is recovered, and the
object frame sits at the bottom centre with z up."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from fixtures import SAMPLE
from mirage2matter.geometry.rotation import axis_angle_to_matrix, rotation_angle
from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.objects.align import align_points_to_mesh, distance_to_mesh, object_frame


def _gt(name: str) -> tuple[trimesh.Trimesh, np.ndarray]:
    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    o = next(o for o in gt["objects"] if o["name"] == name)
    return trimesh.load(SAMPLE / o["mesh"], force="mesh"), np.asarray(o["T_base_obj"])


def _visible_points(mesh_obj, T_base_obj, n=4000, noise=0.001, seed=0) -> np.ndarray:
    """What an object 3DGS gives: points on the surface but not on the underside, noisy, in the base frame."""
    rng = np.random.default_rng(seed)
    pts, faces = trimesh.sample.sample_surface(mesh_obj, 3 * n, seed=seed)
    pts = pts[(pts[:, 2] > 0.003) & (mesh_obj.face_normals[faces][:, 2] > -0.5)][:n]
    pts = pts + rng.normal(0, noise, pts.shape)
    return pts @ T_base_obj[:3, :3].T + T_base_obj[:3, 3]


@pytest.mark.parametrize("name", ["banana", "croissant"])
def test_user_mesh_at_wrong_scale_and_rotation_is_recovered(name):
    mesh_obj, T_base_obj = _gt(name)
    points_base = _visible_points(mesh_obj, T_base_obj)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    wrong = Sim3(1.7, axis_angle_to_matrix(axis, np.radians(40)), np.array([0.2, -0.1, 0.05]))
    user_mesh = mesh_obj.copy()
    user_mesh.apply_transform(wrong.matrix)  # as a user might hand it over: scaled, turned, moved
    a = align_points_to_mesh(points_base, user_mesh)
    expected = wrong @ Sim3.from_matrix(T_base_obj).inverse()  # base -> user mesh frame
    assert a.sim3_points_to_mesh.scale == pytest.approx(expected.scale, rel=0.01)
    R_err = a.sim3_points_to_mesh.rotation @ expected.rotation.T
    assert np.degrees(rotation_angle(R_err)) < 1.0
    # the mesh placed back in the base frame lies on the points
    placed = user_mesh.copy()
    placed.apply_transform(a.sim3_points_to_mesh.inverse().matrix)
    assert np.median(distance_to_mesh(points_base, placed)) < 0.0015


def test_user_keypoints_start():
    mesh_obj, T_base_obj = _gt("banana")
    points_base = _visible_points(mesh_obj, T_base_obj)
    wrong = Sim3(0.5, axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), np.radians(170)), np.array([1.0, 2.0, 3.0]))
    user_mesh = mesh_obj.copy()
    user_mesh.apply_transform(wrong.matrix)
    kp_obj = np.array([[-0.08, 0.0, 0.01], [0.08, 0.0, 0.01], [0.0, 0.02, 0.03], [0.0, -0.02, 0.01]])
    kp_base = kp_obj @ T_base_obj[:3, :3].T + T_base_obj[:3, 3]
    a = align_points_to_mesh(points_base, user_mesh, keypoints=(kp_base, wrong.apply(kp_obj)))
    assert a.start == "user keypoints"
    assert a.sim3_points_to_mesh.scale == pytest.approx(0.5, rel=0.01)


def test_object_frame_is_bottom_centre_z_up():
    mesh_obj, T_base_obj = _gt("banana")
    mesh_base = mesh_obj.copy()
    mesh_base.apply_transform(T_base_obj)
    T = object_frame(mesh_base)
    np.testing.assert_allclose(T[:3, 2], [0, 0, 1], atol=1e-9)
    # the ground-truth frame is also bottom centre, x along the banana: same up to the sign of x
    assert abs(T[2, 3] - T_base_obj[2, 3]) < 5e-4
    assert np.linalg.norm(T[:2, 3] - T_base_obj[:2, 3]) < 0.003
    assert abs(abs(T[:3, 0] @ T_base_obj[:3, 0]) - 1) < 1e-3
    local = trimesh.transformations.transform_points(mesh_base.vertices, np.linalg.inv(T))
    assert abs(local[:, 2].min()) < 1e-6
