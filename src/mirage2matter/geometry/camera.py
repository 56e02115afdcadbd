"""Pinhole cameras in the OpenCV / gsplat convention, and importers that convert at the border.

A camera is ``K`` (3x3, pixels) and ``T_world_cam`` (4x4, camera-to-world), axes x right,
y down, z forward (DESIGN.md section 1). Pixel centres sit at +0.5: the top-left pixel covers
[0, 1) x [0, 1) and its centre is (0.5, 0.5), as in gsplat and COLMAP. (OpenCV's own functions put
centres at integer coordinates; shift cx, cy by -0.5 when handing K to them.)

Importers: instant-ngp / nerfstudio ``transforms.json``, whose camera-to-world matrices use the
OpenGL convention (x right, y up, z backward); they are converted once, here.

Geometry is the bottom of the stack: this module imports nothing else from mirage2matter but ``errors`` and
``inputs`` (the file readers and value checks every command shares).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import posixpath
import secrets
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import M2MError
from ..inputs import InputError, check_image_size, check_intrinsics, read_json
from .distortion import FISHEYE_KEYS, MODELS, RADTAN_KEYS, distort, fisheye_theta, undistort
from .sim3 import invert_rigid

__all__ = [
    "Camera",
    "CameraFormatError",
    "GL_TO_CV",
    "camera_from_transforms_frame",
    "load_camera_json",
    "implausible_intrinsics",
    "load_intrinsics",
    "load_transforms_json",
    "look_at",
    "save_camera_json",
]

# Right-multiplying a camera-to-world pose by this flips its camera y and z axes:
# OpenGL (x right, y up, z backward) <-> OpenCV (x right, y down, z forward). Self-inverse.
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])

RIGID_TOL = 1e-4  # accepted deviation of the last row from 0 0 0 1
ORTHO_REPAIR_TOL = 1e-3  # max |R^T R - I| that is re-orthonormalised rather than rejected
_DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2")
_INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y", *_DISTORTION_KEYS)


class CameraFormatError(M2MError, ValueError):
    """Invalid camera data; the message names the source (file, frame) and the field."""


# ---- validation ---------------------------------------------------------------------------------
def _matrix(value: Any, shape: tuple[int, int], where: str, name: str) -> np.ndarray:
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise CameraFormatError(f"{where}: {name} must be a {shape[0]}x{shape[1]} matrix of numbers ({e})") from e
    if a.shape != shape:
        raise CameraFormatError(f"{where}: {name} must have shape {shape}, got {a.shape}")
    if not np.isfinite(a).all():
        raise CameraFormatError(f"{where}: {name} holds NaN/Inf")
    return a


def _check_K(value: Any, where: str) -> np.ndarray:
    K = _matrix(value, (3, 3), where, "K")
    try:
        return check_intrinsics(K, where)
    except InputError as e:
        raise CameraFormatError(str(e)) from None


def _check_rigid(value: Any, where: str, name: str = "T_world_cam") -> np.ndarray:
    """Validate a 4x4 rigid transform; near-orthonormal rotations are projected onto SO(3) by SVD."""
    T = _matrix(value, (4, 4), where, name)
    if np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > RIGID_TOL:
        raise CameraFormatError(f"{where}: {name}: last row must be 0 0 0 1, got {T[3].tolist()}")
    R = T[:3, :3]
    det = float(np.linalg.det(R))
    if det <= 0:
        raise CameraFormatError(
            f"{where}: {name}: rotation has determinant {det:.3g}, a reflection rather than a rotation "
            "(a mixed-up axis convention?)"
        )
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > ORTHO_REPAIR_TOL:
        raise CameraFormatError(
            f"{where}: {name}: rotation is not orthonormal (max |R^T R - I| = {err:.2g} > {ORTHO_REPAIR_TOL:g}; "
            "scaled or sheared poses are not camera poses)"
        )
    out = np.eye(4)
    out[:3, 3] = T[:3, 3]
    if err > 1e-12:
        # Exporters (nerfstudio, instant-ngp) round poses; snap to the nearest rotation so that the
        # rigid inverse in ``viewmat`` is exact.
        u, _, vt = np.linalg.svd(R)
        out[:3, :3] = u @ vt
    else:
        out[:3, :3] = R
    return out


def _check_size(value: Any, where: str, name: str) -> int:
    try:
        return check_image_size(value, where, name)
    except InputError as e:
        raise CameraFormatError(str(e)) from None


def _check_lens(model: str, distortion: Any, where: str) -> tuple[str, dict[str, float]]:
    """(model, {name: coefficient}) from a model name and a distortion mapping that may carry its own "model"."""
    if not isinstance(distortion, dict):
        raise CameraFormatError(f"{where}: distortion must map coefficient names to numbers, got {distortion!r}")
    d = dict(distortion)
    inner = d.pop("model", "")
    if inner and model and str(inner) != model:
        raise CameraFormatError(f"{where}: distortion model {inner!r} contradicts {model!r}")
    model = str(model or inner or "opencv")
    if model not in MODELS:
        raise CameraFormatError(
            f"{where}: distortion model {model!r} is not supported (known: {', '.join(MODELS)}: "
            "radial-tangential or equidistant fisheye); undistort the images beforehand"
        )
    keys = FISHEYE_KEYS if model == "fisheye" else RADTAN_KEYS
    unknown = sorted(set(d) - set(keys))
    if unknown:
        raise CameraFormatError(f"{where}: distortion terms {unknown} are not in the {model} model "
                                f"({', '.join(keys)})")  # fmt: skip
    out = {}
    for k, v in d.items():
        if not _is_number(v):
            raise CameraFormatError(f"{where}: distortion {k} must be a finite number, got {v!r}")
        out[str(k)] = float(v)
    return model, out


# ---- the camera ---------------------------------------------------------------------------------
@dataclass(eq=False)
class Camera:
    """A pinhole camera with an optional lens model, OpenCV axes, pixel centres at +0.5.

    K                 [3, 3] float64 intrinsics [[fx, s, cx], [0, fy, cy], [0, 0, 1]] in pixels
    T_world_cam       [4, 4] float64 camera-to-world rigid transform
    width, height     image size in pixels
    distortion        lens coefficients by name: "opencv" k1 k2 p1 p2 k3 [k4 k5 k6]; "fisheye" k1..k4
    distortion_model  "opencv" (radial-tangential, the default) or "fisheye" (equidistant, cv2.fisheye); "" reads
                      a "model" entry of ``distortion`` (as our JSON writes it), else "opencv"

    The renderers are pinholes: stages take the lens out (``undistort_pixels``, gaussians' ``undistort_image``),
    and the frames a world is observed in put it back (``env.lens``, ``render.lens``).
    Copy a camera with ``dataclasses.replace`` (keeps the lens model), not by re-listing the fields.
    """

    K: np.ndarray
    T_world_cam: np.ndarray
    width: int
    height: int
    name: str = ""
    distortion: dict[str, float] = field(default_factory=dict)
    distortion_model: str = ""

    def __post_init__(self) -> None:
        where = f"Camera {self.name!r}" if self.name else "Camera"
        self.K = _check_K(self.K, where)
        self.T_world_cam = _check_rigid(self.T_world_cam, where)
        self.width = _check_size(self.width, where, "width")
        self.height = _check_size(self.height, where, "height")
        self.distortion_model, self.distortion = _check_lens(self.distortion_model, self.distortion, where)

    # ---- derived -------------------------------------------------------------------------------
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def viewmat(self) -> np.ndarray:
        """World-to-camera [4, 4]: the rigid inverse [R^T, -R^T t] of ``T_world_cam``."""
        return invert_rigid(self.T_world_cam)

    @property
    def K_opencv(self) -> np.ndarray:
        """K for OpenCV calls (see :func:`opencv_K`)."""
        return opencv_K(self.K)

    def opencv_distortion(self) -> np.ndarray | None:
        """OpenCV's (k1, k2, p1, p2, k3), or with the rational terms (..., k4, k5, k6), for cv2 calls on this
        radial-tangential lens; None when all are zero. A fisheye lens is CameraFormatError (cv2 would read its
        k1..k4 as k1 k2 p1 p2): use ``fisheye_distortion`` with cv2.fisheye, or ``undistort_pixels``. So is a k4
        without k5 / k6, which reads like nerfstudio's fisheye k1..k4."""
        where = self.name or "camera"
        if self.distortion_model == "fisheye":
            raise CameraFormatError(
                f"{where}: a fisheye lens has no radial-tangential coefficients; use "
                "Camera.undistort_pixels / distort_pixels (or fisheye_distortion with cv2.fisheye)"
            )
        d = self.distortion
        rational = "k5" in d or "k6" in d
        if abs(d.get("k4", 0.0)) > 0 and not rational:
            raise CameraFormatError(
                f"{where}: distortion has k4 but no k5 / k6: a fisheye lens (k1..k4)? Say so with distortion model "
                '"fisheye"; for OpenCV\'s rational model give k5 and k6 (0 if unused)'
            )
        keys = RADTAN_KEYS[: 8 if rational else 5]
        coeffs = np.array([d.get(k, 0.0) for k in keys])
        return coeffs if np.any(coeffs) else None

    def fisheye_distortion(self) -> np.ndarray | None:
        """cv2.fisheye's (k1, k2, k3, k4) of this equidistant lens; None when all are zero."""
        if self.distortion_model != "fisheye":
            raise CameraFormatError(f"{self.name or 'camera'}: not a fisheye lens (model {self.distortion_model!r})")
        coeffs = np.array([self.distortion.get(k, 0.0) for k in FISHEYE_KEYS])
        return coeffs if np.any(coeffs) else None

    def _lens(self) -> np.ndarray | None:
        return self.fisheye_distortion() if self.distortion_model == "fisheye" else self.opencv_distortion()

    @property
    def has_distortion(self) -> bool:
        """False for a pure pinhole (no coefficients, or all zero). Fisheye with zero k1..k4 is still not a
        pinhole (theta_d = theta), so it counts as distorted."""
        return self.distortion_model == "fisheye" or self._lens() is not None

    def _normalised(self, uv: np.ndarray) -> np.ndarray:
        """Pixels [N, 2] (ours) -> normalised coordinates [N, 2] through K (skew included)."""
        y = (uv[:, 1] - self.cy) / self.fy
        return np.c_[(uv[:, 0] - self.cx - self.K[0, 1] * y) / self.fx, y]

    def _pixels(self, xy: np.ndarray) -> np.ndarray:
        return np.c_[self.fx * xy[:, 0] + self.K[0, 1] * xy[:, 1] + self.cx, self.fy * xy[:, 1] + self.cy]

    def undistort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Measured pixels [N, 2] -> where an ideal pinhole with the same K sees the same rays [N, 2] (both in our
        +0.5 convention). Iterative, to ~1e-9 px over the image, corners included. Fisheye rays 90 deg or more
        off the axis have no pinhole pixel: NaN."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if not self.has_distortion or not len(uv):
            return uv.copy()
        coeffs = self._lens()
        return self._pixels(undistort(self.distortion_model, np.zeros(4) if coeffs is None else coeffs,
                                      self._normalised(uv)))  # fmt: skip

    def distort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Ideal pinhole pixels [N, 2] -> where this lens images the same rays [N, 2] (our +0.5 convention)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if not self.has_distortion or not len(uv):
            return uv.copy()
        coeffs = self._lens()
        return self._pixels(distort(self.distortion_model, np.zeros(4) if coeffs is None else coeffs,
                                    self._normalised(uv)))  # fmt: skip

    def pixel_rays(self, uv: np.ndarray) -> np.ndarray:
        """Pixels [N, 2] (ours) -> unit ray directions [N, 3] in the camera frame (z forward), through the lens;
        a fisheye's rays beyond 90 deg from the axis included (NaN past the lens polynomial's fold)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if self.distortion_model != "fisheye":
            rays = np.c_[self._normalised(self.undistort_pixels(uv)), np.ones(len(uv))]
            return rays / np.linalg.norm(rays, axis=1, keepdims=True)
        xy_d = self._normalised(uv)
        theta_d = np.hypot(xy_d[:, 0], xy_d[:, 1])
        coeffs = self.fisheye_distortion()
        theta = fisheye_theta(np.zeros(4) if coeffs is None else coeffs, theta_d)
        s = np.sin(theta) * np.where(theta_d > 1e-300, 1.0 / np.maximum(theta_d, 1e-300), 0.0)
        return np.c_[xy_d * s[:, None], np.cos(theta)]

    def distortion_json(self) -> dict[str, Any]:
        """The lens as our JSON writes it: the coefficients, plus ``"model": "fisheye"`` for a fisheye (a dict
        without a model is radial-tangential). Writers that store ``distortion`` should store this."""
        out: dict[str, Any] = dict(self.distortion)
        if self.distortion_model == "fisheye":
            out = {"model": "fisheye", **out}
        return out

    def check_image_size(self, width: int, height: int, where: str) -> None:
        """CameraFormatError when an image of ``width`` x ``height`` is not this camera's size."""
        if (int(width), int(height)) != (self.width, self.height):
            raise CameraFormatError(f"{where} is {width}x{height} but the intrinsics are for {self.width}x"
                                    f"{self.height}; give the intrinsics of the images' own resolution")  # fmt: skip

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates [3]."""
        return self.T_world_cam[:3, 3].copy()

    def project(self, points_world: np.ndarray, distort: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """points_world [N, 3] -> pixel uv [N, 2], depth z [N]. Pinhole by default (the renderer's model);
        ``distort=True`` applies the lens, giving where the real camera images the points.

        Points behind the camera (z <= 0) get meaningless uv; check ``depth > 0``.
        """
        p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        vm = self.viewmat
        pc = p @ vm[:3, :3].T + vm[:3, 3]
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uvw = pc @ self.K.T
            uv = uvw[:, :2] / z[:, None]
        if distort and self.has_distortion:
            front = z > 0
            uv[front] = self.distort_pixels(uv[front])
        return uv, z

    def scaled(self, factor: float) -> Camera:
        """The same camera for images resized by ``factor`` (0.5 = half resolution).

        With pixel centres at +0.5, pixel *edges* sit at integer coordinates and scale exactly,
        so fx, fy, cx, cy (and skew) are simply multiplied by ``factor``.
        """
        if not factor > 0:
            raise ValueError(f"scale factor must be positive, got {factor}")
        w, h = round(self.width * factor), round(self.height * factor)
        if w < 1 or h < 1:
            raise ValueError(f"scaling {self.width}x{self.height} by {factor} leaves no pixels")
        K = np.diag([factor, factor, 1.0]) @ self.K
        return dataclasses.replace(self, K=K, T_world_cam=self.T_world_cam.copy(), width=w, height=h,
                                   distortion=dict(self.distortion))  # fmt: skip

    # ---- serialisation -------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """``{"width", "height", "K" (3x3), "T_world_cam" (4x4)}`` plus name / distortion when set."""
        out: dict[str, Any] = {
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "T_world_cam": self.T_world_cam.tolist(),
        }
        if self.name:
            out["name"] = self.name
        if self.distortion or self.distortion_model == "fisheye":
            out["distortion"] = self.distortion_json()
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any], source: str = "camera JSON") -> Camera:
        """Inverse of ``to_json``; ``source`` (e.g. the file) prefixes error messages."""
        if not isinstance(data, dict):
            raise CameraFormatError(f"{source}: expected a JSON object, got {type(data).__name__}")
        missing = [k for k in ("width", "height", "K", "T_world_cam") if k not in data]
        if missing:
            raise CameraFormatError(f"{source}: missing field(s) {', '.join(missing)}")
        name = data.get("name", "")
        distortion = data.get("distortion", {})
        if not isinstance(name, str):
            raise CameraFormatError(f"{source}: name must be a string, got {name!r}")
        if not isinstance(distortion, dict) or not all(_is_number(v) for k, v in distortion.items() if k != "model"):
            raise CameraFormatError(f"{source}: distortion must map names to numbers (and \"model\" to "
                                    f"\"opencv\" or \"fisheye\"), got {distortion!r}")  # fmt: skip
        model = data.get("distortion_model", "")
        if not isinstance(model, str):
            raise CameraFormatError(f'{source}: distortion_model must be "opencv" or "fisheye", got {model!r}')
        _, _ = _check_lens(model, distortion, source)  # the file's name in the message
        return cls(
            _check_K(data["K"], source),
            _check_rigid(data["T_world_cam"], source),
            _check_size(data["width"], source, "width"),
            _check_size(data["height"], source, "height"),
            name,
            distortion,
            model,
        )


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def opencv_K(K: np.ndarray) -> np.ndarray:
    """K [3,3] with OpenCV's pixel-centre convention: OpenCV puts pixel centres at integers, we
    (like gsplat and COLMAP) at +0.5, so cx and cy move by -0.5. Forgetting it drifts results by
    half a pixel."""
    K_cv = np.asarray(K, dtype=np.float64).copy()
    K_cv[:2, 2] -= 0.5
    return K_cv


def look_at_pose(eye: np.ndarray, target: np.ndarray, up: np.ndarray = (0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_cam [4,4] of a camera at ``eye`` looking at ``target``, OpenCV axes (x right, y down,
    z forward); image "up" follows world ``up``."""
    eye = np.asarray(eye, dtype=np.float64).reshape(3)
    target = np.asarray(target, dtype=np.float64).reshape(3)
    up = np.asarray(up, dtype=np.float64).reshape(3)
    z = target - eye
    if np.linalg.norm(z) < 1e-12:
        raise ValueError("look_at: eye and target coincide")
    z /= np.linalg.norm(z)
    x = np.cross(z, up)  # forward x up = right (image x)
    if np.linalg.norm(x) < 1e-9 * max(np.linalg.norm(up), 1e-300):
        raise ValueError("look_at: up is parallel to the viewing direction (or zero)")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # image y points down, i.e. against world up
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def look_at(
    eye: np.ndarray,
    target: np.ndarray,
    up: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    name: str = "",
) -> Camera:
    """A camera at ``eye`` looking at ``target``; image "up" follows world ``up`` (OpenCV axes)."""
    return Camera(K, look_at_pose(eye, target, up), width, height, name)


# ---- camera JSON files --------------------------------------------------------------------------
def _read_json(path: Path) -> Any:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        return read_json(path, "camera file", expect=None)
    except InputError as e:
        raise CameraFormatError(str(e)) from None


def load_camera_json(path: str | os.PathLike[str]) -> Camera:
    """Read a camera written by ``save_camera_json``."""
    path = Path(path)
    return Camera.from_json(_read_json(path), source=str(path))


def load_intrinsics(
    path: str | os.PathLike[str],
    keys: tuple[str, ...] = ("camera", "head_camera"),
    size: tuple[int, int] | None = None,
) -> Camera:
    """A camera's intrinsics (pose: identity) from any file :mod:`.intrinsics` reads: ours (``K``, ``width``,
    ``height``, ``distortion`` [with ``"model": "fisheye"``], at the top level or under one of ``keys``: a sample's
    ground_truth.json holds the video camera under "camera", the head camera under "head_camera"), OpenCV's
    calibration output, ROS camera_info, COLMAP cameras.txt (``size`` = (width, height) picks one of several) or
    RealSense intrinsics, converted to pixel centres at +0.5. CameraFormatError names the file and the field."""
    from .intrinsics import IntrinsicsFormatError, read_intrinsics

    path = Path(path)
    try:
        data = read_intrinsics(path, keys, size)
    except IntrinsicsFormatError as e:
        raise CameraFormatError(str(e)) from None
    K = np.asarray(data["K"], dtype=np.float64).tolist()
    cam = Camera.from_json({"K": K, "width": data["width"], "height": data["height"], "T_world_cam": np.eye(4).tolist(),
                            "distortion": data.get("distortion") or {}}, source=str(path))  # fmt: skip
    try:
        cam.has_distortion  # noqa: B018  (a lens this model cannot take is an error now, not in a later stage)
    except CameraFormatError as e:
        raise CameraFormatError(f"{path}: {e}") from None
    problem = implausible_intrinsics(cam)
    if problem is not None:  # caught here, not as SfM's "no initial pair ... more parallax" blaming the capture
        raise CameraFormatError(f"{path}: {problem}; check the calibration (`m2m intrinsics {path}` shows how it "
                                "reads)")  # fmt: skip
    return cam


FOV_DEG = (1.0, 170.0)  # a pinhole's horizontal field of view: from a long telephoto to an ultra-wide
FISHEYE_FOV_DEG = 240.0  # an equidistant lens's widest
MAX_PIXEL_ASPECT = 2.0  # fx / fy: square pixels are 1; anamorphic lenses reach 1.33-2


def implausible_intrinsics(cam: Camera) -> str | None:
    """What makes ``cam``'s intrinsics unlike a real camera's, worded for the user (None: plausible): the principal
    point outside the image, a field of view outside :data:`FOV_DEG` (a fisheye's up to :data:`FISHEYE_FOV_DEG`), fx
    and fy more than :data:`MAX_PIXEL_ASPECT` apart, or a lens whose radial distortion turns back before the image's
    corners (two radii on one pixel: no model can undistort that)."""
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
    w, h, fisheye = cam.width, cam.height, cam.distortion_model == "fisheye"
    if not (0 < cx < w and 0 < cy < h):
        return f"the principal point ({cx:g}, {cy:g}) lies outside the {w}x{h} image"
    if not 1 / MAX_PIXEL_ASPECT <= fx / fy <= MAX_PIXEL_ASPECT:
        return f"fx / fy = {fx / fy:.3g} (fx {fx:g}, fy {fy:g}); a camera's pixels are near square (1)"
    fov = np.degrees(w / fx if fisheye else 2 * np.arctan(w / (2 * fx)))
    widest = FISHEYE_FOV_DEG if fisheye else FOV_DEG[1]
    if not FOV_DEG[0] <= fov <= widest:
        return f"fx {fx:g} gives a {fov:.3g} deg field of view over {w} px; a camera sees {FOV_DEG[0]:g}-{widest:g} deg"
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], dtype=np.float64)
    r_max = 1.1 * float(np.hypot((corners[:, 0] - cx) / fx, (corners[:, 1] - cy) / fy).max())
    d = {k: float(cam.distortion.get(k, 0.0)) for k in _DISTORTION_KEYS}
    r = np.linspace(0.0, r_max, 512)
    if fisheye:  # equidistant: theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8), theta up to the corners'
        radial = r * (1 + d["k1"] * r**2 + d["k2"] * r**4 + d["k3"] * r**6 + d["k4"] * r**8)
    else:
        radial = r * (1 + d["k1"] * r**2 + d["k2"] * r**4 + d["k3"] * r**6) / (1 + d["k4"] * r**2 + d["k5"] * r**4
                                                                               + d["k6"] * r**6)  # fmt: skip
    turn = np.nonzero(np.diff(radial) <= 0)[0]
    if len(turn):
        where = r[turn[0]] / r_max * 1.1
        return (f"its distortion ({', '.join(f'{k} {v:g}' for k, v in d.items() if v)}) turns back at {where:.0%} of "
                "the way to the image corners: the lens model cannot map those pixels one to one")
    return None


