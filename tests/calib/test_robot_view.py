"""The robot as the capture saw it: silhouettes, its SfM points, its surface as an alignment target."""

from __future__ import annotations

import numpy as np
import pytest

from mirage2matter.calib.robot_view import (
    THROUGH_MIN_OBSERVATIONS,
    fit_to_robot,
    robot_depths,
    robot_framing,
    robot_points,
    robot_silhouette,
    robot_silhouettes,
    views_behind_robot,
    visual_hull,
)
from mirage2matter.geometry.camera import Camera, look_at_pose
from mirage2matter.geometry.rotation import axis_angle_to_matrix
from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.robots.surface import sample_surface


@pytest.fixture(scope="module")
def scene(turned_panda):
    spec, links = turned_panda
    K = np.array([[260.0, 0, 160.5], [0, 260.0, 120.0], [0, 0, 1]])
    cams = [Camera(K, look_at_pose((0.2 + 1.3 * np.cos(a), 1.3 * np.sin(a), 0.8), (0.15, 0.0, 0.3)), 320, 240, f"c{i}")
            for i, a in enumerate(np.linspace(-2.2, 2.2, 10))]  # fmt: skip
    rng = np.random.default_rng(0)
    table = np.c_[rng.uniform(-0.35, 1.0, 4000), rng.uniform(-0.5, 0.5, 4000), np.zeros(4000)]
    table = table[np.hypot(table[:, 0] + 0.05, table[:, 1]) > 0.2]  # not under the base
    return spec, links, cams, table


def test_the_silhouette_covers_the_projected_surface_and_little_else(scene):
    """Every surface point lands inside its camera's silhouette; pixels no surface point reaches (with a 2 px
    allowance for the sampling) are a few percent of the silhouette at most."""
    import cv2

    _, links, cams, _ = scene
    pts, _ = sample_surface(links, 0.002)
    for cam in cams[::3]:
        sil = robot_silhouette(cam, links)
        uv, z = cam.project(pts)
        u, v = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        ok = (z > 0) & (u >= 0) & (v >= 0) & (u < cam.width) & (v < cam.height)
        assert sil[v[ok], u[ok]].mean() > 0.99  # a point on an edge lands in a pixel whose centre is outside
        assert robot_silhouette(cam, links, 1)[v[ok], u[ok]].mean() > 0.9995
        hit = np.zeros_like(sil, np.uint8)
        hit[v[ok], u[ok]] = 1
        hit = cv2.dilate(hit, np.ones((5, 5), np.uint8)).astype(bool)
        assert 0.05 < sil.mean() < 0.6
        assert (sil & ~hit).sum() / sil.sum() < 0.03


def test_the_robot_points_are_found_and_the_table_is_not(scene):
    _, links, cams, table = scene
    pts, _ = sample_surface(links, 0.008, seed=1)
    noisy = pts + np.random.default_rng(2).normal(0, 0.002, pts.shape)
    cloud = np.r_[noisy, table]
    found = robot_points(cloud, links, cams, robot_silhouettes(cams, links, 1))
    assert found.on_robot[: len(pts)].mean() > 0.995
    assert found.on_robot[len(pts) :].mean() < 0.01
    assert found.seen and found.seen_fraction > 0.5
    empty = robot_points(table, links, cams)
    assert not empty.seen and empty.seen_fraction < 0.02


def test_a_robot_without_sfm_points_counts_where_framed_and_not_seen_through(scene):
    """Smooth paint gives SfM no point on the robot: it is in the capture where keyframes frame it and none of what
    they observed lies behind it (the table points the robot hides are not observed); an empty table where it would
    stand is seen through; keyframes looking away do not frame it."""
    _, links, cams, table = scene
    depths = robot_depths(cams, links)

    def observed(robot_there: bool) -> dict:
        out = {}
        for cam, depth in zip(cams, depths, strict=True):
            uv, z = cam.project(table)
            u, v = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
            ok = (z > 0) & (u >= 0) & (v >= 0) & (u < cam.width) & (v < cam.height)
            if robot_there:  # the robot hides what lies behind it
                ok[ok] &= depth[v[ok], u[ok]] > z[ok] - 0.005
            out[cam.name] = (uv[ok], table[ok])
        return out

    there = robot_framing(cams, lambda cam: links, observed(True))
    assert there.seen and there.keyframes == len(cams) and there.through <= 0.05 * max(there.inside, 1), there
    empty = robot_framing(cams, lambda cam: links, observed(False))
    assert not empty.seen and empty.keyframes == len(cams), empty
    assert empty.inside >= THROUGH_MIN_OBSERVATIONS and empty.through > 0.8 * empty.inside, empty
    assert robot_framing(cams, lambda cam: links, {}).seen  # no observations: nothing says it is not there
    away = [Camera(cams[0].K, look_at_pose((2.0, y, 0.8), (3.5, y, 0.3)), 320, 240, f"away{i}")
            for i, y in enumerate((-0.5, 0.0, 0.5))]  # fmt: skip
    looked_away = robot_framing(away, lambda cam: links, {})
    assert looked_away.keyframes == 0 and not looked_away.seen


