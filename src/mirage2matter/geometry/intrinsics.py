"""Camera intrinsics from the files calibration tools write, converted once, here, to our convention.

Accepted (detected from the content; the suffix picks the reader):

- ours: JSON ``{"K": 3x3, "width", "height", "distortion": {"k1", "k2", "p1", "p2", "k3", ...}}`` (pixel centres
  at +0.5, as COLMAP and gsplat);
- OpenCV calibration output: ``cv2.FileStorage`` YAML / XML / JSON with ``camera_matrix``,
  ``distortion_coefficients``, ``image_width``, ``image_height`` (``%YAML:1.0``, ``!!opencv-matrix``), or plain
  JSON / YAML with ``camera_matrix`` (or ``K``) as 3x3 and ``dist_coeffs`` / ``D`` / ``distortion_coefficients`` as
  a list;
- ROS ``camera_info``: camera_calibration's ``ost.yaml`` (``image_width``, ``image_height``, ``camera_matrix``
  ``{rows, cols, data}``, ``distortion_model``, ``distortion_coefficients {data}``) and the message form
  (``width``, ``height``, ``K`` / ``k`` [9], ``D`` / ``d``, ``distortion_model``);
- COLMAP ``cameras.txt`` (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV, OPENCV_FISHEYE,
  SIMPLE_RADIAL_FISHEYE, RADIAL_FISHEYE, SIMPLE_FISHEYE, FISHEYE); with several cameras, the one of the asked size;
- RealSense intrinsics as pyrealsense2 prints them, as JSON: ``width``, ``height``, ``fx``, ``fy``, ``ppx``,
  ``ppy``, ``model``, ``coeffs`` [5].

OpenCV, ROS and RealSense put pixel centres at integers: cx and cy move by +0.5 here. COLMAP already uses +0.5.
(librealsense's own ``rs2_fov`` in rsutil.h measures the image from ``ppx + 0.5``: its pixel edges sit at -0.5.)

Lens models (:mod:`.distortion`): radial-tangential (OpenCV's k1, k2, p1, p2, k3 and the rational k4, k5, k6) and
equidistant fisheye (cv2.fisheye k1..k4: ROS ``equidistant``, OpenCV's ``fisheye_model: 1``, COLMAP's fisheye
models, RealSense "Kannala Brandt4"). COLMAP's RADIAL_FISHEYE is theta_d = theta (1 + k1 theta^2 + k2 theta^4)
(colmap/src/colmap/sensor/models.h), i.e. cv2.fisheye with k3 = k4 = 0.

RealSense models, as librealsense's include/librealsense2/rsutil.h (rs2_project_point_to_pixel) applies them:
"Brown Conrady" is OpenCV's radial-tangential with coeffs = k1 k2 p1 p2 k3. "Inverse Brown Conrady" (the D400
colour streams) and "Modified Brown Conrady" share one projection there: the radial factor first, then the
tangential terms evaluated at the radially scaled point (OpenCV evaluates them at the undistorted point); the SDK's
deprojection inverts exactly that. Users have measured that ``cv2.undistortPoints`` with these coefficients agrees
with rs2_deproject_pixel_to_point (librealsense issue 13824), and Intel once proposed to relabel the D400 colour
model Brown Conrady (librealsense PR 13833, not merged). We take them as OpenCV's model when the two formulas
differ by less than 0.05 px over the image (a D455 colour stream: 0.02 px), and refuse otherwise.
"Kannala Brandt4" is cv2.fisheye with coeffs[:4] (rsutil.h: theta_d = theta (1 + c0 theta^2 + ... + c3 theta^8)).
F-theta and models with no such equal (COLMAP FOV, thin-prism, division, EUCM) are refused by name: undistort
the images to a pinhole first.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import M2MError
from ..inputs import InputError, read_json, read_yaml
from .distortion import FISHEYE_KEYS, RADTAN_KEYS

__all__ = ["FORMATS", "IntrinsicsFormatError", "colmap_lens", "read_intrinsics"]

FORMATS = (
    "our JSON (K, width, height, distortion)",
    "OpenCV calibration YAML/XML/JSON (camera_matrix, distortion_coefficients, image_width, image_height)",
    "ROS camera_info YAML (ost.yaml, or the message's width, height, K, D, distortion_model)",
    "COLMAP cameras.txt (PINHOLE, OPENCV, FULL_OPENCV, OPENCV_FISHEYE, ...)",
    "RealSense intrinsics JSON (width, height, fx, fy, ppx, ppy, model, coeffs)",
)


class IntrinsicsFormatError(M2MError, ValueError):
    """An intrinsics file we cannot read or a lens we cannot model; the message names the file and field."""


def _fail(path: Path, msg: str) -> IntrinsicsFormatError:
    return IntrinsicsFormatError(f"{path}: {msg}")


def _numbers(path: Path, value: Any, name: str, sizes: tuple[int, ...]) -> np.ndarray:
    if isinstance(value, dict) and "data" in value:  # {rows, cols, data} (ROS, OpenCV JSON)
        value = value["data"]
    try:
        a = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise _fail(path, f"{name} must be numbers, got {value!r}") from None
    if a.size not in sizes or not np.isfinite(a).all():
        raise _fail(path, f"{name} must be {' or '.join(map(str, sizes))} finite numbers, got {a.size}")
    return a


def _size(path: Path, data: dict, keys: tuple[str, str]) -> tuple[int, int]:
    out = []
    for k in keys:
        v = data.get(k)
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        if isinstance(v, bool) or not isinstance(v, int) or not 0 < v < 100_000:
            raise _fail(path, f"{k} must be the image size in pixels (a positive integer), got {v!r}")
        out.append(v)
    return out[0], out[1]


def _radtan(path: Path, coeffs: np.ndarray, name: str) -> dict[str, float]:
    if coeffs.size not in (0, 4, 5, 8):
        raise _fail(path, f"{name}: {coeffs.size} coefficients; radial-tangential takes 4, 5 or 8 (k1 k2 p1 p2 "
                    "[k3 [k4 k5 k6]]); more is a model we do not support (thin prism / tilted): undistort first")
    d = {k: float(v) for k, v in zip(RADTAN_KEYS, coeffs, strict=False) if v != 0.0}
    if "k4" in d and not ({"k5", "k6"} & set(d)):
        d["k5"] = 0.0  # the rational model: a lone k4 must not read as fisheye
    return d


def _cv_K(path: Path, value: Any, name: str) -> np.ndarray:
    K = _numbers(path, value, name, (9,)).reshape(3, 3).copy()
    K[:2, 2] += 0.5  # OpenCV / ROS: pixel centres at integers -> ours at +0.5
    return K


def _fisheye(path: Path, coeffs: np.ndarray, name: str) -> dict[str, Any]:
    """{"model": "fisheye", k1..k4} (our JSON's form) from cv2.fisheye's 4 coefficients (trailing zeros allowed)."""
    if 0 < coeffs.size < 4 or np.any(coeffs[4:]):
        raise _fail(path, f"{name}: the equidistant fisheye takes 4 coefficients (k1 k2 k3 k4), got "
                    f"{coeffs.tolist()}")  # fmt: skip
    return {"model": "fisheye", **{k: float(v) for k, v in zip(FISHEYE_KEYS, coeffs[:4], strict=False)}}


def _from_model(path: Path, model: str, coeffs: np.ndarray) -> dict[str, Any]:
    m = str(model).strip().lower().replace("-", "_").replace(" ", "_")
    if m in ("plumb_bob", "radtan", "radial_tangential", "opencv", "rational_polynomial", "brown_conrady", "none", ""):
        return _radtan(path, coeffs, f"distortion ({model})")
    if m in ("equidistant", "fisheye", "kannala_brandt4", "kannala_brandt", "opencv_fisheye"):
        return _fisheye(path, coeffs, f"distortion ({model})")
    raise _fail(path, f"the lens model {model!r} is not supported (radial-tangential and equidistant fisheye are); "
                "undistort the images to a pinhole first, or calibrate the camera with OpenCV")


def _realsense_brown_conrady(path: Path, K: np.ndarray, w: int, h: int, model: str, c: np.ndarray) -> dict[str, Any]:
    """librealsense's inverse / modified Brown-Conrady as OpenCV's model, where the two agree (module docstring)."""
    if not np.any(c):
        return {}
    k1, k2, p1, p2, k3 = c
    u, v = np.meshgrid(np.linspace(0, w, 33), np.linspace(0, h, 33))
    x, y = (u.ravel() - K[0, 2]) / K[0, 0], (v.ravel() - K[1, 2]) / K[1, 1]  # rays through the image, ~pinhole
    r2 = x * x + y * y
    f = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xf, yf = x * f, y * f
    cv = np.c_[xf + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), yf + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y]
    rs = np.c_[xf + 2 * p1 * xf * yf + p2 * (r2 + 2 * xf * xf), yf + p1 * (r2 + 2 * yf * yf) + 2 * p2 * xf * yf]
    gap = float(np.abs((cv - rs) * [K[0, 0], K[1, 1]]).max())
    if gap > 0.05:
        raise _fail(path, f"RealSense model {model!r}: its tangential terms differ from OpenCV's by up to {gap:.2f} px "
                    "over this image, more than we accept (0.05 px); calibrate the camera with OpenCV or undistort "
                    "the images first")  # fmt: skip
    return _radtan(path, c, "coeffs")


def _parse_mapping(path: Path, data: dict) -> dict[str, Any]:
    """{K, width, height, distortion} in our convention from any of the dict-shaped formats."""
    keys = set(data)
    if "K" in data and isinstance(data["K"], list) and len(data["K"]) == 3 and {"width", "height"} <= keys \
            and "distortion_model" not in data:  # fmt: skip
        return {"K": data["K"], "width": data["width"], "height": data["height"],
                "distortion": data.get("distortion") or {}}  # fmt: skip  (ours: +0.5 already)
    if {"fx", "fy", "ppx", "ppy"} <= keys:  # RealSense
        w, h = _size(path, data, ("width", "height"))
        K = np.array([[data["fx"], 0.0, data["ppx"] + 0.5], [0.0, data["fy"], data["ppy"] + 0.5], [0, 0, 1.0]])
        coeffs = _numbers(path, data.get("coeffs", [0] * 5), "coeffs", (5,))
        model = str(data.get("model", "none"))
        m = model.strip().lower().replace("-", "_").replace(" ", "_").removeprefix("rs2_distortion_")
        if m == "brown_conrady":
            dist = _radtan(path, coeffs, "coeffs")  # librealsense: k1 k2 p1 p2 k3, as OpenCV's
        elif m in ("inverse_brown_conrady", "modified_brown_conrady"):
            dist = _realsense_brown_conrady(path, K, w, h, model, coeffs)
        elif m in ("kannala_brandt4", "none"):
            dist = _from_model(path, m, coeffs)
        else:  # ftheta and anything newer
            raise _fail(path, f"RealSense model {model!r} is not supported (Brown Conrady, Inverse / Modified Brown "
                        "Conrady, Kannala Brandt4, None are); undistort the images first")  # fmt: skip
        return {"K": K, "width": w, "height": h, "distortion": dist}
    matrix_key = next((k for k in ("camera_matrix", "K", "k", "cameraMatrix") if k in data), None)
    if matrix_key is not None:  # OpenCV or ROS (both: centres at integers)
        size_keys = ("image_width", "image_height") if "image_width" in data else ("width", "height")
        w, h = _size(path, data, size_keys)
        dist_key = next((k for k in ("distortion_coefficients", "dist_coeffs", "D", "d", "distCoeffs", "dist")
                         if k in data), None)  # fmt: skip
        coeffs = _numbers(path, data[dist_key], dist_key, tuple(range(0, 15))) if dist_key else np.zeros(0)
        model = data.get("distortion_model", "fisheye" if data.get("fisheye_model") else "plumb_bob")
        return {"K": _cv_K(path, data[matrix_key], matrix_key), "width": w, "height": h,
                "distortion": _from_model(path, model, coeffs)}  # fmt: skip
    raise _fail(path, "not an intrinsics format we know; accepted: " + "; ".join(FORMATS))


_COLMAP_LAYOUTS = {  # model -> (names of the parameters after the focal length(s) and centre, lens model)
    "SIMPLE_PINHOLE": (1, (), "opencv"), "PINHOLE": (2, (), "opencv"),
    "SIMPLE_RADIAL": (1, ("k1",), "opencv"), "RADIAL": (1, ("k1", "k2"), "opencv"),
    "OPENCV": (2, ("k1", "k2", "p1", "p2"), "opencv"), "FULL_OPENCV": (2, RADTAN_KEYS, "opencv"),
    "SIMPLE_FISHEYE": (1, (), "fisheye"), "FISHEYE": (2, (), "fisheye"),
    "SIMPLE_RADIAL_FISHEYE": (1, ("k1",), "fisheye"), "RADIAL_FISHEYE": (1, ("k1", "k2"), "fisheye"),
    "OPENCV_FISHEYE": (2, FISHEYE_KEYS, "fisheye"),
}  # fmt: skip


def colmap_lens(model: str, params: list[float], where: str) -> tuple[np.ndarray, dict[str, Any]]:
    """(K [3, 3] in our convention, distortion as our JSON writes it) of a COLMAP camera model and its parameters
    (COLMAP puts pixel centres at +0.5 as we do: nothing moves). IntrinsicsFormatError names unsupported models."""
    if model not in _COLMAP_LAYOUTS:
        raise IntrinsicsFormatError(f"{where}: COLMAP camera model {model} is not supported (supported: "
                                    f"{', '.join(_COLMAP_LAYOUTS)}); undistort the images to a pinhole first "
                                    "(colmap image_undistorter) and give its PINHOLE cameras.txt")  # fmt: skip
    n_focal, names, lens = _COLMAP_LAYOUTS[model]
    if len(params) != n_focal + 2 + len(names):
        raise IntrinsicsFormatError(f"{where}: COLMAP {model} takes {n_focal + 2 + len(names)} parameters, got "
                                    f"{len(params)}")  # fmt: skip
    fx, fy = (params[0], params[0]) if n_focal == 1 else (params[0], params[1])
    cx, cy, rest = params[n_focal], params[n_focal + 1], params[n_focal + 2 :]
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    dist: dict[str, Any] = {k: float(v) for k, v in zip(names, rest, strict=True) if v != 0.0}
    if model == "FULL_OPENCV" and {"k4", "k5", "k6"} & set(dist):
        dist.update({k: dist.get(k, 0.0) for k in ("k4", "k5", "k6")})  # the rational model, said explicitly
    return K, ({"model": "fisheye", **dist} if lens == "fisheye" else dist)


def _read_colmap_txt(path: Path, size: tuple[int, int] | None) -> dict[str, Any]:
    lines = [ln.split() for ln in path.read_text(encoding="utf-8", errors="replace").splitlines()
             if ln.strip() and not ln.lstrip().startswith("#")]  # fmt: skip
    if not lines:
        raise _fail(path, "no camera line (COLMAP cameras.txt: CAMERA_ID MODEL WIDTH HEIGHT PARAMS...)")
    cams = []
    for ln in lines:
        try:
            _, model, w, h, *params = ln
            cams.append((model, int(w), int(h), [float(v) for v in params]))
        except ValueError:
            raise _fail(path, f"cannot read the camera line {' '.join(ln)!r}") from None
    if size is not None:
        cams = [c for c in cams if (c[1], c[2]) == tuple(size)] or cams
    if len(cams) > 1:
        sizes = ", ".join(f"{c[1]}x{c[2]}" for c in cams)
        raise _fail(path, f"{len(cams)} cameras ({sizes}); keep the one line of the camera to use, or give the "
                    "images' size to pick it")  # fmt: skip
    model, w, h, params = cams[0]
    K, dist = colmap_lens(model, params, str(path))
    return {"K": K.tolist(), "width": w, "height": h, "distortion": dist}


def _read_filestorage(path: Path) -> dict[str, Any]:
    """OpenCV's FileStorage (YAML with %YAML:1.0 / XML / its JSON): every top-level node as plain values."""
    import cv2

    try:  # a truncated or broken file: OpenCV's parser raises cv2.error, or SystemError through its bindings
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as e:
        raise _fail(path, f"OpenCV cannot parse this file (truncated or not a calibration file: "
                          f"{(str(e).strip().splitlines() or [type(e).__name__])[-1][:200]})") from None  # fmt: skip
    try:
        if not fs.isOpened():
            raise _fail(path, "OpenCV cannot read this file")
        root, out = fs.root(), {}
        for key in root.keys():
            node = fs.getNode(key)
            if node.isMap():
                out[key] = node.mat()  # an !!opencv-matrix (None for any other mapping)
            elif node.isReal() or node.isInt():
                out[key] = node.real()
            elif node.isString():
                out[key] = node.string()
            elif node.isSeq():
                out[key] = [node.at(i).real() for i in range(node.size())]
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in out.items()}
    finally:
        fs.release()


