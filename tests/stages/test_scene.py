"""The train-scene stage over a workspace: outputs, the input frame kept, skip, and resume after a kill."""

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from fixtures import SAMPLE
from mirage2matter.configs import to_dict
from mirage2matter.fingerprint import fingerprint
from mirage2matter.gaussians.losses import psnr
from mirage2matter.gaussians.ply import read_ply
from mirage2matter.gaussians.render import render
from mirage2matter.geometry.camera import camera_from_transforms_frame
from mirage2matter.sample.transforms import write_sample_transforms
from mirage2matter.sfm import SfMConfig
from mirage2matter.sfm.importers import import_transforms
from mirage2matter.stages import get_stage, run_stage
from mirage2matter.stages.scene import Config as SceneConfig
from mirage2matter.workspace import Workspace, WorkspaceError

SCENE = get_stage("scene")


def train_scene(ws, cfg, log=print) -> tuple[dict, bool]:
    """The scene stage as `m2m train-scene` runs it; (metrics.json, skipped)."""
    _, skipped = run_stage(SCENE, Workspace(ws), cfg, log)
    return json.loads((Path(ws) / "scene" / "metrics.json").read_text()), skipped


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """A workspace imported from the sample's frames with ground-truth poses (quarter resolution)."""
    if not (SAMPLE / "scene.mp4").is_file():
        pytest.skip("samples/tabletop not built")
    root = tmp_path_factory.mktemp("scene")
    tf = write_sample_transforms(SAMPLE, root / "data", every=45, scale=0.5)
    ws = root / "ws"
    import_transforms(tf, ws / "capture", ws / "sfm", SfMConfig(num_threads=2))
    return tf, ws


def test_train_scene_learns_the_scene_in_the_given_frame_and_skips_when_done(imported):
    tf, ws = imported
    # 300 steps, not fewer: after 150 the scene is a blur whose match with a moved camera is a draw of the threaded
    # backward's summation order (0.9-3.6 dB worse over runs); after 300 it is 3.2-5.4 dB worse (5 runs).
    cfg = SceneConfig(iterations=300, downscale=2, max_gaussians=30_000, checkpoint_every=0)
    logs = []
    m, skipped = train_scene(ws, cfg, log=logs.append)
    assert not skipped and m["frame"] == "sfm" and m["views"] == {"train": 14, "heldout": 2, "head_photo": 0}
    assert m["iterations"] == 300
    # training improves held-out views well beyond the initial point cloud
    assert m["psnr_heldout"] > m["initial"]["psnr"] + 3.0, m
    assert (ws / "scene" / "gaussians.ply").is_file() and (ws / "scene" / "heldout.png").is_file()
    assert not (ws / "scene" / "checkpoint.pt").exists()
    assert json.loads((ws / "pipeline.json").read_text())["scene"]["summary"]["psnr_heldout"] == m["psnr_heldout"]

    # a camera as given in the original transforms.json renders the trained scene where the photo is:
    # no hidden normalisation. A camera moved by 30 cm sees a clearly worse match.
    g = read_ply(ws / "scene" / "gaussians.ply")
    held = m["per_view"][0]["name"]
    cam = camera_from_transforms_frame(tf, held).scaled(0.5)
    photo = torch.from_numpy(np.array(Image.open(tf.parent / held).convert("RGB")))
    photo = torch.nn.functional.avg_pool2d(photo.permute(2, 0, 1)[None].float() / 255, 2)[0].permute(1, 2, 0)

    def score(T_world_cam):
        vm = torch.as_tensor(np.linalg.inv(T_world_cam), dtype=torch.float32)
        rgb = render(g, vm, torch.as_tensor(cam.K, dtype=torch.float32), cam.width, cam.height, backend="cpu").rgb
        return float(psnr(rgb.clamp(0, 1)[2:-2, 2:-2], photo[2:-2, 2:-2]))

    good = score(cam.T_world_cam)
    moved = cam.T_world_cam.copy()
    moved[:3, 3] += [0.30, 0.0, 0.0]
    assert good == pytest.approx(m["per_view"][0]["psnr"], abs=1.0)
    bad = score(moved)
    # the message says whether the training failed (good far below its usual ~18 dB) or the margin shrank
    assert good > bad + 1.0, {"good": good, "moved": bad, "psnr_heldout": m["psnr_heldout"], "initial": m["initial"],
                              "per_view": m["per_view"], "iterations": m["iterations"]}  # fmt: skip

    again, skipped = train_scene(ws, cfg, log=logs.append)
    assert skipped and again == m


