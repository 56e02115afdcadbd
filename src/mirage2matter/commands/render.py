"""``m2m render``: any 3DGS PLY from any camera to a PNG (and optionally its depth)."""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from .. import configure_threads
from ..atomic import atomic_path, atomic_write
from ..configs import add_flags, from_flags, ranged
from ..inputs import InputError, read_json
from ..render.lens import centred_K, depth_through_lens, lens_cover, resample_through_lens
from .args import CliError, backend, check_output, rgb

CAMERA_FIELDS = '{"width", "height", "K" (3x3, pixels), "T_world_cam" (4x4 camera-to-world, OpenCV axes)}'


@dataclass
class RenderConfig:
    """m2m render settings.

    backend     renderer (default auto: cuda if available, else cpu)
    background  background colour in 0..1 (R,G,B, or one value for grey)
    scale       resize the camera by F (0.5 = half resolution)
    """

    backend: Literal["auto", "cpu", "cuda", "reference"] = "auto"
    background: tuple[float, float, float] = ranged((0.0, 0.0, 0.0), ge=0, le=1, metadata={"parse": rgb,
                                                                                          "metavar": "R,G,B"})
    scale: float = ranged(1.0, gt=0, metadata={"metavar": "F"})


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "render",
        help="render a 3DGS PLY from a camera to a PNG",
        description=(
            "Render a 3D Gaussian Splatting PLY (Inria layout) from one camera to an 8-bit RGB PNG.\n"
            f"The camera is a JSON file {CAMERA_FIELDS}, with its lens (\"distortion\") if it has one;\n"
            "or, with --frame NAME, one frame of an instant-ngp / nerfstudio transforms.json (k1, k2, p1, p2...)."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("ply", help="3DGS .ply file")
    p.add_argument("--camera", required=True, metavar="JSON", help="camera JSON, or transforms.json with --frame")
    p.add_argument("--frame", metavar="NAME", help="frame of the transforms.json: file_path, basename or stem")
    p.add_argument("--out", required=True, metavar="PNG", help="output image (.png); its directory must exist")
    add_flags(p, RenderConfig)
    p.add_argument("--depth-out", metavar="PNG|NPY",
                   help="also write expected depth: .npy float32 metres or .png uint16 millimetres (0 = nothing)")
    p.set_defaults(func=run)


def _peek_json(path: Path) -> Any:
    """The parsed JSON, or None when unreadable (used only to improve error messages)."""
    try:
        return read_json(path, expect=None)
    except (InputError, OSError):
        return None


def load_camera(path: Path, frame: str | None):
    from ..geometry.camera import CameraFormatError, camera_from_transforms_frame, load_camera_json

    if not path.is_file():
        what = "is a directory" if path.is_dir() else "not found"
        raise CliError(
            f"camera file {path} {what}; pass a camera JSON {CAMERA_FIELDS} or a transforms.json with --frame NAME"
        )
    if frame is not None:
        data = _peek_json(path)
        if isinstance(data, dict) and "frames" not in data:
            raise CliError(
                f"{path} has no 'frames' list, so --frame {frame!r} cannot apply; drop --frame for a single-camera JSON"
            )
        return camera_from_transforms_frame(path, frame)
    try:
        return load_camera_json(path)
    except CameraFormatError as e:
        data = _peek_json(path)
        if isinstance(data, dict) and isinstance(data.get("frames"), list):
            names = [fr.get("file_path") for fr in data["frames"][:3] if isinstance(fr, dict)]
            raise CliError(
                f"{path} is a transforms.json ({len(data['frames'])} frame(s)), not a single camera; "
                f"choose one with --frame NAME (e.g. {', '.join(map(str, names)) or 'a file_path'})"
            ) from e
        raise CliError(f"{e} (a camera JSON holds {CAMERA_FIELDS})") from e


def to_uint8(rgb_hw3) -> Any:
    """[H,W,3] float tensor -> uint8 array; values clamped to [0,1], rounded to nearest."""
    a = rgb_hw3.detach().to("cpu").float().numpy()
    a = np.nan_to_num(a, nan=0.0, posinf=1.0, neginf=0.0)
    return (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_png(path: Path, image) -> None:
    """Write a uint8 [H,W,3] (RGB) or uint16 [H,W] (16-bit grey) array as PNG, atomically."""
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG")


def _lens(cam: Any) -> tuple[np.ndarray, float, np.ndarray, tuple[int, int]] | None:
    """(rays [H, W, 2], focal, K [3,3] and (width, height) of the centred pinhole covering them) for a camera with a
    lens, None for a pinhole (the renderer takes its K as it is)."""
    if not cam.has_distortion:
        return None
    f = float(cam.fy)
    try:
        rays, (w, h) = lens_cover(cam, f)
    except ValueError as e:
        raise CliError(f"{cam.name or 'the camera'}: its lens {e}; give a camera undistorted to a pinhole") from None
    return rays, f, centred_K(f, (w, h)), (w, h)


def _write_depth(path: Path, d: np.ndarray) -> str:
    """``.npy``: float32 metres; ``.png``: uint16 millimetres (0 = nothing seen, clipped at 65.535 m)."""
    if path.suffix.lower() == ".npy":
        with atomic_write(path, "wb") as f:
            np.save(f, d.astype(np.float32))
        return "float32 metres"
    write_png(path, np.clip(np.round(d * 1000.0), 0, 65535).astype(np.uint16))
    return "16-bit millimetres"


def run(args: argparse.Namespace) -> int:
    cfg = from_flags(RenderConfig, args)
    out = Path(args.out)
    check_output(out, "--out", (".png",))
    depth_out = Path(args.depth_out) if args.depth_out else None
    if depth_out is not None:
        check_output(depth_out, "--depth-out", (".png", ".npy"))
        if depth_out.resolve() == out.resolve():
            raise CliError("--depth-out must differ from --out")
    ply = Path(args.ply)
    if not ply.is_file():
        what = "is a directory" if ply.is_dir() else "not found"
        raise CliError(
            f"PLY file {ply} {what}; pass a 3D Gaussian Splatting .ply (e.g. <workspace>/scene/gaussians.ply)"
        )
    cam = load_camera(Path(args.camera), args.frame)
    if cfg.scale != 1.0:
        cam = cam.scaled(cfg.scale)

    import torch

    from ..gaussians.ply import PlyFormatError, read_ply
    from ..gaussians.render import render

    backend_name = backend(cfg.backend)
    configure_threads()
    g = read_ply(ply)
    if len(g.means) == 0:  # a black picture would look like a render of something
        raise PlyFormatError(f"{ply}: holds no Gaussians (0 vertices); nothing to render")
    lens = _lens(cam)  # a camera with a lens: a wider centred pinhole, resampled through it
    K, w, h = (lens[2], *lens[3]) if lens else (cam.K, cam.width, cam.height)
    with torch.no_grad():
        t0 = time.perf_counter()
        bg = torch.tensor(cfg.background, dtype=torch.float32)
        result = render(g, torch.from_numpy(cam.viewmat), torch.from_numpy(K), w, h, bg, backend_name)
        if backend_name == "cuda":
            torch.cuda.synchronize()
        ms = (time.perf_counter() - t0) * 1e3
    rgb = to_uint8(result.rgb)
    write_png(out, resample_through_lens(rgb, lens[1], lens[0], 1) if lens else rgb)
    extra = "; through the camera's lens" if lens else ""
    if depth_out is not None:
        depth = np.nan_to_num(result.depth.detach().to("cpu").float().numpy(), nan=0.0, posinf=0.0, neginf=0.0)
        depth = depth_through_lens(depth, lens[1], lens[0]) if lens else depth
        extra += f"; depth ({_write_depth(depth_out, depth)}) to {depth_out}"
    print(f"wrote {out} ({cam.width}x{cam.height}, {len(g):,} Gaussians, {backend_name} backend, {ms:.1f} ms){extra}")
    return 0
