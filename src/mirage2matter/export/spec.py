"""What a demonstration dataset holds (DESIGN.md section 5): its cameras, state and action, rate.

One ``DatasetSpec`` describes every episode of a dataset; the LeRobot writers turn it into the
``features`` of ``meta/info.json``. Feature keys follow LeRobot: ``observation.images.<camera>``
(video), ``observation.state``, ``action`` and the bookkeeping columns. It knows no robot: the state /
action names and LeRobot's ``robot_type`` come from the caller (``datagen`` takes them from the world's
``RobotSpec``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

# The bookkeeping columns every LeRobot dataset has, in the order they follow the data columns.
INDEX_FEATURES: dict[str, str] = {
    "timestamp": "float32",
    "frame_index": "int64",
    "episode_index": "int64",
    "index": "int64",
    "task_index": "int64",
}


@dataclass(frozen=True)
class VideoOptions:
    """H.264 encoding. ``bf=0`` (no B-frames) keeps pts == dts so episodes concatenate by remuxing;
    ``threads=1`` keeps the bitstream identical run to run (same seeds -> same bytes)."""

    codec: str = "libx264"
    crf: int = 20
    preset: str = "veryfast"
    gop: int = 10
    pix_fmt: str = "yuv420p"


@dataclass(frozen=True)
class DatasetSpec:
    """state_names  names of ``observation.state``'s entries (joint positions + gripper)
    action_names names of ``action``'s entries
    robot_type   LeRobot's ``robot_type`` (None: not recorded)
    fps          control / video rate (frames per second, an integer as LeRobot wants)
    cameras      camera name -> (height, width); each becomes ``observation.images.<name>``
    video        H.264 encoding of the camera videos
    """

    state_names: tuple[str, ...]
    action_names: tuple[str, ...]
    robot_type: str | None = None
    # given, never defaulted here: a dataset's rate and frames are its episodes' (``env.config.EpisodeSpec``)
    fps: int = field(kw_only=True)
    cameras: dict[str, tuple[int, int]] = field(kw_only=True)
    video: VideoOptions = VideoOptions()

    def __post_init__(self) -> None:
        if isinstance(self.fps, bool) or not isinstance(self.fps, int) or self.fps < 1:
            raise ValueError(f"dataset fps must be a positive integer, got {self.fps!r}")
        if not self.cameras:
            raise ValueError("a dataset needs at least one camera")
        for name, hw in self.cameras.items():
            if not name or "/" in name or "." in name:
                raise ValueError(f"camera name {name!r} must be non-empty without '/' or '.'")
            h, w = hw
            if h < 2 or w < 2 or h % 2 or w % 2:
                raise ValueError(f"camera {name}: H.264 yuv420p needs even height and width, got {h}x{w}")
        if not self.state_names or not self.action_names:
            raise ValueError("state_names and action_names must not be empty")

    @property
    def video_keys(self) -> list[str]:
        return [video_key(c) for c in self.cameras]

    def features(self) -> dict[str, dict[str, Any]]:
        """The ``features`` mapping of ``meta/info.json``."""
        feats: dict[str, dict[str, Any]] = {}
        for cam, (h, w) in self.cameras.items():
            feats[video_key(cam)] = {
                "dtype": "video",
                "shape": [h, w, 3],
                "names": ["height", "width", "channels"],
                "info": {
                    "video.height": h,
                    "video.width": w,
                    "video.codec": "h264",
                    "video.pix_fmt": self.video.pix_fmt,
                    "video.is_depth_map": False,
                    "video.fps": float(self.fps),
                    "video.channels": 3,
                    "has_audio": False,
                },
            }
        feats["observation.state"] = {"dtype": "float32", "shape": [len(self.state_names)],
                                      "names": list(self.state_names)}  # fmt: skip
        feats["action"] = {"dtype": "float32", "shape": [len(self.action_names)], "names": list(self.action_names)}
        for name, dtype in INDEX_FEATURES.items():
            feats[name] = {"dtype": dtype, "shape": [1], "names": None}
        return feats

    def to_json(self) -> dict[str, Any]:
        return {
            "fps": self.fps,
            "cameras": {k: list(v) for k, v in self.cameras.items()},
            "state_names": list(self.state_names),
            "action_names": list(self.action_names),
            "robot_type": self.robot_type,
            "video": vars(self.video).copy(),
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> DatasetSpec:
        return cls(
            fps=int(d["fps"]),
            cameras={k: (int(v[0]), int(v[1])) for k, v in d["cameras"].items()},
            state_names=tuple(d["state_names"]),
            action_names=tuple(d["action_names"]),
            robot_type=d.get("robot_type"),
            video=VideoOptions(**d.get("video", {})),
        )


def video_key(camera: str) -> str:
    return f"observation.images.{camera}"


@dataclass
class EpisodeData:
    """One finished demonstration, as arrays.

    task    language instruction (one per episode)
    images  camera name -> uint8 [T, H, W, 3] RGB frames
    state   float32 [T, S] joint positions + gripper at each frame
    action  float32 [T, A] the command issued at each frame
    """

    task: str
    images: dict[str, np.ndarray]
    state: np.ndarray
    action: np.ndarray

    @property
    def length(self) -> int:
        return int(self.state.shape[0])

    def check(self, spec: DatasetSpec) -> None:
        """Raise ValueError naming the first array that does not fit ``spec``."""
        t = self.length
        if t < 1:
            raise ValueError("an episode needs at least one frame")
        if not isinstance(self.task, str) or not self.task.strip():
            raise ValueError("an episode needs a non-empty language task")
        if self.state.shape != (t, len(spec.state_names)):
            raise ValueError(f"state must be [T={t}, {len(spec.state_names)}], got {self.state.shape}")
        if self.action.shape != (t, len(spec.action_names)):
            raise ValueError(f"action must be [T={t}, {len(spec.action_names)}], got {self.action.shape}")
        for arr, name in ((self.state, "state"), (self.action, "action")):
            if not np.isfinite(arr).all():
                raise ValueError(f"episode {name} holds NaN/Inf")
        if set(self.images) != set(spec.cameras):
            raise ValueError(f"episode cameras {sorted(self.images)} differ from the dataset's {sorted(spec.cameras)}")
        for cam, (h, w) in spec.cameras.items():
            im = self.images[cam]
            if im.dtype != np.uint8 or im.shape != (t, h, w, 3):
                raise ValueError(f"camera {cam}: frames must be uint8 [{t},{h},{w},3], got {im.dtype} {im.shape}")
