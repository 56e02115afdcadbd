"""Cameras: OpenCV conventions, JSON files, look_at, and the transforms.json importer."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fixtures import FOX
from mirage2matter.geometry.camera import (
    Camera,
    CameraFormatError,
    camera_from_transforms_frame,
    load_camera_json,
    load_transforms_json,
    look_at,
    save_camera_json,
)

K0 = np.array([[500.0, 0.0, 320.0], [0.0, 480.0, 240.0], [0.0, 0.0, 1.0]])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def write_transforms(path: Path, frames: list[dict], **top: object) -> Path:
    path.write_text(json.dumps({**top, "frames": frames}))
    return path


# ---- Camera -------------------------------------------------------------------------------------
def test_viewmat_is_rigid_inverse() -> None:
    rng = np.random.default_rng(0)
    T = pose(random_rotation(rng), rng.normal(size=3) * 5)
    cam = Camera(K0, T, 640, 480)
    np.testing.assert_allclose(cam.viewmat @ cam.T_world_cam, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(cam.T_world_cam @ cam.viewmat, np.eye(4), atol=1e-12)
    np.testing.assert_array_equal(cam.center, T[:3, 3])
    assert cam.K.dtype == np.float64 and cam.T_world_cam.dtype == np.float64


def test_project_known_point() -> None:
    rng = np.random.default_rng(1)
    R, c = random_rotation(rng), rng.normal(size=3)
    cam = Camera(K0, pose(R, c), 640, 480)
    p = c + R @ np.array([0.3, -0.2, 4.0])  # 4 m ahead, right of and above the optical axis
    uv, z = cam.project(p[None])
    assert z[0] == pytest.approx(4.0)
    np.testing.assert_allclose(uv[0], [500 * 0.3 / 4 + 320, 480 * -0.2 / 4 + 240])


def test_scaled_camera_scales_pixels() -> None:
    rng = np.random.default_rng(2)
    cam = Camera(K0, pose(random_rotation(rng), rng.normal(size=3)), 640, 480, name="a")
    half = cam.scaled(0.5)
    assert (half.width, half.height, half.name) == (320, 240, "a")
    np.testing.assert_allclose(half.K, [[250, 0, 160], [0, 240, 120], [0, 0, 1]])
    # Pixel edges at integers: the same ray lands at exactly half the (continuous) coordinate.
    p = cam.center + cam.T_world_cam[:3, :3] @ np.array([0.1, 0.2, 3.0])
    np.testing.assert_allclose(half.project(p[None])[0], 0.5 * cam.project(p[None])[0])
    assert cam.scaled(1 / 3).width == round(640 / 3)
    with pytest.raises(ValueError):
        cam.scaled(0)


@pytest.mark.parametrize(
    ("K", "T", "w", "h", "field"),
    [
        (np.diag([-500.0, 480.0, 1.0]), np.eye(4), 640, 480, "K"),
        (np.zeros((2, 3)), np.eye(4), 640, 480, "K"),
        (K0, np.diag([1.0, 1.0, -1.0, 1.0]), 640, 480, "reflection"),
        (K0, np.diag([1.1, 1.0, 1.0, 1.0]), 640, 480, "not orthonormal"),
        (K0, np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1.0]]), 640, 480, "last row"),
        (K0, np.eye(4), 0, 480, "width"),
        (K0, np.eye(4), 640, 480.5, "height"),
        (K0, np.eye(4), True, 480, "width"),
    ],
)
def test_invalid_camera(K: np.ndarray, T: np.ndarray, w: object, h: object, field: str) -> None:
    with pytest.raises(CameraFormatError, match=field):
        Camera(K, T, w, h, name="cam7")  # type: ignore[arg-type]


def test_slightly_non_orthonormal_rotation_is_repaired() -> None:
    rng = np.random.default_rng(3)
    R = random_rotation(rng)
    noisy = R + 1e-4 * rng.normal(size=(3, 3))
    assert 1e-4 < np.abs(noisy.T @ noisy - np.eye(3)).max() < 1e-3  # the repair regime
    T = pose(noisy, [1.0, 2.0, 3.0])
    cam = Camera(K0, T, 640, 480)
    Rr = cam.T_world_cam[:3, :3]
    np.testing.assert_allclose(Rr.T @ Rr, np.eye(3), atol=1e-12)
    assert np.linalg.det(Rr) == pytest.approx(1.0)
    np.testing.assert_allclose(Rr, R, atol=3e-3)
    np.testing.assert_allclose(cam.viewmat @ cam.T_world_cam, np.eye(4), atol=1e-12)


def test_json_round_trip_and_layout(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    cam = Camera(K0, pose(random_rotation(rng), rng.normal(size=3)), 640, 480)
    save_camera_json(tmp_path / "cam.json", cam)
    raw = json.loads((tmp_path / "cam.json").read_text())
    assert set(raw) == {"width", "height", "K", "T_world_cam"}
    assert np.array(raw["K"]).shape == (3, 3) and np.array(raw["T_world_cam"]).shape == (4, 4)
    back = load_camera_json(tmp_path / "cam.json")
    np.testing.assert_array_equal(back.K, cam.K)
    np.testing.assert_array_equal(back.T_world_cam, cam.T_world_cam)
    assert (back.width, back.height) == (640, 480)
    assert [p.name for p in tmp_path.iterdir()] == ["cam.json"]
    named = Camera(K0, np.eye(4), 64, 48, name="head", distortion={"k1": 0.1})
    again = Camera.from_json(json.loads(json.dumps(named.to_json())))
    assert again.name == "head" and again.distortion == {"k1": 0.1}


def test_camera_json_errors_name_file_and_field(tmp_path: Path) -> None:
    p = tmp_path / "cam.json"
    p.write_text(json.dumps({"width": 640, "height": 480, "K": K0.tolist()}))
    with pytest.raises(CameraFormatError, match="T_world_cam") as info:
        load_camera_json(p)
    assert str(p) in str(info.value)
    p.write_text(json.dumps({"width": 640, "height": 480, "K": [[1, 2], [3, 4]], "T_world_cam": np.eye(4).tolist()}))
    with pytest.raises(CameraFormatError, match="K must have shape"):
        load_camera_json(p)
    p.write_text("{not json")
    with pytest.raises(CameraFormatError, match="not valid JSON"):
        load_camera_json(p)
    with pytest.raises(FileNotFoundError, match="absent.json"):
        load_camera_json(tmp_path / "absent.json")


def test_look_at() -> None:
    cam = look_at(eye=[2.0, -3.0, 1.5], target=[0.0, 0.0, 0.5], up=[0, 0, 1], K=K0, width=640, height=480)
    uv, z = cam.project(np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 0.9]]))
    assert z[0] == pytest.approx(math.dist([2.0, -3.0, 1.5], [0.0, 0.0, 0.5]))
    np.testing.assert_allclose(uv[0], [320, 240], atol=1e-9)
    assert uv[1, 1] < uv[0, 1]  # world up is image up (smaller v: OpenCV y points down)
    assert abs(uv[1, 0] - 320) < 1e-9
    assert np.linalg.det(cam.T_world_cam[:3, :3]) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="parallel"):
        look_at([0, 0, 5], [0, 0, 0], [0, 0, 1], K0, 640, 480)


# ---- transforms.json ----------------------------------------------------------------------------
def test_opengl_pose_converted_to_opencv(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    R_gl, c = random_rotation(rng), rng.normal(size=3)
    # In OpenGL camera axes the camera looks down -z and y is up: this point is 3 m in front,
    # 0.4 m right and 0.25 m up.
    p = c + R_gl @ np.array([0.4, 0.25, -3.0])
    path = write_transforms(
        tmp_path / "transforms.json",
        [{"file_path": "images/a.png", "transform_matrix": pose(R_gl, c).tolist()}],
        fl_x=600.0, fl_y=610.0, cx=330.0, cy=250.0, w=640, h=480,
    )  # fmt: skip
    (cam,) = load_transforms_json(path)
    uv, z = cam.project(p[None])
    assert z[0] == pytest.approx(3.0)  # in front of the camera
    np.testing.assert_allclose(uv[0], [330 + 600 * 0.4 / 3, 250 - 610 * 0.25 / 3])  # right of and above centre
    np.testing.assert_allclose(cam.viewmat @ cam.T_world_cam, np.eye(4), atol=1e-12)
    assert cam.name == "images/a.png" and (cam.width, cam.height) == (640, 480)


def test_intrinsics_from_angles_and_per_frame_override(tmp_path: Path) -> None:
    eye = np.eye(4).tolist()
    path = write_transforms(
        tmp_path / "transforms.json",
        [
            {"file_path": "a.png", "transform_matrix": eye},
            {"file_path": "b.png", "transform_matrix": eye, "camera_angle_y": 0.6},
            {"file_path": "c.png", "transform_matrix": eye, "fl_x": 900.0, "w": 1280, "h": 960, "k1": 0.2},
        ],
        camera_angle_x=0.8, w=800, h=600, k1=-0.1, p2=0.01,
    )  # fmt: skip
    a, b, c = load_transforms_json(path)
    f = 0.5 * 800 / math.tan(0.4)
    np.testing.assert_allclose(a.K, [[f, 0, 400], [0, f, 300], [0, 0, 1]])
    assert b.fy == pytest.approx(0.5 * 600 / math.tan(0.3)) and b.fx == pytest.approx(f)
    assert (c.fx, c.fy, c.cx, c.cy, c.width, c.height) == (900.0, 900.0, 640.0, 480.0, 1280, 960)
    assert a.distortion == {"k1": -0.1, "p2": 0.01} and c.distortion == {"k1": 0.2, "p2": 0.01}


def test_nerfstudio_fisheye_and_unknown_camera_models(tmp_path: Path) -> None:
    eye = np.eye(4).tolist()
    frames = [{"file_path": "a.png", "transform_matrix": eye}]
    path = write_transforms(tmp_path / "transforms.json", frames, camera_model="OPENCV_FISHEYE", fl_x=300.0,
                            w=640, h=480, k1=0.05, k2=-0.01, k3=0.002, k4=-0.0004)  # fmt: skip
    (cam,) = load_transforms_json(path)
    assert cam.distortion_model == "fisheye" and cam.distortion == {"k1": 0.05, "k2": -0.01, "k3": 0.002, "k4": -0.0004}
    path = write_transforms(tmp_path / "t2.json", frames, camera_model="EQUIRECTANGULAR", fl_x=300.0, w=640, h=480)
    with pytest.raises(CameraFormatError, match="EQUIRECTANGULAR.*undistort"):
        load_transforms_json(path)


def test_missing_size_read_from_image(tmp_path: Path) -> None:
    from PIL import Image

    (tmp_path / "train").mkdir()
    Image.new("RGB", (40, 30)).save(tmp_path / "train" / "r_0.png")
    path = write_transforms(
        tmp_path / "transforms.json",
        [{"file_path": "./train/r_0", "transform_matrix": np.eye(4).tolist()}],
        camera_angle_x=0.69,
    )
    cam = camera_from_transforms_frame(path, "r_0.png")
    assert (cam.width, cam.height) == (40, 30) and cam.cx == 20.0


def test_transforms_validation_names_file_and_field(tmp_path: Path) -> None:
    bent = np.eye(4)
    bent[0, 1] = 0.05  # far beyond re-orthonormalisation
    nearly = pose(np.eye(3) + 2e-4 * np.random.default_rng(6).normal(size=(3, 3)), [0, 0, 1])
    assert 1e-4 < np.abs(nearly[:3, :3].T @ nearly[:3, :3] - np.eye(3)).max() < 1e-3
    path = write_transforms(
        tmp_path / "transforms.json",
        [
            {"file_path": "ok.png", "transform_matrix": nearly.tolist()},
            {"file_path": "bent.png", "transform_matrix": bent.tolist()},
        ],
        fl_x=100.0, w=64, h=48,
    )  # fmt: skip
    ok = camera_from_transforms_frame(path, "ok")
    np.testing.assert_allclose(ok.viewmat @ ok.T_world_cam, np.eye(4), atol=1e-12)
    with pytest.raises(CameraFormatError, match=r"frames\[1\] \('bent.png'\): transform_matrix: rotation is not") as e:
        load_transforms_json(path)
    assert str(path) in str(e.value)

    path = write_transforms(
        tmp_path / "t2.json", [{"file_path": "a", "transform_matrix": np.eye(4).tolist()}], w=64, h=48
    )
    with pytest.raises(CameraFormatError, match="no focal length"):
        load_transforms_json(path)
    path = write_transforms(tmp_path / "t3.json", [{"file_path": "a", "transform_matrix": np.eye(4).tolist()}], fl_x=-5)
    with pytest.raises(CameraFormatError, match="w / h missing"):
        load_transforms_json(path)
    path = write_transforms(tmp_path / "t4.json", [{"file_path": "a"}], fl_x=5.0, w=4, h=4)
    with pytest.raises(CameraFormatError, match="transform_matrix: missing"):
        load_transforms_json(path)
    path = write_transforms(tmp_path / "t5.json", [{"file_path": "a", "transform_matrix": np.eye(4).tolist()}],
                            fl_x=-5.0, w=4, h=4)  # fmt: skip
    with pytest.raises(CameraFormatError, match=r"t5.json: frames\[0\] \('a'\): K: focal lengths must be positive"):
        load_transforms_json(path)
    (tmp_path / "t6.json").write_text(json.dumps({"fl_x": 5}))
    with pytest.raises(CameraFormatError, match="t6.json: frames: missing"):
        load_transforms_json(tmp_path / "t6.json")


def test_frame_lookup_ambiguous_and_missing(tmp_path: Path) -> None:
    eye = np.eye(4).tolist()
    path = write_transforms(
        tmp_path / "transforms.json",
        [{"file_path": f"{d}/0001.jpg", "transform_matrix": eye} for d in ("left", "right")],
        fl_x=100.0, w=64, h=48,
    )  # fmt: skip
    assert camera_from_transforms_frame(path, "right/0001.jpg").name == "right/0001.jpg"
    assert camera_from_transforms_frame(path, "./left/0001.jpg").name == "left/0001.jpg"
    with pytest.raises(CameraFormatError, match="ambiguous"):
        camera_from_transforms_frame(path, "0001")


# ---- real data: the fox capture -----------------------------------------------------------------
needs_fox = pytest.mark.skipif(
    not (FOX / "transforms.json").is_file(), reason=f"fox sample data not found at {FOX} (see shared/data)"
)


@needs_fox
def test_fox_cameras() -> None:
    path = FOX / "transforms.json"
    cams = load_transforms_json(path)
    raw = json.loads(path.read_text())
    assert len(cams) == len(raw["frames"]) == 54
    assert all((c.width, c.height) == (1080, 1920) for c in cams)
    first = cams[0]
    assert first.name == "images/0001.jpg"
    assert (first.fx, first.fy, first.cx, first.cy) == (1375.52, 1374.49, 554.558, 965.268)
    assert first.distortion == {"k1": 0.0578421, "k2": -0.0805099, "p1": -0.000980296, "p2": 0.00015575}
    T_gl = np.array(raw["frames"][0]["transform_matrix"])
    np.testing.assert_allclose(first.T_world_cam, T_gl @ np.diag([1.0, -1.0, -1.0, 1.0]), atol=1e-5)
    for c in cams:
        np.testing.assert_allclose(c.viewmat @ c.T_world_cam, np.eye(4), atol=1e-12)

    # The cameras circle the figurine: the point closest to all optical axes (+z in OpenCV) must
    # lie in front of every camera and inside every image. With the OpenGL axes left unconverted
    # it would be behind them all.
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in cams:
        d = c.T_world_cam[:3, 2]
        P = np.eye(3) - np.outer(d, d)
        A, b = A + P, b + P @ c.center
    focus = np.linalg.solve(A, b)
    for c in cams:
        uv, z = c.project(focus[None])
        assert z[0] > 1.0, c.name
        assert 0 < uv[0, 0] < c.width and 0 < uv[0, 1] < c.height, c.name


@needs_fox
def test_fox_frame_lookup() -> None:
    path = FOX / "transforms.json"
    by_path = camera_from_transforms_frame(path, "images/0005.jpg")
    for query in ("0005.jpg", "0005", "./images/0005.jpg"):
        cam = camera_from_transforms_frame(path, query)
        assert cam.name == "images/0005.jpg"
        np.testing.assert_array_equal(cam.T_world_cam, by_path.T_world_cam)
    assert not np.allclose(by_path.T_world_cam, camera_from_transforms_frame(path, "0001").T_world_cam)
    with pytest.raises(CameraFormatError, match=r"no frame named '0003' among 54 frames .*images/0001.jpg") as e:
        camera_from_transforms_frame(path, "0003")  # deliberately absent from the sample
    assert str(path) in str(e.value)
