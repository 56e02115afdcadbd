"""Our LeRobot datasets (v3.0, and v2.1 for openpi) read into memory for behaviour cloning.

``load_episodes`` decodes every camera once with PyAV, shrinks the frames to a square ``image_size``
(area filter: the same :func:`resize_area` the deployed policy applies), and keeps them as uint8. At 96 px
300 episodes x 40 frames x 2 cameras hold ~0.66 GB, so training indexes arrays instead of decoding per
step (decoding 224 px H.264 costs more than a training step of our encoder).

A sample is the observation at frame t (each camera's image + ``observation.state``) and the action chunk
``action[t : t + K]`` of the same episode, padded past the episode's end with its last action and a mask
(``chunk_indices``), as ACT / LeRobot's ``action_is_pad`` does.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import M2MError
from ..video import VideoError, read_video_frames

__all__ = [
    "dataset_meta",
    "DatasetMeta",
    "Demonstrations",
    "PolicyError",
    "chunk_indices",
    "load_episodes",
    "normalization_stats",
    "resize_area",
]

STATE_KEY = "observation.state"
ACTION_KEY = "action"
IMAGE_PREFIX = "observation.images."

# ACT clamps std at 1e-2 too: an entry that never moves in the demos (press-button's gripper, 0 throughout)
# would otherwise divide by ~0 and turn any deployment-time deviation into a huge, unseen input.
MIN_STD = 1e-2


class PolicyError(M2MError, ValueError):
    """A dataset, checkpoint or observation the policy cannot use; the message names the file and what to do."""


@dataclass(frozen=True)
class DatasetMeta:
    """What a policy must agree on with every dataset it trains on and every robot it drives.

    robot_type    LeRobot's ``robot_type`` (None when not recorded)
    state_names   names of ``observation.state``'s entries
    action_names  names of ``action``'s entries
    fps           control rate, frames per second
    cameras       camera names (each is ``observation.images.<name>``), in the model's input order
    """

    robot_type: str | None
    state_names: tuple[str, ...]
    action_names: tuple[str, ...]
    fps: int
    cameras: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return {"robot_type": self.robot_type, "state_names": list(self.state_names),
                "action_names": list(self.action_names), "fps": self.fps, "cameras": list(self.cameras)}  # fmt: skip

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> DatasetMeta:
        return cls(d.get("robot_type"), tuple(d["state_names"]), tuple(d["action_names"]), int(d["fps"]),
                   tuple(d["cameras"]))  # fmt: skip


@dataclass
class Demonstrations:
    """Episodes of one or more datasets, back to back (N frames in all, E episodes).

    meta      robot, names, rate and cameras shared by every dataset
    images    camera -> uint8 [N, 3, S, S] (channels first, as the encoder takes them)
    state     float32 [N, S_dim]
    action    float32 [N, A]
    starts    int64 [E] first frame of each episode
    lengths   int64 [E] frames of each episode
    tasks     [E] each episode's language instruction
    sources   [E] (dataset folder, episode_index within it)
    frame_sizes  camera -> (width, height) of the datasets' frames before the resize (None where they differ): a
              live camera's image is cropped to that aspect about its centre before the same resize (``camera_frame``)
    """

    meta: DatasetMeta
    images: dict[str, np.ndarray]
    state: np.ndarray
    action: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray
    tasks: list[str] = field(default_factory=list)
    sources: list[tuple[str, int]] = field(default_factory=list)
    frame_sizes: dict[str, tuple[int, int] | None] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.state.shape[0])

    @property
    def n_episodes(self) -> int:
        return int(self.starts.shape[0])

    @property
    def image_size(self) -> int:
        return int(next(iter(self.images.values())).shape[-1])

    def frames_of(self, episodes: Sequence[int] | np.ndarray) -> np.ndarray:
        """int64 [n] the frame indices of ``episodes``, in order."""
        parts = [np.arange(self.starts[e], self.starts[e] + self.lengths[e]) for e in episodes]
        return np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64)


# ---- pure helpers ---------------------------------------------------------------------------------
def camera_frame(image: np.ndarray, frame_size: tuple[int, int] | None) -> np.ndarray:
    """A live camera's image [H, W, 3] as the policy's training frames of ``frame_size`` (width, height) show it:
    cropped about its centre to their aspect (the frames a world draws are the camera's image at full height, cropped
    about its centre: ``env.lens``), before the resize. None, or the same aspect to a pixel: the image itself."""
    if frame_size is None:
        return image
    h, w = image.shape[:2]
    aspect = frame_size[0] / frame_size[1]
    cw, ch = (round(h * aspect), h) if w / h > aspect else (w, round(w / aspect))
    if abs(cw - w) < 1 and abs(ch - h) < 1:
        return image
    x0, y0 = (w - cw) // 2, (h - ch) // 2
    return image[y0 : y0 + ch, x0 : x0 + cw]


def resize_area(image: np.ndarray, size: int) -> np.ndarray:
    """uint8 [H, W, 3] -> uint8 [size, size, 3] with an area filter (the aspect ratio is not kept: train and
    deployment squash alike). Used for the datasets' frames and for live observations, so both match."""
    import cv2

    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise PolicyError(f"an image must be uint8 [H, W, 3], got {image.dtype} {list(image.shape)}")
    if image.shape[:2] == (size, size):
        return np.ascontiguousarray(image)
    # INTER_AREA averages the source pixels under each target pixel when shrinking (no aliasing of the
    # board's squares); when enlarging a small user camera it falls back to bilinear.
    return cv2.resize(np.ascontiguousarray(image), (size, size), interpolation=cv2.INTER_AREA)


