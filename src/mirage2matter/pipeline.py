"""The whole pipeline over one workspace, stage by stage: what ``m2m demo`` runs on the bundled sample.

video -> keyframes -> SfM -> metric alignment -> hand-eye -> scene 3DGS (+ head-camera check) ->
objects -> world (Gaussians + Genesis twin) -> demonstrations per task (LeRobot) -> validation.

Every stage calls the same functions as its ``m2m`` command and writes its artifacts atomically.
``<ws>/pipeline.json`` records each finished stage with the settings it ran with; a rerun skips a
stage whose record matches and whose outputs exist, so a killed ``make demo`` resumes where it was.
On the sample, stages also compare with the ground truth (``ground_truth.json``) and say how close
they came; a user's capture has no ground truth and those lines are skipped.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import atomic_write

__all__ = ["PipelineConfig", "STAGES", "run_pipeline"]

STAGES = ("capture", "sfm", "align", "handeye", "scene", "head_view", "objects", "world", "generate")


@dataclass
class PipelineConfig:
    """Settings of the demo pipeline (defaults: the bundled sample, about 25 minutes on 2 cores).

    sample           a capture folder in the bundled sample's layout (scene.mp4, board.json,
                     ground_truth.json with the camera calibration, handeye/ images + joints)
    keyframes        keyframes for SfM and training
    scene_minutes    scene 3DGS training budget
    objects          object names to reconstruct (empty: every object found)
    tasks            task strings, as for ``m2m generate --task``
    episodes         demonstrations per task; workers: parallel generation workers
    stop_after       run the stages up to and including this one (tests, partial runs)
    """

    workspace: Path = Path("workspaces/demo")
    sample: Path | None = None
    keyframes: int = 40
    scene_minutes: float = 6.0
    scene_downscale: int = 2
    objects: tuple[str, ...] = ("banana", "croissant", "button")
    tasks: tuple[str, ...] = (
        "grasp banana",
        "grasp croissant",
        "press button",
        "push croissant --direction 0,1 --distance 0.1",
    )
    episodes: int = 3
    workers: int = 2
    seed: int = 0
    stop_after: str = "generate"
    extra: dict[str, Any] = field(default_factory=dict)

    def check(self) -> None:
        if self.stop_after not in STAGES:
            raise ValueError(f"stop_after must be one of {', '.join(STAGES)}, got {self.stop_after!r}")
        if self.keyframes < 8 or self.episodes < 1 or self.workers < 1 or not self.scene_minutes > 0:
            raise ValueError("keyframes >= 8, episodes >= 1, workers >= 1 and scene_minutes > 0 are required")


class _Record:
    """``pipeline.json``: finished stages, their settings and summaries."""

    def __init__(self, ws: Path) -> None:
        self.path = ws / "pipeline.json"
        self.data: dict[str, Any] = json.loads(self.path.read_text()) if self.path.is_file() else {}

    def done(self, stage: str, settings: dict, outputs: Sequence[Path]) -> dict | None:
        rec = self.data.get(stage)
        if rec and rec.get("settings") == settings and all(p.exists() for p in outputs):
            return rec
        return None

    def finish(self, stage: str, settings: dict, summary: dict, seconds: float) -> None:
        self.data[stage] = {"settings": settings, "summary": summary, "seconds": round(seconds, 1)}
        with atomic_write(self.path, "w", encoding="utf-8") as f:
            json.dump(self.data, f, indent=1, default=str)

    def invalidate_after(self, stage: str) -> None:
        """A rerun stage makes every later record stale."""
        for later in STAGES[STAGES.index(stage) + 1 :]:
            self.data.pop(later, None)


def _jsonable(x: Any) -> Any:
    return json.loads(json.dumps(x, default=str))


def _gt(sample: Path) -> dict | None:
    path = sample / "ground_truth.json"
    return json.loads(path.read_text()) if path.is_file() else None


# ---- the stages ---------------------------------------------------------------------------------
def _capture(ws: Path, cfg: PipelineConfig, sample: Path) -> dict:
    from .capture import CaptureConfig, extract_keyframes

    keyframes = extract_keyframes(sample / "scene.mp4", ws / "capture", CaptureConfig(max_keyframes=cfg.keyframes))
    return {"keyframes": len(keyframes), "line": f"{len(keyframes)} keyframes from {sample / 'scene.mp4'}"}


def _sfm(ws: Path, cfg: PipelineConfig, sample: Path) -> dict:
    from .capture import load_keyframes
    from .geometry.camera import Camera
    from .sfm import SfMConfig, compare_poses, run_sfm
    from .sfm.known_poses import with_fixed_intrinsics

    config = SfMConfig()
    gt = _gt(sample)
    if gt is not None and "camera" in gt:  # the capture camera's calibration, held fixed
        cam = gt["camera"]
        config = with_fixed_intrinsics(config, Camera(cam["K"], np.eye(4), cam["width"], cam["height"]))
    result = run_sfm(ws / "capture", ws / "sfm", config)
    out = {"registered": result.registered, "total": result.total, "points": len(result.points),
           "reprojection_px": result.mean_reprojection_error}  # fmt: skip
    line = f"registered {result.registered}/{result.total} keyframes, {len(result.points):,} points"
    if gt is not None:
        keyframes = load_keyframes(ws / "capture")["keyframes"]
        reference = {k["file"]: np.asarray(gt["frames"][k["frame_index"]]["T_base_cam"]) for k in keyframes}
        err = compare_poses(result.poses, reference)
        out.update(rotation_deg=err["rotation_deg_median"], centre_frac=err["center_frac_median"])
        line += (f"; vs ground truth {err['rotation_deg_median']:.3f} deg / {100 * err['center_frac_median']:.3f}%"
                 " (median, after a Sim3 fit)")  # fmt: skip
    return {**out, "line": line}


def _align(ws: Path, cfg: PipelineConfig, sample: Path) -> dict:
    from PIL import Image

    from .calib.align import align_scene, default_T_base_board, save_alignment
    from .calib.board import BoardSpec
    from .calib.kinematics import RobotKinematics
    from .capture import load_keyframes
    from .geometry.rotation import rotation_angle
    from .workspace import Workspace

    board = BoardSpec.load(sample / "board.json")
    gt = _gt(sample)
    T_base_board = np.asarray(gt["board"]["T_base_board"]) if gt is not None else default_T_base_board(board)
    posed = Workspace(ws).posed_capture()
    if posed.frame != "sfm":  # a rerun: align from the SfM frame again
        (ws / "calib" / "sim3_sfm_to_base.json").unlink()
        posed = Workspace(ws).posed_capture()
    images = [np.asarray(Image.open(ws / "capture" / c.name).convert("RGB")) for c in posed.cameras]
    footprint = RobotKinematics().base_footprint()
    result = align_scene(posed.cameras, images, posed.points, board, T_base_board, footprint_xy=footprint)
    cams = save_alignment(ws / "calib", result, T_base_board, board, posed.cameras, posed.points)
    out = {"scale": result.sim3_sfm_to_base.scale, "corner_rms_mm": result.corner_rms_mm}
    line = (f"SfM -> robot base: scale {result.sim3_sfm_to_base.scale:.5f}, board corners "
            f"{result.corner_rms_mm:.2f} mm RMS")  # fmt: skip
    if gt is not None:
        index = {k["file"]: k["frame_index"] for k in load_keyframes(ws / "capture")["keyframes"]}
        rot, trans = [], []
        for c in cams:
            T = np.asarray(gt["frames"][index[c.name]]["T_base_cam"])
            rot.append(float(np.degrees(rotation_angle(c.T_world_cam[:3, :3].T @ T[:3, :3]))))
            trans.append(float(1000 * np.linalg.norm(c.T_world_cam[:3, 3] - T[:3, 3])))
        out.update(rotation_deg=float(np.median(rot)), translation_mm=float(np.median(trans)))
        line += f"; cameras vs ground truth {np.median(rot):.3f} deg / {np.median(trans):.2f} mm (median)"
    return {**out, "line": line}


def _handeye(ws: Path, cfg: PipelineConfig, sample: Path) -> dict:
    from .calib.board import BoardSpec
    from .calib.handeye import calibrate_from_files
    from .geometry.rotation import rotation_angle

    gt = _gt(sample)
    head = (gt or {}).get("head_camera") or json.loads((sample / "handeye" / "camera.json").read_text())
    result, out = calibrate_from_files(
        sample / "handeye" / "images", sample / "handeye" / "joints.json",
        BoardSpec.load(sample / "handeye" / "board.json"), np.asarray(head["K"]),
    )  # fmt: skip
    out.update(width=int(head["width"]), height=int(head["height"]))
    with atomic_write(ws / "calib" / "handeye.json", "w", encoding="utf-8") as f:
        json.dump(out, f, indent=1)
    summary = {"views": len(out["per_view"])}
    line = f"T_base_headcam from {len(out['per_view'])} views"
    if gt is not None:
        T = np.asarray(gt["head_camera"]["T_base_headcam"])
        summary.update(rotation_deg=float(np.degrees(rotation_angle(result.T[:3, :3].T @ T[:3, :3]))),
                       translation_mm=float(1000 * np.linalg.norm(result.T[:3, 3] - T[:3, 3])))  # fmt: skip
        line += f"; vs ground truth {summary['rotation_deg']:.3f} deg / {summary['translation_mm']:.2f} mm"
    return {**summary, "line": line}


def _scene(ws: Path, cfg: PipelineConfig, sample: Path, log: Callable[[str], None]) -> dict:
    from .scene import SceneConfig, train_scene

    m = train_scene(ws, SceneConfig(minutes=cfg.scene_minutes, downscale=cfg.scene_downscale), log=log)
    keys = ("psnr_heldout", "ssim_heldout", "iterations", "gaussians", "train_minutes")
    return {
        **{k: m[k] for k in keys},
        "line": f"held-out PSNR {m['psnr_heldout']:.2f} dB / SSIM {m['ssim_heldout']:.3f}, {m['iterations']} "
        f"iterations, {m['gaussians']:,} Gaussians ({m['train_minutes']:.1f} min)",
    }


def _head_view(ws: Path, cfg: PipelineConfig, sample: Path) -> dict:
    from PIL import Image

    from .calib.board import BoardSpec
    from .calib.headview import check_head_view, save_head_view
    from .gaussians.ply import read_ply
    from .geometry.camera import Camera

    he = json.loads((ws / "calib" / "handeye.json").read_text())
    al = json.loads((ws / "calib" / "sim3_sfm_to_base.json").read_text())
    gt = _gt(sample)
    photo_path = sample / gt["head_camera"]["image"] if gt is not None else None
    photo = np.asarray(Image.open(photo_path).convert("RGB")) if photo_path and photo_path.is_file() else None
    cam = Camera(he["K"], he["T_base_headcam"], he["width"], he["height"], "head")
    check = check_head_view(read_ply(ws / "scene" / "gaussians.ply"), cam, photo, BoardSpec.from_json(al["board"]),
                            np.asarray(al["T_base_board"]))  # fmt: skip
    save_head_view(ws / "calib" / "head_view.png", check, photo)
    parts = [] if check.psnr is None else [f"PSNR {check.psnr:.2f} dB vs the head photo"]
    if check.corners_vs_photo_px.get("n"):
        parts.append(f"board corners {check.corners_vs_photo_px['median']:.2f} px from the photo's (median)")
    return {**check.to_json(), "line": "; ".join(parts) or "rendered (no head photo to compare)"}


def _objects(ws: Path, cfg: PipelineConfig, sample: Path, log: Callable[[str], None]) -> dict:
    from .objects.stage import ObjectsConfig, run_objects

    result = run_objects(ws, ObjectsConfig(names=list(cfg.objects)), log=log, progress=True)
    names = sorted(result)
    return {"objects": _jsonable(result), "line": f"{len(names)} objects: {', '.join(names)}"}


def _world(ws: Path, cfg: PipelineConfig, sample: Path) -> dict:
    from .world import from_workspace, save_world
    from .world.compose import consistency, write_world_ply

    world = from_workspace(ws)
    save_world(world)
    write_world_ply(world)
    cons = consistency(world)
    worst = max(cons.values(), default=0.0)
    return {"consistency_mm": {k: 1000 * v for k, v in cons.items()},
            "line": f"{len(world.objects)} objects, {len(world.articulated)} articulated; Gaussians vs meshes "
                    f"<= {1000 * worst:.2f} mm (median per part)"}  # fmt: skip


def _generate(ws: Path, cfg: PipelineConfig, sample: Path, log: Callable[[str], None]) -> dict:
    from .datagen.workspace import GenerateConfig, generate
    from .export.validate import validate

    per_task, lines = {}, []
    for task in cfg.tasks:
        s = generate(ws, GenerateConfig(task=task, episodes=cfg.episodes, workers=cfg.workers, seed=cfg.seed), log=log)
        problems = validate(s["dataset"])
        per_task[task] = {**_jsonable(s), "validation_problems": problems}
        rate = s.get("success_rate")
        lines.append(
            f"{task!r}: {s.get('episodes')} episodes"
            + ("" if rate is None else f", success {100 * rate:.0f}%")
            + (", valid" if not problems else f", {len(problems)} PROBLEMS")
        )
    return {"tasks": per_task, "line": "; ".join(lines)}


# ---- the driver ---------------------------------------------------------------------------------
def _outputs(ws: Path) -> dict[str, list[Path]]:
    return {
        "capture": [ws / "capture" / "keyframes.json"],
        "sfm": [ws / "sfm" / "sfm.json"],
        "align": [ws / "calib" / "sim3_sfm_to_base.json"],
        "handeye": [ws / "calib" / "handeye.json"],
        "scene": [ws / "scene" / "gaussians.ply", ws / "scene" / "metrics.json"],
        "head_view": [ws / "calib" / "head_view.json"],
        "objects": [ws / "objects" / "summary.json"],
        "world": [ws / "world" / "world.yaml"],
        "generate": [ws / "datasets"],
    }


def run_pipeline(cfg: PipelineConfig, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Run (or resume) the stages up to ``cfg.stop_after``; returns {stage: summary} and writes it to
    ``<ws>/pipeline.json``."""
    from .sample.inspect import BUNDLED_SAMPLE

    cfg.check()
    ws = Path(cfg.workspace)
    sample = Path(cfg.sample) if cfg.sample is not None else BUNDLED_SAMPLE
    if ws.exists() and not ws.is_dir():
        raise ValueError(f"workspace {ws} exists and is not a directory; choose another")
    ws.mkdir(parents=True, exist_ok=True)
    record = _Record(ws)
    base = {"sample": str(sample.resolve()), "seed": cfg.seed}
    settings = {
        "capture": {**base, "keyframes": cfg.keyframes},
        "sfm": base,
        "align": base,
        "handeye": base,
        "scene": {**base, "minutes": cfg.scene_minutes, "downscale": cfg.scene_downscale},
        "head_view": base,
        "objects": {**base, "objects": list(cfg.objects)},
        "world": base,
        "generate": {**base, "tasks": list(cfg.tasks), "episodes": cfg.episodes},
    }
    runners: dict[str, Callable[[], dict]] = {
        "capture": lambda: _capture(ws, cfg, sample),
        "sfm": lambda: _sfm(ws, cfg, sample),
        "align": lambda: _align(ws, cfg, sample),
        "handeye": lambda: _handeye(ws, cfg, sample),
        "scene": lambda: _scene(ws, cfg, sample, log),
        "head_view": lambda: _head_view(ws, cfg, sample),
        "objects": lambda: _objects(ws, cfg, sample, log),
        "world": lambda: _world(ws, cfg, sample),
        "generate": lambda: _generate(ws, cfg, sample, log),
    }
    stages = STAGES[: STAGES.index(cfg.stop_after) + 1]
    outputs = _outputs(ws)
    t_start = time.perf_counter()
    summaries: dict[str, Any] = {}
    for i, stage in enumerate(stages, 1):
        prev = record.done(stage, settings[stage], outputs[stage])
        if prev is not None:
            summaries[stage] = prev["summary"]
            log(f"[{i}/{len(stages)}] {stage}: done earlier ({prev['seconds']:.0f} s) - {prev['summary']['line']}")
            continue
        record.invalidate_after(stage)
        log(f"[{i}/{len(stages)}] {stage} ...")
        t0 = time.perf_counter()
        summary = runners[stage]()
        dt = time.perf_counter() - t0
        record.finish(stage, settings[stage], _jsonable(summary), dt)
        summaries[stage] = summary
        total = time.perf_counter() - t_start
        log(f"[{i}/{len(stages)}] {stage}: {summary['line']}  [{dt:.0f} s, total {total:.0f} s]")
    return {"workspace": str(ws.resolve()), "stages": summaries, "seconds": time.perf_counter() - t_start,
            "config": _jsonable(asdict(cfg))}  # fmt: skip
