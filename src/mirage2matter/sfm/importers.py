"""Bring poses made elsewhere into a workspace: an existing COLMAP model, or an instant-ngp /
nerfstudio ``transforms.json``.

Both write what our own SfM writes (``capture/<images>``, ``sfm/model``, ``sfm/sfm.json``) so the
later stages cannot tell the difference. Poses keep the input's world frame (no re-centring or
re-scaling); OpenGL camera axes are converted to OpenCV at the border by
:func:`~mirage2matter.geometry.camera.load_transforms_json`.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from ..atomic import atomic_dir
from ..geometry.camera import CameraFormatError, load_transforms_json
from .colmap import SfMConfig, SfMError, SfMResult, _result_from_reconstruction, write_summary
from .known_poses import triangulate_known_poses

__all__ = ["import_colmap_model", "import_transforms"]


def _copy_images(names: list[str], src_dir: Path, capture_dir: Path, source: str) -> None:
    """Copy ``src_dir/<name>`` for every name into ``capture_dir`` (same relative paths), atomically."""
    missing = [n for n in names if not (src_dir / n).is_file()]
    if missing:
        raise SfMError(
            f"{source}: {len(missing)} of {len(names)} images not found under {src_dir}, e.g. {missing[:3]}; "
            "fix the paths or pass the folder that holds the images"
        )
    with atomic_dir(capture_dir) as tmp:
        for n in names:
            dst = tmp / n
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src_dir / n, dst)
        with open(tmp / "keyframes.json", "w", encoding="utf-8") as f:
            json.dump({"source": source, "imported": True, "keyframes": [{"name": n} for n in names]}, f, indent=1)


def import_transforms(
    transforms_path: str | os.PathLike[str],
    capture_dir: str | os.PathLike[str],
    sfm_dir: str | os.PathLike[str],
    config: SfMConfig | None = None,
) -> SfMResult:
    """Cameras of ``transforms_path`` (OpenCV axes, the file's world frame, its distortion) and
    points triangulated with those poses (no SfM rerun). Images are copied into ``capture_dir``
    under their ``file_path``; ``Camera.name`` stays the ``file_path``."""
    path = Path(transforms_path)
    if not path.is_file():
        raise SfMError(f"{path}: transforms.json not found")
    try:
        cameras = load_transforms_json(path)
    except CameraFormatError as e:
        raise SfMError(str(e)) from None
    if len(cameras) < 2:
        raise SfMError(f"{path}: {len(cameras)} frame(s); importing needs at least 2 posed images")
    names = [c.name for c in cameras]
    bad = [n for n in names if Path(n).is_absolute() or ".." in Path(n).parts]
    if bad:
        raise SfMError(f"{path}: file_path must be relative to the JSON's folder and stay inside it, got {bad[:3]}")
    if len(set(names)) != len(names):
        raise SfMError(f"{path}: the same file_path appears in several frames")
    _copy_images(names, path.parent, Path(capture_dir), str(path))
    return triangulate_known_poses(cameras, capture_dir, sfm_dir, config)


def import_colmap_model(
    model_dir: str | os.PathLike[str],
    image_dir: str | os.PathLike[str],
    capture_dir: str | os.PathLike[str],
    sfm_dir: str | os.PathLike[str],
) -> SfMResult:
    """A COLMAP sparse model (``cameras``/``images``/``points3D`` .bin or .txt) and its images:
    registered images are copied into ``capture_dir``, the model and ``sfm.json`` into ``sfm_dir``."""
    import pycolmap

    model_dir, image_dir = Path(model_dir), Path(image_dir)
    found = [
        f for f in ("cameras", "images", "points3D") if any((model_dir / f"{f}{s}").is_file() for s in (".bin", ".txt"))
    ]
    if len(found) < 3:
        raise SfMError(
            f"{model_dir}: not a COLMAP sparse model (needs cameras, images and points3D as .bin or .txt; "
            f"found {found or 'none'})"
        )
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as e:  # pycolmap raises plain exceptions on corrupt files
        raise SfMError(f"{model_dir}: COLMAP model does not parse ({e})") from None
    names = sorted(img.name for img in rec.images.values() if img.has_pose)
    bad = [n for n in names if Path(n).is_absolute() or ".." in Path(n).parts]
    if bad:
        raise SfMError(f"{model_dir}: image names must be relative to the images folder and stay inside it, got "
                       f"{bad[:3]}")  # fmt: skip
    if len(names) < 2:
        raise SfMError(f"{model_dir}: {len(names)} registered image(s); need at least 2")
    _copy_images(names, image_dir, Path(capture_dir), str(model_dir))
    sfm_dir = Path(sfm_dir)
    with atomic_dir(sfm_dir) as tmp:
        (tmp / "model").mkdir()
        rec.write(tmp / "model")
        result = _result_from_reconstruction(rec, len(names), names, sfm_dir / "model")
        write_summary(tmp, result, Path(capture_dir).resolve(), SfMConfig(), source=f"COLMAP model {model_dir}")
    return result
