"""Auxiliary training targets: where the tool centre will be, read off the demonstrations' own actions.

Behaviour cloning supervises the next second of joint targets only, which an encoder can predict well enough
from the arm's own progress without ever finding the object (measured on the sample: 300 grasp demos, 55 % in
the reconstructed world and 0/20 in the ground-truth one, the arm driving to places the banana was not). Where
the tool centre point (TCP) will be a few seconds later - where the demonstration grasps, presses or pushes - is
a function of the scene alone, linear in where the object lies. Predicting it from the cameras, as an auxiliary
loss during training only, makes the encoders localise the target; the deployed policy never sees these numbers.

The targets come from the datasets as they are: forward kinematics (MuJoCo, :mod:`..robots.kinematics`) of the
recorded arm joint targets ``action[t + h]`` for each horizon h, clipped to the episode's last frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..robots import ROBOTS, get_robot
from ..robots.kinematics import RobotKinematics
from .data import Demonstrations, chunk_indices

__all__ = ["future_tcp", "robot_for"]


def robot_for(robot_type: str | None):
    """The shipped :class:`~mirage2matter.robots.RobotSpec` whose ``robot_type`` datasets carry, or None."""
    if robot_type is None:
        return None
    return next((spec for spec in map(get_robot, ROBOTS) if spec.robot_type == robot_type), None)


def tcp_of_actions(action: np.ndarray, spec) -> np.ndarray:
    """float32 [N, 3]: the TCP position (base frame, m) where each action's arm joint targets [N, >= n_arm] put it."""
    kin = RobotKinematics(spec.name)  # a shipped robot by name (composed models included)
    tcp = np.append(spec.T_ee_tcp[:3, 3], 1.0)
    out = np.empty((len(action), 3), np.float32)
    for i, a in enumerate(np.asarray(action, np.float64)):
        out[i] = (kin.link_pose(a[: spec.n_arm], spec.ee_link) @ tcp)[:3]
    return out


def future_tcp(demos: Demonstrations, horizons: Sequence[int], spec) -> np.ndarray:
    """float32 [N, 3 * len(horizons)]: for every frame t, the TCP position that action[t + h] commands, for each h
    in ``horizons`` (steps), clipped to the episode's last frame."""
    tcp = tcp_of_actions(demos.action, spec)
    idx, _ = chunk_indices(demos.starts, demos.lengths, max(horizons) + 1)
    return np.concatenate([tcp[idx[:, h]] for h in horizons], axis=1)
