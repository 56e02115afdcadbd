"""A workspace built from a sample's ground truth, as the capture / SfM / align-scene stages would.

``ground_truth_workspace`` writes what the later stages read (DESIGN.md section 3):

    <ws>/capture/frame_XXXXXX.jpg   keyframes decoded from scene.mp4 at evenly spaced indices
    <ws>/capture/keyframes.json     the same record layout as ``m2m capture``
    <ws>/calib/cameras_base.json    one Camera JSON per keyframe, base frame, ground-truth poses
    <ws>/calib/points_base.npy      points [M,3] float32, base frame, triangulated with those poses
    <ws>/calib/ground_truth_workspace.json   how it was made (a rerun with the same settings is skipped)

The points come from COLMAP features and matches triangulated with the known poses
(``sfm.known_poses.triangulate_known_poses``), so they carry the real pipeline's noise, not the
mesh's, and are the same every run.
It is a fast fixture for the object and world stages and lets the real upstream stages (which
write the same files) be swapped in.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_dir, atomic_write
from ..geometry.camera import Camera
from ..sfm.colmap import SfMConfig
from ..sfm.known_poses import triangulate_known_poses
from ..video import read_video_frames
from .inspect import BUNDLED_SAMPLE

__all__ = ["ground_truth_workspace", "keyframe_indices"]

_MARKER = "ground_truth_workspace.json"


def keyframe_indices(n_frames: int, n_keyframes: int) -> list[int]:
    """``n_keyframes`` evenly spaced frame indices over ``0 .. n_frames - 1`` (first and last included)."""
    if n_keyframes < 2 or n_keyframes > n_frames:
        raise ValueError(f"need 2 <= n_keyframes <= {n_frames} (the video's frame count), got {n_keyframes}")
    return sorted({int(round(v)) for v in np.linspace(0, n_frames - 1, n_keyframes)})


def ground_truth_workspace(
    ws: str | os.PathLike[str],
    sample: str | os.PathLike[str] = BUNDLED_SAMPLE,
    n_keyframes: int = 24,
    image_format: str = "jpg",
    match_overlap: int = 5,
    max_features: int = 8192,
) -> dict[str, Any]:
    """Write ``capture/`` and ``calib/`` of workspace ``ws`` from ``sample``'s ground truth (see the
    module docstring). Returns the summary also written to ``calib/ground_truth_workspace.json``.
    Skipped (the existing summary returned) when a previous run with the same settings finished."""
    ws, sample = Path(ws), Path(sample)
    gt_path = sample / "ground_truth.json"
    if not gt_path.is_file():
        raise FileNotFoundError(f"{gt_path} not found; make a sample with `m2m sample make {sample}`")
    if image_format not in ("jpg", "png"):
        raise ValueError(f"image_format must be 'jpg' or 'png', got {image_format!r}")
    gt = json.loads(gt_path.read_text())
    settings = {
        "sample": str(sample.resolve()),
        "n_keyframes": n_keyframes,
        "image_format": image_format,
        "match_overlap": match_overlap,
        "max_features": max_features,
    }
    marker = ws / "calib" / _MARKER
    if marker.is_file() and (ws / "capture" / "keyframes.json").is_file():
        previous = json.loads(marker.read_text())
        if previous.get("settings") == settings:
            return previous

    n_frames = int(gt["video"]["n_frames"])
    wanted = set(keyframe_indices(n_frames, n_keyframes))
    frames = {int(f["index"]): f for f in gt["frames"]}
    K, width, height = np.asarray(gt["camera"]["K"]), int(gt["camera"]["width"]), int(gt["camera"]["height"])
    ws.mkdir(parents=True, exist_ok=True)

    import cv2

    records, cameras = [], []
    with atomic_dir(ws / "capture") as tmp:
        for i, ts, rgb in read_video_frames(sample / gt["video"]["file"]):
            if i not in wanted or i not in frames:
                continue
            name = f"frame_{i:06d}.{image_format}"
            params = [cv2.IMWRITE_JPEG_QUALITY, 95] if image_format == "jpg" else []
            if not cv2.imwrite(str(tmp / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params):
                raise OSError(f"cannot write keyframe {tmp / name}")
            records.append({"file": name, "frame_index": i, "timestamp": ts, "sharpness": None})
            cameras.append(Camera(K, np.asarray(frames[i]["T_base_cam"]), width, height, name))
        if len(records) != len(wanted):
            raise ValueError(f"{sample / gt['video']['file']}: decoded {len(records)} of {len(wanted)} keyframes")
        summary = {
            "source": str((sample / gt["video"]["file"]).resolve()),
            "source_type": "video",
            "n_source_frames": n_frames,
            "width": width,
            "height": height,
            "config": {"ground_truth_workspace": settings},
            "dropped_low_parallax": [],
            "keyframes": records,
        }
        with open(tmp / "keyframes.json", "w", encoding="utf-8") as f:
            json.dump(summary, f, indent=1)
            f.write("\n")

    # the SfM stage's features, matching and triangulator (one thread, seeded: the same points every run)
    sfm = SfMConfig(matching="sequential", overlap=match_overlap, max_num_features=max_features)
    with tempfile.TemporaryDirectory(prefix="m2m-gtws-") as work:
        points = triangulate_known_poses(cameras, ws / "capture", Path(work) / "sfm", sfm).points
    if len(points) < 100:
        raise ValueError(f"{sample}: only {len(points)} points triangulated from {len(cameras)} keyframes")

    calib = ws / "calib"
    calib.mkdir(exist_ok=True)
    with atomic_write(calib / "cameras_base.json", "w", encoding="utf-8") as f:
        json.dump([c.to_json() for c in cameras], f, indent=1)
    with atomic_write(calib / "points_base.npy", "wb") as f:
        np.save(f, points.astype(np.float32))
    result = {"settings": settings, "keyframes": len(cameras), "points": int(len(points))}
    with atomic_write(marker, "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1)
    return result
