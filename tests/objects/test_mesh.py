"""Watertightness (repair or a clear error), user mesh loading errors, mass properties, CoACD."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from mirage2matter.objects import ObjectsError
from mirage2matter.objects.collision import convex_decomposition
from mirage2matter.objects.mesh import ensure_watertight, load_mesh, mass_properties


def test_small_hole_is_repaired():
    box = trimesh.creation.box(extents=[0.1, 0.06, 0.04])
    open_box = trimesh.Trimesh(box.vertices, box.faces[2:], process=False)  # one face (two triangles) gone
    assert not open_box.is_watertight
    fixed = ensure_watertight(open_box, "box")
    assert fixed.is_watertight
    assert fixed.volume == pytest.approx(0.1 * 0.06 * 0.04, rel=0.05)


def test_open_shell_is_an_error_naming_object_and_file():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    keep = sphere.triangles_center[:, 2] > 0.0  # a hemisphere shell: open at the equator
    shell = trimesh.Trimesh(sphere.vertices, sphere.faces[keep], process=True)
    with pytest.raises(ObjectsError, match=r"'cup'.*scan\.stl.*not watertight"):
        ensure_watertight(shell, "cup", source="scan.stl")


def test_unparsable_missing_and_empty_files(tmp_path):
    bad = tmp_path / "broken.glb"
    bad.write_bytes(b"glTF\x02\x00\x00\x00 this is not a real binary gltf")
    with pytest.raises(ObjectsError, match=r"'banana'.*broken\.glb.*does not parse"):
        load_mesh(bad, "banana")
    with pytest.raises(ObjectsError, match=r"'banana'.*nothere\.obj not found"):
        load_mesh(tmp_path / "nothere.obj", "banana")
    empty = tmp_path / "empty.obj"
    empty.write_text("# no faces\nv 0 0 0\n")
    with pytest.raises(ObjectsError, match=r"empty\.obj"):
        load_mesh(empty, "banana")


def test_loaded_mesh_round_trips(tmp_path):
    box = trimesh.creation.box(extents=[0.1, 0.06, 0.04])
    for suffix in ("obj", "stl", "glb"):
        path = tmp_path / f"box.{suffix}"
        box.export(path)
        m = load_mesh(path, "box")
        assert m.is_watertight and m.volume == pytest.approx(box.volume, rel=1e-6)


def test_mass_properties_of_a_cube():
    cube = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    props = mass_properties(cube, 1000.0)
    assert props["mass"] == pytest.approx(1.0, rel=1e-6)
    np.testing.assert_allclose(np.diag(props["inertia"]), 1.0 * 0.1**2 / 6, rtol=1e-6)
    with pytest.raises(ObjectsError, match="density"):
        mass_properties(cube, 0.0)


def test_convex_decomposition_covers_an_l_shape():
    cells = np.zeros((12, 12, 5), bool)
    cells[1:11, 1:4, 1:4] = True
    cells[1:4, 1:11, 1:4] = True
    ell = trimesh.voxel.VoxelGrid(cells).marching_cubes  # one closed L, 1 cm cells once scaled
    ell.apply_scale(0.01)
    assert ell.is_watertight
    parts = convex_decomposition(ell, threshold=0.05)
    assert len(parts) >= 2 and all(p.is_convex and p.is_watertight for p in parts)
    pts = trimesh.sample.volume_mesh(ell, 3000)
    inside_any = np.zeros(len(pts), bool)
    for p in parts:
        inside_any |= p.contains(pts)
    assert inside_any.mean() > 0.97
    corner = np.array([[0.08, 0.08, 0.025]])  # the empty corner of the L
    assert not any(p.contains(corner)[0] for p in parts)
