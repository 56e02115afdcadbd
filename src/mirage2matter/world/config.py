"""``world/world.yaml`` as typed dataclasses: the robot, its cameras, the scene Gaussians, placed objects,
articulated assets and lights, all in the robot-base frame (DESIGN.md sections 1 and 3, stage 7).

Paths in the YAML are relative to the folder holding ``world.yaml`` (absolute paths are kept); the loaded
config carries absolute paths. :func:`read_world` parses; ``world.io.load_world`` parses and validates
(``world.validate``: files exist, names unique, objects apart at start), raising :class:`WorldConfigError`
naming the field and what to do, before any simulator is built.

Object frames: an object's mesh, collision parts and Gaussians share one object frame (for the sample: origin
at the bottom centre, z up); ``placement`` (Sim3, object -> base) maps all of them into the base frame (paper
eq. ``mesh_place``). The simulator moves the object rigidly afterwards; the Gaussians of an object at a
physics pose ``T_base_obj`` are ``apply_sim3(local, Sim3(placement.scale, R, t))`` with R, t from that pose.
"""

from __future__ import annotations

import copy
import math
import os
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..atomic import atomic_write
from ..configs import ranged
from ..errors import M2MError
from ..geometry.sim3 import Sim3
from ..inputs import NAME_RE, InputError, check_image_size, check_intrinsics, check_joints, read_yaml
from ..robots import DEFAULT_ROBOT, RobotError, RobotSpec, get_robot, is_spec_file

__all__ = [
    "ArticulatedConfig",
    "CameraConfig",
    "LightConfig",
    "ObjectConfig",
    "PartConfig",
    "RandomizeConfig",
    "RobotConfig",
    "WorldConfig",
    "WorldConfigError",
    "read_world",
    "save_world",
    "world_yaml_path",
]

_NAME_RE = NAME_RE  # world/validate.py's
ARTICULATED_KINDS = ("press_button",)


class WorldConfigError(M2MError, ValueError):
    """A world.yaml that cannot be used; the message names the field and what to do."""


