"""A low-polygon render copy of an MJCF robot: same kinematics, collision and inertia, lighter visuals.

On the CPU (Mesa llvmpipe) the robot render costs in proportion to its triangles, and Genesis'
bundled Franka Panda draws 134k of them, most in a few finely tessellated links. At 224x224 a link
covers a few thousand pixels, so decimating every visual mesh to ~1500 faces changes the picture
by a pixel at silhouettes and makes each render pass several times cheaper. Only meshes of
``class="visual"`` geoms (no contacts: contype = conaffinity = 0) are touched; collision meshes,
joints and inertias are the original files, so the physics is unchanged.
"""

from __future__ import annotations

import hashlib
import re
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..atomic import atomic_dir
from ..robots.model import genesis_assets_dir, robot_cache_dir

__all__ = ["genesis_asset", "lowpoly_robot", "render_robot_file", "robot_cache_dir"]


def render_robot_file(robot_file: str, max_faces: int | None) -> str:
    """The robot model to build a rendering twin from: the low-polygon copy of an MJCF ``robot_file`` (built once,
    under :func:`robot_cache_dir`), or ``robot_file`` itself (``max_faces`` None, or a URDF)."""
    if not max_faces or not robot_file.lower().endswith(".xml"):
        return robot_file
    return str(lowpoly_robot(robot_file, robot_cache_dir(), max_faces))


def genesis_asset(path: str) -> Path:
    """A robot file given relative to Genesis' bundled assets (as world.yaml does) as an absolute path."""
    p = Path(path)
    if p.is_absolute():
        return p
    assets = genesis_assets_dir()
    return (assets if assets is not None else Path.cwd()) / p


def _visual_classes(root: ET.Element) -> set[str]:
    """Default classes whose geoms draw only (contype = conaffinity = 0, set there or in an enclosing class)."""
    out: set[str] = set()

    def walk(node: ET.Element, inherited: dict[str, str]) -> None:
        for d in node.findall("default"):
            attrs = dict(inherited)
            g = d.find("geom")
            if g is not None:
                attrs.update({k: g.get(k) for k in ("contype", "conaffinity") if g.get(k) is not None})
            if d.get("class") and attrs.get("contype") == "0" and attrs.get("conaffinity") == "0":
                out.add(d.get("class"))
            walk(d, attrs)

    walk(root, {})
    return out


def _visual_mesh_files(xml_path: Path) -> set[str]:
    """Mesh files used only by visual geoms (contype = conaffinity = 0, on the geom or through its default class)."""
    root = ET.parse(xml_path).getroot()
    meshdir = (root.find("compiler").get("meshdir", "") if root.find("compiler") is not None else "") or ""
    files = {}
    for m in root.iter("mesh"):
        f = m.get("file")
        if f:
            files[m.get("name") or Path(f).stem] = str(Path(meshdir) / f)
    visual_classes = _visual_classes(root) | {"visual"}
    used_by_collision, used_by_visual = set(), set()
    for g in root.iter("geom"):
        mesh = g.get("mesh")
        if mesh is None:
            continue
        visual = g.get("class") in visual_classes or (g.get("contype") == "0" and g.get("conaffinity") == "0")
        (used_by_visual if visual else used_by_collision).add(files.get(mesh, mesh))
    return used_by_visual - used_by_collision


def _decimate_obj(src: Path, dst: Path, max_faces: int) -> int:
    """Write ``src`` (OBJ) decimated to at most ~``max_faces`` triangles as a plain v/f OBJ; returns faces."""
    import fast_simplification
    import trimesh

    mesh = trimesh.load(str(src), force="mesh", process=False)
    # OBJ vertices are split at texture / normal seams; decimating that soup tears the surface apart.
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    text = src.read_text(errors="replace")
    header = "".join(line + "\n" for line in text.splitlines() if re.match(r"(mtllib|usemtl) ", line))
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    if len(f) > max_faces:
        v, f = fast_simplification.simplify(v.astype(np.float32), f, target_reduction=1.0 - max_faces / len(f))
    lines = (
        [header] + [f"v {x:.6g} {y:.6g} {z:.6g}\n" for x, y, z in v] + [f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f]
    )
    dst.write_text("".join(lines))
    return len(f)


def lowpoly_robot(robot_file: str, cache_dir: Path, max_faces: int = 1500) -> Path:
    """A copy of the MJCF ``robot_file``'s folder with its visual-only meshes decimated to ``max_faces``
    faces each, built once under ``cache_dir``; returns the copied XML's path."""
    src_xml = genesis_asset(robot_file)
    if src_xml.suffix.lower() != ".xml":
        raise ValueError(f"{robot_file}: a low-polygon render copy needs an MJCF (.xml) robot")
    key = hashlib.sha1(f"{src_xml.resolve()}|{max_faces}|2".encode()).hexdigest()[:12]
    out = Path(cache_dir) / f"{src_xml.parent.name}-lowpoly-{key}"
    if (out / src_xml.name).is_file():
        return out / src_xml.name
    visual = _visual_mesh_files(src_xml)
    with atomic_dir(out) as tmp:
        shutil.copytree(src_xml.parent, tmp, dirs_exist_ok=True)
        for rel in visual:
            p = tmp / rel
            if p.suffix.lower() == ".obj" and p.is_file():
                _decimate_obj(src_xml.parent / rel, p, max_faces)
    return out / src_xml.name
