"""Points from images whose poses are already known (an imported ``transforms.json``, ground truth).

COLMAP's point triangulator: SIFT features and matches as in :func:`run_sfm`, then a model whose
cameras and poses are the given ones (held fixed), triangulated and refined point-wise. No
incremental mapping, so the given poses and their world frame are kept exactly.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from ..atomic import atomic_dir
from ..geometry.camera import Camera
from ..geometry.sim3 import invert_rigid
from .colmap import (
    SfMConfig,
    SfMError,
    SfMResult,
    _image_size,
    _result_from_reconstruction,
    extract_features,
    match_features,
    write_summary,
)

__all__ = ["colmap_camera_params", "triangulate_known_poses", "with_fixed_intrinsics"]

_OPENCV_KEYS = ("k1", "k2", "p1", "p2")
_FULL_OPENCV_KEYS = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
_FISHEYE_KEYS = ("k1", "k2", "k3", "k4")


def colmap_camera_params(cam: Camera) -> tuple[str, list[float]]:
    """(COLMAP model name, params) for ``cam``: PINHOLE, OPENCV or FULL_OPENCV by which radial-tangential terms
    are non-zero; OPENCV_FISHEYE (fx fy cx cy k1..k4, cv2.fisheye's model) for a fisheye. COLMAP also puts pixel
    centres at +0.5, so K passes through unchanged."""
    if abs(float(cam.K[0, 1])) > 1e-9:
        raise SfMError(f"{cam.name}: skewed intrinsics (K[0,1] != 0) have no COLMAP camera model")
    base = [cam.fx, cam.fy, cam.cx, cam.cy]
    d = {k: float(v) for k, v in (cam.distortion or {}).items() if abs(float(v)) > 0}
    if cam.distortion_model == "fisheye":
        return "OPENCV_FISHEYE", base + [d.get(k, 0.0) for k in _FISHEYE_KEYS]
    try:
        cam.opencv_distortion()  # refuses a lone k4 (nerfstudio's fisheye k1..k4 without the model said)
    except ValueError as e:
        raise SfMError(str(e)) from None
    if not d:
        return "PINHOLE", base
    if set(d) <= set(_OPENCV_KEYS):
        return "OPENCV", base + [d.get(k, 0.0) for k in _OPENCV_KEYS]
    return "FULL_OPENCV", base + [d.get(k, 0.0) for k in _FULL_OPENCV_KEYS]


def with_fixed_intrinsics(config: SfMConfig, camera: Camera) -> SfMConfig:
    """``config`` with ``camera``'s intrinsics (K, distortion) given to COLMAP and held fixed.

    Self-calibration lets the focal length drift by tenths of a percent (fx and fy apart on the
    sample), which shows up as millimetres in every pose; a calibrated camera's K avoids that."""
    model, params = colmap_camera_params(camera)
    return replace(
        config,
        camera_model=model,
        camera_params=params,
        refine_intrinsics=False,
        intrinsics_size=(camera.width, camera.height),
    )


def triangulate_known_poses(
    cameras: Sequence[Camera],
    image_dir: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    config: SfMConfig | None = None,
) -> SfMResult:
    """Triangulate SfM points for ``cameras`` (poses and intrinsics fixed) from their images.

    ``Camera.name`` is the image's path relative to ``image_dir``. Writes the same layout as
    :func:`run_sfm` (``database.db``, ``model/``, ``sfm.json`` with ``"source": "known poses"``),
    atomically; returns the model with the given cameras and the triangulated points (in the
    cameras' world frame).
    """
    import pycolmap

    config = config or SfMConfig()
    config.validate()
    image_dir, out_dir = Path(image_dir).resolve(), Path(out_dir)
    cams = sorted(cameras, key=lambda c: c.name)
    if len(cams) < 2:
        raise SfMError(f"triangulation needs at least 2 posed images, got {len(cams)}")
    by_name = {c.name: c for c in cams}
    if len(by_name) != len(cams):
        raise SfMError("camera names must be distinct (they name the images)")
    missing = [n for n in by_name if not (image_dir / n).is_file()]
    if missing:
        raise SfMError(
            f"{image_dir}: {len(missing)} posed image(s) not found, e.g. {missing[:3]}; "
            "the camera names must be the image paths relative to the image folder"
        )
    for c in cams:
        size = _image_size(image_dir / c.name)
        if size != (c.width, c.height):
            raise SfMError(
                f"{image_dir / c.name}: image is {size[0]}x{size[1]} but its camera says {c.width}x{c.height}"
            )

    log_level = pycolmap.logging.minloglevel
    if not config.verbose:
        pycolmap.logging.minloglevel = 1
    try:
        with atomic_dir(out_dir) as tmp:
            t0 = time.perf_counter()
            db_path = tmp / "database.db"
            names = [c.name for c in cams]
            extract_features(db_path, image_dir, names, config, max(max(c.width, c.height) for c in cams), False)
            matching = match_features(db_path, len(cams), config)
            t_matching = time.perf_counter()

            # A model holding the given cameras and poses, with the database's ids (the
            # triangulator looks correspondences up by them). pycolmap 4 puts poses on frames; each
            # image is its own frame with a trivial rig, so rig_from_world == cam_from_world.
            db = pycolmap.Database.open(str(db_path))
            try:
                rec = pycolmap.Reconstruction()
                db_cams = {c.camera_id: c for c in db.read_all_cameras()}
                images = db.read_all_images()
                for im in images:
                    model, params = colmap_camera_params(by_name[im.name])
                    cam = db_cams[im.camera_id]
                    cam.model = getattr(pycolmap.CameraModelId, model)
                    cam.params = params
                    db.update_camera(cam)
                    rec.add_camera(cam)
                for rig in db.read_all_rigs():
                    rec.add_rig(rig)
                cam_from_world = {}
                for im in images:
                    T_cam_world = invert_rigid(by_name[im.name].T_world_cam)
                    cam_from_world[im.frame_id] = pycolmap.Rigid3d(
                        pycolmap.Rotation3d(T_cam_world[:3, :3]), T_cam_world[:3, 3]
                    )
                frames = db.read_all_frames()
                for fr in frames:
                    fr.rig_from_world = cam_from_world[fr.frame_id]
                    rec.add_frame(fr)
                for im in images:
                    rec.add_image(im)
                for fr in frames:
                    rec.register_frame(fr.frame_id)
            finally:
                db.close()
            model_dir = tmp / "model"
            model_dir.mkdir()
            rec = pycolmap.triangulate_points(rec, db_path, image_dir, model_dir)
            t_tri = time.perf_counter()
            if rec.num_points3D() == 0:
                raise SfMError(
                    f"{image_dir}: no point could be triangulated from the given poses; check that the poses belong "
                    "to these images (same order and frame) and that the views overlap"
                )
            result = _result_from_reconstruction(rec, len(cams), [c.name for c in cams], out_dir / "model")
            # keep the given cameras exactly (COLMAP's round trip is float-exact for K but not for names)
            result.cameras = [by_name[c.name] for c in result.cameras]
            result.seconds = t_tri - t0
            seconds = {"features_matching": t_matching - t0, "triangulation": t_tri - t_matching, "total": t_tri - t0}
            write_summary(tmp, result, image_dir, config, source="known poses", matching_used=matching, seconds=seconds)
    finally:
        pycolmap.logging.minloglevel = log_level
    return result
