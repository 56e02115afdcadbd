import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from fixtures import FOX, SAMPLE
from mirage2matter.capture import CaptureConfig, extract_keyframes, load_keyframes
from mirage2matter.geometry import Sim3, load_transforms_json
from mirage2matter.geometry.rotation import axis_angle_to_matrix, random_rotation
from mirage2matter.sfm import SfMConfig, SfMError, compare_poses, load_sfm_summary, run_sfm

needs_sample = pytest.mark.skipif(not (SAMPLE / "scene.mp4").is_file(), reason="samples/tabletop not built")


# ---- compare_poses ------------------------------------------------------------------------------
def _poses(n=12, seed=0):
    rng = np.random.default_rng(seed)
    R = random_rotation(n, seed=seed)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = rng.normal(size=(n, 3))
    return {f"{i:03d}.jpg": T[i] for i in range(n)}


def test_compare_poses_is_invariant_to_a_similarity():
    ref = _poses()
    sim = Sim3(3.7, random_rotation(seed=5), np.array([1.0, -2.0, 0.5]))
    est = {k: sim.apply_pose(v) for k, v in ref.items()}
    est["extra.jpg"] = np.eye(4)  # names only one side holds are ignored
    c = compare_poses(est, ref)
    assert c["n"] == 12
    assert c["rotation_deg_max"] < 1e-6 and c["center_frac_max"] < 1e-9
    assert Sim3.from_json(c["sim3_est_to_ref"]).allclose(sim.inverse(), atol=1e-9)


def test_compare_poses_measures_rotation_and_centre_errors():
    ref = _poses()
    est = {k: v.copy() for k, v in ref.items()}
    name = "004.jpg"
    est[name][:3, :3] = est[name][:3, :3] @ axis_angle_to_matrix(np.array([0.0, 0.0, 1.0]), np.radians(2.0))
    c = compare_poses(est, ref)
    assert c["rotation_deg_max"] == pytest.approx(2.0, abs=1e-6)
    assert c["per_camera"][name]["rotation_deg"] == pytest.approx(2.0, abs=1e-6)
    assert c["rotation_deg_median"] < 1e-6
    with pytest.raises(ValueError, match=">= 3"):
        compare_poses({k: ref[k] for k in list(ref)[:2]}, ref)


# ---- bad input ----------------------------------------------------------------------------------
def test_bad_inputs_give_clear_errors_and_write_nothing(tmp_path):
    out = tmp_path / "sfm"
    with pytest.raises(SfMError, match="not found"):
        run_sfm(tmp_path / "missing", out)
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    rng = np.random.default_rng(0)
    cv2.imwrite(str(imgs / "a.png"), rng.integers(0, 255, (64, 80, 3), dtype=np.uint8))
    with pytest.raises(SfMError, match="at least 3"):
        run_sfm(imgs, out)
    cv2.imwrite(str(imgs / "b.png"), rng.integers(0, 255, (64, 80, 3), dtype=np.uint8))
    cv2.imwrite(str(imgs / "c.png"), rng.integers(0, 255, (32, 80, 3), dtype=np.uint8))
    with pytest.raises(SfMError, match="different sizes"):
        run_sfm(imgs, out)
    with pytest.raises(SfMError, match="loop_detection needs vocab_tree_path"):
        run_sfm(imgs, out, SfMConfig(loop_detection=True))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["imgs"]


def test_unmatchable_images_raise_capture_more_parallax(tmp_path):
    # independent noise images: plenty of SIFT features, no geometrically consistent matches
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    rng = np.random.default_rng(1)
    for i in range(6):
        small = rng.integers(0, 256, (30, 40), dtype=np.uint8)
        cv2.imwrite(str(imgs / f"{i}.png"), cv2.resize(small, (320, 240), interpolation=cv2.INTER_CUBIC))
    with pytest.raises(SfMError, match="parallax"):
        run_sfm(imgs, tmp_path / "sfm", SfMConfig(max_num_features=1024))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["imgs"]


# ---- the rendered sample (ground truth) ---------------------------------------------------------
def _sample_reference(capture_dir):
    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    T = {f["index"]: np.asarray(f["T_base_cam"]) for f in gt["frames"]}
    return gt, {k["file"]: T[k["frame_index"]] for k in load_keyframes(capture_dir)["keyframes"]}


