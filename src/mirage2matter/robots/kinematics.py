"""Forward kinematics of a robot model (MJCF or URDF) with MuJoCo: link poses in the base frame.

MuJoCo loads a model in well under a second, where building a Genesis scene takes tens of seconds,
and its kinematics agree with Genesis' for the same MJCF (the sample's hand poses to 1e-5 degrees).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import M2MError
from . import DEFAULT_ROBOT, get_robot, is_spec_file
from .model import ModelError, load_model, resolve_model

__all__ = ["KinematicsError", "RobotKinematics", "resolve_robot_path", "robot_model_file"]


def resolve_robot_path(robot: str | os.PathLike) -> Path:
    """A robot model file: an existing path, or a path relative to Genesis' bundled assets (FileNotFoundError
    otherwise)."""
    try:
        return resolve_model(robot)
    except ModelError as e:
        raise FileNotFoundError(str(e)) from None


def robot_model_file(robot: str | os.PathLike) -> str:
    """The model file a robot reference comes down to (a registered name, a spec file, or a model file itself): two
    references to one robot compare equal (a calibration records the model file, a workspace the robot's name)."""
    if is_spec_file(robot) or not Path(str(robot)).suffix:
        robot = get_robot(robot).model
    try:
        return str(resolve_model(robot))
    except ModelError:
        return str(robot)


class KinematicsError(M2MError, ValueError):
    """A robot model, link or joint vector the kinematics cannot use."""


class RobotKinematics:
    """Link poses T_base_link [4,4] for joint vectors q; the model's world frame is the robot base.

    ``robot``: a robot (a registered name or a robot spec file: its model, its end-effector link as the default
    link, its named frames) or a model file (MJCF/URDF, or a path in Genesis' bundled assets); default: the default
    robot. Wherever a link is named, a frame the spec names (libfranka's "EE") serves too.
    """

    def __init__(self, robot: str | os.PathLike | None = None) -> None:
        import mujoco

        robot = DEFAULT_ROBOT if robot is None else robot
        spec = get_robot(robot) if is_spec_file(robot) or not Path(str(robot)).suffix else None
        self.default_link: str | None = spec.ee_link if spec is not None else None
        self.frames = dict(spec.frames) if spec is not None else {}
        self.home = np.asarray(spec.home, np.float64) if spec is not None else None
        try:
            self.path = resolve_model(spec.model if spec is not None else robot)
            self._model = load_model(self.path)
        except ModelError as e:
            raise KinematicsError(str(e)) from None
        self._data = mujoco.MjData(self._model)
        self._mujoco = mujoco

    @property
    def n_joints(self) -> int:
        return self._model.nq

    def frame(self, name: str) -> tuple[str, np.ndarray]:
        """(link, T_link_frame [4,4]): a link of the model is itself; a frame the robot's spec names is fixed to one
        (KinematicsError naming both kinds otherwise)."""
        frame = self.frames.get(name)
        if frame is not None:  # its link is the model's: the spec file was checked against the model
            return frame.link, frame.T_link_frame
        self._body(name)  # a link of the model, or an error naming links and frames
        return name, np.eye(4)

    def _body(self, link: str) -> int:
        m = self._model
        try:
            return m.body(link).id
        except KeyError:
            names = [m.body(i).name for i in range(m.nbody)]
            frames = f"; frames the robot's spec names: {', '.join(self.frames)}" if self.frames else ""
            raise KinematicsError(f"link {link!r} not in {self.path.name}; links: {', '.join(names)}{frames}") \
                from None  # fmt: skip

    def chain(self, link: str) -> tuple[int, np.ndarray]:
        """(n, limits [n,2]): the joint values up to ``link`` (a link or a named frame: the first n of q move it)
        and their limits (+-inf where a joint is unlimited)."""
        m = self._model
        body = self._body(self.frame(link)[0])
        n = 0
        while body > 0:
            for j in range(m.body_jntadr[body], m.body_jntadr[body] + m.body_jntnum[body]):
                n = max(n, int(m.jnt_qposadr[j]) + 1)
            body = int(m.body_parentid[body])
        limits = np.full((n, 2), [-np.inf, np.inf])
        for j in range(m.njnt):
            a = int(m.jnt_qposadr[j])
            if a < n and m.jnt_limited[j]:
                limits[a] = m.jnt_range[j]
        return n, limits

    def fixed_pose(self, link: str) -> np.ndarray | None:
        """T_base_link [4,4] of a link or named frame that no joint moves (a controller's base frame), else None."""
        return None if self.chain(link)[0] else self.link_pose(np.zeros(0), link)

    def link_pose(self, q: np.ndarray, link: str | None = None) -> np.ndarray:
        """T_base_link [4,4] at joint positions q [n] (n <= n_joints; the rest stay at 0) of a link or a named frame;
        default link: the robot's end-effector link."""
        if link is None:
            if self.default_link is None:
                raise KinematicsError(f"{self.path.name}: name the link (a bare model file has no end-effector link)")
            link = self.default_link
        q = np.asarray(q, dtype=np.float64).ravel()
        if q.size > self._model.nq:
            raise KinematicsError(f"{q.size} joint values given, the model {self.path.name} has {self._model.nq}")
        parent, T_link_frame = self.frame(link)
        body = self._body(parent)
        self._forward(q)
        return self._pose(body) @ T_link_frame

    def inverse(self, T_base_link: np.ndarray, link: str | None = None, q0: np.ndarray | None = None,
                margin: float = 0.0, tol: float = 1e-7) -> np.ndarray | None:
        """Joint values [n] (the chain's, see :meth:`chain`) putting ``link`` (a link or a named frame; default: the
        end-effector link) at ``T_base_link`` [4,4], at least ``margin`` inside every joint limit; None when no
        start gets every residual (metres, and 0.2 x the rotation matrix's entries) under ``tol``. ``q0``: where to
        start (the arm's rest pose for a spec's robot, else zeros); a second start beside it. Logged poses are
        rounded: a ``tol`` of 1e-5 takes them (10 um)."""
        from scipy.optimize import least_squares

        link = link if link is not None else self.default_link
        if link is None:
            raise KinematicsError(f"{self.path.name}: name the link (a bare model file has no end-effector link)")
        n, limits = self.chain(link)
        lo, hi = limits[:, 0] + margin, limits[:, 1] - margin
        start = np.zeros(n)
        given = q0 if q0 is not None else self.home
        if given is not None:
            given = np.asarray(given, np.float64).ravel()[:n]
            start[: given.size] = given
        T_target = np.asarray(T_base_link, dtype=np.float64)

        def residual(q: np.ndarray) -> np.ndarray:
            T = self.link_pose(q, link)
            # the whole matrix difference: an antisymmetric-part residual would also vanish at a half turn
            return np.concatenate([T[:3, 3] - T_target[:3, 3], 0.2 * (T[:3, :3] - T_target[:3, :3]).ravel()])

        best = None
        for s in (start, start + 0.3 * np.sign(np.sin(np.arange(n) + 1.0))):
            sol = least_squares(residual, np.clip(s, lo, hi), bounds=(lo, hi), xtol=1e-12, ftol=1e-12)
            if best is None or sol.cost < best.cost:
                best = sol
        return best.x if np.max(np.abs(best.fun)) < tol else None

    def link_poses(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """{link: T_base_link [4,4]} of every link (body) at joint positions q [n] (n <= n_joints; the rest 0), from
        one kinematics pass (the viewer poses a whole robot per frame)."""
        q = np.asarray(q, dtype=np.float64).ravel()
        if q.size > self._model.nq:
            raise KinematicsError(f"{q.size} joint values given, the model {self.path.name} has {self._model.nq}")
        self._forward(q)
        return {self._model.body(b).name: self._pose(b) for b in range(1, self._model.nbody)}  # body 0: the world

    def _forward(self, q: np.ndarray) -> None:
        self._data.qpos[:] = 0.0
        self._data.qpos[: q.size] = q
        self._mujoco.mj_kinematics(self._model, self._data)

    def _pose(self, body: int) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self._data.xmat[body].reshape(3, 3)
        T[:3, 3] = self._data.xpos[body]
        return T

    def base_points(self) -> np.ndarray:
        """Vertices [M,3] of the base link's meshes (the root body's geoms) at the zero pose, in
        the base frame: the part of the robot that stands on the table."""
        m = load_model(self.path, meshes=True)
        d = self._mujoco.MjData(m)
        roots = [b for b in range(1, m.nbody) if m.body_parentid[b] == 0]
        d.qpos[:] = 0.0
        self._mujoco.mj_kinematics(m, d)
        pts = []
        for g in range(m.ngeom):
            if m.geom_bodyid[g] not in roots or m.geom_type[g] != self._mujoco.mjtGeom.mjGEOM_MESH:
                continue
            mesh = m.geom_dataid[g]
            v = m.mesh_vert[m.mesh_vertadr[mesh] : m.mesh_vertadr[mesh] + m.mesh_vertnum[mesh]]
            pts.append(v @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g])
        if not pts:
            raise KinematicsError(f"{self.path.name}: the base link has no mesh geometry to take a footprint from")
        return np.concatenate(pts).astype(np.float64)

    def base_footprint(self, height: float = 0.01) -> np.ndarray:
        """The base's footprint on its support plane: the convex hull [P,2] (x, y in metres,
        counter-clockwise) of the base vertices within ``height`` of the lowest one."""
        from scipy.spatial import ConvexHull

        pts = self.base_points()
        low = pts[pts[:, 2] <= pts[:, 2].min() + height][:, :2]
        return low[ConvexHull(low).vertices]
