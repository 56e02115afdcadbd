"""The viewer's scene nodes (viser), all in the robot-base frame (z up, metres).

    /scene                      the scene's Gaussians
    /objects/<name>             an object's placement (R, t; a gizmo when editable), its Gaussians scaled by the
        /splats, /collision/*   placement's scale beneath it; an articulated asset's cap at /objects/<name>/cap
    /robot/<link>               each link at its forward-kinematics pose; its Gaussians (or its mesh) beneath it
    /robot/<mount>/<camera>     a camera on a link (the wrist camera) moves with it; /cameras/<camera> on the base
    /keyframes/<i>              the capture's keyframe cameras with their pictures
    /board                      the calibration target
Viser's frustums and images use OpenCV camera axes (x right, y down, z forward), as ours do.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..geometry.rotation import matrix_to_quat
from ..geometry.sim3 import Sim3
from ..robots.surface import robot_surface
from .config import ViewerConfig
from .inputs import Board, ViewerInputs
from .splats import SplatArrays, read_splats

__all__ = ["KEYFRAME_RGB", "ROBOT_MESH_RGB", "add_board", "add_cameras", "add_keyframes", "add_objects",
           "add_robot", "add_scene", "wxyz"]  # fmt: skip

KEYFRAME_RGB = (255, 40, 200)  # magenta: nothing in a table scene has it, so a screenshot test can count it
CAMERA_RGB = (255, 150, 0)
ROBOT_MESH_RGB = (190, 190, 200)
COLLISION_RGB = (60, 200, 90)

Progress = Callable[[str], None]


def wxyz(R: np.ndarray) -> np.ndarray:
    """The wxyz quaternion [4] of a rotation matrix [3,3]."""
    return np.asarray(matrix_to_quat(np.asarray(R, np.float64)), np.float64)


def _splats(server: Any, name: str, arrays: SplatArrays, **pose: Any) -> Any:
    return server.scene.add_gaussian_splats(name, **arrays.kwargs(), **pose)


def add_scene(server: Any, inputs: ViewerInputs, cfg: ViewerConfig, progress: Progress) -> Any | None:
    """The scene's Gaussians (the world's, else train-scene's), or None without any."""
    path = inputs.world.scene_gaussians if inputs.world is not None else inputs.scene_ply
    if path is None:
        return None
    progress(f"the scene's Gaussians ({Path(path).name})")
    return _splats(server, "/scene", read_splats(path, cfg.max_gaussians))


def _collision(server: Any, name: str, folder: Path | None, mesh: Path | None, scale: float) -> list[Any]:
    """The convex parts (or, without them, the watertight mesh) of one body, in its frame times ``scale``."""
    import trimesh

    files = sorted(folder.glob("*.obj")) if folder is not None and folder.is_dir() else []
    if not files and mesh is not None and mesh.is_file():
        files = [mesh]
    out = []
    for i, f in enumerate(files):
        m = trimesh.load(str(f), force="mesh", process=False)
        out.append(server.scene.add_mesh_simple(f"{name}/collision/{i:02d}", np.asarray(m.vertices) * scale,
                                                np.asarray(m.faces), color=COLLISION_RGB, opacity=0.6,
                                                visible=False))  # fmt: skip
    return out


def add_objects(server: Any, inputs: ViewerInputs, cfg: ViewerConfig, editable: bool,
                progress: Progress) -> tuple[dict[str, Any], list[Any]]:  # fmt: skip
    """({name: its placement node}, the collision meshes). Editable: the node is a gizmo that moves in the table's
    plane and turns about z (what ``m2m world move`` can write)."""
    world = inputs.world
    if world is None:
        return {}, []
    nodes, collision = {}, []
    items = [(o.name, o.placement, [("", o.part, None)]) for o in world.objects]
    items += [(a.name, a.placement, [("", a.base, None), ("/cap", a.cap, a.T_base_cap)]) for a in world.articulated]
    for name, placement, parts in items:
        progress(f"object {name}")
        node = f"/objects/{name}"
        pose = {"wxyz": wxyz(placement.rotation), "position": np.asarray(placement.translation, np.float64)}
        if editable:
            nodes[name] = server.scene.add_transform_controls(node, scale=0.15, active_axes=(True, True, False),
                                                              depth_test=False, **pose)  # fmt: skip
        else:
            nodes[name] = server.scene.add_frame(node, show_axes=False, **pose)
        s = float(placement.scale)
        for suffix, part, T_base_part in parts:
            parent = node + suffix
            if T_base_part is not None:  # the cap's rest pose in the asset's frame; the placement scales it
                server.scene.add_frame(parent, show_axes=False, wxyz=wxyz(T_base_part[:3, :3]),
                                       position=s * np.asarray(T_base_part[:3, 3]))  # fmt: skip
            if part.gaussians is not None:
                _splats(server, f"{parent}/splats", read_splats(part.gaussians, cfg.max_gaussians).scaled(s))
            collision += _collision(server, parent, part.collision, part.mesh, s)
    return nodes, collision


