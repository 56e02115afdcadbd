"""The robot's link poses at a joint state (MuJoCo forward kinematics of the robot's model, as ``robots.surface``
poses the links), with its model loaded once so an episode's frames pose quickly (~0.1 ms a frame)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..robots import RobotSpec
from ..robots.model import load_model, resolve_model

__all__ = ["LinkPoser"]


class LinkPoser:
    """``poses(q) -> {link: T_base_link [4,4]}`` for ``spec``'s robot; ``q`` is [n_arm] (fingers open) or
    [n_dofs] (radians; metres for sliding fingers), the order of ``spec.arm_joints + spec.gripper_joints``."""

    def __init__(self, spec: RobotSpec) -> None:
        import mujoco

        self.spec = spec
        self._mj = mujoco
        self.model = load_model(resolve_model(spec.model))
        self.data = mujoco.MjData(self.model)
        self.links = [self.model.body(b).name for b in range(1, self.model.nbody)]  # body 0 is the world

    def full_q(self, q: Sequence[float] | None) -> np.ndarray:
        """[n_dofs] from [n_arm] (fingers open), [n_dofs], or None (home)."""
        spec = self.spec
        if q is None:
            return spec.home_q(spec.gripper_open)
        q = np.asarray(q, np.float64).reshape(-1)
        if q.size == spec.n_arm:
            q = np.concatenate([q, [spec.gripper_open] * (spec.n_dofs - spec.n_arm)])
        return q[: spec.n_dofs]

    def poses(self, q: Sequence[float] | None) -> dict[str, np.ndarray]:
        q = self.full_q(q)
        self.data.qpos[:] = 0.0
        n = min(q.size, self.model.nq)
        self.data.qpos[:n] = q[:n]
        self._mj.mj_kinematics(self.model, self.data)
        out = {}
        for b, name in enumerate(self.links, start=1):
            T = np.eye(4)
            T[:3, :3] = self.data.xmat[b].reshape(3, 3)
            T[:3, 3] = self.data.xpos[b]
            out[name] = T
        return out
