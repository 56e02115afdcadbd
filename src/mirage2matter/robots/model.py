"""Robot model files (MJCF or URDF): where a model is, what its kinematics and limits are, composed models.

MuJoCo reads both formats in well under a second (a Genesis scene takes tens of seconds), and its kinematics
agree with Genesis' for the same file, so everything that must answer before a simulator exists (a robot spec's
limits and reach, world validation, hand-eye forward kinematics) reads the model here.

A model is named by a path: absolute, relative to a folder given by the caller (a spec file's, a world.yaml's)
or to the working directory, or relative to Genesis' bundled assets (``xml/franka_emika_panda/panda.xml``).

URDF files are read as Genesis reads them: ``package://`` stripped and mesh paths taken relative to the file,
fixed links kept as bodies (MuJoCo would fuse them into their parent, and an end-effector or camera link is
often one), visual-only geometry dropped. URDF joint velocity and effort limits are read from the XML (MuJoCo
keeps the effort only).

A composed model (:func:`compose_model`) fixes a gripper model's root body to an arm model's flange (a site or
a body) with MuJoCo's model editing, and writes the result with copies of both models' meshes into a folder of
its own under :func:`robot_cache_dir` (once per content): one MJCF that Genesis, MuJoCo and the low-polygon
render copy read like any bundled model.
"""

from __future__ import annotations

import hashlib
import importlib.util
import math
import os
import shutil
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_dir
from ..errors import M2MError

__all__ = [
    "ModelError",
    "ModelInfo",
    "compose_model",
    "genesis_assets_dir",
    "genesis_morph",
    "load_model",
    "model_info",
    "resolve_model",
    "robot_cache_dir",
]

MODEL_SUFFIXES = (".xml", ".mjcf", ".urdf")


class ModelError(M2MError, ValueError):
    """A robot model file that is missing or that MuJoCo cannot read; the message names it."""


def genesis_assets_dir() -> Path | None:
    """Genesis' bundled assets folder, found without importing Genesis (10-20 s); None without Genesis."""
    spec = importlib.util.find_spec("genesis")
    if spec is None or not spec.origin:
        return None
    return Path(spec.origin).parent / "assets"


def robot_cache_dir() -> Path:
    """Where generated robot files are kept (``$M2M_CACHE/robots``, default ``~/.cache/mirage2matter/robots``):
    composed models and low-polygon render copies."""
    return Path(os.environ.get("M2M_CACHE", Path.home() / ".cache" / "mirage2matter")) / "robots"


def resolve_model(ref: str | os.PathLike, base: str | os.PathLike | None = None) -> Path:
    """The model file ``ref`` names: an absolute path; else relative to ``base`` (a spec file's or world.yaml's
    folder), to Genesis' bundled assets, or to the working directory, in that order (Genesis itself looks in its
    assets first). :class:`ModelError` when none exists."""
    p = Path(ref)
    assets = genesis_assets_dir()
    if p.is_absolute():
        candidates = [p]
    else:
        candidates = [*([Path(base) / p] if base is not None else []), *([assets / p] if assets else []), p]
    for c in candidates:
        if c.is_file():
            return c.absolute()
    where = f" (nor in Genesis' bundled assets {assets})" if assets is not None and not p.is_absolute() else ""
    raise ModelError(f"robot model {ref} not found{where}; give an MJCF (.xml) or URDF (.urdf) file")


def _is_urdf(path: Path) -> bool:
    if path.suffix.lower() == ".urdf":
        return True
    try:
        for _event, elem in ET.iterparse(path, events=("start",)):
            return elem.tag == "robot"
    except ET.ParseError:
        return False
    return False


def _spec(path: Path) -> Any:
    """MuJoCo's editable model of ``path`` (URDF read as Genesis reads it, see the module docstring)."""
    import mujoco

    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except Exception as e:  # noqa: BLE001 - any parse failure is the same user error
        raise ModelError(f"{path}: MuJoCo cannot read this robot model ({e})") from None
    if _is_urdf(path):
        spec.compiler.fusestatic = False  # keep fixed links (end-effector, camera mounts) as bodies
        for m in spec.meshes:
            f = m.file.removeprefix("package://")
            if f and not Path(f).is_absolute():
                m.file = str(path.parent / f)
    return spec