def test_the_visual_hull_holds_the_links_not_the_space_around(scene):
    _, links, cams, _ = scene
    sils = robot_silhouettes(cams, links, 1)
    inside, _ = sample_surface(links, 0.03)
    out = inside[:, :2] / np.linalg.norm(inside[:, :2], axis=1, keepdims=True)
    around = inside + 0.3 * np.c_[out, np.zeros(len(out))]  # 30 cm further out from the base's axis
    hull = visual_hull(np.r_[inside, around], cams, sils)
    assert hull[: len(inside)].all()
    assert hull[len(inside) :].mean() < 0.01  # a moved point may land on another link


def test_the_keyframes_hiding_an_object_are_those_where_the_robot_stands_in_front(scene):
    """Objects on the table around the robot: a keyframe hides one when rays from the camera to its points meet the
    robot's mesh first (trimesh's ray caster is the reference): none blocked -> not hidden (the robot behind the
    object or beside it in the image does not count), 10 % or more -> hidden."""
    import trimesh

    _, links, cams, _ = scene
    robot = trimesh.util.concatenate([trimesh.Trimesh(link.vertices, link.faces, process=False) for link in links])
    rng = np.random.default_rng(3)
    centres = [(0.45, 0.0), (0.0, 0.45), (-0.3, -0.3), (0.6, 0.35), (0.3, -0.3), (-0.35, 0.2)]
    depths = robot_depths(cams, links)
    hidden = clear = 0
    for cx, cy in centres:
        pts = np.c_[rng.normal(cx, 0.015, 150), rng.normal(cy, 0.015, 150), rng.uniform(0.0, 0.06, 150)]
        got = views_behind_robot(pts, cams, depths)
        for cam, said in zip(cams, got, strict=True):
            origin = cam.T_world_cam[:3, 3]
            ray = pts - origin
            dist = np.linalg.norm(ray, axis=1)
            hit, index, _ = robot.ray.intersects_location(np.repeat(origin[None], len(pts), 0), ray / dist[:, None],
                                                          multiple_hits=False)  # fmt: skip
            blocked = np.zeros(len(pts), bool)
            if len(index):  # trimesh's own ray caster (no embree) gives an empty (0,) array for no hit
                blocked[index] = np.linalg.norm(hit.reshape(-1, 3) - origin, axis=1) < dist[index] - 0.01
            frac = blocked.mean()
            if 0.0 < frac < 0.1:  # a few points behind the robot's edge: the 5 % line is the depth splat's to draw
                continue
            assert said == (frac >= 0.1), (cam.name, (cx, cy), frac)
            hidden += said
            clear += not said
    assert hidden >= 2 and clear >= 30


def test_the_robot_fit_recovers_a_misalignment_the_board_corners_do_not_hold(scene):
    """SfM points of the robot moved by a known rigid error: the fit's correction undoes it (corner anchors at zero
    weight), and with the corners held at full weight it barely moves them."""
    _, links, _, _ = scene
    pts, _ = sample_surface(links, 0.01, seed=4)
    err = Sim3(1.0, axis_angle_to_matrix(np.array([0.3, -1.0, 0.5]), np.radians(0.6)), np.array([0.004, -0.003, 0.002]))
    seen = err.apply(pts + np.random.default_rng(5).normal(0, 0.001, pts.shape))
    corners = np.array([[0.1, 0.3, 0.0], [0.4, 0.3, 0.0], [0.4, 0.5, 0.0], [0.1, 0.5, 0.0]])
    fit = fit_to_robot(seen, links, anchors=(corners, corners), anchor_weight=0.0)
    undone = fit.correction @ err
    assert np.degrees(np.arccos(np.clip((np.trace(undone.rotation) - 1) / 2, -1, 1))) < 0.1
    assert np.linalg.norm(undone.apply(pts) - pts, axis=1).max() < 0.0015
    assert fit.rms_after_mm < 0.5 * fit.rms_before_mm
    held = fit_to_robot(seen, links, anchors=(corners, corners), anchor_weight=1.0)
    assert held.corner_rms_mm < fit.corner_rms_mm
