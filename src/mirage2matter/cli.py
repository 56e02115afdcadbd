"""The single ``m2m`` command: ``m2m render``, ``m2m bench render``, ``m2m demo``.

Only this module wires the library to files and the terminal (DESIGN.md section 4). Expected
failures (bad files, bad fields, missing directories) print ``m2m: error: <message>`` to stderr and
exit with status 2, without a traceback; ``m2m --debug ...`` (or ``M2M_DEBUG=1``) shows the
traceback instead. Heavy imports (torch, numba, plyfile, PIL) happen inside the subcommands so
that ``m2m --help`` answers at once.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from . import __version__, configure_threads

EXIT_ERROR = 2  # bad input, like argparse's own usage errors
EXIT_INTERRUPTED = 130

# Stages of DESIGN.md section 3 that later issues add; `m2m demo` says so.

_CAMERA_FIELDS = '{"width", "height", "K" (3x3, pixels), "T_world_cam" (4x4 camera-to-world, OpenCV axes)}'


class CliError(Exception):
    """An expected failure; printed as ``m2m: error: <message>`` with exit status 2."""


# ---- argument types -------------------------------------------------------------------------------
def _int_at_least(lo: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text.replace("_", ""))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < lo:
            raise argparse.ArgumentTypeError(f"must be >= {lo}, got {value}")
        return value

    parse.__name__ = "integer"  # argparse names the type in "invalid <type> value" messages
    return parse


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def _rgb(text: str) -> tuple[float, float, float]:
    """``R,G,B`` in 0..1, or one value for grey."""
    parts = [p.strip() for p in text.split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected R,G,B numbers in 0..1 (e.g. 1,1,1), got {text!r}") from None
    if len(values) == 1:
        values *= 3
    if len(values) != 3 or not all(0.0 <= v <= 1.0 for v in values):
        raise argparse.ArgumentTypeError(f"expected three values in 0..1 as R,G,B (e.g. 0.5,0.5,0.5), got {text!r}")
    return values[0], values[1], values[2]


# ---- small helpers ----------------------------------------------------------------------------------
def _info(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _check_output(path: Path, flag: str, suffixes: Sequence[str]) -> None:
    """Fail before any expensive work when ``path`` cannot be written."""
    if path.suffix.lower() not in suffixes:
        raise CliError(f"{flag} {path}: unsupported file type {path.suffix or '(none)'}; use {' or '.join(suffixes)}")
    parent = path.parent
    if not parent.is_dir():
        what = "is not a directory" if parent.exists() else "does not exist"
        raise CliError(f"{flag} {path}: output directory {parent} {what}; create it first (mkdir -p {parent})")
    if path.is_dir():
        raise CliError(f"{flag} {path} is a directory; give a file name")


def _resolve_backend(name: str) -> str:
    from .gaussians.render import resolve_backend

    try:
        return resolve_backend(name)
    except (ValueError, RuntimeError) as e:
        raise CliError(f"--backend {name}: {e}") from e


def _peek_json(path: Path) -> Any:
    """The parsed JSON, or None when unreadable (used only to improve error messages)."""
    try:
        with open(path, encoding="utf-8") as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def _load_camera(path: Path, frame: str | None):
    from .geometry.camera import CameraFormatError, camera_from_transforms_frame, load_camera_json

    if not path.is_file():
        what = "is a directory" if path.is_dir() else "not found"
        raise CliError(
            f"camera file {path} {what}; pass a camera JSON {_CAMERA_FIELDS} or a transforms.json with --frame NAME"
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
        raise CliError(f"{e} (a camera JSON holds {_CAMERA_FIELDS})") from e


def _to_uint8(rgb) -> Any:
    """[H,W,3] float tensor -> uint8 array; values clamped to [0,1], rounded to nearest."""
    import numpy as np

    a = rgb.detach().to("cpu").float().numpy()
    a = np.nan_to_num(a, nan=0.0, posinf=1.0, neginf=0.0)
    return (np.clip(a, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _write_png(path: Path, image) -> None:
    """Write a uint8 [H,W,3] (RGB) or uint16 [H,W] (16-bit grey) array as PNG, atomically."""
    from PIL import Image

    from .atomic import atomic_path

    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG")


def _write_depth(path: Path, depth) -> str:
    """``.npy``: float32 metres; ``.png``: uint16 millimetres (0 = nothing seen, clipped at 65.535 m)."""
    import numpy as np

    from .atomic import atomic_write

    d = np.nan_to_num(depth.detach().to("cpu").float().numpy(), nan=0.0, posinf=0.0, neginf=0.0)
    if path.suffix.lower() == ".npy":
        with atomic_write(path, "wb") as f:
            np.save(f, d.astype(np.float32))
        return "float32 metres"
    _write_png(path, np.clip(np.round(d * 1000.0), 0, 65535).astype(np.uint16))
    return "16-bit millimetres"


def _show(path: Path) -> str:
    """A path as the user would type it: relative to the current directory when below it."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


# ---- m2m render ---------------------------------------------------------------------------------------
def _cmd_render(args: argparse.Namespace) -> int:
    out = Path(args.out)
    _check_output(out, "--out", (".png",))
    depth_out = Path(args.depth_out) if args.depth_out else None
    if depth_out is not None:
        _check_output(depth_out, "--depth-out", (".png", ".npy"))
        if depth_out.resolve() == out.resolve():
            raise CliError("--depth-out must differ from --out")
    ply = Path(args.ply)
    if not ply.is_file():
        what = "is a directory" if ply.is_dir() else "not found"
        raise CliError(
            f"PLY file {ply} {what}; pass a 3D Gaussian Splatting .ply (e.g. <workspace>/scene/gaussians.ply)"
        )
    cam = _load_camera(Path(args.camera), args.frame)
    if args.scale != 1.0:
        cam = cam.scaled(args.scale)
    backend = _resolve_backend(args.backend)

    import torch

    from .gaussians.ply import read_ply
    from .gaussians.render import render

    configure_threads()
    g = read_ply(ply)
    with torch.no_grad():
        t0 = time.perf_counter()
        result = render(
            g,
            torch.from_numpy(cam.viewmat),
            torch.from_numpy(cam.K),
            cam.width,
            cam.height,
            background=torch.tensor(args.background, dtype=torch.float32),
            backend=backend,
        )
        if backend == "cuda":
            torch.cuda.synchronize()
        ms = (time.perf_counter() - t0) * 1e3
    _write_png(out, _to_uint8(result.rgb))
    extra = ""
    if depth_out is not None:
        extra = f"; depth ({_write_depth(depth_out, result.depth)}) to {depth_out}"
    print(f"wrote {out} ({cam.width}x{cam.height}, {len(g):,} Gaussians, {backend} backend, {ms:.1f} ms){extra}")
    return 0