def test_train_scene_resumes_after_a_kill(imported, tmp_path):
    _, ws_src = imported
    ws = tmp_path / "ws"
    for sub in ("capture", "sfm"):
        os.symlink(ws_src / sub, ws / sub) if ws.exists() else (ws.mkdir(), os.symlink(ws_src / sub, ws / sub))
    args = ["--iterations", "120", "--downscale", "4", "--max-gaussians", "20000", "--checkpoint-every", "10"]
    proc = subprocess.Popen([sys.executable, "-m", "mirage2matter", "train-scene", "-w", str(ws), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)  # fmt: skip
    ckpt = ws / ".m2m" / "txn" / "scene" / "staged" / "scene" / "checkpoint.pt"  # the stage's staging
    deadline = time.time() + 240
    while not ckpt.exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.5)
    assert ckpt.exists(), proc.communicate()[0].decode()[-2000:]
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (ws / "scene").exists()  # nothing of the killed run is in the workspace
    step_killed = torch.load(ckpt, weights_only=False)["step"]
    assert 0 < step_killed < 120

    logs = []
    m, _ = train_scene(ws, SceneConfig(iterations=120, downscale=4, max_gaussians=20000, checkpoint_every=10),
                       log=logs.append)  # fmt: skip
    assert any("resuming" in line for line in logs)
    assert m["iterations"] == 120
    steps = [c["step"] for c in m["curve"]]
    assert steps == sorted(steps) and steps[-1] == 120


def test_train_scene_minutes_is_bench_trains_budget(imported, tmp_path):
    """`m2m train-scene --minutes M` trains with budget_config, the configuration `m2m bench train` times (one
    code path), and uses the minutes: no step count planned ahead."""
    from mirage2matter.gaussians.budget import budget_config
    from mirage2matter.gaussians.filter3d import FILTER_3D_VARIANCE
    from mirage2matter.gaussians.train import TrainConfig

    _, ws_src = imported
    ws = tmp_path / "ws"
    ws.mkdir()
    for sub in ("capture", "sfm"):
        os.symlink(ws_src / sub, ws / sub)
    cfg = SceneConfig(minutes=0.15, downscale=4, max_gaussians=20000, checkpoint_every=0)
    m, _ = train_scene(ws, cfg)
    plan = json.loads((ws / "scene" / "plan.json").read_text())["train_config"]
    expect = budget_config(
        0.15, TrainConfig(max_gaussians=20000, backend="cpu", checkpoint_every=0, filter_3d=FILTER_3D_VARIANCE)
    )  # bench_train's default
    assert SceneConfig().filter_3d == FILTER_3D_VARIANCE
    assert plan == json.loads(json.dumps(vars(expect)))
    # a step stalled by another process on the machine can end past the budget: at most a step's worth
    assert 0.9 <= m["train_minutes"] / 0.15 <= 1.0 + 2 * 0.15 * 60 / max(m["iterations"], 1)
    assert m["iterations"] >= 20 and m["curve"][-1]["step"] == m["iterations"]


def test_the_scene_trains_with_train_configs_defaults():
    """One owner of the 3DGS training defaults: the scene stage's cap and checkpoint cadence are TrainConfig's (the
    objects stage passes its own), and `m2m demo`'s scene keeps 200k Gaussians and a checkpoint every 200 steps."""
    from mirage2matter.gaussians.train import TrainConfig

    d, scene = TrainConfig(), SceneConfig()
    assert (scene.max_gaussians, scene.checkpoint_every) == (d.max_gaussians, d.checkpoint_every) == (200_000, 200)


@pytest.fixture(scope="module")
def with_head_camera(imported, tmp_path_factory):
    """The imported workspace (whose frame is the robot base: ground-truth poses) as align-scene and
    calibrate-handeye leave it, with the sample's head camera at its true pose, and the head photo."""
    _, ws_src = imported
    ws = tmp_path_factory.mktemp("head") / "ws"
    ws.mkdir()
    for sub in ("capture", "sfm"):
        os.symlink(ws_src / sub, ws / sub)
    w = Workspace(ws)
    posed = w.posed_capture()
    w.cameras_base_file.parent.mkdir(parents=True, exist_ok=True)
    w.cameras_base_file.write_text(json.dumps([c.to_json() for c in posed.cameras]))
    np.save(w.points_base_file, posed.points)
    head = json.loads((SAMPLE / "ground_truth.json").read_text())["head_camera"]
    w.handeye_file.write_text(json.dumps({"mount": "head", **{k: head[k] for k in ("K", "T_base_headcam", "width",
                                                                                     "height")}}))  # fmt: skip
    return ws, head