def chunk_indices(starts: np.ndarray, lengths: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """For every frame t: the frames of its action chunk t..t+k-1 clipped to its episode's last frame,
    int64 [N, k], and whether each is a real step (not padding past the episode's end), bool [N, k]."""
    starts = np.asarray(starts, np.int64)
    lengths = np.asarray(lengths, np.int64)
    ends = np.repeat(starts + lengths, lengths)  # [N] one past each frame's episode end
    t = np.arange(int(lengths.sum()), dtype=np.int64)[:, None] + np.arange(k, dtype=np.int64)[None]
    mask = t < ends[:, None]
    return np.minimum(t, ends[:, None] - 1), mask


def normalization_stats(state: np.ndarray, action: np.ndarray) -> dict[str, np.ndarray]:
    """Mean and std (floored at ``MIN_STD``) of state [N, S] and action [N, A], float32."""
    out = {}
    for name, x in (("state", state), ("action", action)):
        x = np.asarray(x, np.float64)
        out[f"{name}_mean"] = x.mean(0).astype(np.float32)
        out[f"{name}_std"] = np.maximum(x.std(0), MIN_STD).astype(np.float32)
    return out


# ---- reading one dataset --------------------------------------------------------------------------
def _read_info(root: Path) -> dict[str, Any]:
    path = root / "meta" / "info.json"
    if not path.is_file():
        raise PolicyError(f"{path} not found: {root} is not a LeRobot dataset (pass a folder written by "
                          "`m2m generate`, e.g. <workspace>/datasets/<task>)")  # fmt: skip
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise PolicyError(f"{path}: unreadable JSON ({e}); re-export the dataset") from None
    missing = [k for k in ("codebase_version", "fps", "features", "data_path", "video_path") if k not in info]
    if missing:
        raise PolicyError(f"{path} lacks {', '.join(missing)}: not a LeRobot v3.0 / v2.1 dataset")
    if info["codebase_version"] not in ("v3.0", "v2.1"):
        raise PolicyError(f"{path}: codebase_version {info['codebase_version']!r} is not supported (v3.0 or v2.1)")
    return info


def _meta_of(info: dict[str, Any], path: Path, cameras: Sequence[str] | None) -> DatasetMeta:
    feats = info["features"]
    for key in (STATE_KEY, ACTION_KEY):
        if key not in feats or not feats[key].get("names"):
            raise PolicyError(f"{path}: features lack {key} with names; a policy needs both")
    have = [k[len(IMAGE_PREFIX):] for k, f in feats.items() if k.startswith(IMAGE_PREFIX) and f.get("dtype") == "video"]
    if cameras is None:
        cameras = have
    absent = [c for c in cameras if c not in have]
    if absent or not cameras:
        raise PolicyError(f"{path}: no video feature for camera(s) {absent or '(none)'}; it has {have}")
    return DatasetMeta(info.get("robot_type"), tuple(feats[STATE_KEY]["names"]), tuple(feats[ACTION_KEY]["names"]),
                       int(info["fps"]), tuple(cameras))  # fmt: skip


def dataset_meta(root: str | Path) -> tuple[DatasetMeta, tuple[int, int]]:
    """(what a policy must agree on, (width, height) of the first camera's frames) of a dataset folder;
    :class:`PolicyError` naming its info.json when it is not one of ours."""
    root = Path(root)
    info = _read_info(root)
    meta = _meta_of(info, root / "meta" / "info.json", None)
    shape = info["features"][IMAGE_PREFIX + meta.cameras[0]].get("shape") or [0, 0, 3]
    return meta, (int(shape[1]), int(shape[0]))


def _check_same(first: DatasetMeta, first_path: Path, meta: DatasetMeta, path: Path) -> None:
    for what, a, b in (("robot_type", first.robot_type, meta.robot_type), ("fps", first.fps, meta.fps),
                       ("observation.state names", first.state_names, meta.state_names),
                       ("action names", first.action_names, meta.action_names)):  # fmt: skip
        if a != b:
            raise PolicyError(f"{path}: {what} {b!r} differs from {a!r} in {first_path}; one policy trains on "
                              "datasets of one robot at one rate: leave this dataset out or regenerate it")  # fmt: skip


def _column(table, name: str) -> np.ndarray:
    """A column as numpy: [N] for scalars, [N, D] for (fixed size) lists."""
    import pyarrow as pa

    if name not in table.column_names:
        raise PolicyError(f"the data lack the column {name!r}; the dataset is damaged: re-export it")
    col = table.column(name).combine_chunks()
    if pa.types.is_list(col.type) or pa.types.is_fixed_size_list(col.type) or pa.types.is_large_list(col.type):
        return col.flatten().to_numpy(zero_copy_only=False).reshape(len(col), -1)
    return col.to_numpy(zero_copy_only=False)


def _read_table(path: Path):
    import pyarrow.parquet as pq

    if not path.is_file():
        raise PolicyError(f"{path} not found: the dataset is incomplete; re-export it")
    try:
        return pq.read_table(path)
    except Exception as e:  # pyarrow raises several types for damaged files
        raise PolicyError(f"{path}: unreadable parquet ({type(e).__name__}: {e}); re-export the dataset") from None


def _episode_rows_v30(root: Path) -> list[dict[str, Any]]:
    import pyarrow as pa

    files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    if not files:
        raise PolicyError(f"{root / 'meta' / 'episodes'}: no episode metadata; re-export the dataset")
    rows = pa.concat_tables([_read_table(f) for f in files]).to_pylist()
    return sorted(rows, key=lambda r: r["episode_index"])


def _decode_resized(path: Path, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(times float64 [F] s, frames uint8 [F, 3, size, size]) of a video file."""
    times, frames = [], []
    try:
        for _, ts, im in read_video_frames(path):
            times.append(ts)
            frames.append(resize_area(im, size).transpose(2, 0, 1))
    except VideoError as e:
        raise PolicyError(f"{e}; the dataset is damaged: re-export it (`m2m validate` lists what is wrong)") from None
    if not frames:
        raise PolicyError(f"{path}: no frames decode; re-export the dataset")
    return np.asarray(times), np.stack(frames)


def _read_v30(root: Path, info: dict, meta: DatasetMeta, size: int) -> list[dict[str, Any]]:
    rows = _episode_rows_v30(root)
    data_files = sorted({(r["data/chunk_index"], r["data/file_index"]) for r in rows})
    tables = {cf: _read_table(root / info["data_path"].format(chunk_index=cf[0], file_index=cf[1]))
              for cf in data_files}  # fmt: skip
    videos: dict[tuple[str, int, int], tuple[np.ndarray, np.ndarray]] = {}
    half = 0.5 / meta.fps  # a frame belongs to the slice its timestamp falls in, to half a frame
    episodes = []
    for r in rows:
        e = int(r["episode_index"])
        t = tables[(r["data/chunk_index"], r["data/file_index"])]
        ep = _frames_of_episode(t, e, root / info["data_path"].format(chunk_index=r["data/chunk_index"],
                                                                      file_index=r["data/file_index"]))  # fmt: skip
        images = {}
        for cam in meta.cameras:
            key = IMAGE_PREFIX + cam
            vk = (key, r[f"videos/{key}/chunk_index"], r[f"videos/{key}/file_index"])
            vpath = root / info["video_path"].format(video_key=key, chunk_index=vk[1], file_index=vk[2])
            if vk not in videos:
                videos[vk] = _decode_resized(vpath, size)
            times, frames = videos[vk]
            t0, t1 = r[f"videos/{key}/from_timestamp"], r[f"videos/{key}/to_timestamp"]
            sel = (times >= t0 - half) & (times < t1 - half)
            images[cam] = frames[sel]
            if int(sel.sum()) != len(ep["state"]):
                raise PolicyError(f"{vpath}: episode {e} has {int(sel.sum())} frames in [{t0}, {t1}) s but "
                                  f"{len(ep['state'])} data rows; the dataset is damaged: re-export it "
                                  "(`m2m validate` lists what is wrong)")  # fmt: skip
        ep.update(images=images, task=(r.get("tasks") or [""])[0], episode_index=e)
        episodes.append(ep)
    return episodes


def _read_v21(root: Path, info: dict, meta: DatasetMeta, size: int) -> list[dict[str, Any]]:
    path = root / "meta" / "episodes.jsonl"
    try:
        rows = [json.loads(s) for s in path.read_text(encoding="utf-8").splitlines() if s.strip()]
    except (OSError, ValueError) as e:
        raise PolicyError(f"{path}: unreadable ({e}); re-export the dataset") from None
    chunks = int(info.get("chunks_size", 1000))
    episodes = []
    for r in sorted(rows, key=lambda r: r["episode_index"]):
        e = int(r["episode_index"])
        dpath = root / info["data_path"].format(episode_chunk=e // chunks, episode_index=e)
        ep = _frames_of_episode(_read_table(dpath), e, dpath)
        images = {}
        for cam in meta.cameras:
            vpath = root / info["video_path"].format(episode_chunk=e // chunks, video_key=IMAGE_PREFIX + cam,
                                                     episode_index=e)  # fmt: skip
            images[cam] = _decode_resized(vpath, size)[1]
            if len(images[cam]) != len(ep["state"]):
                raise PolicyError(f"{vpath}: {len(images[cam])} frames but {len(ep['state'])} data rows; "
                                  "the dataset is damaged: re-export it")  # fmt: skip
        ep.update(images=images, task=(r.get("tasks") or [""])[0], episode_index=e)
        episodes.append(ep)
    return episodes


def _frames_of_episode(table, e: int, path: Path) -> dict[str, np.ndarray]:
    ep_col = _column(table, "episode_index")
    sel = np.flatnonzero(ep_col == e)
    if sel.size == 0:
        raise PolicyError(f"{path}: no rows of episode {e}; the dataset is damaged: re-export it")
    order = sel[np.argsort(_column(table, "frame_index")[sel], kind="stable")]
    state = _column(table, STATE_KEY)[order].astype(np.float32)
    action = _column(table, ACTION_KEY)[order].astype(np.float32)
    if not (np.isfinite(state).all() and np.isfinite(action).all()):
        raise PolicyError(f"{path}: episode {e} holds NaN/Inf in its state or action; regenerate it")
    return {"state": state, "action": action}


def load_episodes(
    dataset_dirs: str | Path | Sequence[str | Path],
    image_size: int = 96,
    cameras: Sequence[str] | None = None,
    max_episodes: int | None = None,
) -> Demonstrations:
    """Read every episode of one or more of our LeRobot datasets into memory.

    ``image_size``: frames are resized to [image_size, image_size] (area filter). ``cameras``: which
    ``observation.images.<name>`` to load, in the model's input order (default: all of the first dataset's).
    Every dataset must share the first one's robot_type, state / action names and fps (else
    :class:`PolicyError` naming the odd dataset's info.json). ``max_episodes``: only the first N episodes of each
    dataset (fewer there is an error: the data-scale curve must not silently train on less).
    """
    dirs = [Path(dataset_dirs)] if isinstance(dataset_dirs, str | Path) else [Path(d) for d in dataset_dirs]
    if not dirs:
        raise PolicyError("no datasets given: pass one or more dataset folders (<workspace>/datasets/<task>)")
    if isinstance(image_size, bool) or not isinstance(image_size, int) or not 16 <= image_size <= 512:
        raise PolicyError(f"image_size must be an integer in [16, 512], got {image_size!r}")
    first: DatasetMeta | None = None
    first_path = dirs[0]
    episodes: list[dict[str, Any]] = []
    sources: list[tuple[str, int]] = []
    sizes: dict[str, set[tuple[int, int] | None]] = {}  # camera -> the datasets' frame sizes
    for root in dirs:
        info = _read_info(root)
        info_path = root / "meta" / "info.json"
        meta = _meta_of(info, info_path, cameras if first is None else (cameras or first.cameras))
        if first is None:
            first, first_path = meta, info_path
        else:
            _check_same(first, first_path, meta, info_path)
        for c in meta.cameras:
            sizes.setdefault(c, set()).add(_frame_size(info, c))
        reader = _read_v30 if info["codebase_version"] == "v3.0" else _read_v21
        try:
            eps = reader(root, info, meta, image_size)
        except (KeyError, IndexError, ValueError) as e:
            if isinstance(e, PolicyError):
                raise
            raise PolicyError(f"{root}: its metadata does not fit its files ({type(e).__name__}: {e}); the dataset "
                              "is damaged: re-export it (`m2m validate` lists what is wrong)") from None  # fmt: skip
        if max_episodes is not None:
            if len(eps) < max_episodes:
                raise PolicyError(f"{root}: {len(eps)} episodes, fewer than the {max_episodes} asked for; "
                                  "generate more (m2m generate --episodes N) or ask for fewer")  # fmt: skip
            eps = eps[:max_episodes]
        for ep in eps:
            if ep["state"].shape[1] != len(meta.state_names) or ep["action"].shape[1] != len(meta.action_names):
                raise PolicyError(f"{root}: episode {ep['episode_index']} state/action widths "
                                  f"{ep['state'].shape[1]}/{ep['action'].shape[1]} differ from info.json's names "
                                  f"({len(meta.state_names)}/{len(meta.action_names)}); re-export it")  # fmt: skip
        episodes += eps
        sources += [(str(root), int(ep["episode_index"])) for ep in eps]
    assert first is not None
    if not episodes:
        raise PolicyError(f"{', '.join(map(str, dirs))}: no episodes to train on")
    lengths = np.array([len(ep["state"]) for ep in episodes], np.int64)
    return Demonstrations(
        meta=first,
        images={c: np.concatenate([ep["images"][c] for ep in episodes]) for c in first.cameras},
        state=np.concatenate([ep["state"] for ep in episodes]),
        action=np.concatenate([ep["action"] for ep in episodes]),
        starts=np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64),
        lengths=lengths,
        tasks=[ep["task"] for ep in episodes],
        sources=sources,
        frame_sizes={c: next(iter(s)) if len(s) == 1 else None for c, s in sizes.items()},
    )


def _frame_size(info: dict[str, Any], camera: str) -> tuple[int, int] | None:
    """(width, height) of a dataset's frames of ``camera`` (its info.json's video shape [H, W, 3]), None if unsaid."""
    shape = info["features"][IMAGE_PREFIX + camera].get("shape")
    return (int(shape[1]), int(shape[0])) if shape and len(shape) == 3 else None