def _compile(spec: Any, path: Path) -> Any:
    try:
        return spec.compile()
    except Exception as e:  # noqa: BLE001
        raise ModelError(f"{path}: MuJoCo cannot compile this robot model ({e})") from None


def _without_meshes(spec: Any) -> Any:
    """``spec`` with its mesh geometry removed: the kinematics (bodies, joints, actuators) compile in ~25 ms
    instead of ~0.7 s (the Panda), and masses do not matter there."""
    import mujoco

    for g in list(spec.geoms):
        if int(g.type) == int(mujoco.mjtGeom.mjGEOM_MESH):
            spec.delete(g)
    for m in list(spec.meshes):
        spec.delete(m)
    spec.compiler.boundmass, spec.compiler.boundinertia = 1e-6, 1e-9
    return spec


@lru_cache(maxsize=32)
def _load_cached(path: str, mtime_ns: int, size: int, meshes: bool) -> Any:
    p = Path(path)
    spec = _spec(p)
    return _compile(spec if meshes else _without_meshes(spec), p)


def load_model(path: str | os.PathLike, meshes: bool = False) -> Any:
    """The compiled ``mujoco.MjModel`` of the model file ``path`` (cached per file version; share it read-only):
    without its mesh geometry (kinematics only), or with it (``meshes``: what a robot looks like)."""
    p = Path(path)
    if not p.is_file():
        raise ModelError(f"robot model {p} not found")
    st = p.stat()
    return _load_cached(str(p.resolve()), st.st_mtime_ns, st.st_size, bool(meshes))


@dataclass(frozen=True)
class ModelJoint:
    """One joint of a model with one degree of freedom.

    name       the joint's name
    kind       "hinge" (rad) or "slide" (m)
    dof        its index in the model's joint vector (qpos)
    body       the link it moves
    limits     (lo, hi), None where the model leaves it unlimited
    velocity   the model's speed limit (rad/s, m/s; URDF ``<limit velocity>``), None where it has none
    force      the model's force / torque limit (N m, N; actuator or joint force range, URDF effort), or None
    kp, kv     the model's position-actuator gains on it, None without one
    """

    name: str
    kind: str
    dof: int
    body: str
    limits: tuple[float, float] | None
    velocity: float | None
    force: float | None
    kp: float | None
    kv: float | None


@dataclass(frozen=True)
class ModelInfo:
    """What a robot spec reads from its model.

    path     the model file
    joints   the model's joints in qpos order (only hinge and slide joints; see ``others``)
    others   names of joints that are neither (free, ball): a fixed-base arm has none
    bodies   every link name
    parent   {link: parent link} ("world" for the root)
    """

    path: Path
    joints: tuple[ModelJoint, ...]
    others: tuple[str, ...]
    bodies: tuple[str, ...]
    parent: dict[str, str]

    def joint(self, name: str) -> ModelJoint | None:
        return next((j for j in self.joints if j.name == name), None)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def descendants(self, link: str) -> set[str]:
        """``link`` and every link below it."""
        out, grew = {link}, True
        while grew:
            new = {b for b, p in self.parent.items() if p in out} - out
            grew = bool(new)
            out |= new
        return out


def _urdf_joint_limits(path: Path) -> dict[str, tuple[float | None, float | None]]:
    """{joint: (velocity, effort)} from a URDF's ``<limit>`` elements (None where absent or not positive)."""
    out = {}
    for j in ET.parse(path).getroot().iter("joint"):
        lim = j.find("limit")
        if lim is None or not j.get("name"):
            continue
        vals = []
        for key in ("velocity", "effort"):
            try:
                v = float(lim.get(key, "nan"))
            except ValueError:
                v = math.nan
            vals.append(v if math.isfinite(v) and v > 0 else None)
        out[j.get("name")] = tuple(vals)
    return out


