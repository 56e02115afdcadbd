"""The low-polygon render copy of the robot: visual meshes lighter, everything physical untouched."""

from __future__ import annotations

import filecmp
from pathlib import Path

import pytest
import trimesh

from mirage2matter.env.robot_proxy import _visual_mesh_files, genesis_asset, lowpoly_robot

PANDA = "xml/franka_emika_panda/panda.xml"
pytestmark = pytest.mark.slow  # decimating 55 meshes and comparing every file takes ~1 min here


def test_lowpoly_panda_keeps_physics_and_cuts_triangles(tmp_path: Path) -> None:
    src = genesis_asset(PANDA)
    if not src.is_file():
        pytest.skip("Genesis' bundled Panda is not installed")
    visual = _visual_mesh_files(src)
    assert visual and not any(v.endswith(".stl") or "collision" in v for v in visual)
    out = lowpoly_robot(PANDA, tmp_path, max_faces=1500)
    assert lowpoly_robot(PANDA, tmp_path, max_faces=1500) == out  # cached
    assert filecmp.cmp(src, out, shallow=False)  # the MJCF itself (joints, inertias, classes) is the original
    before = after = 0
    for p in sorted(src.parent.rglob("*")):
        rel = p.relative_to(src.parent)
        q = out.parent / rel
        assert q.exists(), rel
        if p.is_dir():
            continue
        if str(rel) in visual and p.suffix == ".obj":
            a = trimesh.load(p, force="mesh", process=False)
            b = trimesh.load(q, force="mesh", process=False)
            before, after = before + len(a.faces), after + len(b.faces)
            assert len(b.faces) <= max(1500 * 1.05, len(a.faces))
            # Same shape: the decimated surface stays within 1 cm of the original's bounds (worst link: 6 mm,
            # about a pixel at 224x224 from the head camera; the rest within 2 mm).
            assert abs(a.bounds - b.bounds).max() < 1e-2, rel
        else:
            assert filecmp.cmp(p, q, shallow=False), f"{rel} (collision or other) must be copied unchanged"
    assert after < 0.4 * before
