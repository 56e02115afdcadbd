"""Read a sample capture the way the pipeline will read a user's: decode the video, find the board."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..calib.board import target_from_json
from ..video import read_video_frames

# Where the repository ships its sample (an editable install keeps src/ beside samples/).
BUNDLED_SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"


def inspect_sample(sample: str | Path = BUNDLED_SAMPLE, n_checked: int = 24) -> dict:
    """Decode ``scene.mp4``, detect the calibration target in ``n_checked`` evenly spaced frames and compare
    the detected corners with the ground-truth projection. Returns a JSON-ready summary."""
    import cv2

    from ..geometry.camera import Camera  # here: the CLI imports this module for BUNDLED_SAMPLE and stays torch-free

    sample = Path(sample)
    gt_path = sample / "ground_truth.json"
    if not gt_path.is_file():
        raise FileNotFoundError(f"{gt_path} not found; make a sample with `m2m sample make {sample}`")
    gt = json.loads(gt_path.read_text())
    board = target_from_json(gt["board"]["spec"])
    T_base_board = np.asarray(gt["board"]["T_base_board"])
    cam = gt["camera"]
    lens = Camera(np.asarray(cam["K"]), np.eye(4), cam["width"], cam["height"], "video", cam.get("distortion") or {})
    n_frames = 0
    checked = detected = 0
    errors: list[float] = []
    every = max(1, gt["video"]["n_frames"] // n_checked)
    for i, _, image in read_video_frames(sample / gt["video"]["file"]):
        n_frames += 1
        if i % every:
            continue
        checked += 1
        ids, corners = board.detect(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))
        if len(ids) < 4:
            continue
        detected += 1
        corners_base = board.points_board(ids) @ T_base_board[:3, :3].T + T_base_board[:3, 3]
        posed = replace(lens, T_world_cam=np.asarray(gt["frames"][i]["T_base_cam"], dtype=np.float64))
        uv, _ = posed.project(corners_base, distort=True)  # through the video camera's lens, if it has one
        errors.extend(np.linalg.norm(corners.reshape(-1, 2) + 0.5 - uv, axis=1).tolist())
    return {
        "sample": str(sample),
        "video_frames": n_frames,
        "fps": gt["video"]["fps"],
        "size": [gt["camera"]["width"], gt["camera"]["height"]],
        "frames_checked": checked,
        "board_detected": detected,
        "board_corner_error_px_median": float(np.median(errors)) if errors else None,
        "handeye_views": len(json.loads((sample / gt["handeye"]["joints"]).read_text())["views"]),
        "objects": [o["name"] for o in gt["objects"]],
    }