def model_info(path: str | os.PathLike) -> ModelInfo:
    """Read joints, limits, gains and links of the model file ``path`` (see :class:`ModelInfo`)."""
    import mujoco

    path = Path(path)
    m = load_model(path)
    urdf = _urdf_joint_limits(path) if _is_urdf(path) else {}
    actuated: dict[int, tuple[float | None, float | None, float | None]] = {}
    for a in range(m.nu):
        if int(m.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            continue  # tendon-driven (e.g. coupled fingers): no per-joint gains
        j = int(m.actuator_trnid[a][0])
        kp = kv = None
        # a position servo: force = gain * ctrl + bias0 + bias1 * q + bias2 * qdot with bias1 = -gain
        if int(m.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_AFFINE) and m.actuator_gainprm[a][0] > 0:
            if abs(m.actuator_biasprm[a][1] + m.actuator_gainprm[a][0]) < 1e-9 * m.actuator_gainprm[a][0]:
                kp, kv = float(m.actuator_gainprm[a][0]), float(-m.actuator_biasprm[a][2])
        force = float(max(abs(v) for v in m.actuator_forcerange[a])) if m.actuator_forcelimited[a] else None
        actuated[j] = (kp, kv, force)
    joints, others = [], []
    for j in range(m.njnt):
        name = m.joint(j).name
        kinds = {int(mujoco.mjtJoint.mjJNT_HINGE): "hinge", int(mujoco.mjtJoint.mjJNT_SLIDE): "slide"}
        kind = kinds.get(int(m.jnt_type[j]))
        if kind is None:
            others.append(name)
            continue
        lo, hi = (float(v) for v in m.jnt_range[j])
        if lo > hi:  # MuJoCo leaves such a joint unlimited, silently
            raise ModelError(f"{path}: joint {name}: range {lo:g} {hi:g} is written backwards; give the lower limit "
                             "first")  # fmt: skip
        kp, kv, force = actuated.get(j, (None, None, None))
        if force is None and m.jnt_actfrclimited[j]:
            force = float(max(abs(v) for v in m.jnt_actfrcrange[j]))
        velocity, effort = urdf.get(name, (None, None))
        joints.append(ModelJoint(
            name=name, kind=kind, dof=int(m.jnt_qposadr[j]), body=m.body(int(m.jnt_bodyid[j])).name,
            limits=tuple(float(v) for v in m.jnt_range[j]) if m.jnt_limited[j] else None,
            velocity=velocity, force=force if force is not None else effort, kp=kp, kv=kv,
        ))  # fmt: skip
    bodies = tuple(m.body(b).name for b in range(m.nbody))
    parent = {bodies[b]: bodies[int(m.body_parentid[b])] for b in range(1, m.nbody)}
    return ModelInfo(path, tuple(sorted(joints, key=lambda jt: jt.dof)), tuple(others), bodies, parent)


# ---- composed models ------------------------------------------------------------------------------
COMPOSE_VERSION = 1  # bump when the composed output changes, so caches are rebuilt


def _absolute_assets(spec: Any, path: Path) -> None:
    """Every mesh / texture file of ``spec`` as an absolute path (the two models' asset folders differ)."""
    meshdir = Path(spec.meshdir or "")
    texturedir = Path(spec.texturedir or "")
    for items, folder in ((spec.meshes, meshdir), (spec.textures, texturedir)):
        for it in items:
            if it.file and not Path(it.file).is_absolute():
                it.file = str((path.parent / folder / it.file).resolve())
    spec.meshdir = ""
    spec.texturedir = ""


def compose_model(arm: Path, gripper: Path, mount: str, name: str, prefix: str = "gripper_",
                  pos: tuple[float, float, float] = (0.0, 0.0, 0.0),
                  quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)) -> Path:  # fmt: skip
    """An MJCF of the arm model ``arm`` with the gripper model ``gripper``'s root body fixed at ``mount`` (a site
    or a link of the arm; ``pos`` / ``quat`` (w, x, y, z) offset it in that frame), the gripper's names prefixed
    with ``prefix``; written once per content under :func:`robot_cache_dir` and returned.

    :class:`ModelError` when a file cannot be read, the mount is not in the arm, or the gripper has not exactly
    one root body."""
    arm, gripper = Path(arm), Path(gripper)
    key_src = [str(COMPOSE_VERSION), mount, prefix, repr(tuple(pos)), repr(tuple(quat))]
    for p in (arm, gripper):
        if not p.is_file():
            raise ModelError(f"robot model {p} not found")
        key_src += [str(p.resolve()), hashlib.sha1(p.read_bytes()).hexdigest()]
    key = hashlib.sha1("|".join(key_src).encode()).hexdigest()[:12]
    out_dir = robot_cache_dir() / "composed" / f"{name}-{key}"
    out = out_dir / f"{name}.xml"
    if out.is_file():
        return out

    with warnings.catch_warnings():  # MuJoCo warns of option conflicts (the integrator); the arm's options win
        warnings.simplefilter("ignore", UserWarning)
        return _compose(arm, gripper, mount, name, prefix, pos, quat, out_dir, out)