# ---- m2m bench render --------------------------------------------------------------------------------
def _cmd_bench_render(args: argparse.Namespace) -> int:
    from .bench import RenderBenchConfig, bench_render

    cfg = RenderBenchConfig(
        gaussians=args.gaussians,
        size=args.size,
        backend=_resolve_backend(args.backend),
        sh_degree=args.sh_degree,
        views=args.views,
        repeats=args.repeats,
        warmup=args.warmup,
        seed=args.seed,
    )
    cfg.validate()
    threads = configure_threads()
    _info(f"bench render: {cfg.backend} backend, {threads} CPU thread(s)")
    result = bench_render(cfg, log=_info)
    print(json.dumps(result), flush=True)  # machine-readable: always the last line on stdout
    return 0


# ---- m2m demo ---------------------------------------------------------------------------------------------
def _print_demo_summary(result: dict[str, Any], elapsed: float) -> None:
    ws = Path(result["workspace"])
    st = result["stages"]
    rel = lambda *parts: _show(ws.joinpath(*parts))
    where = {
        "capture": rel("capture"), "sfm": rel("sfm"), "align": rel("calib", "sim3_sfm_to_base.json"),
        "handeye": rel("calib", "handeye.json"), "scene": rel("scene", "gaussians.ply"),
        "head_view": rel("calib", "head_view.png"), "objects": rel("objects"), "world": rel("world", "world.yaml"),
        "generate": rel("datasets"),
    }  # fmt: skip
    lines = [f"m2m demo finished in {elapsed / 60:.1f} min; workspace {_show(ws)}/"]
    for stage, summary in st.items():
        lines.append(f"  {stage:<10} {where[stage]}: {summary['line']}")
    if "generate" in st:
        for task, t in st["generate"]["tasks"].items():
            lines.append(f"             {task}: {_show(Path(t['dataset']))} (preview.mp4, contact_sheet.png)")
    lines.append(f"  summary    {rel('demo_summary.json')}; stage records in {rel('pipeline.json')}")
    print("\n".join(lines), flush=True)


