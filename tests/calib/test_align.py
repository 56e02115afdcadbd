"""Metric alignment of SfM to the robot base, on the sample whose camera poses are known."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from fixtures import SAMPLE
from mirage2matter.calib.align import AlignError, align_scene, apply_to_cameras, draw_base_overlay, overlay_keyframe
from mirage2matter.calib.board import BoardSpec
from mirage2matter.capture import CaptureConfig, extract_keyframes
from mirage2matter.geometry.camera import Camera, look_at_pose
from mirage2matter.geometry.rotation import axis_angle_to_matrix
from mirage2matter.geometry.sim3 import Sim3
from mirage2matter.geometry.umeyama import umeyama
from mirage2matter.sfm import SfMConfig, run_sfm
from mirage2matter.sfm.known_poses import with_fixed_intrinsics


def test_pose_update_keeps_every_pixel_where_it_was():
    """eq. pose_update: the moved camera sees the moved point at the same pixel (and is rigid)."""
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    cam = Camera(K, look_at_pose([1.0, -2.0, 1.5], [0.0, 0.0, 0.0]), 640, 480, "c")
    sim = Sim3(0.37, axis_angle_to_matrix(np.array([0.2, 1.0, -0.4]), 1.1), np.array([0.3, -0.2, 0.9]))
    (moved,) = apply_to_cameras(sim, [cam])
    R = moved.T_world_cam[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3)) and np.allclose(R, sim.rotation @ cam.T_world_cam[:3, :3])
    assert np.allclose(moved.T_world_cam[:3, 3], sim.apply(cam.T_world_cam[:3, 3]))
    X = np.random.default_rng(0).normal(size=(20, 3)) * 0.3
    uv0, z0 = cam.project(X)
    uv1, z1 = moved.project(sim.apply(X))
    assert np.allclose(uv0, uv1) and np.allclose(z1, sim.scale * z0)


def _gt() -> dict:
    return json.loads((SAMPLE / "ground_truth.json").read_text())


def _reconstruct(tmp: Path, n_keyframes: int, num_threads: int = -1, known_intrinsics: bool = False):
    keyframes = extract_keyframes(SAMPLE / "scene.mp4", tmp / "capture", CaptureConfig(max_keyframes=n_keyframes))
    config = SfMConfig(num_threads=num_threads)
    if known_intrinsics:  # the capture camera's calibration, as a user with a calibrated phone would give it
        cam = _gt()["camera"]
        config = with_fixed_intrinsics(config, Camera(cam["K"], np.eye(4), cam["width"], cam["height"]))
    gt = _gt()
    if gt["robot"].get("capture_moves"):  # the robot moves half-way: kept out of the features after, as sfm does
        from mirage2matter.robots import get_robot
        from mirage2matter.robots.capture_poses import CapturePoses
        from mirage2matter.sfm.robot_mask import run_sfm_without_moved_robot

        board = BoardSpec.from_json(gt["board"]["spec"])
        result, masks, why = run_sfm_without_moved_robot(
            tmp / "capture", tmp / "sfm", config, keyframes, get_robot(gt["robot"]["name"]),
            CapturePoses.from_json(gt["robot"]), board, np.asarray(gt["board"]["T_base_board"]))  # fmt: skip
        assert masks is not None and len(masks.masked) >= n_keyframes // 3, why
    else:
        result = run_sfm(tmp / "capture", tmp / "sfm", config)
    images = [np.asarray(Image.open(tmp / "capture" / c.name).convert("RGB")) for c in result.cameras]
    return keyframes, result, images


def _errors_vs_truth(keyframes, cameras_base, gt) -> tuple[float, float, float]:
    index = {k["file"]: k["frame_index"] for k in keyframes}
    T_gt = np.array([gt["frames"][index[c.name]]["T_base_cam"] for c in cameras_base])
    T_est = np.array([c.T_world_cam for c in cameras_base])
    dR = np.swapaxes(T_est[:, :3, :3], 1, 2) @ T_gt[:, :3, :3]
    rot = np.degrees(np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    trans_mm = 1000 * np.linalg.norm(T_est[:, :3, 3] - T_gt[:, :3, 3], axis=1)
    scale_err = abs(umeyama(T_est[:, :3, 3], T_gt[:, :3, 3]).scale - 1)
    return float(scale_err), float(np.median(rot)), float(np.median(trans_mm))


@pytest.fixture(scope="module")
def small_reconstruction(tmp_path_factory):
    # one thread: multi-threaded pycolmap mapping differs run to run; this way the test is repeatable
    return _reconstruct(tmp_path_factory.mktemp("align16"), 16, num_threads=1, known_intrinsics=True)


def test_sample_aligns_to_the_base(small_reconstruction):
    keyframes, sfm, images = small_reconstruction
    gt = _gt()
    board = BoardSpec.from_json(gt["board"]["spec"])
    result = align_scene(sfm.cameras, images, sfm.points, board, np.asarray(gt["board"]["T_base_board"]))
    assert result.corner_rms_mm < 1.0 and result.method == "marker"
    with_icp = align_scene(sfm.cameras, images, sfm.points, board, np.asarray(gt["board"]["T_base_board"]), icp=True)
    assert with_icp.method == "marker+icp" and with_icp.icp_points > 100  # the base region was filmed
    scale_err, rot, trans = _errors_vs_truth(keyframes, apply_to_cameras(result.sim3_sfm_to_base, sfm.cameras), gt)
    # 16 keyframes: the SfM itself is off by a few tenths of a degree; the slow test uses 48
    assert scale_err < 0.01 and rot < 0.6 and trans < 12.0, (scale_err, rot, trans)


def test_robot_base_out_of_view_keeps_the_marker_alignment(small_reconstruction):
    """A capture that never saw the table around the robot base: no ICP on the few points there (on a real capture
    it slid the cameras 11 mm); the target alone must place the cameras."""
    keyframes, sfm, images = small_reconstruction
    gt = _gt()
    board = BoardSpec.from_json(gt["board"]["spec"])
    T_base_board = np.asarray(gt["board"]["T_base_board"])
    first = align_scene(sfm.cameras, images, sfm.points, board, T_base_board, icp=False)
    base_xy = first.sim3_sfm_to_base.apply(sfm.points)[:, :2]
    kept = sfm.points[np.linalg.norm(base_xy, axis=1) > 0.35]  # nothing within 35 cm of the base's origin
    footprint = np.array([[-0.1, -0.1], [0.1, 0.1]])
    result = align_scene(sfm.cameras, images, kept, board, T_base_board, icp=True, footprint_xy=footprint)
    assert result.method == "marker" and "ICP skipped" in result.note, result.note
    _, rot, trans = _errors_vs_truth(keyframes, apply_to_cameras(result.sim3_sfm_to_base, sfm.cameras), gt)
    # the bundled sample's robot moves half-way, masked out of the second half's features: 0.094 deg / 2.06 mm on
    # these 16 keyframes (filmed at one pose, under 2.0 mm)
    assert rot <= 0.3 and trans <= 2.5, (rot, trans)


def test_unaligned_is_the_identity_and_says_so(small_reconstruction):
    from mirage2matter.calib.align import unaligned_result

    _, sfm, _ = small_reconstruction
    result = unaligned_result(sfm.cameras)
    assert result.method == "unaligned" and result.sim3_sfm_to_base.scale == 1.0 and "not metric" in result.note
    assert json.dumps(result.to_json())  # valid JSON (no NaN)


def test_wrong_board_or_too_few_views_are_clear_errors(small_reconstruction):
    _, sfm, images = small_reconstruction
    gt = _gt()
    wrong = BoardSpec(5, 7, 0.07, 0.055, "DICT_5X5_100")  # right size, wrong dictionary
    with pytest.raises(AlignError, match="detected in 0 of 16 keyframes.*--unaligned"):
        align_scene(sfm.cameras, images, sfm.points, wrong, np.asarray(gt["board"]["T_base_board"]))
    board = BoardSpec.from_json(gt["board"]["spec"])
    with pytest.raises(AlignError, match="needs >= 3"):
        align_scene(sfm.cameras[:2], images[:2], sfm.points, board)


@pytest.mark.slow
def test_sample_alignment_accuracy_with_48_keyframes(tmp_path):
    gt = _gt()
    board = BoardSpec.from_json(gt["board"]["spec"])
    # Issue 5: <= 0.2 %, 0.2 deg, 2 mm (medians). With the capture camera's known intrinsics held fixed
    # in SfM this measured 0.014 %, 0.06 deg, 1.36 mm with ICP; the board alone (the default since issue 22)
    # 0.039 %, 0.033 deg, 1.06 mm. Self-calibrated (OPENCV, fy drifts 0.36 %) it was 0.21 %, 0.09 deg, 2.5 mm:
    # the residual is SfM's, a best-possible Sim3 leaves 1.1 mm.
    keyframes, sfm, images = _reconstruct(tmp_path / "known", 48, known_intrinsics=True)
    result = align_scene(sfm.cameras, images, sfm.points, board, np.asarray(gt["board"]["T_base_board"]))
    scale_err, rot, trans = _errors_vs_truth(keyframes, apply_to_cameras(result.sim3_sfm_to_base, sfm.cameras), gt)
    print(f"\n48 keyframes: scale error {100 * scale_err:.3f} %, rotation {rot:.3f} deg, translation {trans:.2f} mm")
    assert scale_err < 0.002 and rot < 0.2 and trans < 2.0, (scale_err, rot, trans)
    assert np.allclose(sfm.cameras[0].K, gt["camera"]["K"])  # held fixed


@pytest.mark.slow
def test_a_single_aruco_marker_or_apriltag_aligns_about_as_well_as_charuco(tmp_path):
    """The same sample made with one 18 cm marker on the table instead of the ChArUco board. Measured with 48
    keyframes: ChArUco 1.20 mm / 0.035 deg, ArUco 2.28 mm / 0.085 deg, AprilTag 1.92 mm / 0.074 deg (medians):
    within 2x in translation; 4 corners instead of 24 leave rotation 2.1-2.4x behind, still under issue 5's 0.2 deg."""
    from mirage2matter.calib.board import target_from_json
    from mirage2matter.sample.make import SampleConfig, make_sample, with_marker

    gt = _gt()
    keyframes, sfm, images = _reconstruct(tmp_path / "charuco", 48, known_intrinsics=True)
    ref = align_scene(sfm.cameras, images, sfm.points, BoardSpec.from_json(gt["board"]["spec"]),
                      np.asarray(gt["board"]["T_base_board"]))  # fmt: skip
    _, rot_ref, trans_ref = _errors_vs_truth(keyframes, apply_to_cameras(ref.sim3_sfm_to_base, sfm.cameras), gt)
    for marker in ("aruco", "apriltag"):
        root = tmp_path / f"sample_{marker}"
        make_sample(root, with_marker(SampleConfig(seed=0), marker), log=lambda _: None)
        mgt = json.loads((root / "ground_truth.json").read_text())
        kf = extract_keyframes(root / "scene.mp4", tmp_path / marker / "capture", CaptureConfig(max_keyframes=48))
        cam = mgt["camera"]
        config = with_fixed_intrinsics(SfMConfig(), Camera(cam["K"], np.eye(4), cam["width"], cam["height"]))
        res = run_sfm(tmp_path / marker / "capture", tmp_path / marker / "sfm", config)
        imgs = [np.asarray(Image.open(tmp_path / marker / "capture" / c.name).convert("RGB")) for c in res.cameras]
        target = target_from_json(mgt["board"]["spec"])
        assert target.kind == marker
        result = align_scene(res.cameras, imgs, res.points, target, np.asarray(mgt["board"]["T_base_board"]))
        _, rot, trans = _errors_vs_truth(kf, apply_to_cameras(result.sim3_sfm_to_base, res.cameras), mgt)
        print(f"\n{marker}: {rot:.3f} deg / {trans:.2f} mm; ChArUco {rot_ref:.3f} deg / {trans_ref:.2f} mm")
        assert trans <= 2.0 * trans_ref and rot <= 0.2, (marker, rot, trans, rot_ref, trans_ref)


