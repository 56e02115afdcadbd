"""The "ground_truth" observation renderer: the bundled sample's own world, rendered as its video was.

In the sim-to-real experiment on the sample (issue 16) the "real world" is the textured-mesh scene that
rendered ``samples/tabletop/scene.mp4``: room, table, ChArUco board, banana, croissant and the press button,
lit and shaded by the sample maker's Genesis rasterizer. :class:`GroundTruthRenderer` rebuilds that scene from
``ground_truth.json`` (the same ``world.sample_assets.assets_of_sample``, the same look and material
settings, the same scene builder, ``mirage2matter.sim.scene``), adds the robot, and renders it from any number of
named cameras with the movable objects at the poses the physics twin reports and the robot at its joint state.

At the video's own camera poses, with the objects at their ground-truth poses and no robot in the pictures
(``with_robot=False``, or ``set_state(robot_visible=False)``, which puts it far under the floor: the same pixels,
bit for bit), the renders are the video's source frames: encoding all 720 of them with the sample's settings
(``video.write_video``, CRF 23) writes the shipped ``scene.mp4`` byte for byte (``tests/env/test_ground_truth.py``,
slow). Against the decoded frames the RGB PSNR is what H.264 at CRF 23 (yuv420p) leaves of the source:
33.4-36.1 dB per frame (mean 35.1), luma 35.3-38.7 dB, RGB at half resolution 35.9-38.9 dB.

One render costs ~50-90 ms at 224x224 and ~160-230 ms at 640x480 on the 2-core CPU (llvmpipe; most of it
reading back the 4x MSAA framebuffer), linear in the number of cameras; setting the state costs ~1-2 ms.

Object names are the physics twin's (``Twin.object_poses()``): free objects by name (``"banana"``,
``"croissant"``), a press button by its name (its base, ``"button"``) and ``"<name>/cap"`` (its cap). The
sample's asset names (``"button_base"``, ``"button_cap"``) are accepted too.

Cameras (OpenCV axes, ``K`` with pixel centres at +0.5, DESIGN.md section 1) are converted to Genesis' at the
border by ``sim.scene``: ``T_gl = T_base_cam @ GL_TO_CV``, vertical field of view from ``fy``.
Genesis renders only square pixels with the principal point at the image centre. ``intrinsics="exact"``
(the default) refuses any other ``K`` with a clear error; ``intrinsics="twin"`` accepts it with the physics
twin's approximation (``Twin.camera`` at another size, ``sim.scene.render_K``: vertical field of
view kept, ``fx = fy``, principal point centred) and :meth:`GroundTruthRenderer.K` says which ``K`` the pixels have.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
import warnings
import weakref
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from ..errors import EpisodeStalled, M2MError
from ..processes import TimedWorker, WorkerTimeout, can_start_children
from ..robots import DEFAULT_ROBOT, RobotSpec, get_robot
from ..robots.surface import robot_surface
from ..sim.scene import RenderScene, SceneLook, pos_quat, pose_from, render_K
from ..sim.twin import Twin, TwinOptions
from ..world.sample_assets import assets_of_sample
from ..world.sample_robot_look import ROBOT_LOOK_PREFIX, robot_look_meshes
from .config import GROUND_TRUTH_TEXTURE_FILTER, EnvError

__all__ = [
    "INTRINSICS_MODES",
    "TEXTURE_FILTERS",
    "GroundTruthError",
    "GroundTruthRenderer",
    "RenderStalled",
    "read_ground_truth",
    "render_intrinsics",
    "twin_K",
]

INTRINSICS_MODES = ("exact", "twin")
# How the scene's textures are filtered: "anisotropic" as the sample's video was rendered, or "trilinear", which
# llvmpipe does not stall on (RenderScene.trilinear_textures).
TEXTURE_FILTERS = ("anisotropic", "trilinear")
# A principal point this far (px) from the image centre, or fx this far from fy (px), is not "centred, square".
_K_TOL_PX = 1e-3
# Rotation blocks of object and camera poses must be orthonormal to this (physics quaternions are unit).
_ROT_TOL = 1e-4
_SUPPORTED_VERSION = 1
# A hidden robot stands this far under the floor: beyond every camera's far plane and out of the light's shadow
# maps. Measured: renders with the robot there equal renders of a scene without a robot, bit for bit (at -5 m too).
_HIDDEN_ROBOT_Z = -100.0
# a ground-truth render takes 0.05-0.2 s; one that takes a minute is an llvmpipe stall (GroundTruthFrames.render)
RENDER_TIMEOUT_S = 60.0
STALL_NUDGES_M = (0.0002, 0.001)


class GroundTruthError(M2MError, ValueError):
    """No ground truth to render (a capture of one's own), or a bad camera / pose / joint input."""


class RenderStalled(GroundTruthError, EpisodeStalled):
    """The ground-truth renderer stalled on one state at every camera nudge: this episode cannot go on (an evaluation
    counts it a failure cut short); the next render starts a fresh renderer."""


def read_ground_truth(sample_dir: str | Path) -> dict[str, Any]:
    """The parsed ``<sample_dir>/ground_truth.json``; :class:`GroundTruthError` naming what to do otherwise."""
    sample_dir = Path(sample_dir)
    path = sample_dir / "ground_truth.json"
    if not path.is_file():
        raise GroundTruthError(
            f"{path} not found: ground_truth rendering needs a sample's ground_truth.json (the bundled "
            "samples/tabletop, or one made by `m2m sample make DIR`); a capture of your own has no ground truth, "
            "use the hybrid renderer there"
        )
    try:
        gt = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise GroundTruthError(f"{path}: not readable JSON ({exc}); restore it from the sample") from None
    if not isinstance(gt, dict):
        raise GroundTruthError(f"{path}: expected a JSON object; restore it from the sample")
    missing = [k for k in ("version", "seed", "board", "objects") if k not in gt]
    if missing:
        raise GroundTruthError(f"{path}: missing {missing}; restore the sample or re-make it (`m2m sample make`)")
    if gt["version"] != _SUPPORTED_VERSION:
        raise GroundTruthError(
            f"{path}: ground-truth version {gt['version']!r}, this code reads version {_SUPPORTED_VERSION}; "
            "re-make the sample with this version (`m2m sample make DIR`)"
        )
    seed = gt["seed"]
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise GroundTruthError(f"{path}: seed must be a non-negative integer, got {seed!r}")
    return gt


def twin_K(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """The intrinsics Genesis renders for ``K`` at ``width`` x ``height`` under the physics twin's approximation
    (``sim.scene.render_K`` at the same size): vertical field of view kept (``f = K[1,1]``), square pixels,
    principal point at the image centre."""
    return render_K(np.asarray(K, dtype=np.float64), width, height, width, height)


def render_intrinsics(K: Any, width: int, height: int, intrinsics: str = "exact", name: str = "camera") -> np.ndarray:
    """[3,3] the intrinsics Genesis renders for the camera ``(K, width, height)`` (OpenCV, pixel centres at +0.5).

    ``"exact"``: ``K`` itself when Genesis can render it (square pixels, principal point at the image centre,
    within 1e-3 px), else a :class:`GroundTruthError` that says what to do. ``"twin"``: :func:`twin_K` (the
    physics twin's approximation) for any pinhole ``K``.
    """
    if intrinsics not in INTRINSICS_MODES:
        raise GroundTruthError(f"intrinsics must be one of {INTRINSICS_MODES}, got {intrinsics!r}")
    for what, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or not 1 <= v <= 8192:
            raise GroundTruthError(f"{name}: {what} must be an integer pixel count in 1..8192, got {v!r}")
    width, height = int(width), int(height)
    try:
        K = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError):
        raise GroundTruthError(f"{name}: K must be a 3x3 matrix of numbers") from None
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise GroundTruthError(f"{name}: K must be a finite 3x3 matrix, got shape {K.shape}")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (fx > 0 and fy > 0) or K[0, 1] != 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
        raise GroundTruthError(f"{name}: K must be a pinhole [[fx,0,cx],[0,fy,cy],[0,0,1]] with fx, fy > 0")
    centred_square = (
        abs(fx - fy) <= _K_TOL_PX and abs(cx - 0.5 * width) <= _K_TOL_PX and abs(cy - 0.5 * height) <= _K_TOL_PX
    )
    if centred_square or intrinsics == "twin":
        return twin_K(K, width, height)
    raise GroundTruthError(
        f"{name}: Genesis renders only square pixels with the principal point at the image centre; "
        f"K has fx={fx:.4f}, fy={fy:.4f}, (cx, cy)=({cx:.4f}, {cy:.4f}) for a {width}x{height} image "
        f"(centre ({0.5 * width:g}, {0.5 * height:g})). Pass intrinsics='twin' to render it as the physics twin "
        "does (vertical field of view kept, fx = fy, principal point centred), or give a centred, square K"
    )


def _check_rigid(value: Any, what: str) -> np.ndarray:
    T = np.asarray(value, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise GroundTruthError(f"{what}: expected a finite 4x4 rigid transform, got shape {T.shape}")
    R = T[:3, :3]
    if (
        not np.allclose(R.T @ R, np.eye(3), atol=_ROT_TOL)
        or np.linalg.det(R) <= 0
        or not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0])
    ):
        raise GroundTruthError(f"{what}: not a rigid transform (rotation not orthonormal, or last row not 0 0 0 1)")
    return T


