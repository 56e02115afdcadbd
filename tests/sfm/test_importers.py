"""Importing poses made elsewhere: transforms.json (triangulated with the given poses) and COLMAP models."""

import json
from dataclasses import replace

import numpy as np
import pytest

from fixtures import SAMPLE
from mirage2matter.geometry.camera import load_transforms_json
from mirage2matter.sample.transforms import write_sample_transforms
from mirage2matter.sfm import SfMConfig, SfMError, load_sfm_summary
from mirage2matter.sfm.importers import import_colmap_model, import_transforms

needs_sample = pytest.mark.skipif(not (SAMPLE / "scene.mp4").is_file(), reason="samples/tabletop not built")


@pytest.fixture(scope="module")
def sample_transforms(tmp_path_factory):
    if not (SAMPLE / "scene.mp4").is_file():
        pytest.skip("samples/tabletop not built")
    return write_sample_transforms(SAMPLE, tmp_path_factory.mktemp("tf") / "data")


@needs_sample
def test_transforms_import_keeps_the_given_frame_and_triangulates_real_geometry(sample_transforms, tmp_path):
    ws = tmp_path / "ws"
    result = import_transforms(sample_transforms, ws / "capture", ws / "sfm", SfMConfig(num_threads=2))
    given = {c.name: c for c in load_transforms_json(sample_transforms)}
    assert result.registered == result.total == len(given) == 12
    # poses and intrinsics are the given ones (OpenCV axes, same world frame), not re-estimated
    _, cams = load_sfm_summary(ws / "sfm")
    for c in cams:
        assert np.allclose(c.T_world_cam, given[c.name].T_world_cam, atol=1e-9)
        assert np.allclose(c.K, given[c.name].K)
        assert (ws / "capture" / c.name).is_file()
    # the points are where the scene is: a large share on the table top / board (z = 0, metres)
    assert len(result.points) > 200
    assert result.mean_reprojection_error < 1.0
    on_table = np.abs(result.points[:, 2]) < 0.005
    assert on_table.mean() > 0.2, f"only {on_table.mean():.0%} of the points lie on the table plane"

    # the imported model is itself importable as a COLMAP model, with the same cameras
    ws2 = tmp_path / "ws2"
    again = import_colmap_model(ws / "sfm" / "model", ws / "capture", ws2 / "capture", ws2 / "sfm")
    assert again.registered == 12 and len(again.points) == len(result.points)
    for c in again.cameras:
        assert np.allclose(c.T_world_cam, given[c.name].T_world_cam, atol=1e-6)
        assert np.allclose(c.K, given[c.name].K, atol=1e-9)


@needs_sample
def test_transforms_import_with_two_threads_gives_the_same_points_twice(sample_transforms, tmp_path):
    # extraction's threads numbered the images in the order they finished and matching's threads drew one
    # generator in a varying order: every run triangulated other points, and the scene trained on them varied
    two = SfMConfig(num_threads=2)
    runs = [import_transforms(sample_transforms, tmp_path / k / "capture", tmp_path / k / "sfm", two) for k in "ab"]
    assert len(runs[0].points) > 200
    assert np.array_equal(runs[0].points, runs[1].points)


def test_import_bad_inputs_name_the_problem_and_write_nothing(tmp_path):
    tf = tmp_path / "data" / "transforms.json"
    tf.parent.mkdir()
    frame = {"transform_matrix": np.eye(4).tolist()}
    tf.write_text(json.dumps({"fl_x": 100, "w": 64, "h": 48, "frames": [
        {"file_path": "images/a.png", **frame}, {"file_path": "images/b.png", **frame}]}))  # fmt: skip
    ws = tmp_path / "ws"
    with pytest.raises(SfMError, match=r"2 of 2 images not found.*images/a.png"):
        import_transforms(tf, ws / "capture", ws / "sfm")
    assert not ws.exists()
    with pytest.raises(SfMError, match="transforms.json not found"):
        import_transforms(tmp_path / "nope" / "transforms.json", ws / "capture", ws / "sfm")
    (tmp_path / "model").mkdir()
    with pytest.raises(SfMError, match="not a COLMAP sparse model"):
        import_colmap_model(tmp_path / "model", tmp_path, ws / "capture", ws / "sfm")
    assert not ws.exists()


