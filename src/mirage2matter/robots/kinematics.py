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

__all__ = ["KinematicsError", "RobotKinematics", "resolve_robot_path"]


def resolve_robot_path(robot: str | os.PathLike) -> Path:
    """A robot model file: an existing path, or a path relative to Genesis' bundled assets (FileNotFoundError
    otherwise)."""
    try:
        return resolve_model(robot)
    except ModelError as e:
        raise FileNotFoundError(str(e)) from None


class KinematicsError(M2MError, ValueError):
    """A robot model, link or joint vector the kinematics cannot use."""


class RobotKinematics:
    """Link poses T_base_link [4,4] for joint vectors q; the model's world frame is the robot base.

    ``robot``: a robot (a registered name or a robot spec file: its model, its end-effector link as the default
    link) or a model file (MJCF/URDF, or a path in Genesis' bundled assets); default: the default robot.
    """

    def __init__(self, robot: str | os.PathLike | None = None) -> None:
        import mujoco

        robot = DEFAULT_ROBOT if robot is None else robot
        spec = get_robot(robot) if is_spec_file(robot) or not Path(str(robot)).suffix else None
        self.default_link: str | None = spec.ee_link if spec is not None else None
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

    def chain(self, link: str) -> tuple[int, np.ndarray]:
        """(n, limits [n,2]): the joint values up to ``link`` (the first n of q move it) and their limits
        (+-inf where a joint is unlimited)."""
        m = self._model
        try:
            body = m.body(link).id
        except KeyError:
            names = [m.body(i).name for i in range(m.nbody)]
            raise KinematicsError(f"link {link!r} not in {self.path.name}; links: {', '.join(names)}") from None
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

    def link_pose(self, q: np.ndarray, link: str | None = None) -> np.ndarray:
        """T_base_link [4,4] at joint positions q [n] (n <= n_joints; the rest stay at 0); default link: the
        robot's end-effector link."""
        if link is None:
            if self.default_link is None:
                raise KinematicsError(f"{self.path.name}: name the link (a bare model file has no end-effector link)")
            link = self.default_link
        q = np.asarray(q, dtype=np.float64).ravel()
        if q.size > self._model.nq:
            raise KinematicsError(f"{q.size} joint values given, the model {self.path.name} has {self._model.nq}")
        try:
            body = self._model.body(link).id
        except KeyError:
            names = [self._model.body(i).name for i in range(self._model.nbody)]
            raise KinematicsError(f"link {link!r} not in {self.path.name}; links: {', '.join(names)}") from None
        self._forward(q)
        return self._pose(body)

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
