"""Per-keyframe object masks behind one interface: ``provider.masks(target, cameras, images)``.

Providers:
- ``GeometricMasks`` (default): the object's cluster in the metric cloud, matted against the table
  in 3D (``matting``), each keyframe's alpha refined to the image edges with GrabCut (alpha > 0.5
  as probable object, a confident core as sure object, far outside as sure background); twice: the
  second matting takes the table the first pass's masks leave bare as seen (``MattingConfig.passes``);
- ``PromptMasks``: a box or points on one keyframe pick the cluster (prompt -> 3D -> every
  keyframe), then as geometric;
- ``FolderMasks``: ``<dir>/<name>/<keyframe stem>.png`` (non-zero = object);
- ``Sam2Masks``: SAM2 with a local checkpoint, prompted in every keyframe with the box of the
  cluster's projection. Nothing is downloaded; without ``sam2`` or the checkpoint it says what to do.

A provider returns ``MaskResult``: masks [H,W] bool per keyframe (None where not seen) and, when it
made them, the matting Gaussians (a good start for the object's 3DGS).
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from ..gaussians.model import Gaussians
from ..geometry.camera import Camera
from .errors import ObjectsError
from .matting import MattingConfig, matte_object, render_alpha
from .support import ObjectCluster, Plane
from .views import crop_camera, object_rois

__all__ = [
    "FolderMasks",
    "GeometricMasks",
    "MaskProvider",
    "MaskResult",
    "Prompt",
    "PromptMasks",
    "Sam2Masks",
    "Target",
    "fill_holes",
    "in_prompt_box",
    "parse_prompt",
    "refine_grabcut",
]


@dataclass
class Target:
    """The object to mask: its name, cluster (metric points) and the support plane; ``hidden``: indices of the
    keyframes in which something stands in front of most of it (the robot at its capture pose), left out of its
    masks; ``unknown``: per keyframe (empty: none), bool [H,W] where something else may cover it (the robot's pixels):
    neither its masks, nor its 3DGS, nor the carving read those pixels."""

    name: str
    cluster: ObjectCluster | None
    plane: Plane | None
    hidden: tuple[int, ...] = ()
    unknown: tuple[np.ndarray | None, ...] = ()


@dataclass
class MaskResult:
    masks: list[np.ndarray | None]
    gaussians: Gaussians | None = None
    info: dict = field(default_factory=dict)


class MaskProvider(Protocol):
    def masks(self, target: Target, cameras: Sequence[Camera], images: Sequence[np.ndarray]) -> MaskResult: ...


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """``mask`` [H,W] bool with enclosed background regions filled."""
    import cv2

    m = np.pad(mask.astype(np.uint8), 1)
    flood = m.copy()
    cv2.floodFill(flood, None, (0, 0), 1)
    return (mask | (flood[1:-1, 1:-1] == 0)).astype(bool)


def refine_grabcut(image_u8: np.ndarray, alpha: np.ndarray, sure: float = 0.8, erode_px: int = 2) -> np.ndarray:
    """GrabCut [h,w] bool on the crop ``image_u8`` [h,w,3] (RGB) seeded by ``alpha`` [h,w]: alpha > 0.5
    probable object, the eroded alpha > ``sure`` sure object, beyond 4 px of alpha > 0.2 sure background.
    The same inputs give the same mask, whatever ran before."""
    import cv2

    if not (alpha > sure).any():
        return fill_holes(alpha > 0.5)
    k = np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)
    tri = np.full(alpha.shape, cv2.GC_PR_BGD, np.uint8)
    tri[alpha > 0.5] = cv2.GC_PR_FGD
    tri[cv2.erode((alpha > sure).astype(np.uint8), k) > 0] = cv2.GC_FGD
    tri[cv2.dilate((alpha > 0.2).astype(np.uint8), np.ones((9, 9), np.uint8)) == 0] = cv2.GC_BGD
    if not (tri == cv2.GC_FGD).any() or not ((tri == cv2.GC_BGD) | (tri == cv2.GC_PR_BGD)).any():
        return fill_holes(alpha > 0.5)
    bgd, fgd = np.zeros((1, 65)), np.zeros((1, 65))
    bgr = np.ascontiguousarray(image_u8[..., ::-1])
    # GrabCut seeds its colour models from OpenCV's global RNG: without a fixed seed a mask depends on
    # whatever drew from it before (up to 112 pixels of a croissant mask moved)
    cv2.setRNGSeed(0)
    cv2.grabCut(bgr, tri, None, bgd, fgd, 5, cv2.GC_INIT_WITH_MASK)
    # GrabCut moves the matte's soft edge to the image's edges; where the 3D matting is sure it
    # does not overrule it (an object the colour of the table loses its lower flanks otherwise)
    return fill_holes((tri == cv2.GC_FGD) | (tri == cv2.GC_PR_FGD) | (alpha > sure))


@dataclass
class GeometricMasks:
    """Matting in 3D + GrabCut (see the module docstring)."""

    matting: MattingConfig = field(default_factory=MattingConfig)
    grabcut: bool = True
    progress: bool = False

    def masks(self, target: Target, cameras: Sequence[Camera], images: Sequence[np.ndarray]) -> MaskResult:
        if target.cluster is None or target.plane is None:
            raise ObjectsError(f"object {target.name!r}: geometric masks need its points in the cloud")
        import cv2

        if self.matting.passes < 1 or self.matting.hidden_margin_px < 0:
            raise ObjectsError(
                f"objects.matting: passes must be >= 1 and hidden_margin_px >= 0, got {self.matting.passes} and "
                f"{self.matting.hidden_margin_px}; fix them in m2m.yaml"
            )
        hidden, seconds, masks = None, 0.0, []
        grow = np.ones((2 * self.matting.hidden_margin_px + 1,) * 2, np.uint8)
        for k in range(self.matting.passes):  # later passes: the table hidden by the last pass's masks only
            if k > 0:
                hidden = [None if m is None else cv2.dilate(m.astype(np.uint8), grow) > 0 for m in masks]
            matte = matte_object(target.cluster, target.plane, cameras, images, self.matting, self.progress, hidden,
                                 target.unknown or None)  # fmt: skip
            masks = self._refined(matte, cameras, images)
            seconds += matte.metrics["seconds"]
        info = {"provider": "geometric", **matte.metrics, "seconds": seconds, "passes": self.matting.passes}
        return MaskResult(masks, matte.gaussians, info)

    def _refined(self, matte, cameras: Sequence[Camera], images: Sequence[np.ndarray]) -> list[np.ndarray | None]:
        masks = list(matte.masks)
        if self.grabcut:
            for i, (x0, y0, x1, y1) in matte.rois.items():
                _, alpha, _ = render_alpha(matte.gaussians, crop_camera(cameras[i], (x0, y0, x1, y1)))
                crop = (np.clip(images[i][y0:y1, x0:x1], 0, 1) * 255).astype(np.uint8)
                m = np.zeros((cameras[i].height, cameras[i].width), bool)
                m[y0:y1, x0:x1] = refine_grabcut(crop, alpha)
                masks[i] = m
        return masks


# ---- prompts ------------------------------------------------------------------------------------
@dataclass
class Prompt:
    """A user prompt on one keyframe: a box (x0, y0, x1, y1) or points [(x, y), ...], pixels."""

    name: str
    frame: str
    box: tuple[float, float, float, float] | None = None
    points: list[tuple[float, float]] | None = None


def parse_prompt(text: str) -> Prompt:
    """``name@frame:box=x0,y0,x1,y1`` or ``name@frame:points=x,y;x,y`` (frame = keyframe file name)."""
    m = re.fullmatch(r"([^@:=]+)@([^:]+):(box|points)=(.+)", text.strip())
    if not m:
        raise ObjectsError(
            f"prompt {text!r}: expected name@frame:box=x0,y0,x1,y1 or name@frame:points=x,y;x,y "
            "(frame = a keyframe file name in <workspace>/capture, pixels)"
        )
    name, frame, kind, values = m.groups()
    try:
        if kind == "box":
            box = tuple(float(v) for v in values.split(","))
            if len(box) != 4 or box[2] <= box[0] or box[3] <= box[1]:
                raise ValueError
            return Prompt(name, frame, box=box)  # type: ignore[arg-type]
        pts = [tuple(float(v) for v in p.split(",")) for p in values.split(";") if p]
        if not pts or any(len(p) != 2 for p in pts):
            raise ValueError
        return Prompt(name, frame, points=pts)  # type: ignore[arg-type]
    except ValueError:
        raise ObjectsError(f"prompt {text!r}: bad {kind} values {values!r}") from None


def _prompt_camera(prompt: Prompt, cameras: Sequence[Camera]) -> Camera:
    by_name = {os.path.basename(c.name): c for c in cameras}
    cam = by_name.get(os.path.basename(prompt.frame)) or by_name.get(Path(prompt.frame).stem + ".jpg")
    if cam is None:
        stems = {Path(n).stem: c for n, c in by_name.items()}
        cam = stems.get(Path(prompt.frame).stem)
    if cam is None:
        raise ObjectsError(f"prompt for {prompt.name!r}: keyframe {prompt.frame!r} is not in the workspace's capture/")
    return cam


def in_prompt_box(prompt: Prompt, cameras: Sequence[Camera], points: np.ndarray) -> np.ndarray:
    """[K] bool: which of ``points`` [K,3] (base frame) project inside the prompt's box in its keyframe (all of them
    for a points prompt)."""
    if prompt.box is None:
        return np.ones(len(points), bool)
    uv, z = _prompt_camera(prompt, cameras).project(points)
    x0, y0, x1, y1 = prompt.box
    return (z > 0) & (uv[:, 0] >= x0) & (uv[:, 0] <= x1) & (uv[:, 1] >= y0) & (uv[:, 1] <= y1)


def cluster_for_prompt(prompt: Prompt, cameras: Sequence[Camera], clusters: Sequence[ObjectCluster]) -> ObjectCluster:
    """The cluster the prompt points at: most projected points inside the box, or nearest (in
    pixels) to the prompt's points, in the prompted keyframe."""
    cam = _prompt_camera(prompt, cameras)
    best, best_score = None, -np.inf
    for c in clusters:
        uv, z = cam.project(c.points)
        uv = uv[z > 0]
        if not len(uv):
            continue
        if prompt.box is not None:
            x0, y0, x1, y1 = prompt.box
            inside = (uv[:, 0] >= x0) & (uv[:, 0] <= x1) & (uv[:, 1] >= y0) & (uv[:, 1] <= y1)
            score = inside.mean() if inside.any() else -np.inf
        else:
            pts = np.asarray(prompt.points, np.float64)
            d = np.linalg.norm(uv[None] - pts[:, None], axis=-1).min(1)  # each prompt point to the cluster
            score = -float(d.max()) if d.max() < 40 else -np.inf
        if score > best_score:
            best, best_score = c, score
    if best is None or not np.isfinite(best_score):
        raise ObjectsError(
            f"prompt for {prompt.name!r} on {prompt.frame}: no object found there (no points of an object on the "
            "table project into the box / near the points); check the frame and the pixel coordinates"
        )
    return best