def _run_sample(tmp_path, n_keyframes, config):
    cap = tmp_path / "capture"
    extract_keyframes(SAMPLE / "scene.mp4", cap, CaptureConfig(max_keyframes=n_keyframes))
    t0 = time.perf_counter()
    res = run_sfm(cap, tmp_path / "sfm", config)
    seconds = time.perf_counter() - t0
    gt, ref = _sample_reference(cap)
    cmp = compare_poses(res.poses, ref)
    print(
        f"\nsample, {n_keyframes} keyframes: {res.registered}/{res.total} registered in {seconds:.1f} s, "
        f"reproj {res.mean_reprojection_error:.3f} px, rotation median {cmp['rotation_deg_median']:.3f} deg "
        f"(max {cmp['rotation_deg_max']:.3f}), centre median {100 * cmp['center_frac_median']:.3f} % "
        f"(max {100 * cmp['center_frac_max']:.3f} %), fx {res.cameras[0].fx:.1f} vs {gt['camera']['K'][0][0]:.1f}"
    )
    return res, cmp, gt


@needs_sample
def test_sample_16_keyframes_match_ground_truth(tmp_path):
    res, cmp, gt = _run_sample(tmp_path, 16, SfMConfig(max_num_features=4096))
    assert res.registered == res.total == 16 and not res.unregistered
    assert cmp["rotation_deg_median"] <= 0.5
    assert cmp["center_frac_median"] <= 0.01
    assert res.mean_reprojection_error < 1.0
    assert res.points.shape[0] > 500 and res.colors.shape == res.points.shape and res.colors.dtype == np.uint8
    # intrinsics in full-resolution pixels, OpenCV model with its distortion terms
    cam = res.cameras[0]
    assert cam.fx == pytest.approx(gt["camera"]["K"][0][0], rel=0.02)
    assert set(cam.distortion) == {"k1", "k2", "p1", "p2"}
    # what was written round-trips
    summary, cams = load_sfm_summary(tmp_path / "sfm")
    assert summary["registered"] == 16 and summary["matching_used"] == "exhaustive"
    assert [c.name for c in cams] == [c.name for c in res.cameras]
    assert np.allclose(cams[3].T_world_cam, res.cameras[3].T_world_cam)
    assert {p.name for p in (tmp_path / "sfm" / "model").iterdir()} >= {"cameras.bin", "images.bin", "points3D.bin"}


@needs_sample
def test_same_images_give_the_same_model(tmp_path):
    # multi-threaded COLMAP varied run to run (once 4 deg off); the default is reproducible
    cap = tmp_path / "capture"
    extract_keyframes(SAMPLE / "scene.mp4", cap, CaptureConfig(max_keyframes=16))  # 10 leave too few round the robot
    config = SfMConfig(max_num_features=1024, downscale=0.5)
    a, b = run_sfm(cap, tmp_path / "a", config), run_sfm(cap, tmp_path / "b", config)
    assert a.registered == b.registered >= 12
    assert all(np.array_equal(a.poses[k], b.poses[k]) for k in a.poses)
    assert np.array_equal(a.points, b.points)


@pytest.mark.slow
@needs_sample
def test_sample_full_matches_ground_truth(tmp_path):
    """The issue's figure: all keyframes registered, <= 0.2 deg and <= 0.5 % of the scene extent."""
    res, cmp, _ = _run_sample(tmp_path, 48, SfMConfig())
    assert res.registered == res.total
    assert cmp["rotation_deg_median"] <= 0.2
    assert cmp["center_frac_median"] <= 0.005


# ---- real phone footage -------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.skipif(not (FOX / "transforms.json").is_file(), reason=f"fox data not found at {FOX}")
def test_fox_matches_reference_colmap_poses(tmp_path):
    t0 = time.perf_counter()
    res = run_sfm(FOX / "images", tmp_path / "sfm", SfMConfig(matching="sequential", downscale=0.5))
    seconds = time.perf_counter() - t0
    ref = {Path(c.name).name: c.T_world_cam for c in load_transforms_json(FOX / "transforms.json")}
    cmp = compare_poses(res.poses, ref)
    print(
        f"\nfox: {res.registered}/{res.total} registered in {seconds:.1f} s, reproj "
        f"{res.mean_reprojection_error:.3f} px, rotation median {cmp['rotation_deg_median']:.3f} deg "
        f"(max {cmp['rotation_deg_max']:.3f}), centre median {100 * cmp['center_frac_median']:.3f} % "
        f"(max {100 * cmp['center_frac_max']:.3f} %)"
    )
    assert res.total == 54 and res.registered >= 52  # the time is printed, not asserted: speed is a benchmark's
    assert cmp["rotation_deg_median"] <= 0.5
    assert cmp["center_frac_median"] <= 0.005