def test_sample_transforms_helper_round_trips_poses(tmp_path):
    if not (SAMPLE / "scene.mp4").is_file():
        pytest.skip("samples/tabletop not built")
    path = write_sample_transforms(SAMPLE, tmp_path / "data", every=240)
    gt = json.loads((SAMPLE / "ground_truth.json").read_text())
    cams = load_transforms_json(path)
    assert [c.name for c in cams] == ["images/0000.png", "images/0240.png", "images/0480.png"]
    assert np.allclose(cams[1].T_world_cam, gt["frames"][240]["T_base_cam"], atol=1e-9)


def _first_half(transforms):
    """The images filmed before the sample's robot moves (frame 360): after it, its second pose covers a third of
    these small views, and of every 40th frame 5 of the second half's were left unregistered."""
    for image in (transforms.parent / "images").iterdir():
        if int(image.stem) >= 360:
            image.unlink()
    return transforms


@needs_sample
def test_known_intrinsics_are_held_fixed_and_must_match_the_images(tmp_path):
    from mirage2matter.geometry.camera import Camera
    from mirage2matter.sfm import run_sfm
    from mirage2matter.sfm.known_poses import with_fixed_intrinsics

    tf = _first_half(write_sample_transforms(SAMPLE, tmp_path / "data", every=20, scale=0.5))  # 18 views
    given = load_transforms_json(tf)[0]
    cam = Camera(given.K, np.eye(4), given.width, given.height)
    config = with_fixed_intrinsics(SfMConfig(num_threads=2), cam)
    assert config.camera_model == "PINHOLE" and not config.refine_intrinsics
    result = run_sfm(tf.parent / "images", tmp_path / "sfm", config)
    assert result.registered >= 16
    assert all(np.allclose(c.K, given.K) for c in result.cameras)
    wrong = with_fixed_intrinsics(SfMConfig(), cam.scaled(2.0))
    with pytest.raises(SfMError, match="images are 320x240 but the given intrinsics are for 640x480"):
        run_sfm(tf.parent / "images", tmp_path / "sfm2", wrong)
    assert not (tmp_path / "sfm2").exists()


@needs_sample
def test_mapper_runs_again_with_other_seeds_while_images_are_left_out(tmp_path):
    from PIL import Image

    from mirage2matter.geometry.camera import Camera
    from mirage2matter.sfm import run_sfm
    from mirage2matter.sfm.known_poses import with_fixed_intrinsics

    tf = _first_half(write_sample_transforms(SAMPLE, tmp_path / "data", every=20, scale=0.5))  # 18 views
    images = tf.parent / "images"
    given = load_transforms_json(tf)[0]
    fixed = with_fixed_intrinsics(SfMConfig(num_threads=1), Camera(given.K, np.eye(4), given.width, given.height))
    Image.new("RGB", (320, 240), (128, 128, 128)).save(images / "zz_blank.png")  # no features: never registers
    result = run_sfm(images, tmp_path / "sfm", replace(fixed, mapper_attempts=2, retry_below=1.0))
    summary, _ = load_sfm_summary(tmp_path / "sfm")
    assert summary["mapper_attempts"] == 2, "19 images and 18 registered: the mapper must run again"
    assert result.registered == 18 and result.unregistered == ["zz_blank.png"]
    run_sfm(images, tmp_path / "sfm_once", replace(fixed, mapper_attempts=2, retry_below=0.9))
    assert load_sfm_summary(tmp_path / "sfm_once")[0]["mapper_attempts"] == 1, "18 of 19 is enough: one run"
    with pytest.raises(SfMError, match="mapper_attempts"):
        run_sfm(images, tmp_path / "sfm_bad", SfMConfig(mapper_attempts=0))