class GroundTruthRenderer:
    """The sample's textured-mesh world in one Genesis scene, movable objects, the robot, one camera per name.

    sample_dir   a sample folder with ``ground_truth.json`` (``samples/tabletop``); anything else is a
                 :class:`GroundTruthError` ("ground_truth rendering needs a sample's ground_truth.json")
    cameras      ``{name: (K [3,3], width, height)}``, OpenCV convention, pixel centres at +0.5
    with_robot   add the robot (the registered spec's model, base at the origin, at home with the gripper open)
    robot        the robot: a registered name or a robot spec file (default:
                 :data:`~mirage2matter.robots.DEFAULT_ROBOT`, the sample's)
    intrinsics   "exact" (refuse a K Genesis cannot render) or "twin" (approximate it as the physics twin does)
    config       the look (ambient, lights, background, shadow, near, far): a
                 :class:`~mirage2matter.sim.scene.SceneLook` (default: the sample's, as its video was rendered)
    texture_filter "anisotropic" (as the video was rendered: Genesis' 16x on llvmpipe) or "trilinear" (llvmpipe's
                 anisotropic filter can take minutes over one frame at some camera poses, see
                 :meth:`~mirage2matter.sim.scene.RenderScene.trilinear_textures`; built with one render of each camera)
    tmp_dir      where its exported meshes go (a temporary folder inside it; default: the system's temp folder);
                 removed by :meth:`close`, not when the process is killed (:class:`GroundTruthFrames` gives its
                 renderer process a folder it removes itself)

    Building takes ~25 s warm (~2 min with cold Genesis kernel caches); use it as a context manager or call
    :meth:`close`. Not thread-safe: one render at a time.
    """

    def __init__(
        self,
        sample_dir: str | Path,
        cameras: Mapping[str, tuple[np.ndarray, int, int]],
        with_robot: bool = True,
        *,
        robot: str | None = None,
        intrinsics: str = "exact",
        config: SceneLook | None = None,
        texture_filter: str = "anisotropic",
        tmp_dir: str | Path | None = None,
    ) -> None:
        self._scene = None
        self._workdir: Path | None = None
        gt = read_ground_truth(sample_dir)  # before Genesis starts: a capture fails at once
        if texture_filter not in TEXTURE_FILTERS:
            raise GroundTruthError(f"texture_filter: one of {TEXTURE_FILTERS}, got {texture_filter!r}")
        if not isinstance(cameras, Mapping) or not cameras:
            raise GroundTruthError("cameras: give at least one camera as {name: (K [3,3], width, height)}")
        self._K: dict[str, np.ndarray] = {}
        self._size: dict[str, tuple[int, int]] = {}
        for name, value in cameras.items():
            if not isinstance(name, str) or not name:
                raise GroundTruthError(f"camera names must be non-empty strings, got {name!r}")
            try:
                K, w, h = value
            except (TypeError, ValueError):
                raise GroundTruthError(f"camera {name!r}: expected (K [3,3], width, height), got {value!r}") from None
            self._K[name] = render_intrinsics(K, w, h, intrinsics, f"camera {name!r}")
            self._size[name] = (int(w), int(h))
        self.spec: RobotSpec | None = get_robot(robot or DEFAULT_ROBOT) if with_robot else None
        self.sample_dir = Path(sample_dir)
        self.ground_truth = gt
        self.config = config if config is not None else SceneLook()
        try:
            assets = assets_of_sample(gt)
        except (KeyError, TypeError, ValueError) as exc:
            raise GroundTruthError(f"{self.sample_dir / 'ground_truth.json'}: bad board spec or seed ({exc})") from None
        # a sample whose video filmed the robot in a look of its own (world.sample_robot_look): the robot is drawn so
        look = (gt.get("robot") or {}).get("look") if self.spec is not None else None
        try:
            self._check_assets_match(assets, gt)
            self._twin_names, self._movable = self._object_names(assets, gt)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            if isinstance(exc, GroundTruthError):
                raise
            raise GroundTruthError(
                f"{self.sample_dir / 'ground_truth.json'}: malformed objects list ({type(exc).__name__}: {exc}); "
                "restore it from the sample or re-make it (`m2m sample make`)"
            ) from None
        # the twin's names and the sample's asset names -> asset name
        self._aliases = {**self._twin_names, **{a: a for a in self._movable}}

        self._workdir = Path(tempfile.mkdtemp(prefix="m2m_ground_truth_", dir=tmp_dir))
        self._rm_workdir = weakref.finalize(self, shutil.rmtree, self._workdir, True)  # also without close()
        try:
            self._scene = RenderScene(self.config)
            self.entity_names = self._scene.names  # segmentation label i <-> entity_names[i]
            for i, asset in enumerate(assets):  # the sample maker's order: same scene, same pixels
                self._scene.add_mesh(asset.name, asset.mesh, asset.T_base_obj, self._workdir / f"{i:03d}_{asset.name}")
            self.robot = None
            self._look: dict[str, Any] = {}  # link -> its entity in the sample's robot look
            if self.spec is not None:
                self.robot = self._scene.add_robot(self.spec)
                if look:
                    self._add_robot_look(int(gt["seed"]))
            for name, K in self._K.items():
                self._scene.add_camera(name, *self._size[name], K[1, 1])
            self._scene.build()
            self._gt_poses = {name: np.asarray(a.T_base_obj, dtype=np.float64) for name, a in self._movable.items()}
            self._poses = {name: T.copy() for name, T in self._gt_poses.items()}
            if self.robot is not None:
                self.n_dofs = int(self.robot.n_dofs)
                if self.n_dofs != self.spec.n_dofs:
                    raise GroundTruthError(
                        f"robot {self.spec.name}: its model has {self.n_dofs} dofs, its spec {self.spec.n_dofs}"
                    )
                self.robot.set_qpos(self.spec.home_q())
            self._robot_visible = self.robot is not None
            if self._look:  # the model's robot computes the links' poses out of sight; the look draws them
                self.robot.set_pos(np.array([0.0, 0.0, _HIDDEN_ROBOT_Z]))
                self._place_look()
            self.texture_filter = texture_filter
            if texture_filter == "trilinear":
                self._trilinear_textures()
        except BaseException:
            self.close()
            raise

    # ---- construction helpers --------------------------------------------------------------------
    def _add_robot_look(self, seed: int) -> None:
        """The sample's robot in its own look: each link's textured mesh (world.sample_robot_look, the video's) as an
        entity of its own, moved to the link's pose whenever the state changes (:meth:`_place_look`)."""
        links = robot_surface(self.spec, self.spec.home_q())
        for link, mesh in robot_look_meshes(self.spec, links, seed).items():
            T = next(x.T_base_link for x in links if x.link == link)
            name = f"{ROBOT_LOOK_PREFIX}{link}"
            self._look[link] = self._scene.add_mesh(name, mesh, T, self._workdir / name)

    def _place_look(self) -> None:
        """Every link of the robot's look at the model's link pose (under the floor while the robot is hidden)."""
        for link, entity in self._look.items():
            T = self.robot_link_pose(link)
            if not self._robot_visible:
                T[2, 3] += _HIDDEN_ROBOT_Z
            pos, quat = pos_quat(T)
            entity.set_pos(pos)
            entity.set_quat(quat)

    def _trilinear_textures(self) -> None:
        """Every texture filtered trilinearly: each camera renders once from above the table (which puts the
        textures on the GL context), then the filter is set."""
        T_above = np.eye(4)  # 1.5 m above the workspace looking down (OpenCV axes: +z forward, +y down the image)
        T_above[:3, :3] = np.diag([1.0, -1.0, -1.0])
        T_above[:3, 3] = (0.5, 0.0, 1.5)
        self._render_all(dict.fromkeys(self._K, T_above), rgb=True)
        self._scene.trilinear_textures(list(self._scene.entities))

    def _check_assets_match(self, assets: list, gt: dict) -> None:
        """The assets rebuilt from the seed must be the sample's (else this code's asset maker drifted)."""
        built = {a.name: np.asarray(a.T_base_obj, dtype=np.float64) for a in assets}
        for o in gt["objects"]:
            name = o.get("name")
            if name not in built or not np.allclose(built[name], np.asarray(o["T_base_obj"]), atol=1e-6):
                raise GroundTruthError(
                    f"{self.sample_dir / 'ground_truth.json'}: object {name!r} is not where this code's sample assets "
                    f"(seed {gt['seed']}) put it; another version made the sample: re-make it (`m2m sample make`)"
                )

    @staticmethod
    def _object_names(assets: list, gt: dict) -> tuple[dict[str, str], dict[str, Any]]:
        """(twin name -> asset name, asset name -> PlacedAsset) of the movable objects."""
        by_name = {a.name: a for a in assets}
        twin: dict[str, str] = {}
        movable: dict[str, Any] = {}
        for o in gt["objects"]:
            name, category, meta = o["name"], o.get("category"), o.get("meta") or {}
            if category == "object":
                twin[name] = name
                movable[name] = by_name[name]
            elif category == "button" and meta.get("part") == "base":
                twin_name = name.removesuffix("_base") or "button"  # as world.sample_world names it
                cap = meta["cap"]
                twin.update({twin_name: name, f"{twin_name}/cap": cap})
                movable[name], movable[cap] = by_name[name], by_name[cap]
        return twin, movable

    # ---- lifecycle -------------------------------------------------------------------------------
    def close(self) -> None:
        """Free the Genesis scene (GL context, solver) and the exported meshes. Unusable afterwards."""
        if self._scene is not None:
            self._scene.destroy()
            self._scene = None
        if self._workdir is not None:
            self._rm_workdir()
            self._workdir = None

    def __enter__(self) -> GroundTruthRenderer:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def _need_scene(self) -> None:
        if self._scene is None:
            raise RuntimeError("this GroundTruthRenderer is closed")

    # ---- what it holds ---------------------------------------------------------------------------
    @property
    def camera_names(self) -> tuple[str, ...]:
        return tuple(self._K)

    def K(self, camera: str) -> np.ndarray:
        """[3,3] intrinsics the pixels of ``camera`` have (pixel centres at +0.5)."""
        return self._K[self._camera_key(camera)].copy()

    def size(self, camera: str) -> tuple[int, int]:
        """(width, height) of ``camera``."""
        return self._size[self._camera_key(camera)]

    @property
    def object_names(self) -> tuple[str, ...]:
        """Every accepted object name (the twin's, e.g. "banana", "button", "button/cap", and the sample's)."""
        return tuple(self._aliases)

    def ground_truth_poses(self) -> dict[str, np.ndarray]:
        """{twin name: T_base_obj [4,4]} of the movable objects as the sample placed them."""
        return {n: self._gt_poses[a].copy() for n, a in self._twin_names.items()}

    def object_poses(self) -> dict[str, np.ndarray]:
        """{twin name: T_base_obj [4,4]} the objects are rendered at now."""
        return {n: self._poses[a].copy() for n, a in self._twin_names.items()}

    @property
    def robot_visible(self) -> bool:
        """Whether the robot is in the pictures (see :meth:`set_state`)."""
        return self._robot_visible

    def robot_link_pose(self, link: str | None = None) -> np.ndarray:
        """[4,4] T_base_link of a robot link (default: the spec's end-effector link) in the current joint state
        (forward kinematics of the rendered robot; for checks)."""
        if self.robot is None:
            raise GroundTruthError("this renderer was built with with_robot=False")
        lk = self.robot.get_link(self.spec.ee_link if link is None else link)
        T = pose_from(lk.get_pos(), lk.get_quat())
        if self._look or not self._robot_visible:
            T[2, 3] -= _HIDDEN_ROBOT_Z  # where it would be at the origin
        return T

    def _camera_key(self, camera: str) -> str:
        if camera not in self._K:
            raise GroundTruthError(f"no camera {camera!r}; this renderer has {sorted(self._K)}")
        return camera

    # ---- state -----------------------------------------------------------------------------------
    def _check_state(
        self, robot_q: Any, object_poses: Mapping[str, Any] | None
    ) -> tuple[np.ndarray | None, dict[str, np.ndarray]]:
        q = None
        if robot_q is not None:
            if self.robot is None:
                raise GroundTruthError("robot_q given, but this renderer was built with with_robot=False")
            q = np.asarray(robot_q, dtype=np.float64).reshape(-1)
            if q.shape != (self.n_dofs,) or not np.all(np.isfinite(q)):
                raise GroundTruthError(
                    f"robot_q: expected {self.n_dofs} finite joint positions of {self.spec.name} "
                    f"(arm then fingers), got shape {np.shape(robot_q)}"
                )
        poses: dict[str, np.ndarray] = {}
        for name, T in (object_poses or {}).items():
            if name not in self._aliases:
                raise GroundTruthError(f"unknown object {name!r}; the sample's objects are {sorted(self._aliases)}")
            poses[self._aliases[name]] = _check_rigid(T, f"object_poses[{name!r}]")
        return q, poses

    def set_state(
        self, robot_q: Any = None, object_poses: Mapping[str, Any] | None = None, robot_visible: bool | None = None
    ) -> None:
        """Move the robot (``robot_q`` [n_dofs], arm then fingers) and objects (``{name: T_base_obj}``, each part
        on its own: a button's base and cap are two objects); what is not given stays where it is. Everything is
        checked before anything moves.

        ``robot_visible=False`` takes the robot out of the pictures (its base goes far under the floor; joint
        states still apply): the renders are then those of the sample's scene without a robot, as its video was
        rendered. ``True`` puts it back at the origin."""
        self._need_scene()
        q, poses = self._check_state(robot_q, object_poses)
        if robot_visible is not None:
            if self.robot is None:
                if robot_visible:
                    raise GroundTruthError("robot_visible=True, but this renderer was built with with_robot=False")
            else:
                if not self._look:  # with the look the model's robot stays out of sight
                    self.robot.set_pos(np.array([0.0, 0.0, 0.0 if robot_visible else _HIDDEN_ROBOT_Z]))
                self._robot_visible = bool(robot_visible)
        if q is not None:
            self.robot.set_qpos(q)
        if self._look and (q is not None or robot_visible is not None):
            self._place_look()
        for asset, T in poses.items():
            pos, quat = pos_quat(T)
            entity = self._scene.entities[asset]
            entity.set_pos(pos)
            entity.set_quat(quat)
            self._poses[asset] = T.copy()

    def reset_objects(self) -> None:
        """Every movable object back at its ground-truth pose."""
        self.set_state(object_poses={a: T for a, T in self._gt_poses.items()})

    # ---- rendering -------------------------------------------------------------------------------
    def _views(self, T_base_cams: Mapping[str, Any]) -> dict[str, np.ndarray]:
        if not isinstance(T_base_cams, Mapping) or not T_base_cams:
            raise GroundTruthError("T_base_cams: give {camera name: T_base_cam [4,4]} for at least one camera")
        return {self._camera_key(n): _check_rigid(T, f"T_base_cams[{n!r}]") for n, T in T_base_cams.items()}

    def _render_all(self, views: dict[str, np.ndarray], **what: bool) -> dict[str, tuple]:
        return {name: self._scene.render(name, T, **what) for name, T in views.items()}

    def render(
        self,
        T_base_cams: Mapping[str, Any],
        robot_q: Any = None,
        object_poses: Mapping[str, Any] | None = None,
    ) -> dict[str, np.ndarray]:
        """{camera: RGB uint8 [H,W,3]} from each named camera at ``T_base_cams[name]`` [4,4] (OpenCV axes), the
        robot at ``robot_q`` and the objects at ``object_poses`` (see :meth:`set_state`; ``None``: unchanged)."""
        self._need_scene()
        views = self._views(T_base_cams)
        self.set_state(robot_q, object_poses)
        return {n: np.array(r[0], dtype=np.uint8, copy=True) for n, r in self._render_all(views, rgb=True).items()}

    def segmentation(
        self,
        T_base_cams: Mapping[str, Any],
        robot_q: Any = None,
        object_poses: Mapping[str, Any] | None = None,
    ) -> dict[str, np.ndarray]:
        """{camera: int32 [H,W]} entity labels: i -> ``entity_names[i]`` (the sample's asset names, "robot"), -1
        where nothing is hit. Same arguments as :meth:`render`."""
        self._need_scene()
        views = self._views(T_base_cams)
        self.set_state(robot_q, object_poses)
        renders = self._render_all(views, rgb=False, segmentation=True)
        return {name: self._scene.labels(seg) for name, (_, _, seg, _) in renders.items()}

    def mask(self, labels: np.ndarray, name: str) -> np.ndarray:
        """bool [H,W] of a :meth:`segmentation` label image where object ``name`` (twin or asset name, or
        "robot") is the visible surface."""
        if name == "robot" and self._look:  # the robot's look: every link's entity
            ids = [self.entity_names.index(f"{ROBOT_LOOK_PREFIX}{link}") for link in self._look]
            return np.isin(np.asarray(labels), ids)
        asset = "robot" if name == "robot" else self._aliases.get(name)
        if asset is None or asset not in self.entity_names:
            raise GroundTruthError(f"unknown object {name!r}; known: {sorted(self._aliases)} and 'robot'")
        return np.asarray(labels) == self.entity_names.index(asset)


