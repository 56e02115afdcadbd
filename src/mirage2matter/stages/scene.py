"""Stage ``scene`` (``m2m train-scene``): scene 3DGS from the workspace's posed keyframes (DESIGN.md §3 stage 4).

Cameras and SfM points come from :meth:`Workspace.posed_capture` (robot-base frame after ``align-scene``),
so the trained Gaussians live in the frame the simulator uses. Outputs in ``<ws>/scene/``:
``gaussians.ply``, ``metrics.json`` (held-out PSNR / SSIM, curve, timings), ``heldout.png`` (held-out
keyframes: photo above render), ``checkpoint.pt`` + ``plan.json`` while training. Interrupted: resumed
from the last checkpoint when ``plan.json`` (the stage's fingerprint and the training configuration) still
matches; the checkpoint holds the training time spent and the schedule's state, and the schedule follows
the fraction of the budget spent, so the resumed run continues the same schedule.

With ``--minutes`` the training is ``gaussians.budget.budget_config``'s, the one ``m2m bench train``
times: it trains until the minutes are spent, with every schedule a fraction of them.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ..atomic import atomic_write
from ..configs import ranged, to_dict
from ..fingerprint import fingerprint
from ..gaussians.config import FILTER_3D_VARIANCE, TrainConfig
from ..geometry.camera import Camera
from ..geometry.sim3 import invert_rigid
from ..inputs import read_image_rgb
from ..robots import get_robot
from ..robots.surface import robot_surface
from ..workspace import Workspace, WorkspaceError
from . import get_stage
from .base import ADDED_LATER, SHARED, Input, Log, stage_fingerprint, used_with
from .head_view import head_camera, photo_joint_state

__all__ = ["Config", "inputs", "outputs", "run"]


@dataclass
class Config:
    """train-scene settings.

    minutes         training-time budget (steps only; evaluation and checkpoints are extra): it trains until
                    it is spent, on any device, with every schedule a fraction of it
    iterations      fixed iteration count instead of a budget (0: use ``minutes``)
    downscale       train and evaluate at 1/downscale resolution (area filter)
    holdout_every   every n-th keyframe (sorted by name) is held out for evaluation
    max_gaussians   cap on densification
    sh_degree       final SH degree (raised during training)
    backend         "auto" (cuda with gsplat, else the numba cpu rasterizer), "cpu", "cuda"
    seed            initialisation and sampling seed
    checkpoint_every  iterations between checkpoints a killed run resumes from (0: none)
    head_photo      a photo the calibrated head camera took of the scene (e.g. head-view's): trained on as one more
                    view, from the head camera's pose (calibrate-handeye), so the scene seen from the camera a
                    policy looks through is fitted rather than extrapolated from the capture's viewpoints. The
                    head-view check against the same photo then measures a training view
    head_photo_mask  white where the head photo shows the scene, black where it shows what is not (the robot, a
                    person): those pixels are not trained on (default: every pixel). Where the keyframes show the
                    robot, its silhouette in the photo is masked out too, whether or not a mask is given
    head_photo_joints  the robot's joint state when the head photo was taken (the arm's joint angles in radians, or
                    every joint's with the fingers): where the keyframes show the robot, its silhouette at this
                    state through the head camera, grown by robot_margin_px, is not trained on. Default: the
                    capture joints. The pipeline's (m2m.yaml's top-level head_photo_joints, head-view's too):
                    giving it here changes it for every stage
    head_photo_repeat  times the head photo is trained on per pass over the keyframes (1: as one keyframe)
    robot_margin_px  where align-scene found the robot in the keyframes, its silhouette at the capture joint state,
                    grown by this many pixels, is not trained on (nor measured), and the Gaussians only those pixels
                    saw are dropped: no frozen copy of the robot in the scene
    robot_iterations  the robot's own Gaussians (per link, on its meshes) take their colours from the keyframes'
                    robot pixels, the scene in front (each Gaussian the weighted average of the pixels it was drawn
                    into): the robot drawn as the capture saw it (scene/robot/); then this many gradient steps on
                    the Gaussians seen (0: the average alone, best at the poses a task moves the robot to)
    filter_3d       Mip-Splatting's 3D smoothing filter, a variance in squared training pixels (0.2 as in the
                    paper; 0: off): no Gaussian is trained thinner than the finest pixel a keyframe saw it with, so
                    views closer or sharper than the keyframes (the head photo at full size, a wrist camera) do not
                    sparkle
    """

    minutes: float = ranged(10.0, ge=0, le=100_000)
    iterations: int = ranged(0, ge=0, le=10**7)
    downscale: int = ranged(2, ge=1, le=16)
    holdout_every: int = ranged(8, ge=0, le=10_000)
    # the cap and the checkpoint cadence are TrainConfig's defaults (it owns them: bench train trains with them too)
    max_gaussians: int = ranged(TrainConfig.max_gaussians, ge=1000, le=10**8)
    sh_degree: int = ranged(3, ge=0, le=3)
    backend: Literal["auto", "cpu", "cuda"] = "auto"
    seed: int = ranged(0, ge=0, le=2**32 - 1)
    checkpoint_every: int = ranged(TrainConfig.checkpoint_every, ge=0, le=10**7)
    head_photo: Path | None = field(default=None, metadata=ADDED_LATER)
    head_photo_mask: Path | None = field(default=None, metadata=ADDED_LATER)
    head_photo_repeat: int = ranged(4, ge=1, le=1000, metadata=ADDED_LATER)
    # wide: degrees given for radians are the robot's check to name (check_capture_joints), not a bare range; in the
    # fingerprint only with a head photo (head-view's photo shares it: setting it there retrains no scene without one)
    head_photo_joints: list[float] | None = ranged(None, ge=-1000, le=1000, metadata={
        **SHARED, **ADDED_LATER, **used_with("head_photo"), "metavar": "RAD"})  # fmt: skip
    # bench train's too; in every fingerprint: scenes trained before it retrain
    filter_3d: float = ranged(FILTER_3D_VARIANCE, ge=0, le=4)
    # pixels the robot's silhouette grows by before it is masked out of the keyframes (calib/robot.json): the link
    # meshes are the model's and the cameras a few tenths of a pixel off
    robot_margin_px: int = ranged(2, ge=0, le=100, metadata=ADDED_LATER)
    # 300 before the colours were baked (gaussians.robot.MESH_PRIOR_PX); after the bake they lower the robot's pixels
    # at a task's poses (gaussians.robot.fit_robot_colours)
    robot_iterations: int = ranged(0, ge=0, le=10**6, metadata=ADDED_LATER)

    @staticmethod
    def upgrade(data: dict[str, Any]) -> dict[str, Any]:
        """A workspace's settings from before the robot's colours were baked: robot_iterations 300, the default then
        (written into every m2m.yaml), -> the default now, so such a workspace's scene is not retrained for it
        (``m2m train-scene`` again bakes its robot)."""
        if data.get("robot_iterations") == 300:
            data["robot_iterations"] = 0
        return data

    def validate(self) -> None:
        from ..gaussians.filter3d import check_variance

        if self.iterations < 0 or (self.iterations == 0 and not self.minutes > 0):
            raise WorkspaceError("train-scene: give a positive --minutes budget or --iterations")
        if self.downscale < 1 or self.holdout_every < 0 or self.max_gaussians < 1000:
            raise WorkspaceError(
                f"train-scene: downscale >= 1, holdout_every >= 0 and max_gaussians >= 1000, got {self.downscale}, "
                f"{self.holdout_every}, {self.max_gaussians}"
            )
        if not 0 <= self.sh_degree <= 3:
            raise WorkspaceError(f"train-scene: sh_degree must be 0..3, got {self.sh_degree}")
        try:
            check_variance(self.filter_3d)
        except ValueError as e:
            raise WorkspaceError(f"train-scene: {e}") from None
        if self.robot_margin_px < 0 or self.robot_iterations < 0:
            raise WorkspaceError(f"train-scene: robot_margin_px and robot_iterations must be >= 0, got "
                                 f"{self.robot_margin_px}, {self.robot_iterations}")  # fmt: skip
        if self.head_photo_repeat < 1:
            raise WorkspaceError(f"train-scene: head_photo_repeat must be >= 1, got {self.head_photo_repeat}")
        if self.head_photo_mask is not None and self.head_photo is None:
            raise WorkspaceError("train-scene: head_photo_mask is given without a head_photo; give the photo it "
                                 "masks (--head-photo) or leave the mask out")  # fmt: skip


def _heldout_sheet(g, views, config, backend: str, max_views: int = 4) -> np.ndarray:
    """Held-out photos (top row) above their renders (bottom row), uint8."""
    import torch

    from ..gaussians.render import render

    tops, bottoms = [], []
    bg = torch.tensor(config.background, dtype=torch.float32)
    for v in views[:max_views]:
        with torch.no_grad():
            rgb = render(g, v.viewmat, v.K, v.width, v.height, bg, backend).rgb.clamp(0, 1)
        tops.append(v.image.numpy())
        bottoms.append(rgb.cpu().numpy())
    grid = np.concatenate([np.concatenate(tops, axis=1), np.concatenate(bottoms, axis=1)], axis=0)
    return (grid * 255 + 0.5).astype(np.uint8)


def inputs(ws: Workspace, cfg: Config) -> list[Input]:
    # after align-scene the base-frame cameras; before it, the SfM frame
    out = [Input(ws.sfm_file, made_by="sfm")]
    out += [Input(p) for p in (ws.cameras_base_file, ws.points_base_file, ws.robot_capture_file) if p.is_file()]
    if cfg.head_photo is not None:
        out += [Input(ws.handeye_file, made_by="calibrate-handeye"),
                Input(Path(cfg.head_photo), field="scene head_photo")]  # fmt: skip
    if cfg.head_photo_mask is not None:
        out.append(Input(Path(cfg.head_photo_mask), field="scene head_photo_mask"))
    return out


def head_photo_view(ws: Workspace, cfg: Config, frame: str, seen=None) -> tuple[Any, dict[str, Any] | None]:
    """(the head photo as a training view (``gaussians.train.View``) from the calibrated head camera, what of it was
    masked out as the robot: None when nothing was). ``seen``: the robot as the keyframes showed it
    (``calib.robot_view.SeenRobot``, None when they do not): the photo shows it too, at ``head_photo_joints``
    (default: the capture joints), and its silhouette there, grown by ``robot_margin_px`` as the keyframes' is, is
    not trained on, so no scene Gaussian learns the robot from the photo (a ghost in the head camera's view)."""
    import torch

    from ..calib.robot_view import grow_mask, robot_silhouette
    from ..gaussians.dataset import DatasetError, photo_view

    if frame != "base":
        raise WorkspaceError("train-scene --head-photo: the head camera's pose is in the robot-base frame; run "
                             "align-scene first (the scene is in the SfM frame)")  # fmt: skip
    photo = read_image_rgb(cfg.head_photo, "scene head photo")
    cam = head_camera(ws, "train-scene --head-photo", photo, cfg.head_photo)
    keep = None
    if cfg.head_photo_mask is not None:
        keep = read_image_rgb(cfg.head_photo_mask, "scene head photo mask").mean(axis=2) > 127
    try:
        view = photo_view(cam, photo, cfg.downscale, keep)
    except DatasetError as e:
        raise WorkspaceError(f"train-scene --head-photo {cfg.head_photo}: {e}") from None
    if seen is None:
        return view, None
    spec = get_robot(seen.record["robot"])
    q, where = photo_joint_state(spec, cfg.head_photo_joints, seen.record["capture_joints"], ws.robot_capture_file)
    links = seen.links if cfg.head_photo_joints is None else robot_surface(spec, q)
    # the view is the photo undistorted to the pinhole with the training-size camera's K (photo_view): the silhouette
    # is drawn in that pixel grid, through the view's own K and pose, as the keyframes' are (_robot_masks)
    h, w = view.image.shape[:2]
    robot = grow_mask(robot_silhouette(_view_camera(view), links), cfg.robot_margin_px)
    # with a user's mask both apply (the pixels either marks are left out), not the user's alone: a mask drawn for
    # a person or a cable misses the robot, one drawn by hand around the arm its edges; the silhouette costs only
    # pixels the keyframes see too. A silhouette in the wrong place (a wrong joint state) is head_photo_joints' to fix
    valid = view.mask.numpy() if view.mask is not None else np.ones((h, w), bool)
    if not (valid & ~robot).any():
        raise WorkspaceError(f"train-scene --head-photo {cfg.head_photo}: the robot (at {where}) covers every "
                             "pixel of the photo left to train on; check head_photo_joints")  # fmt: skip
    view.mask = torch.from_numpy(valid & ~robot)
    frac = float(robot.mean())
    also = ", and its mask" if cfg.head_photo_mask is not None else ""
    line = (f"the robot masked out of the head photo ({100 * frac:.1f} % of its pixels, {cfg.robot_margin_px} px "
            f"margin{also}) at {where}")  # fmt: skip
    given = "head_photo_joints" if cfg.head_photo_joints is not None else "capture_joints"
    return view, {"masked_fraction": frac, "joints": q.tolist(), "joints_from": given,
                  "user_mask": cfg.head_photo_mask is not None, "line": line}  # fmt: skip


def run(ws: Workspace, config: Config, log: Log) -> dict[str, Any]:
    """Train the scene Gaussians; writes and returns the metrics of ``scene/metrics.json``."""
    from PIL import Image

    from ..gaussians.budget import budget_config
    from ..gaussians.dataset import build_views
    from ..gaussians.ply import write_ply
    from ..gaussians.render import resolve_backend
    from ..gaussians.train import init_gaussians_from_points, train

    posed = ws.posed_capture()
    frame_note = _frame_note(ws, posed.frame)
    frame_label = "SfM" if frame_note else posed.frame  # --unaligned files the SfM frame as the base's
    if frame_note:
        log(f"scene: {frame_note}")
    if len(posed.points) < 100:
        raise WorkspaceError(f"{ws.sfm_dir}: only {len(posed.points)} SfM points; rerun sfm with more keyframes / "
                             "texture")  # fmt: skip
    key = stage_fingerprint(get_stage("scene"), ws, config)
    out = ws.scene_dir
    out.mkdir(parents=True, exist_ok=True)
    backend = resolve_backend(config.backend)

    t0 = time.perf_counter()
    views_train, views_eval = build_views(posed.cameras, posed.image_dir, config.downscale, config.holdout_every)
    robot = _robot_masks(ws, views_train + views_eval, posed.frame, config.robot_margin_px, log)  # keyframes only
    photo_views, photo_key, photo_robot = _head_photo(ws, config, posed.frame, robot, log)
    views_train = views_train + photo_views
    init = init_gaussians_from_points(posed.points, posed.colors.astype(np.float64) / 255.0, config.sh_degree)
    base = TrainConfig(
        sh_degree=config.sh_degree, max_gaussians=config.max_gaussians, backend=backend, seed=config.seed,
        checkpoint_every=config.checkpoint_every, filter_3d=config.filter_3d,
    )  # fmt: skip

    if config.iterations:
        train_cfg = replace(base, iterations=config.iterations, eval_points=10)
    else:
        train_cfg = budget_config(config.minutes, base)
    ckpt, resume = _checkpoint_plan(out, key, train_cfg)
    if resume:
        log(f"scene: resuming from {ckpt}")
    n_photo = config.head_photo_repeat if config.head_photo is not None else 0
    log(
        f"scene: {len(views_train) - n_photo} training + {len(views_eval)} held-out keyframes"
        + (f" + the head photo (x{n_photo})" if n_photo else "")
        + f" at "
        f"{views_train[0].width}x{views_train[0].height}, {len(init):,} initial Gaussians from SfM points, "
        f"{frame_label} frame, "
        + (f"{train_cfg.iterations} iterations" if config.iterations else f"{config.minutes:g} minutes of training")
        + f" ({backend})"
    )
    g, metrics = train(views_train, views_eval, init, train_cfg, progress=True, checkpoint_path=ckpt, resume=resume)
    if robot is not None:  # out of the scene, and into its own Gaussians
        g = _drop_robot_only(g, robot)
        _robot_gaussians(ws, g, robot, views_train, views_eval, config, backend, log)
    metrics["gaussians"] = len(g)

    write_ply(ws.scene_ply, g)
    if views_eval:
        sheet = _heldout_sheet(g, views_eval, train_cfg, backend)
        with atomic_write(out / "heldout.png", "wb") as f:
            Image.fromarray(sheet).save(f, format="PNG")
    result = {
        "fingerprint": key,
        "frame": posed.frame,
        "psnr_heldout": metrics["psnr"],
        "ssim_heldout": metrics["ssim"],
        "initial": metrics["initial"],
        "iterations": metrics["iterations"],
        "gaussians": metrics["gaussians"],
        "train_minutes": metrics["seconds"] / 60.0,
        "wall_minutes": (time.perf_counter() - t0) / 60.0,
        "backend": metrics["backend"],
        "views": {"train": len(views_train) - n_photo, "heldout": len(views_eval), "head_photo": n_photo},
        "image_size": [views_train[0].width, views_train[0].height],
        "per_view": metrics["views"],
        "curve": metrics["curve"],
        "config": to_dict(config),
        # head-view reads it to tell a fit from a new view (survives a moved or deleted photo)
        "head_photo_fingerprint": photo_key,
        "robot": _robot_summary(robot),
        # what of the head photo was masked out as the robot (None: nothing, or no head photo)
        "head_photo_robot": photo_robot,
    }
    with atomic_write(ws.scene_metrics, "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1)
    ckpt.unlink(missing_ok=True)  # finished: the PLY and metrics are the result (checkpoints are ~3x the PLY)
    keys = ("psnr_heldout", "ssim_heldout", "iterations", "gaussians", "train_minutes", "frame")
    from ..capture.coverage import scene_coverage

    coverage = scene_coverage(posed.cameras, posed.points)
    return {
        **{k: result[k] for k in keys}, "coverage": coverage.to_json(), "unaligned": bool(frame_note),
        "robot": result["robot"], "head_photo_robot": photo_robot,
        "line": f"held-out PSNR {result['psnr_heldout']:.2f} dB / SSIM {result['ssim_heldout']:.3f} over "
        f"{len(views_eval)} keyframes, {result['iterations']} iterations, {result['gaussians']:,} Gaussians "
        f"({result['train_minutes']:.1f} min, {frame_label} frame){'; ' + frame_note if frame_note else ''}; "
        f"{coverage.line}{'' if robot is None else '; ' + result['robot']['line']}"
        f"{'' if photo_robot is None else '; ' + photo_robot['line']}",
    }  # fmt: skip


def _view_camera(view) -> Camera:
    """The pinhole camera of a training view (``gaussians.train.View``: already undistorted, at the training size):
    the robot's silhouette is drawn in the view's own pixel grid."""
    h, w = view.image.shape[:2]
    T_world_cam = invert_rigid(view.viewmat.numpy().astype(np.float64))
    return Camera(K=view.K.numpy().astype(np.float64), T_world_cam=T_world_cam, width=w, height=h, name=view.name)


def _head_photo(ws: Workspace, config: Config, frame: str, robot: dict[str, Any] | None,
                log: Log) -> tuple[list, str | None, dict[str, Any] | None]:  # fmt: skip
    """(the head photo's training views (head_photo_repeat of it; none without a head photo), its content's
    fingerprint, what of it was masked out as the robot (:func:`head_photo_view`))."""
    if config.head_photo is None:
        return [], None, None
    view, masked = head_photo_view(ws, config, frame, None if robot is None else robot["seen"])
    if masked is not None:
        log(f"scene: {masked['line']}")
    return [view] * config.head_photo_repeat, fingerprint(Path(config.head_photo)), masked


def _robot_summary(robot: dict[str, Any] | None) -> dict[str, Any] | None:
    """metrics.json's "robot": what was masked and dropped, the robot's look figures, the stage line's words."""
    if robot is None:
        return None
    out = {k: robot.get(k) for k in ("masked_fraction", "gaussians_pruned", "psnr_mesh_look", "psnr_captured")}
    out["line"] = (f"{robot['line']}, {robot['gaussians_pruned']:,} Gaussians it alone saw dropped; "
                   f"{robot['gaussians_line']}")  # fmt: skip
    return out


def _robot_masks(ws: Workspace, views: list, frame: str, margin_px: int, log: Log) -> dict[str, Any] | None:
    """Where align-scene found the robot in the keyframes (calib/robot.json): its silhouette at the joint state each
    keyframe saw (the capture joints, or a move's), grown by ``margin_px``, taken out of every view's valid pixels
    (training and held-out), so no Gaussian is fitted to the robot and the held-out figures measure the scene alone.
    None when the keyframes do not show it.
    ``views``: the keyframes' (a head photo shows the robot at its own joint state: head_photo_view masks it)."""
    from ..calib.robot_view import grow_mask, robot_silhouette, seen_robot

    robot = seen_robot(ws.robot_capture_file) if frame == "base" else None
    if robot is None:
        return None
    import torch

    cameras, silhouettes, exacts, valid, masked = [], [], [], [], []
    for v in views:
        cam = _view_camera(v)
        # rasterized once: grown for the mask, exact for the robot's own fit
        exact = robot_silhouette(cam, robot.links_for(v.name))
        sil = grow_mask(exact, margin_px)
        keep = torch.from_numpy(~sil)
        valid.append(v.mask)  # before the robot is taken out: the robot's own fit reads its pixels
        v.mask = keep if v.mask is None else v.mask & keep
        cameras.append(cam)
        silhouettes.append(sil)
        exacts.append(exact)
        masked.append(float(sil.mean()))
    frac = float(np.mean(masked))
    line = (f"the robot (calib/robot.json) masked out of every keyframe ({100 * frac:.1f} % of the pixels, {margin_px} "
            "px margin)")  # fmt: skip
    log(f"scene: {line}")
    return {"cameras": cameras, "silhouettes": silhouettes, "exact": exacts, "valid": valid, "seen": robot,
            "record": robot.record, "masked_fraction": frac, "line": line}  # fmt: skip


def _robot_gaussians(
    ws: Workspace,
    scene,
    robot: dict[str, Any],
    views_train: list,
    views_eval: list,
    config: Config,
    backend: str,
    log: Log,
) -> None:
    """The robot as the capture saw it (gaussians.robot): per-link Gaussians on its meshes, their colours fitted to
    the keyframes' robot pixels with the scene in front, written to scene/robot/ (<link>.ply in the link's frame,
    robot.json: the capture joints, how much of each link the keyframes saw, held-out PSNR on the robot's pixels of
    the mesh look and of the captured one)."""
    from ..gaussians.ply import write_ply
    from ..gaussians.robot import fit_robot_colours, mesh_gaussians

    captured = robot["seen"]
    n_train = len(views_train) - (config.head_photo_repeat if config.head_photo is not None else 0)
    exact = robot["exact"]
    # the keyframes with their robot pixels back (train-scene masked them out)
    views = [replace(v, mask=m) for v, m in zip(views_train[:n_train] + views_eval, robot["valid"], strict=True)]
    # each keyframe's links at the pose it saw (the Gaussians are the same: each link's own frame)
    poses = [{link.link: link.T_base_link for link in links} for links in captured.pose_links]
    view_pose = [captured.keyframe_pose.get(v.name, 0) for v in views]
    fit = fit_robot_colours(
        mesh_gaussians(captured.links), poses, scene, views[:n_train], exact[:n_train], views[n_train:],
        exact[n_train:], iterations=config.robot_iterations, backend=backend, seed=config.seed,
        view_pose_train=view_pose[:n_train], view_pose_eval=view_pose[n_train:],
    )  # fmt: skip
    out = ws.robot_gaussians_dir
    out.mkdir(parents=True, exist_ok=True)
    for name, g in fit.link_gaussians.items():
        write_ply(out / f"{name}.ply", g)
    record = robot["record"]
    summary = {"robot": record["robot"], "capture_joints": record["capture_joints"],
               "capture_moves": record.get("capture_moves") or {}, "frame": "each link's own",
               "links": {name: f"{name}.ply" for name in fit.link_gaussians}, "seen_fraction": fit.seen_fraction,
               "psnr_mesh_look": fit.psnr_mesh, "psnr_captured": fit.psnr_captured,
               "iterations": fit.iterations, "view_error": fit.view_error,
               "disagreeing_views": fit.disagreeing}  # fmt: skip
    with atomic_write(out / "robot.json", "w", encoding="utf-8") as f:
        json.dump(summary, f, indent=1)
    seen = sum(fit.seen_fraction[n] * len(g) for n, g in fit.link_gaussians.items()) / \
        max(sum(len(g) for g in fit.link_gaussians.values()), 1)  # fmt: skip
    figures = "" if fit.psnr_mesh is None else \
        f", held-out robot pixels {fit.psnr_mesh:.1f} dB in the mesh look -> {fit.psnr_captured:.1f} dB"  # fmt: skip
    robot["gaussians_line"] = (f"the robot's Gaussians (scene/robot/): {100 * seen:.0f} % seen by the keyframes"
                               f"{figures}")  # fmt: skip
    if fit.disagreeing:
        warning = (
            f"WARNING: the robot in keyframe(s) {', '.join(fit.disagreeing)} disagrees with the rest (its "
            "colours there are explained far worse): did the robot move while filming? Its joint state must "
            "be the one capture_joints / capture_moves give for that keyframe's frame; log the moves, remove "
            "those keyframes or film again"
        )
        robot["gaussians_line"] += f"; {warning}"
        log(f"scene: {warning}")
    robot.update(psnr_mesh_look=fit.psnr_mesh, psnr_captured=fit.psnr_captured)
    log(f"scene: {robot['gaussians_line']}")


def _drop_robot_only(g, robot: dict[str, Any]):
    """``g`` without the Gaussians inside the robot's visual hull (every keyframe that sees one sees the robot there):
    they never had a pixel to learn from but the robot's, which is masked out, so they keep what they started as."""
    import torch

    from ..calib.robot_view import visual_hull

    hull = visual_hull(g.means.detach().cpu().numpy(), robot["cameras"], robot["silhouettes"])
    robot["gaussians_pruned"] = int(hull.sum())
    return g.select(torch.from_numpy(~hull).to(g.means.device))


def _checkpoint_plan(out: Path, key: str, train_cfg) -> tuple[Path, bool]:
    """The checkpoint path and whether to resume from it.

    A checkpoint is resumed only by the same stage fingerprint and the same training configuration (the
    schedule is a function of it and of the progress the checkpoint holds); otherwise it is dropped.
    """
    plan_path, ckpt = out / "plan.json", out / "checkpoint.pt"
    plan = {"fingerprint": key, "train_config": json.loads(json.dumps(asdict(train_cfg)))}
    try:
        previous = json.loads(plan_path.read_text()) if plan_path.is_file() else None
    except ValueError:
        previous = None
    if previous != plan:
        ckpt.unlink(missing_ok=True)
        with atomic_write(plan_path, "w", encoding="utf-8") as f:
            json.dump(plan, f, indent=1)
        return ckpt, False
    return ckpt, ckpt.is_file()


def _frame_note(ws: Workspace, frame: str) -> str:
    """A loud word when the scene is not in the robot's metric base frame ("" when it is)."""
    if frame == "sfm":
        return (
            "UNALIGNED: align-scene has not run, so the scene is in the SfM frame (not metric, not the robot's "
            "base); run `m2m align-scene --board ...` for a robot twin, or `--unaligned` to say it is meant"
        )
    if ws.alignment_file.is_file():
        try:
            method = json.loads(ws.alignment_file.read_text()).get("method")
        except (OSError, ValueError):
            method = None
        if method == "unaligned":
            return "UNALIGNED (align-scene --unaligned): the scene is in the SfM frame, not metric, not the robot's"
    return ""


def outputs(ws: Workspace, cfg: Config) -> list[Path]:
    return [ws.scene_ply, ws.scene_metrics]


def writes(ws: Workspace, cfg: Config) -> list[Path]:
    """What the stage replaces (its transaction swaps these in together)."""
    return [ws.scene_dir]
