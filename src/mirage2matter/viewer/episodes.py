"""Recorded episodes as the viewer plays them: the robot's joint state and the recorded camera frames per frame.

A dataset episode (``m2m generate``'s LeRobot dataset) holds the state and both cameras' frames; it is a success
(generation keeps its successful demonstrations), and ``meta/m2m_episodes.jsonl`` names the objects' start poses.
The objects' poses along the episode are not recorded, so they stay at their start. An evaluation
(``m2m eval-policy``) keeps each episode's success and reason, and the frames of its first episodes
(``rollout.mp4``), not the robot's state: the robot stays at its home.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..env.config import EpisodeSpec
from ..policy.data import dataset_meta, load_episodes
from ..robots import RobotSpec
from ..video import VideoError, read_video_frames
from .inputs import ViewerError

__all__ = ["Episode", "dataset_episode", "eval_episode"]

FRAME_PX = EpisodeSpec.size[0]  # the side the recorded frames are shown at (the datasets' default frame size)
EVAL_PAD_FRAMES = 5  # eval-policy's rollout.mp4 repeats each episode's last frame this many times


@dataclass
class Episode:
    """One recorded episode.

    title        what it is ("grasp_banana episode 2")
    fps          frames per second
    state        float32 [T, n_dofs] joint state per frame, or None (not recorded: the robot stays put)
    frames       {camera: uint8 [T,H,W,3]} the recorded pictures
    success      whether the episode succeeded (None: unknown)
    note         the outcome in words (a failure's reason)
    start_poses  {object: T_base_obj [4,4]} where the episode started the objects ({}: unknown)
    """

    title: str
    fps: float
    state: np.ndarray | None
    frames: dict[str, np.ndarray]
    success: bool | None
    note: str = ""
    start_poses: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def length(self) -> int:
        if self.state is not None:
            return int(self.state.shape[0])
        return int(min((len(f) for f in self.frames.values()), default=0))


def _check_robot(root: Path, spec: RobotSpec) -> None:
    """A dataset recorded with another robot (or other joint names) cannot drive this world's robot."""
    meta, _ = dataset_meta(root)
    if meta.robot_type not in (None, spec.robot_type) or tuple(meta.state_names[: spec.n_dofs]) != spec.state_names:
        raise ViewerError(
            f"{root} was recorded with robot {meta.robot_type!r} (state {', '.join(meta.state_names)}); this "
            f"world's robot is {spec.name} ({spec.robot_type}, state {', '.join(spec.state_names)}): view it in a "
            "workspace of that robot"
        )


def dataset_episode(root: Path, index: int, spec: RobotSpec) -> Episode:
    """Episode ``index`` of the LeRobot dataset at ``root`` (one of ours: v3.0 or v2.1)."""
    root = Path(root)
    _check_robot(root, spec)
    info = json.loads((root / "meta" / "info.json").read_text(encoding="utf-8"))
    total = int(info.get("total_episodes", 0))
    if not 0 <= index < total:
        raise ViewerError(f"{root} has {total} episodes (0..{total - 1}); episode {index} is not one of them")
    demos = load_episodes(root, image_size=FRAME_PX, max_episodes=index + 1)
    frames = demos.frames_of([index])
    start_poses = {}
    extra = root / "meta" / "m2m_episodes.jsonl"
    if extra.is_file():
        for line in extra.read_text(encoding="utf-8").splitlines():
            row = json.loads(line) if line.strip() else {}
            if row.get("episode_index") == index:
                poses = (row.get("record") or {}).get("start_poses") or {}
                start_poses = {k: np.asarray(v, np.float64) for k, v in poses.items()}
    return Episode(
        title=f"{root.name} episode {index}: {demos.tasks[index]}",
        fps=float(demos.meta.fps),
        state=demos.state[frames],
        frames={c: demos.images[c][frames].transpose(0, 2, 3, 1) for c in demos.meta.cameras},
        success=True,
        note="a kept demonstration (generation keeps its successes)",
        start_poses=start_poses,
    )


def eval_episode(root: Path, index: int) -> Episode:
    """Episode ``index`` of the evaluation report at ``root`` (``episodes.jsonl`` + ``rollout.mp4``)."""
    root = Path(root)
    rows_file = root / "episodes.jsonl"
    if not rows_file.is_file():
        raise ViewerError(f"{rows_file} not found: {root} is not an evaluation report (m2m eval-policy writes one)")
    rows = [json.loads(s) for s in rows_file.read_text(encoding="utf-8").splitlines() if s.strip()]
    if not 0 <= index < len(rows):
        raise ViewerError(f"{root} has {len(rows)} episodes (0..{len(rows) - 1}); episode {index} is not one of them")
    row = rows[index]
    frames: dict[str, np.ndarray] = {}
    video = root / "rollout.mp4"
    if video.is_file():
        try:
            pictures = [im for _, _, im in read_video_frames(video)]
        except VideoError as e:
            raise ViewerError(str(e)) from None
        shown = [int(r.get("steps", 0)) for r in rows]
        # the video holds the first k episodes, each with its pad; find k and the frames per step's offset
        for k in range(len(rows), 0, -1):
            extra = len(pictures) - EVAL_PAD_FRAMES * k - sum(shown[:k])
            if extra >= 0 and extra % k == 0 and index < k:
                first = sum(shown[:index]) + index * (extra // k + EVAL_PAD_FRAMES)
                frames["rollout"] = np.stack(pictures[first : first + shown[index] + extra // k])
                break
    ok = bool(row.get("success"))
    note = "success" if ok else f"failure: {row.get('reason') or 'no reason recorded'}"
    return Episode(title=f"{root.name} episode {index} (seed {row.get('seed')})", fps=10.0, state=None,
                   frames=frames, success=ok, note=note)  # fmt: skip
