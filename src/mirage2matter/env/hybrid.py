"""The "hybrid" observation renderer (paper section 3.3): the Gaussian world with every part at its physics pose,
the Genesis robot rendered over it, depth-aware (``render.composite``), the episode's colour jitter on the splats.
What generation records and what the environment observes by default: the same code makes both.

The twin it renders is built for it (:func:`build_hybrid`): cameras at the frame size, only the robot drawn
(its mask is where its depth is finite), the robot's visual meshes decimated (``robot_proxy``).
"""

from __future__ import annotations

import json
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from ..render.composite import ColorJitter, composite, to_uint8
from ..render.splat_server import RemoteSplatLayer
from ..render.table_texture import TableGaussians
from ..sim.scene import render_K
from .config import EnvConfig, HybridOptions
from .robot_proxy import render_robot_file

if TYPE_CHECKING:
    from pathlib import Path

    from ..sim.twin import Twin
    from ..world.config import WorldConfig
    from .episode import EpisodeDraw

__all__ = ["ROBOT_PART", "TIMING_KEYS", "HybridRenderer", "build_hybrid", "render_K", "robot_links", "splat_parts"]

TIMING_KEYS = ("pose_splats", "splat_render", "robot_render", "composite")


class HybridRenderer:
    """Hybrid frames of a twin's current state from the named cameras.

    Use :meth:`start_episode` after every reset (it forgets the per-episode caches and takes the episode's colour
    jitter), then :meth:`render` per control tick. ``timings`` holds the episode's seconds per part so far.
    ``splat_server``: a running ``render.splat_server.SplatServer``'s handle; the splat layer is then drawn there
    (batched with other workers' episodes, every camera whole) and this process holds no Gaussians
    (``self.splat`` is None).
    """

    def __init__(self, twin: Twin, cameras: tuple[str, ...], size: tuple[int, int], options: HybridOptions,
                 splat_server: Any = None) -> None:  # fmt: skip

        world = twin.cfg
        self.twin, self.cameras, self.size, self.options = twin, tuple(cameras), tuple(size), options
        # the robot's own Gaussians, posed per link in the splat pass; else Genesis draws its meshes over the splats
        self.robot_links = robot_links(world) if options.robot_gaussians(world) else []
        self.static_cameras = {c for c in cameras if world.cameras[c].mount == "base"}
        self.hand_cameras = {c for c in cameras if world.cameras[c].mount == world.robot.ee_link}
        self.remote = None
        if splat_server is not None:
            self.remote, self.splat = RemoteSplatLayer(splat_server), None
        else:  # with mesh objects Genesis draws them, in the robot layer (``build_hybrid``)
            from ..render.splat_world import SplatWorld

            parts = splat_parts(world, objects=options.objects == "gaussians", robot=bool(self.robot_links))
            self.splat = SplatWorld.from_files(parts, options.splat)
            self._placement_scales = [p.scale for p in self.splat.parts]
        self._table = None  # TableGaussians, found when an episode first re-colours them
        self._table_changed = False
        self.jitter = ColorJitter()
        self._robot_cache: dict[str, tuple] = {}
        self.timings = dict.fromkeys(TIMING_KEYS, 0.0)

    def start_episode(self, draw: EpisodeDraw) -> None:
        """A new episode: its colour jitter; every cache forgotten, so a frame depends on this episode alone."""
        self.jitter = draw.jitter
        self._robot_cache = {}
        self.timings = dict.fromkeys(TIMING_KEYS, 0.0)
        if self.remote is not None:
            self.remote.start_episode(draw.object_scale, draw.table_texture)
            return
        for part, scale in zip(self.splat.parts, self._placement_scales, strict=True):
            part.scale = scale * draw.object_scale  # takes effect as every part is re-posed below
        self._retexture_table(draw.table_texture)
        self.splat.reset_cache()
        self.splat.poses.clear()  # re-pose every part exactly (not "unchanged within tolerance" of the last episode)

    def _retexture_table(self, texture: Any) -> None:
        """The table's Gaussians in this episode's look (``texture``: a TableTexture; None: as reconstructed)."""
        import torch

        if texture is None and not self._table_changed:
            return
        if self._table is None:  # found when an episode first re-colours them, kept as built
            self._table = TableGaussians.find(self.splat.gaussians, self.splat.static_rows, self.twin.cfg.table_z)
        with torch.no_grad():
            self.splat.gaussians.sh[self._table.rows, 0] = self._table.sh_dc(texture)
        self._table_changed = texture is not None

    def _robot_layer(self, camera: str, state: np.ndarray) -> dict[str, np.ndarray]:
        w, h = self.size
        # with mesh objects the layer holds the objects too, which move in a hand camera
        reuse = self.options.reuse_hand_camera_robot and self.options.objects == "gaussians"
        if not (reuse and camera in self.hand_cameras):
            return self.twin.render_robot(camera, w, h)
        fingers = np.asarray(state[self.twin.spec.n_arm :], np.float64)
        key = tuple(np.round(fingers / 5e-4).astype(int))  # 0.5 mm finger steps
        hit = self._robot_cache.get(camera)
        if hit is None or hit[0] != key:
            hit = (key, self.twin.render_robot(camera, w, h))
            self._robot_cache[camera] = hit
        return hit[1]

    def splat_views(self) -> tuple[dict[str, np.ndarray], dict[str, tuple[np.ndarray, np.ndarray]]]:
        """What the splat layer of the twin's current state is drawn from: the parts' physics poses {name: T_base_obj
        [4,4]} and each camera's (viewmat [4,4] base-to-camera, K [3,3] at the frame size)."""
        from ..geometry.sim3 import invert_rigid

        w, h = self.size
        views = {}
        for c in self.cameras:
            T_base_cam, K, cw, ch = self.twin.camera(c)
            views[c] = (invert_rigid(T_base_cam), render_K(K, cw, ch, w, h))
        poses = self.twin.object_poses()
        for link in self.robot_links:  # forward kinematics of this tick
            poses[f"{ROBOT_PART}{link}"] = self.twin.T_base_link(link)
        return poses, views

    def render(self) -> dict[str, np.ndarray]:
        """{camera: uint8 [H,W,3]} hybrid frames of the twin's current state."""
        twin, opt, (w, h) = self.twin, self.options, self.size
        t0 = time.perf_counter()
        poses, views = self.splat_views()
        served = None
        if self.remote is not None:  # every camera's layers in one request, drawn with other episodes'
            served = self.remote.render(poses, np.stack([views[c][0] for c in self.cameras]),
                                        np.stack([views[c][1] for c in self.cameras]))  # fmt: skip
            self.timings["splat_render"] += time.perf_counter() - t0
        else:
            self.splat.set_poses(poses)
            self.timings["pose_splats"] += time.perf_counter() - t0
        state = twin.robot_state()
        frames = {}
        for i, c in enumerate(self.cameras):
            t1 = time.perf_counter()
            view, Kr = views[c]
            if served is not None:
                rgb, alpha, depth = (layer[i] for layer in served)
            elif c in self.static_cameras:  # fixed in the base: the scene is drawn once per episode
                rgb, alpha, depth = self.splat.render_static_camera(c, view, Kr, w, h, opt.background)
            else:
                rgb, alpha, depth = self.splat.render_camera(c, view, Kr, w, h, opt.background)
            t2 = time.perf_counter()
            if self.robot_links:  # the robot was in the splat pass
                frames[c] = to_uint8(self.jitter.apply(rgb))
                self.timings["splat_render"] += t2 - t1
                continue
            robot = self._robot_layer(c, state)
            t3 = time.perf_counter()
            splat8 = to_uint8(self.jitter.apply(rgb))
            # Mesh objects share the robot's z-buffer, and a splat table's blurred surface would hide their lower
            # half under a depth test: the Genesis layer is pasted whole then.
            if opt.depth_aware and opt.objects == "gaussians":
                im, _ = composite(splat8, robot["rgb"], robot["robot_mask"], robot["depth"], depth, alpha)
            else:
                im, _ = composite(splat8, robot["rgb"], robot["robot_mask"])
            frames[c] = im
            self.timings["splat_render"] += t2 - t1
            self.timings["robot_render"] += t3 - t2
            self.timings["composite"] += time.perf_counter() - t3
        return frames

    def close(self) -> None:
        """Give a splat server's slot back (the twin is the environment's)."""
        if self.remote is not None:
            self.remote.close()


