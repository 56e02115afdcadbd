"""The robot's joint states while a capture was filmed: one from the first frame on, and one more per move.

A user who films the table, moves the arm half-way and films on (the pipeline's ``capture_joints``
then ``capture_moves``) gives the keyframes two robots: each keyframe is compared with, masked by and fitted to the
robot at the joint state of the video frame it came from. A second pose shows what the first hid: the upper arm and
hand from another side, and the table behind the first pose.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .spec import RobotSpec
from .surface import CaptureJointsError, check_capture_joints

__all__ = ["CapturePoses", "capture_poses"]


@dataclass(frozen=True)
class CapturePoses:
    """joints [P] arrays [n_dofs] (radians; metres for sliding fingers), from_frame [P] ints: pose p holds from video
    frame ``from_frame[p]`` (0 for the first, increasing) until the next one's."""

    joints: tuple[np.ndarray, ...]
    from_frame: tuple[int, ...]

    def __len__(self) -> int:
        return len(self.joints)

    def index_at(self, frame_index: int) -> int:
        """The pose the robot held at video frame ``frame_index``."""
        return int(np.searchsorted(np.asarray(self.from_frame), frame_index, side="right") - 1)

    def to_json(self) -> dict:
        """calib/robot.json's words: ``capture_joints`` (the first) and ``capture_moves`` {frame: joints}."""
        return {"capture_joints": self.joints[0].tolist(),
                "capture_moves": {str(f): q.tolist() for f, q in zip(self.from_frame[1:], self.joints[1:],
                                                                       strict=True)}}  # fmt: skip

    @classmethod
    def from_json(cls, record: Mapping) -> CapturePoses:
        moves = sorted((int(f), q) for f, q in (record.get("capture_moves") or {}).items())
        return cls(tuple(np.asarray(q, np.float64) for q in [record["capture_joints"], *[q for _, q in moves]]),
                   (0, *[f for f, _ in moves]))  # fmt: skip


def capture_poses(
    spec: RobotSpec,
    capture_joints: Sequence[float] | None,
    capture_moves: Mapping[int, Sequence[float]] | None = None,
    what: str = "align",
) -> CapturePoses:
    """The poses ``capture_joints`` and ``capture_moves`` (the pipeline's) give, each checked by
    :func:`check_capture_joints` (length, limits, degrees: an error naming the setting); a move at frame 0 or below
    is refused (frame 0 is ``capture_joints``')."""
    joints, frames = [check_capture_joints(spec, capture_joints, f"{what} capture_joints")], [0]
    for frame, q in sorted((capture_moves or {}).items()):
        if int(frame) < 1:
            raise CaptureJointsError(f"{what} capture_moves: frame {frame}: a move is from a later frame (>= 1); the "
                                     "joint state at frame 0 is capture_joints")  # fmt: skip
        joints.append(check_capture_joints(spec, q, f"{what} capture_moves[{frame}]"))
        frames.append(int(frame))
    return CapturePoses(tuple(joints), tuple(frames))