def test_a_fisheye_lens_goes_through_alignment():
    """Corner rays through an equidistant fisheye (past 60 deg off the axis) are the points' own directions, and
    aligned cameras keep their lens model."""
    from mirage2matter.calib.align import _undistorted_normalized

    K = np.array([[300.0, 0.0, 320.0], [0.0, 300.0, 240.0], [0.0, 0.0, 1.0]])
    lens = {"model": "fisheye", "k1": -0.02, "k2": 0.004, "k3": -0.001, "k4": 0.0002}
    cam = Camera(K, look_at_pose([0.3, -0.2, 0.5], [0.0, 0.0, 0.0]), 640, 480, "fish", lens)
    rng = np.random.default_rng(0)
    pc = np.c_[rng.uniform(-1.5, 1.5, (50, 2)), np.ones(50)]  # up to ~65 deg off the axis, camera frame
    points = pc @ cam.T_world_cam[:3, :3].T + cam.T_world_cam[:3, 3]
    uv, _ = cam.project(points, distort=True)
    assert np.abs(uv - cam.project(points)[0]).max() > 50  # the lens matters here
    assert np.allclose(_undistorted_normalized(cam, uv), pc[:, :2], atol=1e-9)
    moved = apply_to_cameras(Sim3(2.0, axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), 0.3), np.ones(3)), [cam])[0]
    assert moved.distortion_model == "fisheye" and moved.distortion == cam.distortion


