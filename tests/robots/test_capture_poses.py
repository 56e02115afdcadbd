"""The robot's joint states while filmed: the capture joints, then each logged move (robots.capture_poses)."""

from __future__ import annotations

import numpy as np
import pytest

from mirage2matter.robots import get_robot
from mirage2matter.robots.capture_poses import CapturePoses, capture_poses
from mirage2matter.robots.surface import CaptureJointsError


def test_each_frame_gets_the_pose_it_was_filmed_at_and_the_record_round_trips():
    spec = get_robot("panda")
    q0 = np.asarray(spec.home, float)
    q1 = q0.copy()
    q1[0] += 0.8
    poses = capture_poses(spec, q0.tolist(), {360: q1.tolist()})
    assert len(poses) == 2 and poses.from_frame == (0, 360)
    assert [poses.index_at(f) for f in (0, 359, 360, 719)] == [0, 0, 1, 1]
    np.testing.assert_allclose(poses.joints[1][: spec.n_arm], q1)
    back = CapturePoses.from_json(poses.to_json())
    assert back.from_frame == poses.from_frame
    assert all(np.array_equal(a, b) for a, b in zip(back.joints, poses.joints, strict=True))
    # no move: one pose, the home when no joints are given
    home = capture_poses(spec, None)
    assert len(home) == 1 and home.index_at(10**6) == 0


@pytest.mark.parametrize(
    ("moves", "words"),
    [({0: None}, "frame 0"), ({200: [0.1] * 3}, "capture_moves[200]: 3 values"),
     ({200: [60.0, 0, 0, -100.0, 0, 90.0, 45.0]}, "reads as degrees")],
)  # fmt: skip
def test_a_bad_move_is_named(moves, words):
    spec = get_robot("panda")
    moves = {f: (list(spec.home) if q is None else q) for f, q in moves.items()}
    with pytest.raises(CaptureJointsError, match="capture_moves") as e:
        capture_poses(spec, list(spec.home), moves)
    assert words in str(e.value)