ROBOT_PART = "robot/"  # a robot link's movable part: robot/<link>


def robot_link_files(world: WorldConfig) -> dict[str, Path]:
    """{link: its Gaussians' PLY} of the world's robot (``robot.gaussians``/robot.json), in its order; {} without."""
    if world.robot.gaussians is None:
        return {}
    info = json.loads((world.robot.gaussians / "robot.json").read_text(encoding="utf-8"))
    return {link: world.robot.gaussians / f for link, f in info["links"].items()}


def robot_links(world: WorldConfig) -> list[str]:
    """The links whose Gaussians the world's robot has, in its order."""
    return list(robot_link_files(world))


def splat_parts(world: WorldConfig, objects: bool = True, robot: bool = False) -> dict[str, Any]:
    """The Gaussian files of ``world``'s splat layer: {"scene": path or None, "parts": [[name, path, scale], ...]},
    each object's and articulated asset's (base and cap) a movable part named as its physics pose is
    (``objects=False``: the scene alone, the objects being drawn elsewhere); with ``robot``, each robot link's
    Gaussians too (``robot/<link>``, posed by forward kinematics)."""
    parts = []
    if objects:
        parts = [[o.name, str(o.part.gaussians), float(o.placement.scale)] for o in world.objects]
        for a in world.articulated:
            parts.append([a.name, str(a.base.gaussians), float(a.placement.scale)])
            parts.append([f"{a.name}/cap", str(a.cap.gaussians), float(a.placement.scale)])
    if robot:
        parts += [[f"{ROBOT_PART}{link}", str(path), 1.0] for link, path in robot_link_files(world).items()]
    scene = str(world.scene_gaussians) if world.scene_gaussians is not None else None
    return {"scene": scene, "parts": parts}


def build_hybrid(cfg: EnvConfig) -> tuple[Twin, HybridRenderer]:
    """The twin a hybrid renderer needs (render cameras at the frame size, only the robot drawn, the low-polygon
    robot copy) and the renderer."""
    from ..sim.twin import Twin, TwinOptions

    meshes = cfg.hybrid.objects == "meshes"
    if meshes:
        from .mesh_objects import mesh_object_world

        world = mesh_object_world(cfg.world)
    else:
        world = cfg.world.copy()
    world.robot.file = render_robot_file(world.robot.file, cfg.hybrid.robot_render_faces)
    w, h = cfg.size
    # a Gaussian robot with Gaussian objects: nothing left for Genesis to draw, no camera in the per-frame loop
    render = meshes or not cfg.hybrid.robot_gaussians(world)
    options = TwinOptions(backend=cfg.backend, render=render, camera_sizes={c: (w, h) for c in cfg.cameras},
                          draw_scene=False, draw_objects=meshes)  # fmt: skip
    twin = Twin.build(world, options)
    try:
        return twin, HybridRenderer(twin, cfg.cameras, cfg.size, cfg.hybrid, cfg.splat_server)
    except BaseException:
        twin.close()
        raise
