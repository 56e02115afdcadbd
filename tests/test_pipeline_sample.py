"""The bundled sample through the reconstruction stages with the `m2m` commands a user runs:
capture -> sfm (calibrated intrinsics) -> align-scene -> calibrate-handeye -> train-scene -> head-view."""

import json

import pytest

from fixtures import SAMPLE
from mirage2matter.cli import main


@pytest.mark.slow
def test_sample_scene_is_reconstructed_in_the_base_frame_and_seen_by_the_head_camera(tmp_path):
    if not (SAMPLE / "scene.mp4").is_file():
        pytest.skip("samples/tabletop not built")
    ws, s = str(tmp_path / "ws"), str(SAMPLE)
    assert main(["capture", f"{s}/scene.mp4", "-w", ws, "--max-keyframes", "48"]) == 0
    # the robot stands in the video at its logged joint state (not home): a user gives it, as the sample's m2m.yaml does
    # (and, half-way through the video, the second pose it was moved to). The pipeline's settings, given to the first
    # stage that reads them (sfm keeps the moved robot out of its features), are every later stage's
    robot = json.loads((SAMPLE / "ground_truth.json").read_text())["robot"]
    joints = [str(q) for q in robot["capture_joints"]]
    moves = [f"{frame}={','.join(map(str, q))}" for frame, q in (robot.get("capture_moves") or {}).items()]
    assert main(["sfm", "-w", ws, "--intrinsics", f"{s}/ground_truth.json", "--board", f"{s}/board.json",
                 "--board-pose", f"{s}/ground_truth.json", "--capture-joints", *joints,
                 *[w for m in moves for w in ("--capture-moves", m)]]) == 0  # fmt: skip
    masks = json.loads((tmp_path / "ws" / "sfm" / "robot_masks.json").read_text())
    assert len(masks["masked"]) >= 15 and not masks["unplaced"]  # 48 keyframes, about half after the move
    assert main(["align-scene", "-w", ws]) == 0
    he = f"{s}/handeye"
    assert main(["calibrate-handeye", "--images", f"{he}/images", "--joints", f"{he}/joints.json",
                 "--board", f"{he}/board.json", "--intrinsics", f"{s}/ground_truth.json", "-w", ws]) == 0  # fmt: skip
    assert main(["train-scene", "-w", ws, "--minutes", "8"]) == 0
    metrics = json.loads((tmp_path / "ws" / "scene" / "metrics.json").read_text())
    print("\nscene:", {k: metrics.get(k) for k in ("psnr_heldout", "ssim_heldout", "iterations", "gaussians")})
    # issue 4: held-out PSNR >= 28 dB on the sample (measured 31.7 dB after 12 min on a busy machine)
    assert metrics["frame"] == "base" and metrics["psnr_heldout"] >= 28.0, metrics["psnr_heldout"]
    assert main(["head-view", "-w", ws, "--photo", f"{s}/head_view.png"]) == 0
    check = json.loads((tmp_path / "ws" / "calib" / "head_view.json").read_text())
    print("head view:", {k: check[k] for k in ("psnr", "corners_vs_photo_px", "corners_vs_known_px")})
    # issue 5: the board lands on the same pixels (<= 3 px); measured 0.6 px, PSNR 22 dB (the head camera
    # sees floor the hand-held orbit never did). With the robot in the photo its forearm hides most of the board, and
    # the render and the photo find corners in different places (2026-12-05: 1 in both); the calibration itself is the
    # photo's corners against the board's known pose
    assert check["photo_vs_known_px"]["n"] >= 6 and check["photo_vs_known_px"]["median"] <= 3.0
    # with the robot in the photo, its Gaussians are drawn there. Filmed at one pose, the upper arm no keyframe saw
    # kept the model's white (2026-12-05: 16.0 dB whole, the robot's pixels 9.3 dB); with the second pose the orbit
    # sees it (23.0 dB whole, the robot's pixels 23.2 dB)
    scene_psnr = check["psnr"]
    assert not check.get("robot_drawn") or check["psnr_robot"] > 18.0, check
    # the render's own corners against the known pose, where the drawn robot leaves any (at the capture joints its hand
    # covers them all: 2026-12-05, 0 found)
    known = check["corners_vs_known_px"]
    assert (not known.get("n") or known["median"] <= 3.0) and scene_psnr > 18.0
