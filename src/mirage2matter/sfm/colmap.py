"""Structure from motion with pycolmap (pipeline stage ``sfm``), and pose evaluation.

One shared camera for all images (a single phone / video capture) with the OPENCV model, and
bundle adjustment refines the principal point: a model that pins it at the image centre
(SIMPLE_RADIAL) tilted every fox camera by about 0.5 degrees (FIELD_NOTES.md, pycolmap).

When the camera is self-calibrated, incremental mapping is followed by one more global bundle adjustment
with a robust (Cauchy) loss (:func:`robust_bundle_adjustment`): COLMAP's own global adjustment weighs every
residual squared, and on an orbit the camera's vertical intrinsics (fy, cy) are nearly undetermined (a
principal point lower in the image is almost the same as every camera looking from a little lower), so the
few features that move with the viewpoint (occlusion junctions, highlights) pulled them off: see
``SfMConfig.robust_ba``.

COLMAP and we share conventions (OpenCV axes, pixel centres at +0.5), so intrinsics pass through
as they are and poses only need inverting: COLMAP stores world-to-camera, we keep
camera-to-world. The SfM world frame is kept as COLMAP returns it (arbitrary scale and origin);
align-scene maps it to the robot base later.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_dir
from ..errors import M2MError
from ..geometry.camera import Camera
from ..geometry.rotation import rotation_angle
from ..geometry.umeyama import umeyama

__all__ = ["SfMConfig", "SfMError", "SfMResult", "compare_poses", "load_model_points", "load_observations",
           "load_sfm_summary", "robust_bundle_adjustment", "run_sfm"]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
MIN_IMAGES = 3


class SfMError(M2MError, RuntimeError):
    """SfM that cannot run or did not reconstruct enough; the message says what to do."""


@dataclass
class SfMConfig:
    """pycolmap settings.

    camera_model        COLMAP camera model shared by all images (OPENCV fits phone lenses)
    matching            "sequential" (video order, neighbours within ``overlap``), "exhaustive"
                        (all pairs) or "auto": exhaustive below ``exhaustive_below`` images
    loop_detection      sequential matching also matches visually similar far-apart frames;
                        needs a COLMAP vocabulary tree file (``vocab_tree_path``)
    max_num_features    SIFT features per image
    downscale           features are extracted at this fraction of the image size (keypoints
                        are scaled back, so intrinsics stay in full-resolution pixels)
    refine_principal_point  let bundle adjustment move cx, cy
    camera_params   known intrinsics as COLMAP params of ``camera_model`` (a calibrated camera, see
                    :func:`mirage2matter.sfm.known_poses.with_fixed_intrinsics`); with
                    ``refine_intrinsics=False`` bundle adjustment keeps them fixed;
                    ``intrinsics_size`` (width, height) they are for, checked against the images
    min_registered_fraction  fewer registered images than this fraction is an error
    mapper_attempts  incremental mapping is run again with the next seeds (up to this many runs in all) while
                     its largest model holds fewer than ``retry_below`` of the images; the largest model wins
    robust_ba       a last global bundle adjustment with a Cauchy loss whose scale is the model's median track
                    reprojection error (:func:`robust_bundle_adjustment`): "auto" when the camera is self-calibrated
                    (``refine_intrinsics``), "always", or "never"
    verbose             keep COLMAP's INFO log (thousands of lines); otherwise warnings and up only
    mask_dir        a folder of masks, ``<image name>.png``: no features where a mask is black (the moved robot,
                    sfm.robot_mask); an image without one keeps all its features
    """

    camera_model: str = "OPENCV"
    matching: str = "auto"
    exhaustive_below: int = 40
    overlap: int = 10
    loop_detection: bool = False
    vocab_tree_path: str | None = None
    max_num_features: int = 8192
    downscale: float = 1.0
    refine_principal_point: bool = True
    camera_params: list[float] | None = None
    refine_intrinsics: bool = True
    intrinsics_size: tuple[int, int] | None = None
    min_registered_fraction: float = 0.5
    # The mapper's initial pair and registration order depend on its seed: on 12 keyframes of the sample, 2 of 32
    # (seed, feature run) pairs stopped at 3 images while the others registered all 12; another seed fixes it.
    mapper_attempts: int = 3
    retry_below: float = 0.9
    # Measured with the camera self-calibrated (40 keyframes, cameras vs ground truth after the board alignment,
    # medians): the phone-lens sample (`m2m sample make --lens phone --seed 8`) 4.18 mm / 0.153 deg -> 1.1 mm /
    # 0.15 deg (fy 0.29 % -> 0.03 % off, cy 2.8 -> 1.4 px); the bundled sample 4.71 mm / 0.139 deg -> 1.6 mm / 0.08
    # deg; with the lens known and held fixed 1.56 mm / 0.076 deg -> 0.70 mm / 0.023 deg. More keyframes alone did
    # not help (64: 2.94 mm, 96: 2.67 mm, fy and cy as far off): a bias, not noise. "auto" leaves a run with the
    # intrinsics held fixed (the bundled sample's demo) as it was: there the bias it removes is small already.
    robust_ba: str = "auto"
    # One thread: the whole SfM is reproducible (~1.5x the time of all cores). With more, feature extraction and
    # matching are too (images numbered by name, each pair's RANSAC seeded), but the incremental mapper's threads
    # are not (10 keyframes of the sample, 2 threads: three runs, three models; earlier, 1 in 4 multi-threaded
    # runs of 16 keyframes converged 4 deg off). A known-pose import (no mapper) with 2 threads gave one model in 7
    # runs. -1 = all cores.
    num_threads: int = 1
    seed: int = 0
    verbose: bool = False
    mask_dir: str | None = None

    def validate(self) -> None:
        if not self.refine_intrinsics and self.camera_params is None:
            raise SfMError("sfm config: refine_intrinsics=False needs camera_params (the known intrinsics)")
        if self.matching not in ("sequential", "exhaustive", "auto"):
            raise SfMError(f"sfm config: matching must be sequential, exhaustive or auto, got {self.matching!r}")
        if self.robust_ba not in ("auto", "always", "never"):
            raise SfMError(f"sfm config: robust_ba must be auto, always or never, got {self.robust_ba!r}")
        if not 0 < self.downscale <= 1:
            raise SfMError(f"sfm config: downscale must be in (0, 1], got {self.downscale}")
        if self.loop_detection and not (self.vocab_tree_path and Path(self.vocab_tree_path).is_file()):
            raise SfMError(
                "sfm config: loop_detection needs vocab_tree_path pointing at a COLMAP vocabulary tree file "
                f"(got {self.vocab_tree_path!r}); download one or turn loop_detection off"
            )
        if self.mapper_attempts < 1 or not 0 <= self.retry_below <= 1:
            raise SfMError(f"sfm config: mapper_attempts >= 1 and retry_below in [0, 1], got {self.mapper_attempts}, "
                           f"{self.retry_below}")  # fmt: skip
        if self.overlap < 1 or self.max_num_features < 100:
            raise SfMError(f"sfm config: overlap >= 1 and max_num_features >= 100, got {self.overlap}, "
                           f"{self.max_num_features}")  # fmt: skip


@dataclass(eq=False)
class SfMResult:
    """The largest reconstructed model, in our conventions.

    cameras   registered images, sorted by name; ``Camera.name`` is the file name relative to
              the image folder, ``T_world_cam`` camera-to-world (OpenCV), distortion as
              {k1, k2, p1, p2, ...}
    points    [M, 3] float64 3D points (SfM world frame); colors [M, 3] uint8 RGB
    registered / total   registered images / images given
    """

    cameras: list[Camera]
    points: np.ndarray
    colors: np.ndarray
    registered: int
    total: int
    mean_reprojection_error: float
    model_dir: Path
    seconds: float = 0.0
    unregistered: list[str] = field(default_factory=list)

    @property
    def poses(self) -> dict[str, np.ndarray]:
        """name -> T_world_cam."""
        return {c.name: c.T_world_cam for c in self.cameras}


# ---- conversion ---------------------------------------------------------------------------------
def _camera_from_colmap(image: Any, cam: Any) -> Camera:
    from ..geometry.intrinsics import IntrinsicsFormatError, colmap_lens

    model = cam.model.name if hasattr(cam.model, "name") else str(cam.model)
    try:  # one table of COLMAP's models for cameras.txt and for reconstructions
        K, distortion = colmap_lens(model, [float(v) for v in cam.params], f"COLMAP camera {cam.camera_id}")
    except IntrinsicsFormatError as e:
        raise SfMError(str(e)) from None
    T_cam_world = np.eye(4)
    T_cam_world[:3, :4] = image.cam_from_world().matrix()
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = R.T
    T_world_cam[:3, 3] = -R.T @ t
    return Camera(K, T_world_cam, cam.width, cam.height, image.name, distortion)


def _result_from_reconstruction(rec: Any, total: int, names: list[str], model_dir: Path) -> SfMResult:
    cameras = sorted(
        (_camera_from_colmap(img, rec.cameras[img.camera_id]) for img in rec.images.values() if img.has_pose),
        key=lambda c: c.name,
    )
    pts = list(rec.points3D.values())
    points = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)
    colors = np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3)
    registered = {c.name for c in cameras}
    return SfMResult(
        cameras=cameras,
        points=points,
        colors=colors,
        registered=len(cameras),
        total=total,
        mean_reprojection_error=float(rec.compute_mean_reprojection_error()),
        model_dir=model_dir,
        unregistered=[n for n in names if n not in registered],
    )


# ---- running ------------------------------------------------------------------------------------
def _robust_ba(config: SfMConfig) -> bool:
    """Whether ``config`` asks for the robust global bundle adjustment ("auto": when self-calibrating)."""
    return config.robust_ba == "always" or (config.robust_ba == "auto" and config.refine_intrinsics)


def robust_bundle_adjustment(rec: Any, config: SfMConfig) -> dict[str, Any]:
    """A global bundle adjustment of ``rec`` (in place) with a Cauchy loss, refining what the mapping refined (the
    intrinsics unless held fixed, the principal point per ``config``). The loss scale is the median of the tracks'
    mean reprojection errors: residuals at the model's typical noise keep nearly full weight, a track off by 4x
    that (where a feature slid along an occlusion edge as the camera moved) about 1/17. Returns what it did
    (scale, reprojection before and after, seconds, the intrinsics before)."""
    import pycolmap

    t0 = time.perf_counter()
    errors = np.array([p.error for p in rec.points3D.values()], dtype=np.float64)
    scale = max(0.1, float(np.median(errors))) if len(errors) else 1.0
    before = float(rec.compute_mean_reprojection_error())
    cam_before = [float(v) for v in rec.cameras[next(iter(rec.cameras))].params] if rec.cameras else []
    opts = pycolmap.BundleAdjustmentOptions()
    opts.refine_focal_length = config.refine_intrinsics
    opts.refine_extra_params = config.refine_intrinsics
    opts.refine_principal_point = config.refine_intrinsics and config.refine_principal_point
    opts.print_summary = False
    opts.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    opts.ceres.loss_function_scale = scale
    opts.ceres.solver_options.num_threads = config.num_threads if config.num_threads > 0 else (os.cpu_count() or 1)
    pycolmap.bundle_adjustment(rec, opts)
    return {"loss": "cauchy", "scale_px": scale, "reprojection_before": before,
            "reprojection_after": float(rec.compute_mean_reprojection_error()), "camera_params_before": cam_before,
            "seconds": time.perf_counter() - t0}  # fmt: skip


def extract_features(
    db: Path, image_dir: Path, names: list[str], config: SfMConfig, max_side: int, single_camera: bool
) -> None:
    """SIFT features of ``names`` into database ``db``: one shared camera (``config``'s model and
    params) or one camera per image (intrinsics set by the caller afterwards)."""
    import pycolmap

    pycolmap.set_random_seed(config.seed)  # matching's RANSAC draws from the global generator
    eo = pycolmap.FeatureExtractionOptions()
    eo.num_threads = config.num_threads
    eo.sift.max_num_features = config.max_num_features
    eo.max_image_size = max(16, round(max_side * config.downscale))
    mode = pycolmap.CameraMode.SINGLE if single_camera else pycolmap.CameraMode.PER_IMAGE
    ro = _reader_options(config) if single_camera else pycolmap.ImageReaderOptions()  # pycolmap's default
    if config.mask_dir is not None:
        ro.mask_path = str(config.mask_dir)
    # The images enter the database in name order first: extraction's threads would number them in the order
    # they finish, and matching, triangulation and mapping follow the ids (same input, different points).
    pycolmap.Database.open(str(db)).close()
    pycolmap.import_images(db, image_dir, camera_mode=mode, image_names=sorted(names), options=ro)
    pycolmap.extract_features(
        db,
        image_dir,
        image_names=names,
        camera_mode=mode,
        reader_options=ro,
        extraction_options=eo,
        device=pycolmap.Device.cpu,
    )


def match_features(db: Path, n_images: int, config: SfMConfig) -> str:
    """Exhaustive or sequential matching (``config.matching``, "auto" by image count); returns the one used."""
    import pycolmap

    matching = config.matching
    if matching == "auto":
        matching = "exhaustive" if n_images < config.exhaustive_below else "sequential"
    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = config.num_threads
    vo = pycolmap.TwoViewGeometryOptions()
    if config.num_threads != 1:
        # one thread draws the global generator (seeded by extract_features) in pair order; with more, the
        # threads' order varies, so each pair's RANSAC gets its own generator seeded the same
        vo.ransac.random_seed = config.seed
    if matching == "exhaustive":
        pycolmap.match_exhaustive(db, matching_options=mo, verification_options=vo, device=pycolmap.Device.cpu)
    else:
        po = pycolmap.SequentialPairingOptions()
        po.overlap = config.overlap
        po.loop_detection = config.loop_detection
        if config.loop_detection:
            po.vocab_tree_path = str(config.vocab_tree_path)
        pycolmap.match_sequential(
            db, matching_options=mo, pairing_options=po, verification_options=vo, device=pycolmap.Device.cpu
        )
    return matching


def map_incrementally(db: Path, image_dir: Path, tmp: Path, n_images: int, config: SfMConfig) -> tuple[dict, int]:
    """COLMAP's incremental mapper, run again with seeds ``seed + 1, ...`` (``config.mapper_attempts`` runs at
    most) while its largest model holds fewer than ``config.retry_below`` of the images.

    Returns the models of the run with the largest model, and the number of runs."""
    import pycolmap

    best: dict = {}
    best_count = -1
    for attempt in range(config.mapper_attempts):
        opts = pycolmap.IncrementalPipelineOptions()
        opts.ba_refine_principal_point = config.refine_principal_point and config.refine_intrinsics
        if not config.refine_intrinsics:
            opts.ba_refine_focal_length = False
            opts.ba_refine_extra_params = False
        opts.num_threads = config.num_threads
        opts.random_seed = config.seed + attempt
        out = tmp / "mapper" / str(attempt)
        out.mkdir(parents=True)
        models = pycolmap.incremental_mapping(db, image_dir, out, options=opts)
        count = max((r.num_reg_images() for r in models.values()), default=0)
        if count > best_count:
            best, best_count = models, count
        if best_count >= config.retry_below * n_images:
            break
    return best, attempt + 1


def _reader_options(config: SfMConfig) -> Any:
    import pycolmap

    ro = pycolmap.ImageReaderOptions(camera_model=config.camera_model)
    if config.camera_params is not None:
        ro.camera_params = ",".join(repr(float(v)) for v in config.camera_params)
    return ro


def list_images(image_dir: Path) -> list[str]:
    if not image_dir.is_dir():
        raise SfMError(f"{image_dir}: image folder not found; run the capture stage first")
    names = sorted(p.name for p in image_dir.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if len(names) < MIN_IMAGES:
        raise SfMError(
            f"{image_dir}: {len(names)} image(s); SfM needs at least {MIN_IMAGES} overlapping views "
            "(capture more keyframes)"
        )
    return names


def _image_size(path: Path) -> tuple[int, int]:
    from PIL import Image  # reads only the header

    try:
        with Image.open(path) as im:
            return im.size
    except Exception as e:
        raise SfMError(f"{path}: not a readable image ({e}); remove or replace it") from None


def run_sfm(
    image_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str], config: SfMConfig | None = None
) -> SfMResult:
    """Features, matching and incremental mapping on every image in ``image_dir``.

    Writes ``out_dir/database.db``, ``out_dir/model/`` (the largest COLMAP model, binary) and
    ``out_dir/sfm.json`` (config, counts, timings, reprojection error, cameras in our
    conventions). ``out_dir`` is built under a temporary name and renamed only on success.

    Raises SfMError when fewer than ``min_registered_fraction`` of the images register, or
    when the images are unusable (too few, different sizes, unreadable).
    """
    import pycolmap

    config = config or SfMConfig()
    config.validate()
    image_dir, out_dir = Path(image_dir).resolve(), Path(out_dir)
    names = list_images(image_dir)
    sizes = {n: _image_size(image_dir / n) for n in names}
    width, height = sizes[names[0]]
    odd = [n for n in names if sizes[n] != (width, height)]
    if odd:
        raise SfMError(
            f"{image_dir}: images have different sizes ({names[0]} is {width}x{height}, {odd[0]} is "
            f"{sizes[odd[0]][0]}x{sizes[odd[0]][1]}); SfM assumes one camera, so resize them to one size"
        )

    if config.intrinsics_size is not None and tuple(config.intrinsics_size) != (width, height):
        raise SfMError(
            f"{image_dir}: images are {width}x{height} but the given intrinsics are for "
            f"{config.intrinsics_size[0]}x{config.intrinsics_size[1]}; pass intrinsics for this image size"
        )

    log_level = pycolmap.logging.minloglevel
    if not config.verbose:
        pycolmap.logging.minloglevel = 1  # glog WARNING
    try:
        with atomic_dir(out_dir) as tmp:
            t0 = time.perf_counter()
            db = tmp / "database.db"
            extract_features(db, image_dir, names, config, max(width, height), single_camera=True)
            t_features = time.perf_counter()
            matching = match_features(db, len(names), config)
            t_matching = time.perf_counter()

            models, attempts = map_incrementally(db, image_dir, tmp, len(names), config)
            t_mapping = time.perf_counter()
            if not models:
                raise SfMError(
                    f"{image_dir}: SfM found no initial image pair ({len(names)} images); capture more parallax "
                    "(move the camera, do not only rotate it) and more texture"
                )
            rec = max(models.values(), key=lambda r: r.num_reg_images())
            robust = robust_bundle_adjustment(rec, config) if _robust_ba(config) else None
            t_refined = time.perf_counter()
            model_dir = tmp / "model"
            model_dir.mkdir()
            rec.write(model_dir)
            shutil.rmtree(tmp / "mapper", ignore_errors=True)  # all models; the largest is in model/

            result = _result_from_reconstruction(rec, len(names), names, out_dir / "model")
            result.seconds = t_refined - t0
            if result.registered < config.min_registered_fraction * len(names):
                raise SfMError(
                    f"{image_dir}: SfM registered only {result.registered} of {len(names)} images (need "
                    f"{config.min_registered_fraction:.0%}); capture more parallax / texture (walk around the scene, "
                    "avoid blur and blank surfaces) or use exhaustive matching"
                )
            seconds = {
                "features": t_features - t0,
                "matching": t_matching - t_features,
                "mapping": t_mapping - t_matching,
                "robust_ba": t_refined - t_mapping,
                "total": t_refined - t0,
            }
            write_summary(tmp, result, image_dir, config, matching_used=matching, models_found=len(models),
                          mapper_attempts=attempts, seconds=seconds, robust_ba=robust)  # fmt: skip
    finally:
        pycolmap.logging.minloglevel = log_level
    return result


def write_summary(folder: Path, result: SfMResult, image_dir: Path, config: SfMConfig, **extra: Any) -> None:
    """``folder/sfm.json``: what every way of getting poses records (counts, reprojection error, the
    cameras in our conventions) plus ``extra`` (source, timings, ...); read by :func:`load_sfm_summary`."""
    summary = {
        **{k: v for k, v in extra.items() if k == "source"},
        "image_dir": str(image_dir),
        "config": asdict(config),
        "registered": result.registered,
        "total": result.total,
        "unregistered": result.unregistered,
        "num_points": int(len(result.points)),
        "mean_reprojection_error": result.mean_reprojection_error,
        **{k: v for k, v in extra.items() if k != "source"},
        "cameras": [c.to_json() for c in result.cameras],
    }
    with open(folder / "sfm.json", "w", encoding="utf-8") as f:
        json.dump(summary, f, indent=1)
        f.write("\n")


def load_sfm_summary(out_dir: str | os.PathLike[str]) -> tuple[dict[str, Any], list[Camera]]:
    """``sfm.json`` written by ``run_sfm`` and its cameras (our conventions)."""
    path = Path(out_dir) / "sfm.json"
    if not path.is_file():
        raise SfMError(f"{path}: not found; run the sfm stage first")
    with open(path, encoding="utf-8") as f:
        summary = json.load(f)
    cams = [Camera.from_json(c, source=f"{path}: camera {i}") for i, c in enumerate(summary["cameras"])]
    return summary, cams


def load_model_points(model_dir: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """The SfM model's 3D points in its own frame: ``(xyz [N,3] float64, rgb [N,3] uint8)``."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(model_dir))
    pts = list(rec.points3D.values())
    xyz = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3)
    return xyz, rgb


