"""The moved robot kept out of SfM's features (sfm/robot_mask.py): its silhouette through a real lens, a keyframe
placed by the board alone, COLMAP's masks written whole, and SfM with them on a capture where the robot moved."""

import json

import numpy as np
import pytest

from fixtures import SAMPLE, sample_present
from mirage2matter.calib.align import board_in_base
from mirage2matter.calib.board import load_target
from mirage2matter.calib.robot_view import grow_mask, robot_silhouette
from mirage2matter.geometry.camera import Camera, load_intrinsics, look_at
from mirage2matter.robots import get_robot
from mirage2matter.robots.capture_poses import CapturePoses
from mirage2matter.robots.surface import robot_surface, sample_surface
from mirage2matter.sfm.robot_mask import board_camera, lens_silhouette, moved_keyframes, write_robot_masks

needs_sample = pytest.mark.skipif(not sample_present(), reason="the bundled sample is not present")
Q_HOME = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]


def _camera(distortion: dict | None = None) -> Camera:
    K = np.array([[260.0, 0.0, 160.0], [0.0, 260.0, 120.0], [0.0, 0.0, 1.0]])
    cam = look_at(np.array([1.1, -0.6, 0.8]), np.array([0.3, 0.5, 0.3]), np.array([0.0, 0.0, 1.0]), K, 320, 240)
    return Camera(cam.K, cam.T_world_cam, 320, 240, distortion=distortion or {})


def test_the_silhouette_through_a_lens_is_where_the_lens_images_the_robot():
    links = robot_surface(get_robot("panda"), Q_HOME)
    pinhole = _camera()
    assert np.array_equal(lens_silhouette(pinhole, links, 0), robot_silhouette(pinhole, links))  # no lens: as is
    barrel = _camera({"k1": -0.3, "k2": 0.08})
    sil = lens_silhouette(barrel, links, 0)
    samples, _ = sample_surface(links, 0.0015)
    uv, z = barrel.project(samples, distort=True)
    inside = (z > 0) & (uv >= 0).all(axis=1) & (uv[:, 0] < 320) & (uv[:, 1] < 240)
    u, v = np.floor(uv[inside]).astype(int).T
    assert inside.sum() > 1000 and sil[v, u].mean() > 0.99  # the surface points the lens images are masked ...
    assert lens_silhouette(barrel, links, 1)[v, u].mean() > 0.999  # (those left: at the outline, within a pixel)
    imaged = np.zeros_like(sil)
    imaged[v, u] = True
    assert (sil & grow_mask(imaged, 1)).sum() > 0.97 * sil.sum()  # ... and little else is
    # drawn without the lens (the robot off the image centre), it would miss where the barrel pulls it inwards
    assert robot_silhouette(barrel, links)[v, u].mean() < 0.9


def _frames(indices):
    from mirage2matter.video import read_video_frames

    want = set(indices)
    return {i: rgb for i, _, rgb in read_video_frames(SAMPLE / "scene.mp4") if i in want}


@needs_sample
def test_a_keyframe_is_placed_by_the_board_alone(tmp_path):
    from PIL import Image

    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    board = load_target(SAMPLE / "board.json")
    lens = load_intrinsics(SAMPLE / "ground_truth.json")
    T_base_board = board_in_base(board, SAMPLE / "ground_truth.json")
    placed = 0
    for i, rgb in _frames(range(0, 720, 60)).items():
        Image.fromarray(rgb).save(tmp_path / f"{i:06d}.png")
        cam = board_camera(tmp_path / f"{i:06d}.png", board, T_base_board, lens)
        if cam is None:
            continue
        placed += 1
        T = np.asarray(gt["frames"][i]["T_base_cam"])
        assert np.linalg.norm(cam.T_world_cam[:3, 3] - T[:3, 3]) < 0.01  # m
        cos = (np.trace(cam.T_world_cam[:3, :3].T @ T[:3, :3]) - 1) / 2
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 0.5
    assert placed >= 3
    Image.new("RGB", (640, 480)).save(tmp_path / "blank.png")
    assert board_camera(tmp_path / "blank.png", board, T_base_board, lens) is None


