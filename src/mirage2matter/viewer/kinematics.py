"""The robot's link poses at a joint state for the viewer: the calibration's forward kinematics
(``robots.kinematics.RobotKinematics``, MuJoCo, model loaded once, ~0.1 ms a frame) with the viewer's joint vectors
(the arm alone means the fingers open)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..robots import RobotSpec
from ..robots.kinematics import RobotKinematics

__all__ = ["LinkPoser"]


class LinkPoser:
    """``poses(q) -> {link: T_base_link [4,4]}`` for ``spec``'s robot; ``q`` is [n_arm] (fingers open) or
    [n_dofs] (radians; metres for sliding fingers), the order of ``spec.arm_joints + spec.gripper_joints``."""

    def __init__(self, spec: RobotSpec) -> None:
        self.spec = spec
        self._kinematics = RobotKinematics(spec.source or spec.name)  # the spec file it came from, or its name

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
        return self._kinematics.link_poses(q[: self._kinematics.n_joints])
