"""The bundled sample as a nerfstudio ``transforms.json`` data set with its ground-truth poses.

Lets the importers, training and the benchmarks run on the sample the way they run on any posed
capture (e.g. ``../shared/data/fox``), with the truth known.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..atomic import atomic_dir
from ..geometry.camera import GL_TO_CV
from ..video import read_video_frames

__all__ = ["write_sample_transforms"]


def write_sample_transforms(
    sample_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str], every: int = 60, scale: float = 0.5
) -> Path:
    """Every ``every``-th frame of ``sample_dir/scene.mp4``, resized by ``scale``, as PNGs under
    ``out_dir/images/`` with a ``transforms.json`` of their ground-truth poses (OpenGL axes, robot-base
    world frame, metres). Returns the JSON's path. Written atomically."""
    from PIL import Image

    sample_dir, out_dir = Path(sample_dir), Path(out_dir)
    gt = json.loads((sample_dir / "ground_truth.json").read_text())
    if gt["camera"].get("distortion"):
        raise ValueError(f"{sample_dir}: its video was filmed through a lens with distortion; transforms.json here "
                         "holds pinhole intrinsics only (use a sample made with the default --lens pinhole)")
    K = np.asarray(gt["camera"]["K"], dtype=np.float64) * np.array([[scale], [scale], [1.0]])
    frames, size = [], None
    with atomic_dir(out_dir) as tmp:
        (tmp / "images").mkdir()
        for index, _, rgb in read_video_frames(sample_dir / gt["video"]["file"], every=every):
            h, w = rgb.shape[:2]
            img = Image.fromarray(rgb)
            if scale != 1:
                img = img.resize((round(w * scale), round(h * scale)), Image.BILINEAR)
            size = img.size
            name = f"images/{index:04d}.png"
            img.save(tmp / name)
            T_cv = np.asarray(gt["frames"][index]["T_base_cam"], dtype=np.float64)
            frames.append({"file_path": name, "transform_matrix": (T_cv @ GL_TO_CV).tolist()})
        meta = {"fl_x": K[0, 0], "fl_y": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "w": size[0], "h": size[1]}
        with open(tmp / "transforms.json", "w", encoding="utf-8") as f:
            json.dump({**meta, "frame": "robot base (metres)", "frames": frames}, f, indent=1)
    return out_dir / "transforms.json"