def test_train_scene_trains_on_the_head_photo_from_the_head_camera_without_its_masked_pixels(
    with_head_camera, tmp_path, monkeypatch
):
    """--head-photo adds the photo to the training views (repeated), seen from the calibrated head camera at the
    training resolution, with the pixels its mask marks as not scene (a robot arm, here a painted patch) left out
    of the loss; at the defaults the stage's fingerprint is what it was before the option existed."""

    ws, head = with_head_camera
    photo = np.asarray(Image.open(SAMPLE / head["image"]).convert("RGB"))
    painted = photo.copy()
    painted[200:320, 300:460] = (255, 0, 255)
    keep = np.ones(photo.shape[:2], bool)
    keep[200:321, 300:460] = False  # row 320 too: the half-size pixel of rows 320-321 is half masked
    Image.fromarray(painted).save(tmp_path / "head.png")
    Image.fromarray(keep.astype(np.uint8) * 255).save(tmp_path / "mask.png")

    seen = {}
    import mirage2matter.gaussians.train as gaussians_train

    real_train = gaussians_train.train

    def spy(views_train, views_eval, *args, **kwargs):
        seen["views"] = list(views_train)
        return real_train(views_train, views_eval, *args, **kwargs)

    monkeypatch.setattr(gaussians_train, "train", spy)  # the stage imports it when it runs
    base = SceneConfig(iterations=20, downscale=2, max_gaussians=30_000, checkpoint_every=0)
    plain, _ = train_scene(ws, base)
    assert plain["views"] == {"train": 14, "heldout": 2, "head_photo": 0} and len(seen["views"]) == 14
    key = json.loads((ws / "pipeline.json").read_text())["scene"]["fingerprint"]
    assert key == fingerprint("scene", {k: v for k, v in to_dict(base).items()
                                        if not k.startswith(("head_photo", "robot_"))},  # added later: at default, out
                              *[i.path for i in SCENE.inputs(Workspace(ws), base)])  # fmt: skip

    cfg = replace(base, head_photo=tmp_path / "head.png", head_photo_mask=tmp_path / "mask.png", head_photo_repeat=3)
    m, skipped = train_scene(ws, cfg)
    assert not skipped and m["views"] == {"train": 14, "heldout": 2, "head_photo": 3}
    assert json.loads((ws / "pipeline.json").read_text())["scene"]["fingerprint"] != key
    views = seen["views"]
    assert len(views) == 17 and views[-1] is views[-2] is views[-3]
    v = views[-1]
    assert v.image.shape == (240, 320, 3)
    small = painted.astype(np.float32).reshape(240, 2, 320, 2, 3).mean(axis=(1, 3)) / 255.0
    assert np.allclose(v.image.numpy(), small, atol=1e-5)
    np.testing.assert_allclose(v.viewmat.numpy(), np.linalg.inv(head["T_base_headcam"]), atol=1e-6)
    np.testing.assert_allclose(v.K.numpy(), np.diag([0.5, 0.5, 1.0]) @ np.asarray(head["K"]), atol=1e-4)
    mask = v.mask.numpy()
    assert not mask[100:160, 150:230].any()  # the painted patch is out of the loss ...
    assert mask[:100].all() and mask[161:].all() and mask[:, :150].all() and mask[:, 230:].all()  # ... the rest in
    # head-view against the same photo says it measures a training view; against another photo, not
    from mirage2matter.stages.head_view import _scene_trained_on

    assert _scene_trained_on(Workspace(ws), tmp_path / "head.png")
    assert not _scene_trained_on(Workspace(ws), SAMPLE / head["image"])
    # by contents: the photo moved after training is still the photo trained on
    (tmp_path / "head.png").rename(tmp_path / "moved.png")
    assert _scene_trained_on(Workspace(ws), tmp_path / "moved.png")


def test_train_scene_head_photo_refusals(with_head_camera, imported, tmp_path):
    ws, head = with_head_camera
    wrong = tmp_path / "small.png"
    Image.new("RGB", (320, 240)).save(wrong)
    cfg = SceneConfig(iterations=5, downscale=2, max_gaussians=30_000, checkpoint_every=0)
    with pytest.raises(WorkspaceError, match=r"small.png is 320x240 but the head camera is 640x480"):
        train_scene(ws, replace(cfg, head_photo=wrong))
    with pytest.raises(WorkspaceError, match="head_photo_mask is given without a head_photo"):
        replace(cfg, head_photo_mask=wrong).validate()
    unaligned = tmp_path / "unaligned"  # no align-scene: the head camera's pose has no frame to go in
    (unaligned / "calib").mkdir(parents=True)
    for sub in ("capture", "sfm"):
        os.symlink(imported[1] / sub, unaligned / sub)
    (unaligned / "calib" / "handeye.json").write_text((ws / "calib" / "handeye.json").read_text())
    with pytest.raises(WorkspaceError, match="run align-scene first"):
        train_scene(unaligned, replace(cfg, head_photo=SAMPLE / head["image"]))
    (unaligned / "calib" / "handeye.json").unlink()
    with pytest.raises(WorkspaceError, match="calibrate-handeye"):
        train_scene(unaligned, replace(cfg, head_photo=SAMPLE / head["image"]))