def load_observations(model_dir: str | os.PathLike[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per registered image (by name): where it saw the model's 3D points and which: ``(xy [K,2] pixels, COLMAP's
    convention: pixel centres at +0.5, as ours; xyz [K,3] in the model's frame)``, one row per observation."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(model_dir))
    out = {}
    for image in rec.images.values():
        seen = [p for p in image.points2D if p.has_point3D()]
        xy = np.array([p.xy for p in seen], np.float64).reshape(-1, 2)
        xyz = np.array([rec.points3D[p.point3D_id].xyz for p in seen], np.float64).reshape(-1, 3)
        out[image.name] = (xy, xyz)
    return out


# ---- evaluation ---------------------------------------------------------------------------------
def compare_poses(estimated: dict[str, np.ndarray], reference: dict[str, np.ndarray]) -> dict[str, Any]:
    """Compare camera-to-world poses up to a similarity (SfM has no scale or origin of its own).

    Fits ``sim3_est_to_ref`` by Umeyama on the camera centres of the names both hold, applies it
    to the estimated poses and reports, in degrees, the rotation difference of each camera
    (angle of ``R_ref^T R_aligned``), and the centre difference as a fraction of the mean
    distance of the reference cameras from their centroid (a scale-free "scene extent").
    """
    common = sorted(set(estimated) & set(reference))
    if len(common) < 3:
        raise ValueError(f"compare_poses: need >= 3 cameras in common, got {len(common)}")
    T_est = np.stack([np.asarray(estimated[n], dtype=np.float64) for n in common])
    T_ref = np.stack([np.asarray(reference[n], dtype=np.float64) for n in common])
    sim = umeyama(T_est[:, :3, 3], T_ref[:, :3, 3])
    T_aligned = sim.apply_pose(T_est)
    rot_err = np.degrees(rotation_angle(np.swapaxes(T_ref[:, :3, :3], 1, 2) @ T_aligned[:, :3, :3]))
    c_ref = T_ref[:, :3, 3]
    extent = float(np.linalg.norm(c_ref - c_ref.mean(0), axis=1).mean())
    ctr_err = np.linalg.norm(T_aligned[:, :3, 3] - c_ref, axis=1) / extent
    return {
        "n": len(common),
        "rotation_deg_median": float(np.median(rot_err)),
        "rotation_deg_max": float(rot_err.max()),
        "center_frac_median": float(np.median(ctr_err)),
        "center_frac_max": float(ctr_err.max()),
        "extent": extent,
        "sim3_est_to_ref": sim.to_json(),
        "per_camera": {
            n: {"rotation_deg": float(r), "center_frac": float(c)}
            for n, r, c in zip(common, rot_err, ctr_err, strict=True)
        },  # fmt: skip
    }