@needs_sample
def test_masks_are_written_for_every_keyframe_and_only_the_moved_robot_is_black(tmp_path):
    from PIL import Image

    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    lens = load_intrinsics(SAMPLE / "ground_truth.json")
    board = load_target(SAMPLE / "board.json")
    frames = _frames([0, 360, 400])
    images = tmp_path / "images"
    images.mkdir()
    for i, rgb in frames.items():
        Image.fromarray(rgb).save(images / f"frame_{i:06d}.png")
    Image.new("RGB", (640, 480)).save(images / "frame_000650.png")  # after the move, no camera, no board
    q2 = [0.7, 0.77, 0.0, -1.55, 0.0, 1.53, 0.785]
    poses = CapturePoses.from_json({"capture_joints": Q_HOME, "capture_moves": {"300": q2}})
    keyframes = [{"file": f"frame_{i:06d}.png", "frame_index": i} for i in (0, 360, 400, 650)]
    moved = moved_keyframes(keyframes, poses)
    assert moved == {"frame_000360.png": 1, "frame_000400.png": 1, "frame_000650.png": 1}
    cameras = [Camera(lens.K, np.asarray(gt["frames"][i]["T_base_cam"]), 640, 480, name=f"frame_{i:06d}.png")
               for i in (0, 400)]  # frame 360: not registered by the first run, placed by the board (18 corners)
    out = tmp_path / "masks"
    masks = write_robot_masks(out, images, sorted(p.name for p in images.iterdir()), moved, cameras,
                              get_robot("panda"), poses, board, board_in_base(board, SAMPLE / "ground_truth.json"))
    assert sorted(p.name for p in out.iterdir()) == sorted(f"{p.name}.png" for p in images.iterdir())
    read = {p.name.removesuffix(".png"): np.asarray(Image.open(p)) for p in out.iterdir()}
    assert (read["frame_000000.png"] == 255).all()  # the first pose keeps its features
    assert (read["frame_000650.png"] == 255).all() and masks.unplaced == ["frame_000650.png"]
    assert masks.masked == ["frame_000360.png", "frame_000400.png"] and masks.by_board == ["frame_000360.png"]
    assert 0.02 < masks.robot_px["frame_000400.png"] < 0.6 and 0.02 < masks.robot_px["frame_000360.png"] < 0.6
    black = read["frame_000400.png"] == 0
    assert black.mean() == pytest.approx(masks.robot_px["frame_000400.png"], abs=1e-3)
    # the mask is the second pose's robot, not the first's
    second = robot_silhouette(cameras[1], robot_surface(get_robot("panda"), q2))
    first = robot_silhouette(cameras[1], robot_surface(get_robot("panda"), Q_HOME))
    beyond = first & ~grow_mask(second, 16)  # where only the first pose stood, past the mask's 2 % margin
    assert black[second].mean() == 1.0 and beyond.sum() > 500 and not black[beyond].any()
    assert "1 filmed after a move neither registered nor showing the board" in masks.line
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".masks")]  # no half-written folder left


@needs_sample
def test_without_the_board_in_view_the_first_run_is_the_result(tmp_path):
    """A target the capture never shows cannot place the first run's cameras: that run, unmasked, is the result (in
    place, its model where it says), and the reason is given; no staging folder is left."""
    from mirage2matter.calib.board import MarkerSpec
    from mirage2matter.capture import CaptureConfig, extract_keyframes
    from mirage2matter.sfm import SfMConfig, load_sfm_summary
    from mirage2matter.sfm.robot_mask import run_sfm_without_moved_robot

    keyframes = extract_keyframes(SAMPLE / "scene.mp4", tmp_path / "capture", CaptureConfig(max_keyframes=12))
    marker = MarkerSpec(kind="aruco", size_m=0.15, id=7, dictionary="DICT_6X6_250")  # not in the video
    out = tmp_path / "sfm"
    result, masks, why = run_sfm_without_moved_robot(
        tmp_path / "capture", out, SfMConfig(max_num_features=2048, downscale=0.5), keyframes, get_robot("panda"),
        CapturePoses.from_json({"capture_joints": Q_HOME, "capture_moves": {"360": Q_HOME}}), marker, np.eye(4))
    assert masks is None and "the board did not place the first run's cameras" in why
    assert result.model_dir == out / "model" and (out / "model" / "images.bin").is_file()
    assert [c.name for c in load_sfm_summary(out)[1]] == [c.name for c in result.cameras] and result.registered >= 6
    assert sorted(p.name for p in tmp_path.iterdir()) == ["capture", "sfm"]