# ---- the environment's "ground_truth" observation renderer ----------------------------------------------------
class GroundTruthFrames:
    """The env's ``ground_truth`` frames (``env.renderers``): the sample's own world, driven by the twin's state.

    The twin simulates the world under test (e.g. the one reconstructed from the sample's video); its bodies need
    not have the sample assets' frames (a reconstructed banana's origin and axes are the objects stage's). Each
    body is tied to its asset by the rigid offset between them where the world placed it, which is where the
    sample's ground truth has it: ``T_body_asset = T_base_body(placement)^-1 @ T_base_asset(ground truth)``; at
    every frame an asset is drawn at ``T_base_body(now) @ T_body_asset``. The robot is drawn at the twin's joint
    state, the cameras where the twin has them (its mount jitter included); no colour jitter (the "real world"
    is as it is). Bodies without a ground-truth asset are an error: this world is not the sample's.

    Its textures are filtered trilinearly (``texture_filter``: :data:`~.config.GROUND_TRUTH_TEXTURE_FILTER`), not
    anisotropically as the video was rendered: with the video's filtering llvmpipe held single frames for minutes,
    cutting 2-3 of every 10 episodes at a 4-minute limit; the frames differ from the video's filtering by 37-40 dB
    PSNR (median; H.264 left 35 dB of the video's own frames).
    """

    def __init__(self, twin: Any, sample_dir: str | Path, cameras: tuple[str, ...], size: tuple[int, int],
                 timeout_s: float | None = RENDER_TIMEOUT_S,
                 texture_filter: str = GROUND_TRUTH_TEXTURE_FILTER) -> None:  # fmt: skip
        self.twin, self.cameras, self.timeout_s = twin, tuple(cameras), timeout_s
        self.timings: dict[str, float] = dict.fromkeys(("ground_truth_render", "ground_truth_stalls"), 0.0)
        T_base_body0 = twin.object_poses()  # at the placements, straight after the build
        w, h = size
        views = {c: (twin.camera(c)[1], w, h) for c in self.cameras}
        args = (sample_dir, views)
        kwargs = dict(with_robot=True, robot=twin.cfg.robot.name, intrinsics="twin", texture_filter=texture_filter)
        if timeout_s is not None and not can_start_children():  # e.g. in one of generation's worker processes
            warnings.warn("the ground-truth renderer runs in this process (a daemonic worker may not start one): "
                          "no time limit on its renders, an llvmpipe stall is waited out", stacklevel=2)  # fmt: skip
            self.timeout_s = timeout_s = None
        self._tmp: Path | None = None
        if timeout_s is None:
            self.renderer: Any = GroundTruthRenderer(*args, **kwargs)
        else:  # in a child process: a render that hangs in llvmpipe can be stopped (see ``render``)
            # a killed child cannot remove its exported meshes (~50 MB each): they go in a folder this process removes
            self._tmp = Path(tempfile.mkdtemp(prefix="m2m_ground_truth_"))
            self._rm_tmp = weakref.finalize(self, shutil.rmtree, self._tmp, True)
            self.renderer = TimedWorker(GroundTruthRenderer, args, {**kwargs, "tmp_dir": self._tmp},
                                        name="ground-truth renderer")  # fmt: skip
        try:
            known = set(self._call("object_names"))
            unknown = sorted(set(T_base_body0) - known)
            gt = self._call("ground_truth_poses")
            if unknown:
                raise GroundTruthError(
                    f"the world's object(s) {unknown} are not in {Path(sample_dir) / 'ground_truth.json'} (objects: "
                    f"{sorted(gt)}); ground_truth rendering needs that sample's world"
                )
            self.T_body_asset = {n: np.linalg.inv(T) @ gt[n] for n, T in T_base_body0.items()}
        except BaseException:
            self.close()
            raise

    def _call(self, method: str, *args: Any, **kwargs: Any) -> Any:
        if self.timeout_s is None:
            value = getattr(self.renderer, method)
            return value(*args, **kwargs) if callable(value) else value
        return self.renderer.call(method, *args, timeout_s=self.timeout_s, **kwargs)

    def start_episode(self, draw: Any) -> None:
        self.timings = dict.fromkeys(("ground_truth_render", "ground_truth_stalls"), 0.0)

    def asset_poses(self) -> dict[str, np.ndarray]:
        """{name: T_base_asset [4,4]} of every body in the twin's current state."""
        return {n: T @ self.T_body_asset[n] for n, T in self.twin.object_poses().items()}

    def render(self) -> dict[str, np.ndarray]:
        """The frames of the twin's state. A render past ``timeout_s`` (a stall) is stopped and retried from a fresh
        renderer with every camera moved back along its axis by :data:`STALL_NUDGES_M` in turn (llvmpipe's stalls
        happen at exact poses: HTL1's seed 1000196 held one wrist render for 460 s; 0.01 mm off it took 2.3 s, 0.1
        mm off 0.04 s); ``timings["ground_truth_stalls"]`` counts them. The whole state goes with every render, so
        a fresh renderer draws the same world."""
        t0 = time.perf_counter()
        views = {c: self.twin.camera(c)[0] for c in self.cameras}
        state = {"robot_q": self.twin.robot_state(), "object_poses": self.asset_poses()}
        for nudge in (0.0, *STALL_NUDGES_M):
            moved = {c: _moved_back(T, nudge) for c, T in views.items()}
            try:
                frames = self._call("render", moved, **state)
                break
            except WorkerTimeout:
                self.timings["ground_truth_stalls"] += 1
                warnings.warn(f"a ground-truth render took over {self.timeout_s:g} s (an llvmpipe stall); retrying with"
                              f" the cameras {1000 * STALL_NUDGES_M[0]:g} mm or more back", stacklevel=2)  # fmt: skip
        else:
            cameras = {c: np.round(T, 5).tolist() for c, T in views.items()}
            raise RenderStalled(
                f"the ground-truth renderer stalled {len(STALL_NUDGES_M) + 1} times on one state (each over "
                f"{self.timeout_s:g} s); cameras {cameras}, robot_q {np.round(state['robot_q'], 5).tolist()}"
            )
        self.timings["ground_truth_render"] += time.perf_counter() - t0
        return frames

    def close(self) -> None:
        self.renderer.close()
        if self._tmp is not None:
            self._rm_tmp()