def read_intrinsics(
    path: str | os.PathLike[str], keys: tuple[str, ...] = (), size: tuple[int, int] | None = None
) -> dict[str, Any]:
    """``{"K" [3x3] (our +0.5 convention), "width", "height", "distortion" {name: value, "model" for a fisheye}}``
    from any accepted file (see the module docstring). ``keys``: objects of a larger JSON to look in (e.g.
    "head_camera"); ``size`` (width, height): picks that camera of a COLMAP cameras.txt holding several."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".txt":
        return _read_colmap_txt(path, size)
    head = path.read_bytes()[:64].lstrip()
    if suffix == ".xml" or head.startswith(b"%YAML") or b"opencv-matrix" in path.read_bytes()[:4096]:
        data = _read_filestorage(path)
    else:
        try:
            data = read_json(path, "intrinsics file", expect=None) if suffix == ".json" else \
                read_yaml(path, "intrinsics file")  # fmt: skip
        except InputError as e:
            raise IntrinsicsFormatError(str(e)) from None
    if isinstance(data, dict) and not _looks_like_intrinsics(data):
        data = next((data[k] for k in keys if isinstance(data.get(k), dict)), data)
    if not isinstance(data, dict):
        raise _fail(path, "expected an object (mapping) of intrinsics; accepted: " + "; ".join(FORMATS))
    return _parse_mapping(path, data)


def _looks_like_intrinsics(data: dict) -> bool:
    return any(k in data for k in ("K", "k", "camera_matrix", "cameraMatrix", "fx"))