def save_camera_json(path: str | os.PathLike[str], cam: Camera) -> None:
    """Write ``cam.to_json()`` atomically (temporary file in the same directory, then rename)."""
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: directory {path.parent} does not exist")
    # A local temp+rename instead of mirage2matter.atomic: geometry imports nothing of ours but errors and inputs.
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(cam.to_json(), f, indent=2)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


# ---- instant-ngp / nerfstudio transforms.json ---------------------------------------------------
def _read_transforms(path: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    meta = _read_json(path)
    if not isinstance(meta, dict):
        raise CameraFormatError(f"{path}: expected a JSON object at the top level")
    frames = meta.get("frames")
    if not isinstance(frames, list):
        raise CameraFormatError(f"{path}: frames: missing or not a list")
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict) or not isinstance(fr.get("file_path"), str):
            raise CameraFormatError(f"{path}: frames[{i}]: file_path: missing or not a string")
    return meta, frames


def _image_size(root: Path, file_path: str) -> tuple[int, int] | None:
    """(width, height) from the image header, for files (NeRF synthetic) that omit w / h."""
    candidate = root / file_path
    options = [candidate] if candidate.suffix else [candidate.with_suffix(s) for s in (".png", ".jpg", ".jpeg")]
    for p in options:
        if p.is_file():
            try:
                from PIL import Image

                with Image.open(p) as im:
                    return im.size
            except Exception:
                return None
    return None