def add_robot(server: Any, inputs: ViewerInputs, T_base_link: dict[str, np.ndarray], cfg: ViewerConfig,
              progress: Progress) -> tuple[dict[str, Any], list[Any]]:  # fmt: skip
    """({link: its frame node}, the nodes that draw it): the robot's captured look (per-link Gaussians) where it has
    one, else its model's meshes."""
    files: dict[str, Path] = {}
    if inputs.robot_gaussians is not None:
        info = json.loads((inputs.robot_gaussians / "robot.json").read_text(encoding="utf-8"))
        files = {link: inputs.robot_gaussians / f for link, f in info["links"].items()}
    nodes, looks = {}, []
    for link, T in T_base_link.items():
        nodes[link] = server.scene.add_frame(f"/robot/{link}", show_axes=False, wxyz=wxyz(T[:3, :3]),
                                             position=T[:3, 3])  # fmt: skip
    if files:
        progress(f"the robot's captured look ({len(files)} links)")
        per_link = max(cfg.max_gaussians // max(len(files), 1), 1)
        for link, path in files.items():
            if link in nodes:
                looks.append(_splats(server, f"/robot/{link}/splats", read_splats(path, per_link)))
        return nodes, looks
    progress("the robot's meshes (no captured look: train-scene draws one when the keyframes show the robot)")

    for s in robot_surface(inputs.robot, None):
        if s.link in nodes:
            rgb = s.face_rgb.mean(0) if s.face_rgb is not None else np.array([0.75, 0.75, 0.78])
            looks.append(
                server.scene.add_mesh_simple(
                    f"/robot/{s.link}/mesh",
                    s.vertices_link,
                    s.faces,
                    color=tuple(int(255 * c) for c in np.clip(rgb, 0, 1)),
                )
            )
    return nodes, looks


def _fov(K: np.ndarray, height: int) -> float:
    return 2.0 * math.atan(0.5 * height / float(K[1, 1]))


def add_cameras(server: Any, inputs: ViewerInputs, links: dict[str, Any]) -> dict[str, Any]:
    """{camera: frustum}: the world's cameras, each under its mount (the base, or a link it moves with)."""
    out = {}
    for name, c in inputs.world.cameras.items() if inputs.world is not None else []:
        parent = f"/robot/{c.mount}" if c.mount in links else "/cameras"
        T = np.asarray(c.T_mount_cam)
        out[name] = server.scene.add_camera_frustum(
            f"{parent}/{name}", fov=_fov(c.K, c.height), aspect=c.width / c.height, scale=0.06, thickness=3.0,
            thickness_units="screen", color=CAMERA_RGB, wxyz=wxyz(T[:3, :3]), position=T[:3, 3],
        )  # fmt: skip
        server.scene.add_label(f"{parent}/{name}/label", name)
    return out


def add_keyframes(server: Any, inputs: ViewerInputs, cfg: ViewerConfig, progress: Progress) -> list[Any]:
    """The keyframe cameras as frustums with their pictures (thumbnails)."""
    import cv2

    out = []
    if inputs.keyframes:
        progress(f"{len(inputs.keyframes)} keyframe cameras")
    for i, cam in enumerate(inputs.keyframes):
        image = None
        path = inputs.image_dir / cam.name if inputs.image_dir is not None else None
        if path is not None and path.is_file():
            bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if bgr is not None:
                h = max(1, round(bgr.shape[0] * cfg.thumbnail_px / bgr.shape[1]))
                image = cv2.resize(bgr, (cfg.thumbnail_px, h), interpolation=cv2.INTER_AREA)[:, :, ::-1].copy()
        T = np.asarray(cam.T_world_cam)
        out.append(server.scene.add_camera_frustum(
            f"/keyframes/{i:03d}", fov=_fov(cam.K, cam.height), aspect=cam.width / cam.height, scale=cfg.frustum_m,
            thickness=2.0, thickness_units="screen", color=KEYFRAME_RGB, image=image, format="jpeg",
            wxyz=wxyz(T[:3, :3]), position=T[:3, 3],
        ))  # fmt: skip
    return out


def add_board(server: Any, board: Board | None) -> Any | None:
    """The board as a checkerboard plane where alignment found it (a frame alone for other targets)."""
    if board is None:
        return None
    T = np.asarray(board.T_base_board, np.float64)
    nx, ny, sq = (board.layout.get(k) for k in ("squares_x", "squares_y", "square"))
    if not (nx and ny and sq):
        return server.scene.add_frame("/board", axes_length=0.05, axes_radius=0.003, wxyz=wxyz(T[:3, :3]),
                                      position=T[:3, 3])  # fmt: skip
    px = 16
    checker = ((np.arange(ny * px)[:, None] // px + np.arange(nx * px)[None, :] // px) % 2).astype(np.uint8)
    image = np.repeat((40 + 200 * checker)[:, :, None], 3, axis=2)
    centre = T @ np.array([nx * sq / 2, ny * sq / 2, 0.0, 1.0])
    return server.scene.add_image("/board", image, render_width=nx * sq, render_height=ny * sq,
                                  wxyz=wxyz(T[:3, :3]), position=centre[:3] + [0.0, 0.0, 0.002])  # fmt: skip


def placement_pose(placement: Sim3) -> tuple[np.ndarray, np.ndarray]:
    """(wxyz [4], position [3]) of a placement's rigid part."""
    return wxyz(placement.rotation), np.asarray(placement.translation, np.float64)