def _compose(arm: Path, gripper: Path, mount: str, name: str, prefix: str, pos, quat, out_dir: Path, out: Path) -> Path:
    arm_spec, grip_spec = _spec(arm), _spec(gripper)
    _compile(arm_spec, arm)  # readable on their own first: the errors name the file
    _compile(grip_spec, gripper)
    _absolute_assets(arm_spec, arm)
    _absolute_assets(grip_spec, gripper)
    roots = [b for b in grip_spec.worldbody.bodies]
    if len(roots) != 1:
        raise ModelError(f"{gripper}: a gripper model needs exactly one root body to mount, it has "
                         f"{[b.name for b in roots]}")  # fmt: skip
    site = next((s for s in arm_spec.sites if s.name == mount), None)
    body = next((b for b in arm_spec.bodies if b.name == mount), None)
    if site is None and body is None:
        names = sorted([s.name for s in arm_spec.sites if s.name] + [b.name for b in arm_spec.bodies if b.name])
        raise ModelError(f"{arm}: no site or link named {mount!r} to mount the gripper on; sites and links: {names}")
    if site is not None:  # the site's pose in its link, then the offset
        import mujoco

        q_frame, p_off = np.zeros(4), np.zeros(3)
        mujoco.mju_mulQuat(q_frame, np.asarray(site.quat, dtype=np.float64), np.asarray(quat, dtype=np.float64))
        mujoco.mju_rotVecQuat(p_off, np.asarray(pos, dtype=np.float64), np.asarray(site.quat, dtype=np.float64))
        frame = site.parent.add_frame(pos=np.asarray(site.pos) + p_off, quat=q_frame)
    else:
        frame = body.add_frame(pos=list(pos), quat=list(quat))
    grip_spec.option.integrator = arm_spec.option.integrator  # the arm's options win (else MuJoCo logs a conflict)
    frame.attach_body(roots[0], prefix, "")
    arm_spec.modelname = name
    _compile(arm_spec, arm)
    # Copy the meshes beside the MJCF (meshes/<n>_<file name>): a self-contained folder, as bundled models are.
    root = ET.fromstring(arm_spec.to_xml())
    files: dict[str, str] = {}
    for it in root.iter():
        if it.tag in ("mesh", "texture", "hfield", "skin") and it.get("file"):
            src = str(Path(it.get("file")))
            files.setdefault(src, f"{len(files):03d}_{Path(src).name}")
            it.set("file", files[src])
    compiler = root.find("compiler")
    if compiler is None:
        compiler = ET.SubElement(root, "compiler")
    compiler.set("meshdir", "meshes")
    compiler.set("texturedir", "meshes")
    ET.indent(root, space="  ")
    xml = ET.tostring(root, encoding="unicode")

    with atomic_dir(out_dir) as tmp:
        (tmp / "meshes").mkdir()
        for src, dst in files.items():
            shutil.copyfile(src, tmp / "meshes" / dst)
        (tmp / out.name).write_text(
            f"<!-- {name}: {arm} with {gripper} at {mount!r}; generated by mirage2matter.robots.model -->\n{xml}"
        )
    return out


# ---- Genesis --------------------------------------------------------------------------------------
def genesis_morph(gs: Any, path: str | os.PathLike, keep_links: tuple[str, ...] = (), **kwargs: Any) -> Any:
    """Genesis' morph of a robot model file, base fixed at the origin: MJCF as it is, URDF with its fixed links in
    ``keep_links`` kept (Genesis merges fixed links into their parents, and the end-effector link is often one)."""
    path = Path(path)
    if _is_urdf(path):
        return gs.morphs.URDF(file=str(path), fixed=True, links_to_keep=list(keep_links), **kwargs)
    return gs.morphs.MJCF(file=str(path), **kwargs)