def _frame_camera(path: Path, meta: dict[str, Any], index: int, frame: dict[str, Any]) -> Camera:
    file_path = frame["file_path"]
    where = f"{path}: frames[{index}] ({file_path!r})"
    # Per-frame intrinsics (nerfstudio multi-camera captures) override the top-level ones.
    params = {k: meta[k] for k in _INTRINSIC_KEYS if k in meta}
    params.update({k: frame[k] for k in _INTRINSIC_KEYS if k in frame})
    for k, v in params.items():
        if not _is_number(v):
            raise CameraFormatError(f"{where}: {k} must be a finite number, got {v!r}")

    if "w" in params and "h" in params:
        w = _check_size(params["w"], where, "w")
        h = _check_size(params["h"], where, "h")
    else:
        size = _image_size(path.parent, file_path)
        if size is None:
            raise CameraFormatError(f"{where}: w / h missing (top level or per frame) and the image was not found")
        w, h = size

    def focal(key: str, angle_key: str, extent: int) -> float | None:
        if key in params:
            return float(params[key])
        if angle_key in params:
            angle = float(params[angle_key])
            if not 0 < angle < math.pi:
                raise CameraFormatError(f"{where}: {angle_key} must be in (0, pi) radians, got {angle}")
            return 0.5 * extent / math.tan(0.5 * angle)
        return None

    fx, fy = focal("fl_x", "camera_angle_x", w), focal("fl_y", "camera_angle_y", h)
    if fx is None and fy is None:
        raise CameraFormatError(f"{where}: no focal length (fl_x / fl_y or camera_angle_x / camera_angle_y)")
    fx = fy if fx is None else fx
    fy = fx if fy is None else fy
    cx = float(params.get("cx", 0.5 * w))
    cy = float(params.get("cy", 0.5 * h))
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    if "transform_matrix" not in frame:
        raise CameraFormatError(f"{where}: transform_matrix: missing")
    raw = frame["transform_matrix"]
    if isinstance(raw, list) and len(raw) == 3:  # some writers drop the constant last row
        raw = [*raw, [0.0, 0.0, 0.0, 1.0]]
    T_gl = _check_rigid(raw, where, "transform_matrix")
    T_cv = T_gl @ GL_TO_CV

    distortion = {k: float(params[k]) for k in _DISTORTION_KEYS if k in params}
    # nerfstudio names the lens: OPENCV (k1 k2 k3 p1 p2; its k4 is an r^8 term OpenCV lacks, refused where used) or
    # OPENCV_FISHEYE (k1..k4, equidistant).
    model = frame.get("camera_model", meta.get("camera_model", "OPENCV"))
    if model == "OPENCV_FISHEYE":
        distortion = {k: v for k, v in distortion.items() if k in FISHEYE_KEYS}
        return Camera(_check_K(K, where), T_cv, w, h, file_path, distortion, "fisheye")
    if model not in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE"):
        raise CameraFormatError(f"{where}: camera_model {model!r} is not supported (OPENCV, OPENCV_FISHEYE, PINHOLE); "
                                "undistort the images to a pinhole beforehand")  # fmt: skip
    return Camera(_check_K(K, where), T_cv, w, h, file_path, distortion)


