"""train-scene's head photo shows the robot (every real head camera sees the arm): where the keyframes show it, its
silhouette at the photo's joint state (the pipeline's head_photo_joints, default the capture joints) is masked out of
the photo, in the training view's own (undistorted, downscaled) pixel grid. The photo here is ray-traced through a
distorting lens (trimesh's ray caster, the robot's meshes at the photo's joints): its robot pixels, undistorted as
the training view is, are the reference the mask is measured against."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mirage2matter.calib.robot_view import seen_robot
from mirage2matter.errors import M2MError
from mirage2matter.geometry.camera import Camera, look_at_pose
from mirage2matter.robots import get_robot
from mirage2matter.robots.surface import robot_surface
from mirage2matter.stages.scene import Config as SceneConfig
from mirage2matter.stages.scene import head_photo_view
from mirage2matter.workspace import Workspace

# the references are ray-cast by trimesh through embree (a dev dependency): its Python fallback would take minutes and
# gigabytes for these 77k rays
pytest.importorskip("embreex", reason="embreex (pip install -e '.[dev]'): trimesh's ray caster for the references")

Q_PHOTO = [-0.35, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]  # the sample's capture joints (the arm's)
BACKGROUND_G = 0.8  # the background's green; the robot is magenta (no green): a pixel's green says its robot share


def head_camera() -> Camera:
    """A 320x240 head camera beside the robot, with a strong barrel lens (the corners move ~25 px)."""
    K = np.array([[250.0, 0, 160.0], [0, 250.0, 120.0], [0, 0, 1]])
    T = look_at_pose(np.array([0.95, 0.65, 0.85]), np.array([0.25, 0.0, 0.35]))
    return Camera(K, T, 320, 240, "head", {"k1": -0.25, "k2": 0.06})


def ray_traced_photo(cam: Camera, q) -> tuple[np.ndarray, np.ndarray]:
    """(the photo [H,W,3] uint8, the robot's pixels [H,W] bool): rays through the lens (Camera.pixel_rays) meeting
    the robot's meshes at joint state ``q`` (trimesh) are magenta; the rest a red/blue texture, green constant."""
    import trimesh

    links = robot_surface(get_robot("panda"), q)
    mesh = trimesh.util.concatenate([trimesh.Trimesh(s.vertices, s.faces, process=False) for s in links])
    u, v = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    rays = cam.pixel_rays(np.c_[u.ravel(), v.ravel()]) @ cam.T_world_cam[:3, :3].T
    hit = mesh.ray.intersects_any(np.repeat(cam.T_world_cam[None, :3, 3], len(rays), 0), rays)
    hit = hit.reshape(cam.height, cam.width)
    bg = np.stack([0.5 + 0.3 * np.sin(u / 7.0), np.full_like(u, BACKGROUND_G), 0.5 + 0.3 * np.cos(v / 5.0)], -1)
    img = np.where(hit[..., None], np.array([1.0, 0.0, 1.0]), bg)
    return np.round(img * 255).astype(np.uint8), hit


@pytest.fixture(scope="module")
def head_ws(tmp_path_factory):
    """A workspace as align-scene (the robot seen, at Q_PHOTO) and calibrate-handeye leave it, and the head photo."""
    root = tmp_path_factory.mktemp("head_photo_robot")
    ws = Workspace(root / "ws")
    ws.handeye_file.parent.mkdir(parents=True)
    cam = head_camera()
    ws.handeye_file.write_text(json.dumps({"mount": "head", "K": cam.K.tolist(), "T_base_headcam":
                                           cam.T_world_cam.tolist(), "width": cam.width, "height": cam.height,
                                           "distortion": cam.distortion_json()}))  # fmt: skip
    ws.robot_capture_file.write_text(json.dumps({"robot": "panda", "seen": True, "capture_joints": Q_PHOTO}))
    photo, hit = ray_traced_photo(cam, Q_PHOTO)
    Image.fromarray(photo).save(root / "head.png")
    return ws, root / "head.png", hit


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def masked(ws: Workspace, cfg: SceneConfig):
    """(the head photo's training view, its robot summary, the robot's pixels in the view as the photo shows them
    (more than half of a pixel), the pixels the lens leaves valid, the pixels masked as the robot)."""
    view, info = head_photo_view(ws, cfg, "base", seen_robot(ws.robot_capture_file))
    plain, _ = head_photo_view(ws, replace(cfg, head_photo_mask=None), "base", None)  # the lens's valid pixels
    lens = plain.mask.numpy() if plain.mask is not None else np.ones(view.image.shape[:2], bool)
    truth = view.image.numpy()[..., 1] < 0.5 * BACKGROUND_G
    return view, info, truth & lens, lens, lens & ~view.mask.numpy()


def test_the_head_photo_loses_the_robots_silhouette_at_the_photo_joints_in_the_views_own_pixels(head_ws):
    """At no margin the mask holds every robot pixel of the view (the photo undistorted and downscaled as the
    training view) and little else: its extra pixels are the silhouette's 1 px conservative edge (IoU 0.90 at
    160x120). Drawn in the lens's pixel grid instead it would miss 13 % of them; with the keyframes' 2 px margin it
    holds every one; at a wrong joint state (the shoulder 0.4 rad off) it is elsewhere (IoU 0.42, 23 % of the robot
    trained on)."""
    from mirage2matter.calib.robot_view import grow_mask

    ws, photo, hit = head_ws
    cfg = SceneConfig(head_photo=photo, downscale=2)
    view, info, truth, lens, mask = masked(ws, replace(cfg, robot_margin_px=0))
    assert view.image.shape == (120, 160, 3) and truth.mean() > 0.05
    assert (truth & ~mask).sum() == 0 and (mask & ~grow_mask(truth, 1) & lens).sum() == 0
    assert iou(mask, truth) > 0.85, iou(mask, truth)
    assert info["joints_from"] == "capture_joints" and info["joints"][:7] == pytest.approx(Q_PHOTO)
    # the photo's own robot pixels (the lens's grid, downscaled) miss many of the undistorted view's: the lens matters
    distorted = hit.reshape(120, 2, 160, 2).mean(axis=(1, 3)) > 0.5
    assert (truth & ~distorted).sum() > 0.08 * truth.sum(), (truth & ~distorted).sum() / truth.sum()

    view, info, truth, lens, mask = masked(ws, cfg)  # the default margin, the keyframes'
    assert (truth & ~mask).sum() == 0 and iou(mask, truth) > 0.55, iou(mask, truth)
    assert info["masked_fraction"] == pytest.approx(float((~view.mask.numpy() & lens).mean()), abs=0.005)
    assert f"({100 * info['masked_fraction']:.1f} % of its pixels, 2 px margin)" in info["line"]
    assert "at the capture joints" in info["line"] and not info["user_mask"]

    wrong = list(np.asarray(Q_PHOTO) + [0, 0.4, 0, 0, 0, 0, 0])
    _, info, truth, _, mask = masked(ws, replace(cfg, head_photo_joints=wrong))
    assert iou(mask, truth) < 0.5 and (truth & ~mask).sum() > 0.15 * truth.sum(), iou(mask, truth)
    assert info["joints_from"] == "head_photo_joints" and "at head_photo_joints" in info["line"]
    # the photo's own state given (every joint, the fingers too): as the default
    _, _, truth, _, mask = masked(ws, replace(cfg, robot_margin_px=0, head_photo_joints=[*Q_PHOTO, 0.04, 0.04]))
    assert (truth & ~mask).sum() == 0 and iou(mask, truth) > 0.85


def test_a_users_mask_is_applied_with_the_robots(head_ws, tmp_path):
    """A user's mask (here: a person in the photo's corner, away from the robot) and the robot's silhouette both
    leave their pixels out."""
    ws, photo, _ = head_ws
    keep = np.ones((240, 320), bool)
    keep[:60, :80] = False
    Image.fromarray(keep.astype(np.uint8) * 255).save(tmp_path / "mask.png")
    cfg = SceneConfig(head_photo=photo, downscale=2, robot_margin_px=0)
    robot, _, truth, lens, _ = masked(ws, cfg)
    both, info, _, _, _ = masked(ws, replace(cfg, head_photo_mask=tmp_path / "mask.png"))
    assert info["user_mask"] and "and its mask" in info["line"]
    robot, both = robot.mask.numpy(), both.mask.numpy()
    assert not both[truth].any() and (robot & lens)[:25, :35].any() and not both[:25, :35].any()
    differ = robot != both
    differ[:35, :45] = False  # the user's patch, undistorted (the lens moves it a few pixels)
    assert not differ.any()


def test_no_robot_in_the_keyframes_masks_nothing_and_a_joint_state_that_does_not_fit_is_refused(head_ws, tmp_path):
    ws, photo, _ = head_ws
    cfg = SceneConfig(head_photo=photo, downscale=2)
    view, info = head_photo_view(ws, cfg, "base", None)  # seen_robot None: the capture did not show the robot
    assert info is None and view.mask is not None  # the lens's border only
    bad = [0.1, -0.7, 0.0, -2.3, 0.0]
    with pytest.raises(M2MError, match=r"head_photo_joints: 5 values given; panda has 7 arm joints"):
        head_photo_view(ws, replace(cfg, head_photo_joints=bad), "base", seen_robot(ws.robot_capture_file))
    degrees = [float(np.degrees(v)) for v in Q_PHOTO]
    with pytest.raises(M2MError, match=r"head_photo_joints: .* reads as degrees"):
        head_photo_view(ws, replace(cfg, head_photo_joints=degrees), "base", seen_robot(ws.robot_capture_file))


def test_the_head_photo_joints_count_in_the_scenes_fingerprint_only_with_a_head_photo(head_ws):
    """head-view shares the setting: giving it for the head-view check retrains no scene that has no head photo."""
    from mirage2matter.stages import get_stage
    from mirage2matter.stages.base import stage_fingerprint

    ws, photo, _ = head_ws
    (ws.root / "sfm").mkdir(exist_ok=True)
    ws.sfm_file.write_text("{}")
    stage, q = get_stage("scene"), [*Q_PHOTO]
    key = lambda cfg: stage_fingerprint(stage, ws, cfg)  # noqa: E731
    assert key(SceneConfig(head_photo_joints=q)) == key(SceneConfig())
    with_photo = SceneConfig(head_photo=photo)
    assert key(replace(with_photo, head_photo_joints=q)) != key(with_photo)


@pytest.fixture(scope="module")
def sample_with_robot(tmp_path_factory):
    """test_scene's workspace of the sample's keyframes (ground-truth poses, the robot base's frame) with its head
    camera, and calib/robot.json as align-scene leaves it: the robot seen, at the sample's capture joints."""
    import os
    import shutil
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from test_scene import imported, with_head_camera  # the module's fixtures, as functions

    from fixtures import SAMPLE

    if not (SAMPLE / "scene.mp4").is_file():
        pytest.skip("samples/tabletop not built")
    src, head = with_head_camera.__wrapped__(imported.__wrapped__(tmp_path_factory), tmp_path_factory)
    ws = tmp_path_factory.mktemp("robot_head") / "ws"
    ws.mkdir()
    for sub in ("capture", "sfm"):
        os.symlink(os.readlink(src / sub), ws / sub)
    shutil.copytree(src / "calib", ws / "calib")
    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    (ws / "calib" / "robot.json").write_text(json.dumps({"robot": "panda", "seen": True,
                                                         "capture_joints": gt["robot"]["capture_joints"]}))  # fmt: skip
    return ws, head, SAMPLE / head["image"], gt["robot"]["capture_joints"]


def test_train_scene_masks_the_robot_out_of_the_sample_head_photo_and_says_how_much(sample_with_robot, monkeypatch):
    """The stage line and metrics.json say how much of the head photo was masked as the robot; the view trained on
    leaves out the robot's pixels (trimesh's rays through the head camera, at the capture joints)."""
    import trimesh

    import mirage2matter.gaussians.train as gaussians_train
    from mirage2matter.stages import get_stage, run_stage

    ws, head, photo, q = sample_with_robot
    seen = {}
    real_train = gaussians_train.train

    def spy(views_train, views_eval, *args, **kwargs):
        seen["views"] = list(views_train)
        return real_train(views_train, views_eval, *args, **kwargs)

    monkeypatch.setattr(gaussians_train, "train", spy)
    cfg = SceneConfig(iterations=10, downscale=2, max_gaussians=30_000, checkpoint_every=0, robot_iterations=2,
                      head_photo=photo, head_photo_repeat=2)  # fmt: skip
    summary, _ = run_stage(get_stage("scene"), Workspace(ws), cfg, log=lambda s: None)
    metrics = json.loads((ws / "scene" / "metrics.json").read_text())
    info = metrics["head_photo_robot"]
    assert summary["head_photo_robot"] == info and info["joints_from"] == "capture_joints"
    assert f"the robot masked out of the head photo ({100 * info['masked_fraction']:.1f} % of its pixels, 2 px " \
        "margin) at the capture joints" in summary["line"]  # fmt: skip
    view = seen["views"][-1]
    mask = ~view.mask.numpy()
    assert info["masked_fraction"] == pytest.approx(mask.mean(), abs=1e-6) and 0.05 < mask.mean() < 0.5

    cam = Camera(view.K.numpy().astype(np.float64), np.asarray(head["T_base_headcam"]), 320, 240)
    links = robot_surface(get_robot("panda"), q)
    mesh = trimesh.util.concatenate([trimesh.Trimesh(s.vertices, s.faces, process=False) for s in links])
    u, v = np.meshgrid(np.arange(320) + 0.5, np.arange(240) + 0.5)
    rays = cam.pixel_rays(np.c_[u.ravel(), v.ravel()]) @ cam.T_world_cam[:3, :3].T
    truth = mesh.ray.intersects_any(np.repeat(cam.T_world_cam[None, :3, 3], len(rays), 0), rays).reshape(240, 320)
    assert (truth & ~mask).sum() == 0 and iou(mask, truth) > 0.8, iou(mask, truth)  # 0.88: the 2 px margin


def test_a_workspace_written_before_the_bake_keeps_its_scene_fingerprint():
    """Every m2m.yaml written before the robot's colours were baked holds robot_iterations: 300, the default then: it
    reads as today's default (no scene retrained for it); another count is kept, and fingerprinted."""
    from mirage2matter.configs import fingerprinted, from_dict

    old = from_dict(SceneConfig, {"robot_iterations": 300})
    assert old.robot_iterations == 0 and fingerprinted(old) == fingerprinted(SceneConfig())
    assert "robot_iterations" in fingerprinted(from_dict(SceneConfig, {"robot_iterations": 50}))
