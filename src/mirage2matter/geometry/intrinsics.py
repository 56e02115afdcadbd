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
- COLMAP ``cameras.txt`` (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV);
- RealSense intrinsics as pyrealsense2 prints them, as JSON: ``width``, ``height``, ``fx``, ``fy``, ``ppx``,
  ``ppy``, ``model``, ``coeffs`` [5].

OpenCV, ROS and RealSense put pixel centres at integers: cx and cy move by +0.5 here. COLMAP already uses +0.5.
Lens models: radial-tangential (OpenCV's k1, k2, p1, p2, k3 and the rational k4, k5, k6). Equidistant fisheye
(ROS ``equidistant``, COLMAP OPENCV_FISHEYE, RealSense Kannala Brandt4) and models OpenCV has no equal for
(RealSense's modified / inverse Brown-Conrady with non-zero coefficients, COLMAP FOV, thin-prism) are refused by
name: undistort the images to a pinhole first.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import M2MError

__all__ = ["FORMATS", "IntrinsicsFormatError", "read_intrinsics"]

FORMATS = (
    "our JSON (K, width, height, distortion)",
    "OpenCV calibration YAML/XML/JSON (camera_matrix, distortion_coefficients, image_width, image_height)",
    "ROS camera_info YAML (ost.yaml, or the message's width, height, K, D, distortion_model)",
    "COLMAP cameras.txt",
    "RealSense intrinsics JSON (width, height, fx, fy, ppx, ppy, model, coeffs)",
)
_RADTAN = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")  # OpenCV's coefficient order


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
    d = {k: float(v) for k, v in zip(_RADTAN, coeffs, strict=False) if v != 0.0}
    if "k4" in d and not ({"k5", "k6"} & set(d)):
        d["k5"] = 0.0  # the rational model: a lone k4 must not read as fisheye
    return d


def _cv_K(path: Path, value: Any, name: str) -> np.ndarray:
    K = _numbers(path, value, name, (9,)).reshape(3, 3).copy()
    K[:2, 2] += 0.5  # OpenCV / ROS: pixel centres at integers -> ours at +0.5
    return K


def _from_model(path: Path, model: str, coeffs: np.ndarray) -> dict[str, float]:
    m = str(model).strip().lower().replace("-", "_").replace(" ", "_")
    if m in ("plumb_bob", "radtan", "radial_tangential", "opencv", "rational_polynomial", "brown_conrady", "none", ""):
        return _radtan(path, coeffs, f"distortion ({model})")
    if m in ("equidistant", "fisheye", "kannala_brandt4", "kannala_brandt", "opencv_fisheye"):
        raise _fail(path, f"the lens model {model!r} (equidistant fisheye) is not supported yet; undistort the images "
                    "to a pinhole first (cv2.fisheye.undistortImage) and give the pinhole intrinsics")
    if m in ("inverse_brown_conrady", "modified_brown_conrady") and not np.any(coeffs):
        return {}
    raise _fail(path, f"the lens model {model!r} has no OpenCV equal we can use; undistort the images to a pinhole "
                "first, or calibrate the camera with OpenCV (radial-tangential)")


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
        if model.strip().lower().replace(" ", "_") == "brown_conrady":
            dist = _radtan(path, coeffs, "coeffs")  # librealsense: k1 k2 p1 p2 k3, as OpenCV's
        else:
            dist = _from_model(path, model, coeffs)
        return {"K": K, "width": w, "height": h, "distortion": dist}
    matrix_key = next((k for k in ("camera_matrix", "K", "k", "cameraMatrix") if k in data), None)
    if matrix_key is not None:  # OpenCV or ROS (both: centres at integers)
        size_keys = ("image_width", "image_height") if "image_width" in data else ("width", "height")
        w, h = _size(path, data, size_keys)
        dist_key = next((k for k in ("distortion_coefficients", "dist_coeffs", "D", "d", "distCoeffs", "dist")
                         if k in data), None)  # fmt: skip
        coeffs = _numbers(path, data[dist_key], dist_key, tuple(range(0, 15))) if dist_key else np.zeros(0)
        model = data.get("distortion_model", "plumb_bob")
        return {"K": _cv_K(path, data[matrix_key], matrix_key), "width": w, "height": h,
                "distortion": _from_model(path, model, coeffs)}  # fmt: skip
    raise _fail(path, "not an intrinsics format we know; accepted: " + "; ".join(FORMATS))


def _read_colmap_txt(path: Path) -> dict[str, Any]:
    lines = [ln.split() for ln in path.read_text(encoding="utf-8", errors="replace").splitlines()
             if ln.strip() and not ln.lstrip().startswith("#")]  # fmt: skip
    if not lines:
        raise _fail(path, "no camera line (COLMAP cameras.txt: CAMERA_ID MODEL WIDTH HEIGHT PARAMS...)")
    if len(lines) > 1:
        raise _fail(path, f"{len(lines)} cameras; keep the one line of the camera to use")
    try:
        _, model, w, h, *params = lines[0]
        w, h, p = int(w), int(h), [float(v) for v in params]
    except ValueError:
        raise _fail(path, f"cannot read the camera line {' '.join(lines[0])!r}") from None
    layouts = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8, "FULL_OPENCV": 12}
    if model in ("OPENCV_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "THIN_PRISM_FISHEYE", "FOV"):
        raise _fail(path, f"COLMAP model {model} is not supported; undistort the images to a pinhole first "
                    "(colmap image_undistorter) and give its PINHOLE cameras.txt")  # fmt: skip
    if model not in layouts:
        raise _fail(path, f"unknown COLMAP camera model {model!r}; supported: {', '.join(layouts)}")
    if len(p) != layouts[model]:
        raise _fail(path, f"COLMAP {model} takes {layouts[model]} parameters, got {len(p)}")
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy, rest = p[1], p[2], p[3:]
        dist = dict(zip(("k1", "k2"), rest, strict=False))
    else:
        fx, fy, cx, cy, rest = p[0], p[1], p[2], p[3], p[4:]
        dist = _radtan(path, np.asarray(rest), model)
    K = [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]  # COLMAP: pixel centres at +0.5 already
    return {"K": K, "width": w, "height": h, "distortion": {k: v for k, v in dist.items() if v != 0.0}}


def _read_filestorage(path: Path) -> dict[str, Any]:
    """OpenCV's FileStorage (YAML with %YAML:1.0 / XML / its JSON): every top-level node as plain values."""
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
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


def read_intrinsics(path: str | os.PathLike[str], keys: tuple[str, ...] = ()) -> dict[str, Any]:
    """``{"K" [3x3] (our +0.5 convention), "width", "height", "distortion" {name: value}}`` from any accepted
    file (see the module docstring). ``keys``: objects of a larger JSON to look in (e.g. "head_camera")."""
    from ..inputs import InputError, read_json, read_yaml

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".txt":
        return _read_colmap_txt(path)
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
