"""Silhouette fit: a mesh placed by its outlines in masks rendered from a known pose."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from fixtures.object_checks import silhouette  # ground-truth masks: pixel coverage > 1/2, supersampled
from mirage2matter.geometry.camera import Camera, look_at_pose
from mirage2matter.geometry.rotation import axis_angle_to_matrix, rotation_angle
from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.objects.silhouette import SilhouetteCost, refine_by_silhouettes
from mirage2matter.objects.support import Plane


def club() -> trimesh.Trimesh:
    """An object with a long axis and different ends (a rod with a ball at one end, a knob on its side)."""
    rod = trimesh.creation.capsule(height=0.12, radius=0.012, count=[24, 24])
    rod.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.025)
    ball.apply_translation([0.07, 0.0, 0.01])
    knob = trimesh.creation.icosphere(subdivisions=2, radius=0.012)  # off the axis: no free spin about it
    knob.apply_translation([-0.04, 0.03, 0.0])
    return trimesh.util.concatenate([rod, ball, knob])  # overlapping closed parts: folds in the outline


def bent_tube() -> trimesh.Trimesh:
    """A banana-like object: a capsule bent into an arc about the vertical, lying on its side (round in
    cross-section: its outline changes little when it rolls about its length)."""
    tube = trimesh.creation.capsule(height=0.14, radius=0.015, count=[32, 32])
    tube.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))  # along x
    x, y, z = tube.vertices.T
    bend = 0.12  # radius of the arc (metres)
    tube.vertices = np.c_[(bend - y) * np.sin(x / bend), bend - (bend - y) * np.cos(x / bend), z]
    return tube


def orbit_cameras(n: int = 10) -> list[Camera]:
    K = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        eye = np.array([0.5 * np.cos(a), 0.5 * np.sin(a), 0.3 + 0.1 * np.sin(3 * a)])
        cams.append(Camera(K, look_at_pose(eye, np.zeros(3)), 640, 480, f"c{k}"))
    return cams


@pytest.fixture(scope="module")
def scene():
    mesh = club()
    truth = Sim3(1.0, axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), 0.4), np.array([0.01, -0.02, 0.03]))
    placed = mesh.copy()
    placed.apply_transform(truth.matrix)
    cams = orbit_cameras()
    return mesh, truth, cams, [silhouette(placed, cam) for cam in cams]


def test_refine_recovers_a_perturbed_pose(scene):
    mesh, truth, cams, masks = scene
    cost = SilhouetteCost(mesh, cams, masks)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    off = Sim3(1.04, axis_angle_to_matrix(axis, np.radians(4.0)), np.array([0.004, 0.003, -0.002]))
    start = off @ truth
    fitted, final = refine_by_silhouettes(cost, start)
    rot_err = float(np.degrees(rotation_angle(fitted.rotation @ truth.rotation.T)))
    assert abs(fitted.scale - 1) < 0.005, fitted.scale
    assert rot_err < 0.5
    assert np.linalg.norm(fitted.translation - truth.translation) < 0.001
    assert final < cost(start)


def test_cost_tells_the_ends_apart(scene):
    # the half-turned club covers nearly the same pixels along its rod, but not at its ends
    mesh, truth, cams, masks = scene
    cost = SilhouetteCost(mesh, cams, masks)
    centre = truth.apply(mesh.vertices).mean(0)
    R = axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), np.pi)
    flipped = Sim3(1.0, R, centre - R @ centre) @ truth
    assert cost(truth) < 0.3  # both outlines within a fraction of a pixel (Cauchy, 1 px scale)
    assert cost(flipped) > 5 * cost(truth) + 0.5


def test_masks_must_not_be_empty(scene):
    mesh, _, cams, masks = scene
    with pytest.raises(ValueError, match="no keyframe has a non-empty mask"):
        SilhouetteCost(mesh, cams, [None] + [np.zeros_like(m) for m in masks[1:]])


def test_contact_with_the_table_resists_a_shadowed_foot():
    # masks that also hold a contact shadow on one side (the object flattened onto the table, shifted
    # 3-4 mm) pull the outline fit towards it and into a roll; the support plane keeps its lowest point on
    # the table, which takes most of the roll away
    mesh = bent_tube()
    R = axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), 0.4)
    truth = Sim3(1.0, R, np.array([0.01, -0.02, -(mesh.vertices @ R.T)[:, 2].min()]))
    placed = mesh.copy()
    placed.apply_transform(truth.matrix)
    shadow = placed.copy()
    shadow.vertices = placed.vertices * [1.0, 1.0, 0.02] + [0.003, 0.002, 0.0]
    cams = orbit_cameras()
    masks = [silhouette(placed, cam) | silhouette(shadow, cam) for cam in cams]
    table = Plane(np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(0, bool))
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    start = Sim3(1.03, axis_angle_to_matrix(axis, np.radians(3.0)), np.array([0.003, 0.002, 0.002])) @ truth
    errors = {}
    for name, plane in (("free", None), ("resting", table)):
        fitted, _ = refine_by_silhouettes(SilhouetteCost(mesh, cams, masks, plane=plane), start)
        lowest = fitted.apply(mesh.vertices)[:, 2].min()
        errors[name] = float(np.degrees(rotation_angle(fitted.rotation @ truth.rotation.T)))
        if plane is not None:
            assert abs(lowest) < 0.0003
    # resting on the table, only the roll the round tube hides from the outline is left (1.6 deg here)
    assert errors["resting"] < 2.5, errors
    assert errors["free"] > 4.0, errors  # rolled towards the shadow (7.0 deg here)