def _moved_back(T_base_cam: np.ndarray, metres: float) -> np.ndarray:
    """The camera ``metres`` back along its optical axis (OpenCV +z looks forward)."""
    T = np.array(T_base_cam, dtype=np.float64, copy=True)
    T[:3, 3] -= metres * T[:3, 2]
    return T


def build_ground_truth(cfg: Any) -> tuple[Any, GroundTruthFrames]:
    """The env's ``ground_truth`` renderer (``env.renderers``): a physics-only twin of ``cfg.world`` and the
    sample's world at ``cfg.ground_truth`` drawn at its state."""
    if cfg.ground_truth is None:
        raise EnvError(
            "the ground_truth renderer needs a sample's ground truth (a sample folder with ground_truth.json, such "
            "as samples/tabletop: ground_truth=...); a world reconstructed from your own capture has none: use "
            "renderer='hybrid'"
        )
    read_ground_truth(cfg.ground_truth)  # a capture without ground truth fails before the twin's build
    w, h = cfg.size
    twin = Twin.build(cfg.world.copy(), TwinOptions(backend=cfg.backend, render=False,
                                                    camera_sizes={c: (w, h) for c in cfg.cameras}))  # fmt: skip
    try:
        return twin, GroundTruthFrames(twin, cfg.ground_truth, cfg.cameras, cfg.size)
    except BaseException:
        twin.close()
        raise
