"""``m2m intrinsics FILE``: the camera a calibration file describes, as the project reads it (pixel centres at
+0.5, the lens model, the field of view); ``--json`` prints it as our intrinsics JSON."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

from .args import CliError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "intrinsics", help="show the camera an intrinsics file describes, as the pipeline reads it",
        description="Read an intrinsics file (our JSON, OpenCV calibration YAML/XML/JSON, ROS camera_info, COLMAP "
        "cameras.txt, RealSense JSON) and print K in our convention (pixel centres at +0.5: OpenCV's, ROS' and "
        "RealSense's cx, cy are 0.5 px less), the lens model and the field of view.",
    )  # fmt: skip
    p.add_argument("file", help="the intrinsics file")
    p.add_argument("--size", default=None, metavar="WxH", help="COLMAP cameras.txt with several cameras: this one")
    p.add_argument("--json", action="store_true", help="print our intrinsics JSON (K, width, height, distortion)")
    p.set_defaults(func=run)


def _fov_deg(cam, a: tuple[float, float], b: tuple[float, float]) -> float:
    """The angle (deg) from the ray through pixel ``a`` over the optical axis to the one through ``b`` (on either
    side of the principal point): a fisheye's field of view may pass 180 deg."""
    rays = cam.pixel_rays(np.array([a, b]))
    return math.degrees(float(np.arccos(np.clip(rays[:, 2], -1.0, 1.0)).sum()))


def run(args: argparse.Namespace) -> int:
    from ..geometry.camera import load_intrinsics

    size = None
    if args.size:
        try:
            size = tuple(int(v) for v in args.size.lower().split("x"))
        except ValueError:
            raise CliError(f"--size must look like 1280x720, got {args.size!r}") from None
    cam = load_intrinsics(args.file, size=size)
    if args.json:
        out = {"K": cam.K.tolist(), "width": cam.width, "height": cam.height}
        if cam.distortion or cam.distortion_model == "fisheye":
            out["distortion"] = cam.distortion_json()
        print(json.dumps(out, indent=2))
        return 0
    w, h = cam.width, cam.height
    print(f"size        {w} x {h}")
    print(f"K           fx {cam.fx:.3f}  fy {cam.fy:.3f}  cx {cam.cx:.3f}  cy {cam.cy:.3f}  skew {cam.K[0, 1]:.3g}"
          "  (pixel centres at +0.5)")  # fmt: skip
    print(f"            OpenCV / ROS / RealSense: cx {cam.cx - 0.5:.3f}  cy {cam.cy - 0.5:.3f}")
    terms = "  ".join(f"{k} {v:.6g}" for k, v in cam.distortion.items()) or "none"
    names = {"opencv": "radial-tangential (OpenCV)", "fisheye": "equidistant fisheye (cv2.fisheye)"}
    print(f"lens        {names[cam.distortion_model] if cam.has_distortion else 'none (pinhole)'}: {terms}")
    fovs = [_fov_deg(cam, (0.0, cam.cy), (w, cam.cy)), _fov_deg(cam, (cam.cx, 0.0), (cam.cx, h)),
            _fov_deg(cam, (0.0, 0.0), (w, h))]  # fmt: skip
    show = lambda f: "beyond the lens model's range" if math.isnan(f) else f"{f:.1f} deg"  # noqa: E731
    print(f"fov         horizontal {show(fovs[0])}, vertical {show(fovs[1])}, diagonal {show(fovs[2])}")
    return 0