# ---- small helpers -------------------------------------------------------------------------------
def _matrix(value: Any, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise WorldConfigError(f"{where}: expected numbers of shape {shape}, got {value!r}") from None
    if arr.shape != shape or not np.isfinite(arr).all():
        raise WorldConfigError(f"{where}: expected finite numbers of shape {shape}, got {np.shape(value)}")
    return arr


def _rigid(value: Any, where: str) -> np.ndarray:
    T = _matrix(value, (4, 4), where)
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-5 or np.linalg.det(R) < 0 or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9:
        raise WorldConfigError(f"{where}: not a rigid transform (rotation must be orthonormal, last row 0 0 0 1)")
    return T


def _lens(value: Any, where: str) -> dict[str, Any]:
    """A camera's lens as world.yaml gives it (our camera JSON's ``distortion``); {} for none."""
    from ..geometry.camera import Camera, CameraFormatError

    if value is None:
        return {}
    try:
        cam = Camera(np.eye(3), np.eye(4), 1, 1, distortion=value)
    except CameraFormatError as e:
        raise WorldConfigError(f"{where}: {e}") from None
    return cam.distortion_json() if cam.has_distortion else {}


def _sim3(value: Any, where: str) -> Sim3:
    if isinstance(value, Sim3):
        return value
    try:
        return Sim3.from_json(value)
    except (ValueError, TypeError) as e:
        raise WorldConfigError(f"{where}: {e}") from None


def _path(value: Any, root: Path, where: str) -> Path | None:
    """A file world.yaml names, resolved; it must lie in the world's workspace (the folder holding the world
    folder), so a world can neither read nor, through an edit, write outside it."""
    if value in (None, ""):
        return None
    if not isinstance(value, str | os.PathLike):
        raise WorldConfigError(f"{where}: expected a path, got {value!r}")
    p = Path(value)
    p = (p if p.is_absolute() else root / p).resolve()
    home = root.parent
    if home not in p.parents:
        raise WorldConfigError(
            f"{where}: {value} is outside the workspace {home}; a world names files inside its workspace (copy the "
            "asset in, or add it with `m2m world insert`)"
        )
    return p


def _bool(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise WorldConfigError(f"{where}: expected true or false, got {value!r}")
    return value


def _rel(path: Path | None, root: Path) -> str | None:
    if path is None:
        return None
    try:
        return os.path.relpath(path, root)
    except ValueError:  # another drive
        return str(path)


def _float(value: Any, where: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise WorldConfigError(f"{where}: expected a number, got {value!r}") from None
    if not (math.isfinite(v) and lo <= v <= hi):
        raise WorldConfigError(f"{where}: {v} is outside [{lo}, {hi}]")
    return v


def _list(data: Any, where: str) -> list:
    if data is None:
        return []
    if not isinstance(data, list):
        raise WorldConfigError(f"{where}: expected a list, got {type(data).__name__}")
    return data


def _check_keys(data: Any, allowed: set[str] | None, where: str) -> dict:
    """``data`` as a mapping (None: any keys)."""
    if not isinstance(data, dict):
        raise WorldConfigError(f"{where}: expected a mapping, got {type(data).__name__}")
    if allowed is None:
        return data
    unknown = set(data) - allowed
    if unknown:
        raise WorldConfigError(f"{where}: unknown field(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
    return data


def _robot(data: Any, root: Path) -> RobotConfig:
    """``robot:``; a world.yaml written before robots had names (file / ee_link / home only) is the default robot.
    A robot spec file (``name: my_arm.yaml``) and a model file are taken relative to world.yaml's folder first."""
    r = _check_keys(data, {f.name for f in fields(RobotConfig)}, "robot")
    ref = r.get("name", DEFAULT_ROBOT)
    if not isinstance(ref, str) or not ref:
        raise WorldConfigError(f"robot.name: expected a robot name or a robot spec file, got {ref!r}")
    if is_spec_file(ref) and not Path(ref).is_absolute():
        ref = str((root / ref).resolve())
    try:
        spec = get_robot(ref)
    except RobotError as e:
        raise WorldConfigError(f"robot.name: {e}") from None
    robot_file = str(r.get("file") or spec.model)
    if not Path(robot_file).is_absolute() and (root / robot_file).is_file():  # beside world.yaml
        robot_file = str((root / robot_file).resolve())
    home = r.get("home") or spec.home
    try:
        home = tuple(check_joints(home, spec.arm_joints, None, "robot.home").tolist())
    except InputError as e:
        raise WorldConfigError(f"{e} (rad)") from None
    gaussians = _path(r.get("gaussians"), root, "robot.gaussians")
    if gaussians is not None and not (gaussians / "robot.json").is_file():
        raise WorldConfigError(f"robot.gaussians: {gaussians} holds no robot.json (the robot's Gaussians that "
                               "train-scene writes to scene/robot/); fix the path or remove the key")  # fmt: skip
    return RobotConfig(name=ref, file=robot_file, ee_link=str(r.get("ee_link") or spec.ee_link), home=home,
                       gaussians=gaussians)  # fmt: skip


# ---- the dataclasses -----------------------------------------------------------------------------
@dataclass
class RobotConfig:
    """The world's robot: a registered :class:`~mirage2matter.robots.RobotSpec` and what the world overrides.

    name     the robot (``robots.get_robot``): a registered name or a robot spec file (YAML/JSON; world.yaml
             writes it relative to its folder); joints, gains, limits, gripper; default ``robots.DEFAULT_ROBOT``
    file     MJCF/URDF path, or a path inside Genesis' bundled assets (empty: the spec's model)
    ee_link  the link the gripper TCP hangs off (empty: the spec's)
    home     the arm's rest joints [n_arm] (rad) (empty: the spec's)
    gaussians  the robot as the capture saw it: a folder of per-link Gaussians (robot.json + <link>.ply, each in its
             link's frame, ``train-scene``'s scene/robot/); None: the robot is drawn from its model's meshes
    """

    name: str = DEFAULT_ROBOT
    file: str = ""
    ee_link: str = ""
    home: tuple[float, ...] = ()
    gaussians: Path | None = None

    def __post_init__(self) -> None:
        if is_spec_file(self.name):
            self.name = str(Path(self.name).resolve())
        spec = get_robot(self.name)  # RobotError (an M2MError) for an unknown name
        self.file = self.file or spec.model
        self.ee_link = self.ee_link or spec.ee_link
        self.home = tuple(float(v) for v in (self.home or spec.home))

    @property
    def spec(self) -> RobotSpec:
        return get_robot(self.name)

    def to_dict(self, root: Path) -> dict:
        """world.yaml's ``robot:``; a spec file relative to ``root``, the model file only where it is not the
        spec's generated one (a composed model in the robot cache is made again from the spec when missing)."""
        spec = self.spec
        out: dict[str, Any] = {"name": _rel(Path(self.name), root) if is_spec_file(self.name) else self.name}
        if self.file != spec.model or not Path(self.file).is_absolute():
            out["file"] = self.file
        out = {**out, "ee_link": self.ee_link, "home": list(self.home)}
        if self.gaussians is not None:
            out["gaussians"] = _rel(self.gaussians, root)
        return out


@dataclass
class CameraConfig:
    """A camera rigidly mounted on ``mount`` ("base" or a robot link): ``T_mount_cam`` [4,4] (OpenCV axes),
    intrinsics ``K`` [3,3] (pixel centres at +0.5) for ``width`` x ``height`` pixels, and its lens: ``distortion``
    as our camera JSON writes it (``geometry.camera.Camera.distortion_json``; {}: a pinhole). The environment draws
    a camera with a lens through it (``env.lens``)."""

    mount: str
    T_mount_cam: np.ndarray
    K: np.ndarray
    width: int
    height: int
    distortion: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.distortion = _lens(self.distortion or None, "camera distortion")  # zero coefficients: a pinhole


@dataclass
class PartConfig:
    """Gaussians, watertight mesh and convex collision parts of one rigid body, in its object frame."""

    gaussians: Path | None
    mesh: Path | None
    collision: Path | None = None  # folder of convex *.obj parts; None: the simulator decomposes the mesh


@dataclass
class ObjectConfig:
    """A free rigid object placed by ``placement`` (Sim3 object -> base).

    mass (kg) wins over density (kg/m^3); friction is the Coulomb coefficient used by the simulator.
    """

    name: str
    part: PartConfig
    placement: Sim3
    mass: float | None = None
    density: float | None = 500.0
    friction: float = 1.0


@dataclass
class ArticulatedConfig:
    """An articulated asset. ``press_button``: a fixed ``base`` and a ``cap`` on a prismatic joint along
    ``axis`` (the press direction in the base's object frame) with a spring of ``stiffness`` N/m, a travel
    limit ``travel`` m, and success when pressed beyond ``threshold`` m. ``T_base_cap`` [4,4] is the cap's
    rest pose in the base's object frame; ``placement`` places the base (and so the cap)."""

    name: str
    kind: str
    base: PartConfig
    cap: PartConfig
    placement: Sim3
    T_base_cap: np.ndarray = field(default_factory=lambda: np.eye(4))
    axis: tuple[float, float, float] = (0.0, 0.0, -1.0)
    travel: float = 0.008
    threshold: float = 0.006
    stiffness: float = 300.0
    cap_mass: float = 0.02
    friction: float = 1.0


@dataclass
class LightConfig:
    """A directional light: ``dir`` is the direction light travels (base frame)."""

    dir: tuple[float, float, float]
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    intensity: float = 3.0


@dataclass
class RandomizeConfig:
    """Where :meth:`Twin.reset` may put objects.

    x            range of the objects' x (m, base frame)
    y            range of the objects' y (m, base frame)
    yaw_deg      range of their turn about z (degrees)
    min_gap      gap (m) kept between the objects' footprints
    articulated  articulated assets (buttons) move too (their yaw stays)
    """

    x: tuple[float, float] = ranged((0.35, 0.62), ge=-5, le=5, ordered=True)
    y: tuple[float, float] = ranged((-0.3, 0.3), ge=-5, le=5, ordered=True)
    yaw_deg: tuple[float, float] = ranged((-180.0, 180.0), ge=-360, le=360, ordered=True)
    min_gap: float = ranged(0.03, ge=0, le=1)
    articulated: bool = True


@dataclass
class WorldConfig:
    """Everything the simulator and the compositor need, in the robot-base frame (z up, metres).

    root: the folder ``world.yaml`` lives in (relative paths resolve against it).
    """

    root: Path
    robot: RobotConfig = field(default_factory=RobotConfig)
    cameras: dict[str, CameraConfig] = field(default_factory=dict)
    scene_gaussians: Path | None = None
    objects: list[ObjectConfig] = field(default_factory=list)
    articulated: list[ArticulatedConfig] = field(default_factory=list)
    lights: list[LightConfig] = field(default_factory=list)
    ambient: tuple[float, float, float] = (0.3, 0.3, 0.3)
    table_z: float = 0.0
    randomize: RandomizeConfig = field(default_factory=RandomizeConfig)

    # ---- lookups ---------------------------------------------------------------------------------
    @property
    def names(self) -> list[str]:
        return [o.name for o in self.objects] + [a.name for a in self.articulated]

    def object(self, name: str) -> ObjectConfig:
        for o in self.objects:
            if o.name == name:
                return o
        raise WorldConfigError(f"no object named {name!r} in the world; objects: {[o.name for o in self.objects]}")

    def articulated_asset(self, name: str) -> ArticulatedConfig:
        for a in self.articulated:
            if a.name == name:
                return a
        raise WorldConfigError(
            f"no articulated asset named {name!r} in the world; articulated: {[a.name for a in self.articulated]}"
        )

    def copy(self) -> WorldConfig:
        return copy.deepcopy(self)

    def relocated(self, src: Path, dst: Path) -> WorldConfig:
        """A copy whose files under folder ``src`` are named under ``dst`` instead (and whose root moves the same
        way): a world built in a staging folder, as it reads once swapped into place."""
        src, dst = Path(src).resolve(), Path(dst).resolve()

        def move(p: Path | None) -> Path | None:
            if p is None or (p != src and src not in p.parents):
                return p
            return dst / p.relative_to(src)

        new = self.copy()
        new.root = move(new.root)
        for it in [*new.objects, *new.articulated]:
            for attr in ("part", "base", "cap"):
                part = getattr(it, attr, None)
                if part is not None:
                    setattr(it, attr, PartConfig(move(part.gaussians), move(part.mesh), move(part.collision)))
        new.scene_gaussians = move(new.scene_gaussians)
        return new

    # ---- (de)serialisation -----------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: dict, root: str | os.PathLike) -> WorldConfig:
        root = Path(root).resolve()
        allowed = {"version", "robot", "cameras", "scene", "objects", "articulated", "lights", "ambient", "table_z"}
        data = _check_keys(data, allowed | {"randomize"}, "world.yaml")
        if data.get("version", 1) != 1:
            raise WorldConfigError(f"world.yaml: version {data.get('version')!r} is not supported (expected 1)")
        robot = _robot(data.get("robot") or {}, root)
        cameras = {}
        for name, c in _check_keys(data.get("cameras") or {}, None, "cameras").items():
            where = f"cameras.{name}"
            c = _check_keys(c, {"mount", "T_mount_cam", "K", "width", "height", "distortion"}, where)
            for key in ("mount", "T_mount_cam", "K", "width", "height"):
                if key not in c:
                    raise WorldConfigError(f"{where}: missing {key!r}")
            try:
                K = check_intrinsics(c["K"], f"{where}.K")
                width, height = (check_image_size(c[k], f"{where}.{k}", k) for k in ("width", "height"))
            except InputError as e:
                raise WorldConfigError(str(e)) from None
            cameras[str(name)] = CameraConfig(
                mount=str(c["mount"]), T_mount_cam=_rigid(c["T_mount_cam"], f"{where}.T_mount_cam"), K=K,
                width=width, height=height, distortion=_lens(c.get("distortion"), f"{where}.distortion"),
            )  # fmt: skip
        scene = _check_keys(data.get("scene") or {}, {"gaussians"}, "scene")

        def part(d: Any, where: str) -> PartConfig:
            d = _check_keys(d, {"gaussians", "mesh", "collision"}, where)
            return PartConfig(
                gaussians=_path(d.get("gaussians"), root, f"{where}.gaussians"),
                mesh=_path(d.get("mesh"), root, f"{where}.mesh"),
                collision=_path(d.get("collision"), root, f"{where}.collision"),
            )

        objects = []
        for i, o in enumerate(_list(data.get("objects"), "objects")):
            where = f"objects[{i}]"
            o = _check_keys(
                o, {"name", "gaussians", "mesh", "collision", "placement", "mass", "density", "friction"}, where
            )
            if "name" not in o:
                raise WorldConfigError(f"{where}: missing 'name'")
            where = f"objects[{i}] ({o['name']})"
            if "placement" not in o:
                raise WorldConfigError(f"{where}: missing 'placement' (a Sim3: scale, rotation, translation)")
            objects.append(
                ObjectConfig(
                    name=str(o["name"]),
                    part=part({k: o.get(k) for k in ("gaussians", "mesh", "collision")}, where),
                    placement=_sim3(o["placement"], f"{where}.placement"),
                    mass=None if o.get("mass") is None else _float(o["mass"], f"{where}.mass", 1e-6, 1e3),
                    density=None if o.get("density") is None else _float(o["density"], f"{where}.density", 1, 1e5),
                    friction=_float(o.get("friction", 1.0), f"{where}.friction", 0.0, 10.0),
                )
            )
        articulated = []
        for i, a in enumerate(_list(data.get("articulated"), "articulated")):
            where = f"articulated[{i}]"
            allowed_a = {f.name for f in fields(ArticulatedConfig)}
            a = _check_keys(a, allowed_a, where)
            for key in ("name", "kind", "base", "cap", "placement"):
                if key not in a:
                    raise WorldConfigError(f"{where}: missing {key!r}")
            where = f"articulated[{i}] ({a['name']})"
            if a["kind"] not in ARTICULATED_KINDS:
                raise WorldConfigError(f"{where}.kind: {a['kind']!r} is not one of {ARTICULATED_KINDS}")
            travel = _float(a.get("travel", 0.008), f"{where}.travel", 1e-4, 0.1)
            articulated.append(
                ArticulatedConfig(
                    name=str(a["name"]),
                    kind=str(a["kind"]),
                    base=part(a["base"], f"{where}.base"),
                    cap=part(a["cap"], f"{where}.cap"),
                    placement=_sim3(a["placement"], f"{where}.placement"),
                    T_base_cap=_rigid(a.get("T_base_cap", np.eye(4)), f"{where}.T_base_cap"),
                    axis=tuple(_matrix(a.get("axis", (0, 0, -1)), (3,), f"{where}.axis").tolist()),
                    travel=travel,
                    threshold=_float(a.get("threshold", 0.75 * travel), f"{where}.threshold", 0.0, travel),
                    stiffness=_float(a.get("stiffness", 300.0), f"{where}.stiffness", 1.0, 1e6),
                    cap_mass=_float(a.get("cap_mass", 0.02), f"{where}.cap_mass", 1e-4, 10.0),
                    friction=_float(a.get("friction", 1.0), f"{where}.friction", 0.0, 10.0),
                )
            )
        lights = []
        for i, li in enumerate(_list(data.get("lights"), "lights")):
            li = _check_keys(li, {"dir", "color", "intensity"}, f"lights[{i}]")
            if "dir" not in li:
                raise WorldConfigError(f"lights[{i}]: missing 'dir' (the direction the light travels, base frame)")
            lights.append(
                LightConfig(
                    dir=tuple(_matrix(li["dir"], (3,), f"lights[{i}].dir").tolist()),
                    color=tuple(_matrix(li.get("color", (1, 1, 1)), (3,), f"lights[{i}].color").tolist()),
                    intensity=_float(li.get("intensity", 3.0), f"lights[{i}].intensity", 0.0),
                )
            )
        rz = _check_keys(data.get("randomize") or {}, {f.name for f in fields(RandomizeConfig)}, "randomize")
        defaults = RandomizeConfig()
        randomize = RandomizeConfig(
            x=tuple(_matrix(rz.get("x", defaults.x), (2,), "randomize.x").tolist()),
            y=tuple(_matrix(rz.get("y", defaults.y), (2,), "randomize.y").tolist()),
            yaw_deg=tuple(_matrix(rz.get("yaw_deg", defaults.yaw_deg), (2,), "randomize.yaw_deg").tolist()),
            min_gap=_float(rz.get("min_gap", defaults.min_gap), "randomize.min_gap", 0.0, 1.0),
            articulated=_bool(rz.get("articulated", defaults.articulated), "randomize.articulated"),
        )
        return cls(
            root=root,
            robot=robot,
            cameras=cameras,
            scene_gaussians=_path(scene.get("gaussians"), root, "scene.gaussians"),
            objects=objects,
            articulated=articulated,
            lights=lights,
            ambient=tuple(_matrix(data.get("ambient", (0.3, 0.3, 0.3)), (3,), "ambient").tolist()),
            table_z=_float(data.get("table_z", 0.0), "table_z", -10, 10),
            randomize=randomize,
        )

    def to_dict(self) -> dict:
        """YAML-ready dict; paths relative to :attr:`root`."""
        root = self.root

        def part(p: PartConfig) -> dict:
            return {
                "gaussians": _rel(p.gaussians, root),
                "mesh": _rel(p.mesh, root),
                "collision": _rel(p.collision, root),
            }

        return {
            "version": 1,
            "robot": self.robot.to_dict(root),
            "cameras": {
                name: {
                    "mount": c.mount,
                    "T_mount_cam": np.asarray(c.T_mount_cam).tolist(),
                    "K": np.asarray(c.K).tolist(),
                    "width": int(c.width),
                    "height": int(c.height),
                    **({"distortion": dict(c.distortion)} if c.distortion else {}),
                }
                for name, c in self.cameras.items()
            },
            "scene": {"gaussians": _rel(self.scene_gaussians, root)},
            "table_z": self.table_z,
            "objects": [
                {
                    "name": o.name,
                    **part(o.part),
                    "placement": o.placement.to_json(),
                    "mass": o.mass,
                    "density": o.density,
                    "friction": o.friction,
                }
                for o in self.objects
            ],
            "articulated": [
                {
                    "name": a.name,
                    "kind": a.kind,
                    "base": part(a.base),
                    "cap": part(a.cap),
                    "placement": a.placement.to_json(),
                    "T_base_cap": np.asarray(a.T_base_cap).tolist(),
                    "axis": list(a.axis),
                    "travel": a.travel,
                    "threshold": a.threshold,
                    "stiffness": a.stiffness,
                    "cap_mass": a.cap_mass,
                    "friction": a.friction,
                }
                for a in self.articulated
            ],
            "lights": [{"dir": list(li.dir), "color": list(li.color), "intensity": li.intensity} for li in self.lights],
            "ambient": list(self.ambient),
            "randomize": {
                "x": list(self.randomize.x),
                "y": list(self.randomize.y),
                "yaw_deg": list(self.randomize.yaw_deg),
                "min_gap": self.randomize.min_gap,
                "articulated": self.randomize.articulated,
            },
        }


# ---- files ---------------------------------------------------------------------------------------
def world_yaml_path(world: str | os.PathLike) -> Path:
    """The world.yaml of a world folder, or the given YAML file itself."""
    p = Path(world)
    return p if p.suffix in (".yaml", ".yml") else p / "world.yaml"


def read_world(path: str | os.PathLike) -> WorldConfig:
    """Parse the world.yaml file ``path`` (no checks of the files it names: ``world.io.load_world`` does those)."""
    path = Path(path)
    if not path.is_file():
        raise WorldConfigError(f"{path} not found; create it with `m2m compose -w <workspace>` or by hand")
    try:
        data = read_yaml(path, "world file")
    except InputError as e:
        raise WorldConfigError(str(e)) from None
    try:
        return WorldConfig.from_dict(data, path.parent)
    except WorldConfigError as e:
        raise WorldConfigError(f"{path}: {e}") from None


def save_world(
    cfg: WorldConfig, path: str | os.PathLike | None = None, *, home: str | os.PathLike | None = None
) -> Path:
    """Write ``cfg`` as YAML (atomically) to ``path`` (default ``<cfg.root>/world.yaml``); returns the path.
    Paths are written relative to ``home``, the folder the file will be read from (default: ``path``'s)."""
    path = Path(path) if path is not None else cfg.root / "world.yaml"
    home = Path(home).resolve() if home is not None else path.parent.resolve()
    if home != cfg.root:
        cfg = cfg.copy()  # paths are absolute in memory; only their relative spelling changes
        cfg.root = home
    path.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(cfg.to_dict(), sort_keys=False, default_flow_style=None, width=200)
    with atomic_write(path, "w", encoding="utf-8") as f:
        f.write("# Mirage2Matter world: robot-base frame, z up, metres. Paths relative to this file.\n")
        f.write(text)
    return path