def load_transforms_json(path: str | os.PathLike[str]) -> list[Camera]:
    """All frames of an instant-ngp / nerfstudio ``transforms.json`` as OpenCV cameras, in file order.

    ``Camera.name`` is the frame's ``file_path`` as written (relative to the JSON's folder).
    Poses stay in the file's world frame; only the camera axes are converted (OpenGL -> OpenCV).
    """
    path = Path(path)
    meta, frames = _read_transforms(path)
    return [_frame_camera(path, meta, i, fr) for i, fr in enumerate(frames)]


def _stem(name: str) -> str:
    return posixpath.splitext(name)[0]


def camera_from_transforms_frame(path: str | os.PathLike[str], frame_name: str) -> Camera:
    """One frame of a ``transforms.json``, found by ``file_path``, by basename, or by basename
    without extension (``"images/0001.jpg"``, ``"0001.jpg"`` and ``"0001"`` all work)."""
    path = Path(path)
    meta, frames = _read_transforms(path)
    names = [fr["file_path"] for fr in frames]

    def norm(s: str) -> str:
        return posixpath.normpath(s.replace("\\", "/"))

    q = norm(frame_name)
    q_base = posixpath.basename(q)
    rules = [
        lambda n: n == frame_name,
        lambda n: norm(n) == q,
        lambda n: posixpath.basename(norm(n)) == q_base,
        # "0001" finds "images/0001.jpg"; "r_0.png" finds NeRF-synthetic "./train/r_0".
        lambda n: _stem(posixpath.basename(norm(n))) == q_base or posixpath.basename(norm(n)) == _stem(q_base),
    ]
    for rule in rules:
        hits = [i for i, n in enumerate(names) if rule(n)]
        if len(hits) == 1:
            return _frame_camera(path, meta, hits[0], frames[hits[0]])
        if len(hits) > 1:
            shown = ", ".join(names[i] for i in hits[:5])
            raise CameraFormatError(f"{path}: frame name {frame_name!r} is ambiguous; it matches {shown}")
    some = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
    raise CameraFormatError(
        f"{path}: no frame named {frame_name!r} among {len(names)} frames (file_path values: {some or 'none'})"
    )
