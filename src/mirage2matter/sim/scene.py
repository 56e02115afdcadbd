"""The Genesis scene builder: every Genesis scene of the package is set up here.

The physics twin (``sim.twin``), the ground-truth world (``env.ground_truth``) and the sample maker's renderer
(``sample.render``) start Genesis, create their scene (look, lights, physics), add the robot, fixed textured
meshes and cameras, convert poses and read entity-level segmentation through this module, so the sample's video
and the ground-truth world that re-renders it draw the same pixels, and the twin's scene is set up the same way.

Genesis 1.4.5 conventions, converted here at the border (checked by
``tests/sample/test_sample_render.py::test_projection_convention``):

- ``Camera.set_pose(transform=T)`` takes camera-to-world with OpenGL axes (x right, y up, looking along -z;
  ``gs.utils.geom.pos_lookat_up_to_T`` builds ``z = pos - lookat``). Ours is OpenCV axes, so
  ``T_gl = T_base_cam @ GL_TO_CV``.
- Intrinsics: ``fx = fy = (H / 2) / tan(fov_y / 2)`` (``fov`` is vertical, degrees), principal point
  ``(W / 2, H / 2)`` with pixel centres at +0.5 (Genesis' own depth unprojection uses ``u + 0.5``), i.e. the same
  convention as ours. Only square pixels and a centred principal point are possible.
- Depth is planar (distance along the optical axis), not the ray length.
- Without a physics step, state changes (``set_qpos``, ``set_pos``) reach the rasterizer only with
  ``render(force_render=True)``; every render here forces.
- Anti-aliasing: the offscreen rasterizer always resolves 4x MSAA (``min(GL_MAX_SAMPLES, 4)``); it is not
  configurable (``render(antialiasing=...)`` is for the batch renderer only).
- Poses of entities and links are position [3] + wxyz quaternion [4] (:func:`pos_quat`, :func:`pose_from`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from ..geometry.camera import GL_TO_CV
from ..geometry.rotation import matrix_to_quat, quat_to_matrix
from ..robots import RobotSpec
from ..robots.model import genesis_morph, resolve_model
from ..world.config import LightConfig

__all__ = [
    "RenderScene",
    "SceneLook",
    "SimCamera",
    "add_camera",
    "add_ground_plane",
    "add_robot",
    "ensure_genesis",
    "new_scene",
    "pos_quat",
    "pose_from",
    "render_K",
    "render_view",
]


def ensure_genesis(backend: str = "cpu") -> Any:
    """Import Genesis and initialise it once per process (``gs.init`` may only run once)."""
    import genesis as gs

    if not gs._initialized:
        gs.init(backend=getattr(gs, backend), logging_level="warning")
    return gs


# ---- the scene -----------------------------------------------------------------------------------------------
def _sample_lights() -> tuple[LightConfig, ...]:
    # A key light from above-front-left and a weaker fill from the other side: faces of a box get
    # distinct shades, which SfM and the eye need.
    return (
        LightConfig(dir=(-0.6, -0.8, -1.0), intensity=3.0),
        LightConfig(dir=(0.8, 0.5, -0.7), color=(0.95, 0.97, 1.0), intensity=1.2),
    )


@dataclass
class SceneLook:
    """How a scene is lit and shaded, and where its cameras clip. The defaults are the sample's look: its video,
    its hand-eye images and the ground-truth world that re-renders them.

    ambient      ambient light colour (linear, 0..1)
    lights       directional lights (a world's ``LightConfig``; shadows come from these)
    background   background colour (0..1) where no geometry is hit; None: Genesis' default
    shadow       shadow maps for the directional lights
    near, far    the cameras' clipping planes (metres). Depth reads ~far where nothing is hit and is quantised to
                 ~z^2 / (near * 2^24) (metres near ``far``), so readings beyond far / 2 count as "nothing"
    """

    ambient: tuple[float, float, float] = (0.3, 0.3, 0.3)
    lights: tuple[LightConfig, ...] = field(default_factory=_sample_lights)
    background: tuple[float, float, float] | None = (0.62, 0.66, 0.70)
    shadow: bool = True
    near: float = 0.02
    far: float = 20.0


def new_scene(look: SceneLook, *, dt: float | None = None, substeps: int = 1) -> Any:
    """An empty Genesis rasterizer scene (no viewer) with ``look``'s ambient light, background, lights and shadows;
    entity-level segmentation. With ``dt`` a physics scene: that step (s) in ``substeps``, the robot's links
    colliding with each other; without, Genesis' default simulation options (a scene that is posed and drawn)."""
    gs = ensure_genesis()
    vis: dict[str, Any] = {"ambient_light": tuple(look.ambient)}
    if look.background is not None:
        vis["background_color"] = tuple(look.background)
    vis["lights"] = [
        {"type": "directional", "dir": tuple(li.dir), "color": tuple(li.color), "intensity": li.intensity}
        for li in look.lights
    ]
    physics: dict[str, Any] = {}
    if dt is not None:
        physics = {
            "sim_options": gs.options.SimOptions(dt=dt, substeps=substeps),
            "rigid_options": gs.options.RigidOptions(enable_self_collision=True),
        }
    return gs.Scene(
        show_viewer=False,
        **physics,
        renderer=gs.renderers.Rasterizer(),
        vis_options=gs.options.VisOptions(**vis, shadow=look.shadow, segmentation_level="entity"),
    )


# ---- entities ------------------------------------------------------------------------------------------------
def pos_quat(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Genesis' pose of a rigid [4,4]: position [3] and wxyz quaternion [4]."""
    T = np.asarray(T, dtype=np.float64)
    return T[:3, 3].copy(), matrix_to_quat(np.ascontiguousarray(T[:3, :3]))


def pose_from(pos: Any, quat: Any) -> np.ndarray:
    """[4,4] rigid pose of a Genesis position [3] and wxyz quaternion [4] (normalised here)."""
    q = np.asarray(quat, dtype=np.float64).reshape(4)
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(q / np.linalg.norm(q))
    T[:3, 3] = np.asarray(pos, dtype=np.float64).reshape(3)
    return T


def add_ground_plane(scene: Any, z: float, visible: bool = True) -> Any:
    """The table top as an infinite plane at height ``z`` (base frame); ``visible=False``: physics only."""
    gs = ensure_genesis()
    return scene.add_entity(gs.morphs.Plane(pos=(0.0, 0.0, z), visualization=visible))


def add_robot(
    scene: Any,
    spec: RobotSpec,
    *,
    model: str | Path | None = None,
    ee_link: str | None = None,
    extra_links: tuple[str, ...] = (),
) -> Any:
    """The robot (base fixed at the origin) from ``model`` (default: the spec's model), keeping the end-effector link
    (``ee_link``, default the spec's), the finger links and ``extra_links`` (e.g. a camera's mount) as links of their
    own. Returns the Genesis entity."""
    gs = ensure_genesis()
    keep = (ee_link or spec.ee_link, *spec.finger_links, *extra_links)
    path = resolve_model(spec.model) if model is None else model
    return scene.add_entity(genesis_morph(gs, path, keep_links=keep))


# ---- cameras -------------------------------------------------------------------------------------------------
@dataclass
class SimCamera:
    """A Genesis camera drawing ``res`` (width, height) pixels. Genesis reads its framebuffer back in rows of whole
    4-byte words and a row of RGB pixels whose width is not a multiple of 4 overruns its buffer (the process aborts
    in malloc: seen at 98 and 130 px); such a camera renders ``2 * x0`` px wider, cropped back about its centre."""

    camera: Any
    res: tuple[int, int]
    x0: int = 0

    @property
    def intrinsics(self) -> np.ndarray:
        """[3,3] K of the cropped image (Genesis', centres at +0.5 like ours)."""
        K = np.array(self.camera.intrinsics, dtype=np.float64, copy=True)
        K[0, 2] -= self.x0
        return K


def render_K(K: np.ndarray, width: int, height: int, out_w: int, out_h: int) -> np.ndarray:
    """Intrinsics [3,3] of the ``out_w`` x ``out_h`` render of the camera ``(K, width, height)`` as Genesis draws it
    (and the splats must be drawn to match): the vertical field of view kept, square pixels, principal point at the
    centre. A camera with a lens or an off-centre principal point is drawn exactly through ``env.lens``."""
    f = float(np.asarray(K)[1, 1]) * out_h / height
    return np.array([[f, 0.0, out_w / 2.0], [0.0, f, out_h / 2.0], [0.0, 0.0, 1.0]])


def add_camera(scene: Any, width: int, height: int, fy: float, near: float, far: float) -> SimCamera:
    """A camera of ``width`` x ``height`` pixels and focal length ``fy`` (px; fx = fy, principal point centred)
    to an unbuilt ``scene``; pose it at each render (:func:`render_view`). ValueError for an odd width (the padded
    render could not be cropped about its centre)."""
    if int(width) % 2:
        raise ValueError(f"a camera {width} px wide: the simulator's cameras need an even width (frames of 224, 128, "
                         "96 px...)")  # fmt: skip
    x0 = (-int(width) % 4) // 2
    fov_deg = math.degrees(2.0 * math.atan(0.5 * height / fy))
    camera = scene.add_camera(
        res=(int(width) + 2 * x0, int(height)), pos=(1.0, 0.0, 1.0), lookat=(0.0, 0.0, 0.0), fov=fov_deg, near=near,
        far=far, GUI=False,
    )  # fmt: skip
    return SimCamera(camera, (int(width), int(height)), x0)


def render_view(camera: SimCamera, T_base_cam: np.ndarray, **what: bool) -> tuple:
    """Genesis' ``(rgb, depth, segmentation, normal)`` render of ``camera`` posed at ``T_base_cam`` [4,4] (OpenCV
    axes); ``what`` picks the outputs (``rgb=True, depth=True, segmentation=True``)."""
    camera.camera.set_pose(transform=np.asarray(T_base_cam, dtype=np.float64) @ GL_TO_CV)
    out = camera.camera.render(force_render=True, **what)
    if not camera.x0:
        return out
    x0, w = camera.x0, camera.res[0]
    return tuple(None if a is None else np.asarray(a)[:, x0 : x0 + w] for a in out)


# ---- a scene that is posed and drawn -------------------------------------------------------------------------
class RenderScene:
    """A Genesis scene that is posed and drawn, not stepped: fixed textured meshes and the robot as named entities
    (segmentation label i is ``names[i]``, in the order added), and named cameras. Add everything, :meth:`build`,
    then move entities (``set_pos`` / ``set_quat`` / ``set_qpos``) and :meth:`render`. The sample maker's renderer
    and the ground-truth world both draw through one, so the same assets give the same pixels."""

    def __init__(self, look: SceneLook) -> None:
        self.look = look
        self.scene = new_scene(look)
        self.names: list[str] = []
        self.entities: dict[str, Any] = {}
        self.cameras: dict[str, Any] = {}
        self._K: dict[str, np.ndarray] = {}
        self._lut: np.ndarray | None = None

    def _add(self, name: str, entity: Any) -> Any:
        if name in self.entities:
            raise ValueError(f"duplicate entity name {name!r}")
        self.entities[name] = entity
        self.names.append(name)
        return entity

    def add_mesh(self, name: str, mesh: trimesh.Trimesh, T_base_obj: np.ndarray, folder: str | Path) -> Any:
        """A fixed, non-colliding textured mesh at ``T_base_obj`` (its OBJ + MTL + texture written into ``folder``:
        trimesh names materials generically, so each mesh needs a folder of its own). Returns the Genesis entity."""
        gs = ensure_genesis()
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        obj = folder / "mesh.obj"
        mesh.export(obj)
        pos, quat = pos_quat(T_base_obj)
        morph = gs.morphs.Mesh(file=str(obj), pos=tuple(pos), quat=tuple(quat), fixed=True, collision=False)
        return self._add(name, self.scene.add_entity(morph, surface=gs.surfaces.Default()))

    def add_robot(self, spec: RobotSpec, name: str = "robot") -> Any:
        """The robot of ``spec`` (its model, base at the origin; see :func:`add_robot`). Returns the Genesis entity."""
        return self._add(name, add_robot(self.scene, spec))

    def add_camera(self, name: str, width: int, height: int, fy: float) -> Any:
        """Camera ``name``: ``width`` x ``height`` pixels, focal length ``fy`` (px, fx = fy, principal point centred),
        clipped at the look's near and far planes."""
        self._K[name] = np.array([[fy, 0.0, 0.5 * width], [0.0, fy, 0.5 * height], [0.0, 0.0, 1.0]])
        self.cameras[name] = add_camera(self.scene, width, height, fy, self.look.near, self.look.far)
        return self.cameras[name]

    def build(self) -> None:
        """Build the scene; every camera's intrinsics are checked against ours."""
        self.scene.build()
        for name, cam in self.cameras.items():
            if not np.allclose(np.asarray(cam.intrinsics), self._K[name], atol=1e-6):
                raise RuntimeError(
                    f"camera {name!r}: Genesis intrinsics {cam.intrinsics} differ from ours {self._K[name]}"
                )

    def render(self, camera: str, T_base_cam: np.ndarray, **what: bool) -> tuple:
        """Genesis' ``(rgb, depth, segmentation, normal)`` from ``camera`` at ``T_base_cam`` (:func:`render_view`)."""
        return render_view(self.cameras[camera], T_base_cam, **what)

    def trilinear_textures(self, names: Any) -> int:
        """Draw the textures of the entities ``names`` with trilinear filtering instead of the anisotropic filtering
        Genesis gives every texture (the most the driver offers: 16x on llvmpipe). llvmpipe's anisotropic filter loops
        over a pixel's whole footprint in the texture, which at some exact camera poses has no practical bound: one
        128-px render of the sample's scene from a camera beside the banana took 24-37 s (0.01 s with trilinear
        filtering, and 0.04 s with the camera 0.1 mm away; docs/results/robot-in-capture.md). The textures must be on
        the GL context: call this after a render. Returns how many textures were changed."""
        from OpenGL.GL import GL_TEXTURE_2D, glBindTexture, glTexParameterf
        from OpenGL.GL.EXT.texture_filter_anisotropic import GL_TEXTURE_MAX_ANISOTROPY_EXT

        vis = self.scene.visualizer  # Genesis 1.4.5's rasterizer: a pyrender node per visual geom, its GL texture ids
        textures = []
        for name in names:
            for geom in self.entities[name].vgeoms:
                node = vis.context.rigid_nodes.get(geom.uid)
                for primitive in node.mesh.primitives if node is not None else ():
                    for texture in primitive.material.textures:
                        if texture._texid is None:
                            raise RuntimeError(f"{name}: its textures are not on the GL context yet; render once first")
                        textures.append(texture)
        renderer = vis.rasterizer._renderer
        renderer.make_current()
        try:
            for texture in textures:
                glBindTexture(GL_TEXTURE_2D, texture._texid)
                glTexParameterf(GL_TEXTURE_2D, GL_TEXTURE_MAX_ANISOTROPY_EXT, 1.0)
            glBindTexture(GL_TEXTURE_2D, 0)
        finally:
            renderer.make_uncurrent()
        return len(textures)

    def labels(self, seg: Any) -> np.ndarray:
        """int32 [H,W] labels of a segmentation render: i -> ``names[i]``, -1 where nothing (or no named entity)."""
        if self._lut is None:
            # Genesis numbers segmentation "idxc" in node-creation order; map them to our entity order.
            by_entity_idx = {e.idx: i for i, e in enumerate(self.entities.values())}
            idxc_map = self.scene.segmentation_idx_dict
            lut = np.full(max(idxc_map) + 2, -1, dtype=np.int32)
            for idxc, key in idxc_map.items():
                if key in by_entity_idx:
                    lut[idxc] = by_entity_idx[key]
            self._lut = lut
        seg = np.asarray(seg).astype(np.int64)
        seg = np.where((seg >= 0) & (seg < len(self._lut) - 1), seg, len(self._lut) - 1)
        return self._lut[seg]

    def destroy(self) -> None:
        """Free the Genesis scene (GL context, solver)."""
        self.scene.destroy()