def test_the_overlay_is_drawn_where_the_base_is_seen_with_the_robots_outline():
    """Of the keyframes that see the board, the overlay takes one that sees the base's origin (nearest its centre): a
    wrist camera looking down at the board first in name order does not; the robot's outline is drawn there too."""
    K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    wrist = Camera(K, look_at_pose((0.45, 0.05, 0.5), (0.45, 0.0, 0.0)), 320, 240, "0.jpg")  # the board only
    aside = Camera(K, look_at_pose((1.0, 1.0, 0.6), (0.6, 0.3, 0.0)), 320, 240, "1.jpg")  # the origin near an edge
    side = Camera(K, look_at_pose((1.2, -0.6, 0.6), (0.1, 0.0, 0.1)), 320, 240, "2.jpg")  # the base in the middle
    cams = [wrist, aside, side]
    assert overlay_keyframe(cams, ["0.jpg", "1.jpg", "2.jpg"]) == 2
    assert overlay_keyframe(cams, ["0.jpg", "1.jpg"]) == 1
    assert overlay_keyframe(cams, ["0.jpg"]) == 0  # none sees the base: the first that sees the board
    images = [np.zeros((240, 320, 3), np.uint8) for _ in cams]
    disc = np.zeros((240, 320), bool)
    disc[100:140, 140:180] = True
    plain = draw_base_overlay(images, cams, ["0.jpg", "2.jpg"])
    drawn = draw_base_overlay(images, cams, ["0.jpg", "2.jpg"], robot_mask=lambda cam: disc)
    yellow = np.all(drawn == (255, 255, 0), axis=2)
    assert yellow[98:142, 138:182].sum() > 100 and not np.all(plain == (255, 255, 0), axis=2).any()