def _cmd_demo(args: argparse.Namespace) -> int:
    from .atomic import atomic_write
    from .pipeline import PipelineConfig, run_pipeline

    configure_threads()
    cfg = PipelineConfig(
        workspace=Path(args.workspace), keyframes=args.keyframes, scene_minutes=args.scene_minutes,
        episodes=args.episodes, workers=args.workers, stop_after=args.stop_after,
        sample=Path(args.sample) if args.sample else None,
    )  # fmt: skip
    ws = cfg.workspace
    if ws.exists() and not ws.is_dir():
        raise CliError(f"workspace {ws} exists and is not a directory; choose another with -w")
    t0 = time.perf_counter()
    try:
        result = run_pipeline(cfg, log=_info)
    except ValueError as e:
        raise CliError(str(e)) from None
    result["mirage2matter_version"] = __version__
    with atomic_write(ws / "demo_summary.json", "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1, default=str)
    _print_demo_summary(result, time.perf_counter() - t0)
    return 0


def _cmd_bench_train(args: argparse.Namespace) -> int:
    from .gaussians.bench_train import bench_train

    configure_threads()
    result = bench_train(
        args.data, minutes=args.minutes, downscale=args.downscale, poses=args.poses, work_dir=args.work_dir,
        max_gaussians=args.max_gaussians, progress=True,
    )  # fmt: skip
    keys = ("psnr_heldout", "ssim_heldout", "iterations", "gaussians", "minutes", "backend")
    _info(json.dumps(result.get("curve", []), separators=(",", ":")))
    print(json.dumps({k: result[k] for k in keys}))
    return 0


def _generate_config(args: argparse.Namespace):
    from .datagen.workspace import GenerateConfig

    return GenerateConfig(
        task=args.task, episodes=args.episodes, workers=args.workers, ray_address=args.ray_address,
        format=getattr(args, "format", "lerobot-v3.0"), seed=args.seed, out=getattr(args, "out", None),
        size=(args.size, args.size), fps=args.fps,
    )  # fmt: skip


def _datagen_errors():
    from .datagen import GenerateError, RunnerError
    from .export import StagingError

    return (GenerateError, RunnerError, StagingError)


def _cmd_generate(args: argparse.Namespace) -> int:
    from .datagen.workspace import generate

    if not args.task:
        raise CliError('--task is required, e.g. --task "grasp banana"')
    try:
        s = generate(args.workspace, _generate_config(args), log=_info)
    except _datagen_errors() as e:
        raise CliError(str(e)) from None
    rate = f"{s.get('demos_per_min')} demos/min with {s['workers']} {s['backend']} worker(s)"
    done = f"{s['episodes']} episodes ({s['failed']} failed attempts, success {s['success_rate']:.0%})"
    _info(f"{done} in {s['dataset']}; {rate}")
    print(json.dumps({k: s.get(k) for k in ("dataset", "episodes", "failed", "success_rate", "demos_per_min")}))
    return 0


def _cmd_validate(args: argparse.Namespace) -> int:
    from .export import validate

    problems = validate(args.dataset)
    for p in problems:
        _info(f"  - {p}")
    if problems:
        raise CliError(f"{args.dataset}: {len(problems)} problem(s) found (listed above)")
    info = json.loads((Path(args.dataset) / "meta" / "info.json").read_text(encoding="utf-8"))
    _info(f"{args.dataset}: valid LeRobot {info['codebase_version']} dataset, {info['total_episodes']} episodes, "
          f"{info['total_frames']} frames")  # fmt: skip
    return 0


def _cmd_bench_datagen(args: argparse.Namespace) -> int:
    from .datagen.workspace import BENCH_KEYS, bench_datagen

    try:
        result = bench_datagen(args.workspace, _generate_config(args), runs=args.runs, log=_info)
    except _datagen_errors() as e:
        raise CliError(str(e)) from None
    _info(json.dumps(result))
    print(json.dumps({k: result[k] for k in BENCH_KEYS}))
    return 0


def _cmd_capture(args: argparse.Namespace) -> int:
    from .capture import CaptureConfig, extract_keyframes

    out = Path(args.workspace) / "capture"
    out.parent.mkdir(parents=True, exist_ok=True)
    keyframes = extract_keyframes(args.source, out, CaptureConfig(max_keyframes=args.max_keyframes))
    print(f"wrote {len(keyframes)} keyframes and keyframes.json to {_show(out)}")
    return 0


def _cmd_sfm(args: argparse.Namespace) -> int:
    from .sfm import SfMConfig, SfMError, run_sfm
    from .sfm.importers import import_colmap_model, import_transforms

    ws = Path(args.workspace)
    config = SfMConfig(matching=args.matching, downscale=1.0 / args.downscale)
    if args.intrinsics:
        from .sfm.known_poses import with_fixed_intrinsics

        config = with_fixed_intrinsics(config, _load_intrinsics(Path(args.intrinsics)))
    try:
        if args.from_transforms:
            result = import_transforms(args.from_transforms, ws / "capture", ws / "sfm", config)
            how = f"imported {result.total} posed images from {args.from_transforms}; triangulated with those poses"
        elif args.from_colmap:
            if not args.images:
                raise CliError("--from-colmap needs --images DIR (the folder the model's image names are relative to)")
            result = import_colmap_model(args.from_colmap, args.images, ws / "capture", ws / "sfm")
            how = f"imported the COLMAP model {args.from_colmap}"
        else:
            images = ws / "capture"
            if not images.is_dir():
                raise CliError(f"{images} not found; run `m2m capture <video> -w {ws}` first")
            result = run_sfm(images, ws / "sfm", config)
            how = f"registered {result.registered}/{result.total} keyframes"
    except SfMError as e:
        raise CliError(str(e)) from None
    print(
        f"SfM: {how}, mean reprojection error {result.mean_reprojection_error:.2f} px, {len(result.points):,} points, "
        f"{result.seconds:.0f} s -> {_show(ws / 'sfm')}"
    )
    return 0


def _load_intrinsics(path: Path):
    """A Camera (pose unused) from a camera JSON, or from a JSON holding one under "camera" (e.g. a
    sample's ground_truth.json): K, width, height and optional distortion."""
    import numpy as np

    from .geometry.camera import Camera, CameraFormatError

    data = _peek_json(path)
    data = data.get("camera", data) if isinstance(data, dict) else data
    if not isinstance(data, dict) or "K" not in data or "width" not in data or "height" not in data:
        raise CliError(f"{path}: need a JSON with K (3x3), width and height (or such an object under 'camera')")
    try:
        return Camera.from_json({"T_world_cam": np.eye(4).tolist(), **data, "distortion": data.get("distortion") or {}},
                                source=str(path))  # fmt: skip
    except CameraFormatError as e:
        raise CliError(str(e)) from None


def _cmd_train_scene(args: argparse.Namespace) -> int:
    from .scene import SceneConfig, train_scene
    from .workspace import WorkspaceError

    configure_threads()
    config = SceneConfig(
        minutes=args.minutes, iterations=args.iterations, downscale=args.downscale, max_gaussians=args.max_gaussians,
        backend=_resolve_backend(args.backend),
    )  # fmt: skip
    try:
        config.validate()
        m = train_scene(args.workspace, config, force=args.force, log=_info)
    except (WorkspaceError, ValueError) as e:
        raise CliError(str(e)) from None
    scene = Path(args.workspace) / "scene"
    print(
        f"scene: held-out PSNR {m['psnr_heldout']:.2f} dB, SSIM {m['ssim_heldout']:.3f} over {m['views']['heldout']} "
        f"keyframes; {m['iterations']} iterations, {m['gaussians']:,} Gaussians, {m['train_minutes']:.1f} min "
        f"({m['frame']} frame) -> {_show(scene / 'gaussians.ply')}, metrics.json, heldout.png"
    )
    return 0


def _key_value(text: str, flag: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name or not value:
        raise CliError(f"{flag} {text!r}: expected NAME=VALUE")
    return name, value


def _cmd_objects(args: argparse.Namespace) -> int:
    from .objects import ObjectsError
    from .objects.matting import MattingConfig
    from .objects.splat import SplatConfig
    from .objects.stage import ObjectsConfig, run_objects

    meshes = dict(_key_value(t, "--mesh") for t in args.mesh)
    try:
        density = {k: float(v) for k, v in (_key_value(t, "--density") for t in args.density)}
    except ValueError:
        raise CliError("--density: expected NAME=KG_PER_M3 with a number") from None
    config = ObjectsConfig(
        names=args.names,
        prompts=args.prompts,
        masks_dir=args.masks,
        meshes=meshes,
        sam2_checkpoint=args.sam2_checkpoint,
        density=density,
        matting=MattingConfig(iterations=args.iterations),
        splat=SplatConfig(iterations=args.iterations),
    )
    try:
        out = run_objects(args.workspace, config, log=_info, progress=True)
    except ObjectsError as e:
        raise CliError(str(e)) from None
    for name, s in out.items():
        held = s["gaussians"]["heldout"]
        print(
            f"{name}: mesh {s['mesh']['volume'] * 1e6:.1f} cm3, {s['mesh']['mass'] * 1000:.0f} g, watertight "
            f"{s['mesh']['watertight']}, {s['collision']['parts']} convex parts; 3DGS masked PSNR "
            f"{held['psnr_masked']:.2f} dB, alpha outside {held['alpha_outside']:.3f}; Gaussians to mesh "
            f"{1000 * s['alignment']['median_distance_to_mesh_m']:.2f} mm (median)"
        )
    print(f"-> {_show(Path(args.workspace) / 'objects')}/<name>/ (mesh.obj, collision/, gaussians.ply, align.json)")
    return 0


def _cmd_align_scene(args: argparse.Namespace) -> int:
    import numpy as np
    import pycolmap
    from PIL import Image

    from .atomic import atomic_write
    from .calib.align import align_scene, default_T_base_board, save_alignment
    from .calib.board import BoardSpec
    from .sfm import load_sfm_summary

    ws = Path(args.workspace)
    if not (ws / "sfm" / "sfm.json").is_file():
        raise CliError(f"{ws / 'sfm'} has no SfM result; run `m2m sfm -w {ws}` first")
    board = BoardSpec.load(args.board)
    T_base_board = default_T_base_board(board)
    if args.board_pose:
        data = json.loads(Path(args.board_pose).read_text())
        T_base_board = np.asarray(data.get("T_base_board") or data["board"]["T_base_board"], dtype=np.float64)
    _, cameras = load_sfm_summary(ws / "sfm")
    rec = pycolmap.Reconstruction(str(ws / "sfm" / "model"))
    points = np.array([p.xyz for p in rec.points3D.values()]).reshape(-1, 3)
    images = [np.asarray(Image.open(ws / "capture" / c.name).convert("RGB")) for c in cameras]
    footprint = None
    if args.robot.lower() != "none":
        from .calib.kinematics import RobotKinematics

        try:
            footprint = RobotKinematics(args.robot).base_footprint()
        except (FileNotFoundError, ValueError) as e:
            raise CliError(f"--robot {args.robot}: {e}") from None
    result = align_scene(cameras, images, points, board, T_base_board, icp=not args.no_icp, footprint_xy=footprint)
    sim = result.sim3_sfm_to_base
    calib = ws / "calib"
    cameras_base = save_alignment(calib, result, T_base_board, board, cameras, points)
    overlay = _base_overlay(images, cameras_base, result.triangulation.frames_with_board, footprint)
    with atomic_write(calib / "overlay.png", "wb") as f:
        Image.fromarray(overlay).save(f, format="PNG")
    print(
        f"aligned SfM to the robot base: scale {sim.scale:.5f}, board corners {result.corner_rms_mm:.2f} mm RMS "
        f"from {len(result.triangulation.ids)} corners in {len(result.triangulation.frames_with_board)} keyframes"
        f"{'' if result.icp_rmse_mm is None else f', ICP {result.icp_rmse_mm:.1f} mm over {result.icp_points} points'}"
        f" -> {_show(calib)}/ (sim3_sfm_to_base.json, cameras_base.json, points_base.npy, overlay.png)"
    )
    return 0


def _base_overlay(images, cameras_base, frames_with_board, footprint_xy=None) -> Any:
    """The robot base footprint (from the robot model, else a 10 cm circle at the origin) and the
    base axes (x red, y green, z blue, 15 cm) drawn into a keyframe that sees the board."""
    import cv2
    import numpy as np

    k = next(i for i, c in enumerate(cameras_base) if c.name in frames_with_board)
    cam, image = cameras_base[k], images[k].copy()
    if footprint_xy is None:
        t = np.linspace(0, 2 * np.pi, 64)
        footprint_xy = 0.1 * np.c_[np.cos(t), np.sin(t)]
    outline = np.c_[footprint_xy, np.zeros(len(footprint_xy))]
    axes = np.array([[0, 0, 0], [0.15, 0, 0], [0, 0.15, 0], [0, 0, 0.15]], float)

    def px(points):
        uv, depth = cam.project(points)
        return [tuple(int(round(v)) for v in p - 0.5) for p in uv], depth

    outline_px, _ = px(outline)
    cv2.polylines(image, [np.asarray(outline_px, np.int32)], True, (255, 0, 255), 2, cv2.LINE_AA)
    (o, x, y, z), _ = px(axes)
    for end, colour in ((x, (255, 0, 0)), (y, (0, 255, 0)), (z, (0, 0, 255))):
        cv2.line(image, o, end, colour, 2, cv2.LINE_AA)
    return image


def _cmd_board(args: argparse.Namespace) -> int:
    from .calib.board import BoardSpec, write_printable

    try:
        sx, sy = (int(v) for v in args.squares.lower().split("x"))
    except ValueError:
        raise CliError(f"--squares must look like 5x7, got {args.squares!r}") from None
    spec = BoardSpec(sx, sy, args.square, args.marker, f"DICT_{args.dict.upper().removeprefix('DICT_')}")
    out = write_printable(spec, args.out, dpi=args.dpi)
    w, h = out["size_mm"]
    print(
        f"wrote {_show(out['pdf'])}, {_show(out['png'])} and {_show(out['json'])}: {sx}x{sy} squares of "
        f"{args.square * 1000:g} mm, sheet {w:.0f} x {h:.0f} mm. Print at 100% (no fit-to-page) and measure "
        "one square: it must be exactly that size"
    )
    return 0


def _cmd_calibrate_handeye(args: argparse.Namespace) -> int:
    import numpy as np

    from .atomic import atomic_write
    from .calib.board import BoardSpec
    from .calib.handeye import calibrate_from_files

    intrinsics = json.loads(Path(args.intrinsics).read_text())
    K = intrinsics.get("K") or intrinsics.get("head_camera", {}).get("K")
    if K is None:
        raise CliError(f"{args.intrinsics}: no 'K' (3x3) found; pass a camera JSON with the camera's intrinsics")
    result, out = calibrate_from_files(
        args.images, args.joints, BoardSpec.load(args.board), np.asarray(K, dtype=np.float64),
        mount=args.mount, method=args.method, robot=args.robot, link=args.link, refine=not args.no_refine,
    )  # fmt: skip
    cam = intrinsics.get("head_camera", intrinsics)
    if "width" in cam and "height" in cam:
        out["width"], out["height"] = int(cam["width"]), int(cam["height"])
    path = Path(args.workspace) / "calib" / "handeye.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "w", encoding="utf-8") as f:
        json.dump(out, f, indent=1)
    print(
        f"hand-eye ({args.mount}, {args.method}{'' if args.no_refine else ' + reprojection refinement'}): "
        f"{len(out['per_view'])} views used, {len(out['skipped'])} skipped; residual median "
        f"{out['residual_deg_median']:.3f} deg / {out['residual_mm_median']:.2f} mm -> {_show(path)}"
    )
    return 0


def _cmd_head_view(args: argparse.Namespace) -> int:
    import numpy as np
    from PIL import Image

    from .calib.board import BoardSpec
    from .calib.headview import check_head_view, save_head_view
    from .gaussians.ply import read_ply
    from .geometry.camera import Camera

    ws = Path(args.workspace)
    ply, he_path = ws / "scene" / "gaussians.ply", ws / "calib" / "handeye.json"
    align_path = ws / "calib" / "sim3_sfm_to_base.json"
    for path, stage in ((ply, "train-scene"), (he_path, "calibrate-handeye"), (align_path, "align-scene")):
        if not path.is_file():
            raise CliError(f"{path} not found; run `m2m {stage} -w {ws}` first")
    he, al = json.loads(he_path.read_text()), json.loads(align_path.read_text())
    if he.get("mount") != "head":
        raise CliError(f"{he_path}: mount is {he.get('mount')!r}; the head-view check needs a head camera")
    photo = np.asarray(Image.open(args.photo).convert("RGB")) if args.photo else None
    width, height = he.get("width"), he.get("height")
    if width is None:
        if photo is None:
            raise CliError(f"{he_path} has no image size; pass --photo (a head-camera image) to take it from")
        height, width = photo.shape[:2]
    cam = Camera(he["K"], he["T_base_headcam"], width, height, "head")
    try:
        check = check_head_view(read_ply(ply), cam, photo, BoardSpec.from_json(al["board"]),
                                np.asarray(al["T_base_board"]), backend=_resolve_backend(args.backend))  # fmt: skip
    except ValueError as e:
        raise CliError(str(e)) from None
    out = Path(args.out) if args.out else ws / "calib" / "head_view.png"
    save_head_view(out, check, photo)
    known, seen = check.corners_vs_known_px, check.corners_vs_photo_px
    parts = [] if check.psnr is None else [f"PSNR {check.psnr:.2f} dB vs the photo"]
    if known.get("n"):
        parts.append(f"board corners {known['median']:.2f} px (median, {known['n']}) from the board's known pose")
    if seen.get("n"):
        parts.append(f"{seen['median']:.2f} px from the photo's")
    print(f"head view: {'; '.join(parts) or 'board not seen in the render'} -> {_show(out)} (+ .json)")
    return 0


def _cmd_sample_make(args: argparse.Namespace) -> int:
    from .sample.make import SampleConfig, make_sample

    config = SampleConfig.short(args.seed) if args.short else SampleConfig(seed=args.seed)
    make_sample(args.dir, config, log=_info)
    print(f"wrote the sample to {args.dir} (ground_truth.json, scene.mp4, handeye/, gt/, contact_sheet.jpg)")
    return 0


def _xyz(text: str, flag: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 3:
        raise CliError(f"{flag} must be three numbers x,y,z (metres, robot-base frame), got {text!r}")
    return v


def _cmd_compose(args: argparse.Namespace) -> int:
    from .world import WorkspaceWorldOptions, from_workspace, load_world, sample_world
    from .world.compose import consistency, write_world_ply
    from .world.config import world_yaml_path

    ws = Path(args.workspace)
    if args.sample:
        sample_world(args.sample, ws, overwrite=args.overwrite)
    elif args.rebuild or not world_yaml_path(ws).is_file():  # the world from the workspace's reconstruction
        opts = WorkspaceWorldOptions(buttons=tuple(args.button), crop_margin=args.crop_margin)
        from_workspace(ws, opts, log=_info)
    cfg = load_world(ws)
    ply = write_world_ply(cfg)
    cons = consistency(cfg)
    print(f"world: {len(cfg.objects)} objects, {len(cfg.articulated)} articulated -> {_show(ply)} (+ world.json)")
    for name, d in cons.items():
        print(f"  {name}: median Gaussian-to-mesh distance {1000 * d:.2f} mm")
    worst = max(cons.values(), default=0.0)
    if worst > args.max_mm / 1000:
        raise CliError(f"an object's Gaussians and mesh disagree by {1000 * worst:.1f} mm (> {args.max_mm} mm)")
    return 0


def _cmd_world(args: argparse.Namespace) -> int:
    from .world import edit, load_world, save_world
    from .world.compose import write_world_ply

    cfg = load_world(args.workspace)
    op = args.op
    if op == "delete":
        new = edit.delete(cfg, args.name)
    elif op == "import-placement":
        new, sim = edit.import_placement(cfg, args.name, args.ply)
        print(f"{args.name}: placement from {args.ply}: {sim}")
    elif op == "match-lighting":
        new, gain = edit.match_lighting(cfg, args.name, strength=args.strength, radius=args.radius)
        print(f"{args.name}: colour gain r,g,b = {', '.join(f'{g:.3f}' for g in gain)}")
    else:
        base = None if op == "insert" else edit.placement_of(cfg, args.name)
        if op == "move" and args.by:
            d = _xyz(args.by, "--by")
            placement = edit.placement_from_pose(base.translation + d, args.yaw, base.scale, base)
        else:
            if not args.to:
                raise CliError(f"`m2m world {op}` needs --to x,y,z")
            scale = args.scale if args.scale else (base.scale if base is not None else 1.0)
            placement = edit.placement_from_pose(_xyz(args.to, "--to"), args.yaw, scale, base)
        if op == "insert":
            new = edit.insert(cfg, args.name, args.gaussians, args.mesh, placement, collision=args.collision,
                              mass=args.mass)  # fmt: skip
        elif op == "move":
            new = edit.move(cfg, args.name, placement)
        else:
            new = edit.duplicate(cfg, args.name, args.as_name, placement)
    save_world(new)
    ply = write_world_ply(new)
    print(f"{op} {args.name}: saved {_show(new.root / 'world.yaml')}, recomposed {_show(ply)}")
    return 0


def _cmd_task(args: argparse.Namespace) -> int:
    from .atomic import atomic_write
    from .sim.tasks import evaluate, parse_task
    from .sim.twin import Twin, TwinOptions
    from .world import load_world

    cfg = load_world(args.workspace)
    specs = [parse_task(t, cfg) for t in args.task]  # unknown tasks / objects fail before Genesis starts
    out = Path(args.out) if args.out else cfg.root / "task_summary.json"
    _check_output(out, "--out", (".json",))
    t0 = time.perf_counter()
    twin = Twin.build(cfg, TwinOptions(render=False))
    build_s = time.perf_counter() - t0
    results = []
    for spec in specs:
        r = evaluate(twin, spec, args.episodes, seed=args.seed, progress=True)
        results.append(r)
        print(
            f"{spec.instruction!r}: {r['successes']}/{r['episodes']} = {100 * r['success_rate']:.0f}% "
            f"(mean {r['mean_sim_s']:.1f} s simulated, {r['mean_wall_s']:.2f} s wall per episode)"
        )
    summary = {"world": str(cfg.root / "world.yaml"), "build_s": build_s, "seed": args.seed, "tasks": results}
    with atomic_write(out, "w", encoding="utf-8") as f:
        json.dump(summary, f, indent=1)
    print(f"-> {_show(out)}")
    return 0


# ---- the parser ---------------------------------------------------------------------------------------------
def _generation_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("-w", "--workspace", required=True, type=Path, help="workspace folder (with world/world.yaml)")
    p.add_argument("--task", help='instruction, e.g. "grasp banana", "press button", "push croissant --direction 0,1"')
    p.add_argument("--episodes", type=_int_at_least(1), required=True, metavar="N", help="successful episodes wanted")
    p.add_argument("--workers", type=_int_at_least(1), default=1, metavar="W", help="parallel workers (default 1)")
    p.add_argument("--ray-address", metavar="ADDR", help="run the workers on Ray: auto, host:port, or local")
    p.add_argument("--seed", type=_int_at_least(0), default=0, help="run seed (default 0): same seed, same episodes")
    p.add_argument("--size", type=_int_at_least(2), default=224, metavar="S", help="square frame side (default 224)")
    p.add_argument("--fps", type=_int_at_least(1), default=10, help="control and video rate (default 10 Hz)")


def build_parser() -> argparse.ArgumentParser:
    fmt = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(
        prog="m2m",
        description=(
            "Mirage2Matter: multi-view video of a robot workspace -> photorealistic, physically grounded simulator."
        ),
        epilog=(
            "examples:\n"
            "  m2m demo                                   what the pipeline does today, in ./workspaces/demo\n"
            "  m2m render scene.ply --camera cam.json --out view.png\n"
            "  m2m render scene.ply --camera transforms.json --frame 0001 --out view.png --scale 0.5\n"
            "  m2m bench render --gaussians 100000 --size 224"
        ),
        formatter_class=fmt,
    )
    parser.add_argument("--version", action="version", version=f"m2m (mirage2matter) {__version__}")
    parser.add_argument("--debug", action="store_true", help="show Python tracebacks for errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    # m2m render
    p = sub.add_parser(
        "render",
        help="render a 3DGS PLY from a camera to a PNG",
        description=(
            "Render a 3D Gaussian Splatting PLY (Inria layout) from one camera to an 8-bit RGB PNG.\n"
            f"The camera is a JSON file {_CAMERA_FIELDS};\n"
            "or, with --frame NAME, one frame of an instant-ngp / nerfstudio transforms.json."
        ),
        formatter_class=fmt,
    )
    p.add_argument("ply", help="3DGS .ply file")
    p.add_argument("--camera", required=True, metavar="JSON", help="camera JSON, or transforms.json with --frame")
    p.add_argument("--frame", metavar="NAME", help="frame of the transforms.json: file_path, basename or stem")
    p.add_argument("--out", required=True, metavar="PNG", help="output image (.png); its directory must exist")
    p.add_argument(
        "--backend",
        default="auto",
        choices=("auto", "cpu", "cuda", "reference"),
        help="renderer (default auto: cuda if available, else cpu)",
    )
    p.add_argument(
        "--background",
        type=_rgb,
        default=(0.0, 0.0, 0.0),
        metavar="R,G,B",
        help="background colour in 0..1 (default 0,0,0)",
    )
    p.add_argument(
        "--scale", type=_positive_float, default=1.0, metavar="F", help="resize the camera by F (0.5 = half resolution)"
    )
    p.add_argument(
        "--depth-out",
        metavar="PNG|NPY",
        help="also write expected depth: .npy float32 metres or .png uint16 millimetres (0 = nothing)",
    )
    p.set_defaults(func=_cmd_render)

    # m2m bench render
    bench = sub.add_parser("bench", help="benchmarks (prints one JSON line last on stdout)")
    bench_sub = bench.add_subparsers(dest="what", metavar="WHAT", required=True)
    b = bench_sub.add_parser(
        "render",
        help="time the renderer on a synthetic tabletop scene",
        description=(
            "Time render() on tabletop_scene(N) from V orbit cameras: W untimed warm-up renders, then R rounds "
            "of all V views. Progress goes to stderr; the last stdout line is JSON with backend, gaussians, width, "
            "height, sh_degree, ms_median, ms_min, ms_max, runs."
        ),
    )
    b.add_argument("--gaussians", type=_int_at_least(1), required=True, metavar="N", help="scene size")
    b.add_argument("--size", type=_int_at_least(1), required=True, metavar="S", help="square image side in pixels")
    b.add_argument(
        "--backend", default="auto", choices=("auto", "cpu", "cuda"), help="default auto: cuda if available, else cpu"
    )
    b.add_argument("--sh-degree", type=int, default=3, choices=range(4), metavar="D", help="SH degree 0..3 (default 3)")
    b.add_argument("--views", type=_int_at_least(1), default=8, metavar="V", help="cameras per round (default 8)")
    b.add_argument("--repeats", type=_int_at_least(1), default=5, metavar="R", help="timed rounds (default 5)")
    b.add_argument(
        "--warmup", type=_int_at_least(0), default=2, metavar="W", help="untimed warm-up renders (default 2)"
    )
    b.add_argument("--seed", type=_int_at_least(0), default=0, help="scene and camera seed (default 0)")
    b.set_defaults(func=_cmd_bench_render)
    bt = bench_sub.add_parser(
        "train",
        help="train 3DGS on a transforms.json capture for M minutes; held-out PSNR/SSIM as a JSON line last",
    )
    bt.add_argument("--data", required=True, metavar="DIR", help="folder with transforms.json + images (e.g. fox)")
    bt.add_argument("--minutes", type=_positive_float, default=15.0, metavar="M", help="training time (default 15)")
    bt.add_argument("--downscale", type=_int_at_least(1), default=4, metavar="F", help="1/F resolution (default 4)")
    bt.add_argument("--poses", default="given", choices=("given", "sfm"), help="given poses or our own SfM")
    bt.add_argument("--work-dir", metavar="DIR", help="cache for the SfM used for initial points")
    bt.add_argument("--max-gaussians", type=_int_at_least(1000), default=150_000, metavar="N")
    bt.set_defaults(func=_cmd_bench_train)
    bd_ = bench_sub.add_parser(
        "datagen",
        help="demonstrations per minute on a workspace's world; JSON line last",
        description=(
            "Generate N episodes R times into throw-away folders; the last stdout line is JSON with demos_per_min "
            "(workers warm), success_rate, episodes, frames, workers, backend, ms_per_frame (medians over runs)."
        ),
    )
    _generation_args(bd_)
    bd_.add_argument("--runs", type=_int_at_least(1), default=1, metavar="R", help="repetitions (default 1)")
    bd_.set_defaults(func=_cmd_bench_datagen, task="grasp banana")

    # m2m demo
    d = sub.add_parser(
        "demo",
        help="the whole pipeline on the bundled sample: video -> reconstruction -> world -> demonstrations",
        description=(
            "Run every stage on the bundled sample capture (as it would run on yours): keyframes, SfM, metric "
            "alignment, hand-eye, scene 3DGS and its head-camera check, objects, the world and its Genesis twin, "
            "and a few LeRobot demonstrations per task, validated. Each stage is recorded in pipeline.json; a "
            "rerun (e.g. after an interruption) skips the finished ones."
        ),
    )
    d.add_argument("-w", "--workspace", default="workspaces/demo", metavar="DIR", help="default ./workspaces/demo")
    d.add_argument("--keyframes", type=_int_at_least(8), default=40, metavar="N", help="keyframes (default 40)")
    d.add_argument("--scene-minutes", type=_positive_float, default=6.0, metavar="M", help="3DGS budget (default 6)")
    d.add_argument("--episodes", type=_int_at_least(1), default=3, metavar="N", help="demonstrations per task (3)")
    d.add_argument("--workers", type=_int_at_least(1), default=2, metavar="W", help="generation workers (default 2)")
    from .pipeline import STAGES

    d.add_argument("--stop-after", default="generate", choices=STAGES, help="last stage to run (default: all)")
    d.add_argument("--sample", metavar="DIR", help=argparse.SUPPRESS)
    d.set_defaults(func=_cmd_demo)

    # m2m capture / m2m sfm
    c = sub.add_parser(
        "capture",
        help="pick keyframes (sharpness + parallax) from a video or an image folder into <workspace>/capture",
    )
    c.add_argument("source", help="video file (mp4/mov/mkv) or folder of images")
    c.add_argument("-w", "--workspace", required=True, metavar="DIR", help="workspace folder")
    c.add_argument("--max-keyframes", type=_int_at_least(3), default=60, metavar="N", help="at most N (default 60)")
    c.set_defaults(func=_cmd_capture)
    s_ = sub.add_parser("sfm", help="COLMAP structure-from-motion of <workspace>/capture into <workspace>/sfm")
    s_.add_argument("-w", "--workspace", required=True, metavar="DIR", help="workspace folder")
    s_.add_argument(
        "--matching", default="auto", choices=("auto", "sequential", "exhaustive"), help="default auto: exhaustive < 40"
    )
    s_.add_argument("--downscale", type=_positive_float, default=1.0, metavar="F", help="match at 1/F resolution")
    src = s_.add_mutually_exclusive_group()
    src.add_argument(
        "--from-transforms", metavar="JSON",
        help="import poses from an instant-ngp / nerfstudio transforms.json (copies its images into capture/, "
        "triangulates points with the given poses; keeps its world frame)",
    )  # fmt: skip
    src.add_argument("--from-colmap", metavar="MODEL_DIR", help="import a COLMAP sparse model (needs --images)")
    s_.add_argument("--images", metavar="DIR", help="with --from-colmap: the folder holding the model's images")
    s_.add_argument(
        "--intrinsics", metavar="JSON",
        help="known camera intrinsics (K, width, height, distortion), held fixed; more accurate poses than "
        "self-calibration when the camera is calibrated",
    )  # fmt: skip
    s_.set_defaults(func=_cmd_sfm)

    # m2m train-scene
    ts = sub.add_parser(
        "train-scene", help="scene 3D Gaussian Splatting from <workspace>'s posed keyframes -> <workspace>/scene"
    )
    ts.add_argument("-w", "--workspace", required=True, metavar="DIR", help="workspace with capture/ and sfm/")
    ts.add_argument("--minutes", type=_positive_float, default=10.0, metavar="M", help="training budget (default 10)")
    ts.add_argument("--iterations", type=_int_at_least(0), default=0, metavar="N", help="fixed iterations instead")
    ts.add_argument("--downscale", type=_int_at_least(1), default=2, metavar="F", help="train at 1/F (default 2)")
    ts.add_argument("--max-gaussians", type=_int_at_least(1000), default=200_000, metavar="N")
    ts.add_argument("--backend", default="auto", choices=("auto", "cpu", "cuda"))
    ts.add_argument("--force", action="store_true", help="retrain even if an identical run finished")
    ts.set_defaults(func=_cmd_train_scene)

    # m2m objects
    ob = sub.add_parser(
        "objects", help="per object: masks, watertight mesh + collision parts, object 3DGS, aligned, in one frame"
    )
    ob.add_argument("-w", "--workspace", required=True, metavar="DIR", help="workspace with capture/ and calib/")
    ob.add_argument(
        "--names", nargs="+", default=[], metavar="NAME", help="names for the objects found, nearest the base first "
        "(NAME=x,y picks the object nearest that base-frame point); default object_0, object_1, ..."
    )  # fmt: skip
    ob.add_argument(
        "--prompts", nargs="+", default=[], metavar="PROMPT",
        help="NAME@KEYFRAME:box=x0,y0,x1,y1 or NAME@KEYFRAME:points=x,y;x,y (pixels in that keyframe)",
    )  # fmt: skip
    ob.add_argument("--masks", metavar="DIR", help="masks from a folder: DIR/<name>/<keyframe stem>.png")
    ob.add_argument("--mesh", action="append", default=[], metavar="NAME=FILE", help="user mesh (obj/stl/glb)")
    ob.add_argument("--sam2-checkpoint", metavar="PATH", help="SAM2 masks with this local checkpoint")
    ob.add_argument("--density", action="append", default=[], metavar="NAME=KG_M3", help="default 500 kg/m3")
    ob.add_argument("--iterations", type=_int_at_least(1), default=1000, metavar="N", help="3DGS steps (1000)")
    ob.set_defaults(func=_cmd_objects)

    # m2m align-scene
    al = sub.add_parser(
        "align-scene", help="metric alignment of <workspace>/sfm to the robot base via the ChArUco board"
    )
    al.add_argument("-w", "--workspace", required=True, metavar="DIR", help="workspace with capture/ and sfm/")
    al.add_argument("--board", required=True, metavar="JSON", help="board spec (from `m2m board`)")
    al.add_argument(
        "--board-pose",
        metavar="JSON",
        help="a JSON with T_base_board (4x4) if the board is not centred on the base with its x along base x",
    )
    al.add_argument("--no-icp", action="store_true", help="board corners only, no ICP refinement")
    al.add_argument(
        "--robot", default="xml/franka_emika_panda/panda.xml", metavar="URDF|MJCF",
        help="robot model whose base footprint bounds the ICP support region and is drawn in the overlay "
        "(default: Genesis' Franka Panda; 'none' for a 10 cm circle)",
    )  # fmt: skip
    al.set_defaults(func=_cmd_align_scene)

    # m2m board
    bd = sub.add_parser("board", help="a printable ChArUco board at true scale (PDF + PNG) and its JSON spec")
    bd.add_argument("--out", required=True, metavar="PDF", help="output .pdf (a .png and .json go beside it)")
    bd.add_argument("--squares", default="5x7", help="squares across x down (default 5x7)")
    bd.add_argument("--square", type=_positive_float, default=0.04, metavar="M", help="square side, metres (0.04)")
    bd.add_argument("--marker", type=_positive_float, default=0.03, metavar="M", help="marker side, metres (0.03)")
    bd.add_argument("--dict", default="5X5_100", help="ArUco dictionary (default 5X5_100)")
    bd.add_argument("--dpi", type=_int_at_least(72), default=300, help="print resolution (default 300)")
    bd.set_defaults(func=_cmd_board)

    # m2m calibrate-handeye
    h = sub.add_parser(
        "calibrate-handeye",
        help="camera mount from images of a ChArUco board + the robot's joint angles (Tsai-Lenz + refinement)",
    )
    h.add_argument("--images", required=True, metavar="DIR", help="folder of board images")
    h.add_argument("--joints", required=True, metavar="JSON", help='{"robot", "link", "views": [{"image", "joints"}]}')
    h.add_argument("--board", required=True, metavar="JSON", help="board spec (e.g. from `m2m board`)")
    h.add_argument("--intrinsics", required=True, metavar="JSON", help="a JSON with the camera's 'K' (3x3)")
    h.add_argument("-w", "--workspace", required=True, metavar="DIR", help="writes <DIR>/calib/handeye.json")
    h.add_argument("--mount", default="head", choices=("head", "wrist"), help="head: eye-to-hand (default)")
    h.add_argument("--method", default="tsai", choices=("tsai", "park", "horaud", "andreff", "daniilidis"))
    h.add_argument("--robot", help="robot MJCF/URDF (default: from the joints file, else Genesis' Panda)")
    h.add_argument("--link", help="gripper link (default: from the joints file, else 'hand')")
    h.add_argument("--no-refine", action="store_true", help="skip the reprojection refinement")
    h.set_defaults(func=_cmd_calibrate_handeye)

    # m2m generate / validate
    g = sub.add_parser(
        "generate",
        help="demonstrations of a task in the workspace's world -> a LeRobot dataset in <ws>/datasets/<task>",
        description=(
            "Run the task in the Genesis twin of <ws>/world/world.yaml with randomised start poses, render head and "
            "wrist hybrid frames (splats + robot), and write the successful episodes as a LeRobot dataset with "
            "summary.json, preview.mp4 and contact_sheet.png. A killed run resumes when rerun with the same options."
        ),
    )
    _generation_args(g)
    g.add_argument("--format", default="lerobot-v3.0", choices=("lerobot-v3.0", "lerobot-v2.1"),
                   help="dataset format (v2.1 for openpi; default v3.0)")  # fmt: skip
    g.add_argument("--out", type=Path, metavar="DIR", help="dataset folder (default <ws>/datasets/<task>)")
    g.set_defaults(func=_cmd_generate)
    v = sub.add_parser("validate", help="check a LeRobot v3.0 / v2.1 dataset with an independent reader")
    v.add_argument("dataset", help="dataset folder")
    v.set_defaults(func=_cmd_validate)

    # m2m sample make
    hv = sub.add_parser(
        "head-view", help="render the scene from the calibrated head camera; compare with a head-camera photo"
    )
    hv.add_argument("-w", "--workspace", required=True, metavar="DIR", help="workspace with scene/ and calib/")
    hv.add_argument("--photo", metavar="PNG", help="an image the head camera took of the same scene")
    hv.add_argument("--out", metavar="PNG", help="default <workspace>/calib/head_view.png (render | photo)")
    hv.add_argument("--backend", default="auto", choices=("auto", "cpu", "cuda"))
    hv.set_defaults(func=_cmd_head_view)

    sample = sub.add_parser("sample", help="the bundled sample capture with ground truth")
    sample_sub = sample.add_subparsers(dest="what", metavar="WHAT", required=True)
    sm = sample_sub.add_parser(
        "make",
        help="render a sample capture (video + hand-eye images + ground truth) with Genesis",
        description=(
            "Render a hand-held video orbiting a table with a ChArUco board, two objects and a button, the fixed "
            "head camera's hand-eye images of a board held by a Franka Panda, and ground_truth.json, into a NEW "
            "directory (written under a temporary name and renamed when complete). Deterministic for a seed."
        ),
    )
    sm.add_argument("dir", help="output directory (must not exist, or be empty)")
    sm.add_argument("--seed", type=_int_at_least(0), default=0, help="scene and trajectory seed (default 0)")
    sm.add_argument("--short", action="store_true", help="a quick version: 4 s of video at 5 fps, 6 hand-eye views")
    sm.set_defaults(func=_cmd_sample_make)

    # m2m compose / m2m world <edit> / m2m task
    co = sub.add_parser(
        "compose", help="world/world.yaml (from the workspace's reconstruction when absent) -> world/world.ply, checked"
    )
    co.add_argument("-w", "--workspace", required=True, metavar="DIR", help="workspace (world/world.yaml is made "
                    "from scene/, objects/ and calib/handeye.json when absent)")  # fmt: skip
    co.add_argument("--sample", metavar="DIR", help="first write the world from a sample's ground truth")
    co.add_argument("--overwrite", action="store_true", help="with --sample: rebuild existing object folders")
    co.add_argument("--rebuild", action="store_true", help="rewrite world.yaml from the workspace's reconstruction")
    co.add_argument("--button", action="append", default=[], metavar="NAME",
                    help="a reconstructed object that is a press button (names with 'button' always are)")
    co.add_argument("--crop-margin", type=_positive_float, default=0.01, metavar="M",
                    help="scene Gaussians this close to an object's mesh are removed (0.01 m)")  # fmt: skip
    co.add_argument("--max-mm", type=_positive_float, default=3.0, help="max median Gaussian-mesh distance (3 mm)")
    co.set_defaults(func=_cmd_compose)
    wo = sub.add_parser("world", help="edit world.yaml: insert, move, duplicate, delete, import-placement, ...")
    wo_sub = wo.add_subparsers(dest="op", metavar="OP", required=True)
    for op, text in (
        ("insert", "add an object from a Gaussian PLY + a mesh"),
        ("move", "move an object (--to x,y,z or --by dx,dy,dz; --yaw about z)"),
        ("duplicate", "copy an object under a new name (--as NAME --to x,y,z)"),
        ("delete", "remove an object"),
        ("import-placement", "take an object's placement from a PLY moved in SuperSplat"),
        ("match-lighting", "shift an object's colours toward the scene's illumination"),
    ):
        w = wo_sub.add_parser(op, help=text)
        w.add_argument("-w", "--workspace", required=True, metavar="DIR")
        w.add_argument("--name", required=True)
        if op in ("insert", "move", "duplicate"):
            w.add_argument("--to", metavar="X,Y,Z", help="new origin in the base frame (m)")
            w.add_argument("--yaw", type=float, default=0.0, help="turn about z (deg)")
            w.add_argument("--scale", type=_positive_float, help="placement scale (default: kept, or 1)")
        if op == "move":
            w.add_argument("--by", metavar="DX,DY,DZ", help="shift by (m)")
        if op == "insert":
            w.add_argument("--gaussians", required=True, metavar="PLY")
            w.add_argument("--mesh", required=True, metavar="OBJ")
            w.add_argument("--collision", metavar="DIR", help="convex parts (*.obj); computed when absent")
            w.add_argument("--mass", type=_positive_float, help="kg (default: density 500 kg/m^3)")
        if op == "duplicate":
            w.add_argument("--as", dest="as_name", required=True, metavar="NEW")
        if op == "import-placement":
            w.add_argument("--ply", required=True, help="the object's (or world.ply's) Gaussians, moved")
        if op == "match-lighting":
            w.add_argument("--strength", type=_positive_float, default=1.0, help="0..1 of the full correction")
            w.add_argument("--radius", type=_positive_float, default=0.3, help="scene neighbourhood (m)")
        w.set_defaults(func=_cmd_world)
    ta = sub.add_parser("task", help="run scripted tasks on randomised starts in the Genesis twin -> summary.json")
    ta.add_argument("-w", "--workspace", required=True, metavar="DIR", help="workspace with world/world.yaml")
    ta.add_argument("task", nargs="+", help='e.g. "grasp banana" "press button" "push croissant --direction 0,1"')
    ta.add_argument("--episodes", type=_int_at_least(1), default=50, metavar="N", help="per task (default 50)")
    ta.add_argument("--seed", type=_int_at_least(0), default=0, help="first reset seed (default 0)")
    ta.add_argument("--out", metavar="JSON", help="default <workspace>/world/task_summary.json")
    ta.set_defaults(func=_cmd_task)
    return parser


def _describe(e: BaseException) -> str:
    if isinstance(e, OSError) and e.filename and e.strerror:
        return f"{e.filename}: {e.strerror}"
    return str(e) or type(e).__name__


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``m2m`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, --version and usage errors; return rather than exit for in-process callers
        return e.code if isinstance(e.code, int) else (0 if e.code is None else EXIT_ERROR)
    debug = args.debug or os.environ.get("M2M_DEBUG", "") not in ("", "0")
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("m2m: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (CliError, ValueError, OSError) as e:
        # ValueError covers PlyFormatError, CameraFormatError and the validators' messages, which
        # name the file / field; OSError covers missing or unwritable files.
        if debug:
            raise
        print(f"m2m: error: {_describe(e)}", file=sys.stderr)
        return EXIT_ERROR