@dataclass
class PromptMasks(GeometricMasks):
    """Geometric masks of the cluster a prompt picked (``Target.cluster`` is set by the stage)."""


# ---- a folder of masks --------------------------------------------------------------------------
@dataclass
class FolderMasks:
    """``root/<name>/<keyframe stem>.png`` (any image format OpenCV reads; non-zero = object), of the keyframes as
    captured. ``lens``: the keyframes' cameras with their lens when the object steps see them undistorted (the masks
    are undistorted likewise)."""

    root: Path
    min_views: int = 6
    lens: Sequence[Camera] | None = None

    def masks(self, target: Target, cameras: Sequence[Camera], images: Sequence[np.ndarray]) -> MaskResult:
        import cv2

        folder = Path(self.root) / target.name
        if not folder.is_dir():
            raise ObjectsError(f"object {target.name!r}: mask folder {folder} not found (expected <masks>/<name>/)")
        files = {p.stem: p for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg", ".bmp")}
        out: list[np.ndarray | None] = []
        for i, cam in enumerate(cameras):
            path = files.get(Path(cam.name).stem)
            if path is None:
                out.append(None)
                continue
            m = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if m is None:
                raise ObjectsError(f"object {target.name!r}: mask {path} is not a readable image")
            if m.shape != (cam.height, cam.width):
                raise ObjectsError(
                    f"object {target.name!r}: mask {path} is {m.shape[1]}x{m.shape[0]}, its keyframe "
                    f"{cam.width}x{cam.height}"
                )
            mask = m > 0
            if self.lens is not None and self.lens[i].has_distortion:
                from ..gaussians.dataset import undistort_image

                # object where more than half of the pixel's bilinear footprint was
                mask = undistort_image(mask.astype(np.float32)[..., None], self.lens[i], erode_px=0)[0][..., 0] > 0.5
            out.append(mask)
        seen = sum(1 for m in out if m is not None and m.any())
        if seen < self.min_views:
            raise ObjectsError(
                f"object {target.name!r}: {folder} holds non-empty masks for only {seen} keyframe(s) "
                f"(need {self.min_views}); name them like the keyframes (<stem>.png)"
            )
        return MaskResult(out, None, {"provider": "folder", "root": str(folder)})


# ---- SAM2 ---------------------------------------------------------------------------------------
@dataclass
class Sam2Masks:
    """SAM2 image predictor with a local checkpoint, prompted per keyframe by the box of the
    object's projected points (grown by 15%)."""

    checkpoint: Path
    model_config: str = "configs/sam2.1/sam2.1_hiera_s.yaml"
    device: str = "cpu"
    min_views: int = 6

    def _predictor(self):
        try:
            from sam2.build_sam import build_sam2
            from sam2.sam2_image_predictor import SAM2ImagePredictor
        except ImportError as e:
            raise ObjectsError(
                f"SAM2 masks need the sam2 package ({e}); install it (pip install sam2, with a torchvision that "
                "matches torch) or use the default geometric masks / --masks DIR"
            ) from None
        if not Path(self.checkpoint).is_file():
            raise ObjectsError(
                f"SAM2 checkpoint {self.checkpoint} not found; download a SAM2 checkpoint (e.g. sam2.1_hiera_small.pt) "
                "yourself and pass its path with --sam2-checkpoint (nothing is downloaded here)"
            )
        return SAM2ImagePredictor(build_sam2(self.model_config, str(self.checkpoint), device=self.device))

    def masks(self, target: Target, cameras: Sequence[Camera], images: Sequence[np.ndarray]) -> MaskResult:
        if target.cluster is None or target.plane is None:
            raise ObjectsError(f"object {target.name!r}: SAM2 prompts come from its points in the cloud")
        predictor = self._predictor()
        rois = object_rois(cameras, target.cluster, target.plane, margin=0.0)
        out: list[np.ndarray | None] = [None] * len(cameras)
        for i, (x0, y0, x1, y1) in rois.items():
            cx, cy, hw, hh = (x0 + x1) / 2, (y0 + y1) / 2, 0.575 * (x1 - x0), 0.575 * (y1 - y0)
            predictor.set_image((np.clip(images[i], 0, 1) * 255).astype(np.uint8))
            m, scores, _ = predictor.predict(box=np.array([cx - hw, cy - hh, cx + hw, cy + hh]), multimask_output=False)
            out[i] = np.asarray(m[0]) > 0
        if sum(1 for m in out if m is not None and m.any()) < self.min_views:
            raise ObjectsError(f"object {target.name!r}: SAM2 found it in fewer than {self.min_views} keyframes")
        return MaskResult(out, None, {"provider": "sam2", "checkpoint": str(self.checkpoint)})
