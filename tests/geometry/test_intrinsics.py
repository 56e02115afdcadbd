"""One intrinsics reader for the files calibration tools write, and the lens model every stage uses."""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest

from mirage2matter.geometry.camera import Camera, CameraFormatError, load_intrinsics

# a RealSense-like colour camera, in OpenCV's convention (pixel centres at integers)
K_CV = np.array([[912.0, 0.0, 645.8], [0.0, 911.0, 362.3], [0.0, 0.0, 1.0]])
D = np.array([0.11, -0.24, 0.0012, -0.0009, 0.12])
OURS_CX, OURS_CY = 646.3, 362.8


def _write_all(tmp_path):
    files = {}
    for suffix, shape in ((".yaml", (1, 5)), (".xml", (5, 1))):  # OpenCV's calibration output, as cv2 writes it
        path = tmp_path / f"opencv{suffix}"
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", 1280)
        fs.write("image_height", 720)
        fs.write("camera_matrix", K_CV)
        fs.write("distortion_coefficients", D.reshape(shape))
        fs.release()
        files[f"opencv{suffix}"] = path
    files["ost.yaml"] = tmp_path / "ost.yaml"  # ROS camera_calibration
    files["ost.yaml"].write_text(
        "image_width: 1280\nimage_height: 720\ncamera_name: wrist\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
        f"  data: {K_CV.ravel().tolist()}\ndistortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n"
        f"  cols: 5\n  data: {D.tolist()}\n"
    )
    files["camera_info.json"] = tmp_path / "camera_info.json"  # the ROS message
    files["camera_info.json"].write_text(json.dumps({"width": 1280, "height": 720, "k": K_CV.ravel().tolist(),
                                                     "d": D.tolist(), "distortion_model": "plumb_bob"}))  # fmt: skip
    files["realsense.json"] = tmp_path / "realsense.json"
    files["realsense.json"].write_text(json.dumps({"width": 1280, "height": 720, "fx": 912.0, "fy": 911.0,
                                                   "ppx": 645.8, "ppy": 362.3, "model": "Brown Conrady",
                                                   "coeffs": D.tolist()}))  # fmt: skip
    files["cameras.txt"] = tmp_path / "cameras.txt"  # COLMAP: centres at +0.5 already
    files["cameras.txt"].write_text(f"# Camera list\n1 FULL_OPENCV 1280 720 912 911 {OURS_CX} {OURS_CY} "
                                    f"{D[0]} {D[1]} {D[2]} {D[3]} {D[4]} 0 0 0\n")  # fmt: skip
    files["ours.json"] = tmp_path / "ours.json"
    ours = Camera(np.array([[912.0, 0, OURS_CX], [0, 911.0, OURS_CY], [0, 0, 1]]), np.eye(4), 1280, 720, "",
                  dict(zip(("k1", "k2", "p1", "p2", "k3"), D.tolist(), strict=True)))  # fmt: skip
    files["ours.json"].write_text(json.dumps(ours.to_json()))
    return files


def test_every_format_reads_as_the_same_camera(tmp_path):
    for name, path in _write_all(tmp_path).items():
        cam = load_intrinsics(path)
        assert (cam.width, cam.height) == (1280, 720), name
        # the pixel-centre convention converted once: OpenCV's cx 645.8 is our 646.3
        assert np.allclose(cam.K, [[912.0, 0, OURS_CX], [0, 911.0, OURS_CY], [0, 0, 1]]), (name, cam.K)
        assert np.allclose(cam.opencv_distortion(), D), (name, cam.distortion)


def test_the_lens_model_agrees_with_opencv_and_inverts():
    cam = Camera(np.array([[912.0, 0, OURS_CX], [0, 911.0, OURS_CY], [0, 0, 1]]), np.eye(4), 1280, 720, "",
                 dict(zip(("k1", "k2", "p1", "p2", "k3"), D.tolist(), strict=True)))  # fmt: skip
    u, v = np.meshgrid(np.linspace(0, 1280, 17), np.linspace(0, 720, 11))  # to the image's very corners
    measured = np.c_[u.ravel(), v.ravel()]
    ideal = cam.undistort_pixels(measured)
    assert np.abs(cam.distort_pixels(ideal) - measured).max() < 1e-4
    # distort_pixels is OpenCV's projection of the same rays, shifted to our convention once
    rays = np.c_[(ideal[:, 0] - OURS_CX) / 912.0, (ideal[:, 1] - OURS_CY) / 911.0, np.ones(len(ideal))]
    cv_uv, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K_CV, D)
    assert np.abs(cv_uv.reshape(-1, 2) + 0.5 - measured).max() < 1e-4
    # a point on the optical axis lands on the principal point, in our convention
    assert np.allclose(cam.distort_pixels(np.array([[OURS_CX, OURS_CY]])), [[OURS_CX, OURS_CY]])


# a fisheye (equidistant) camera, OpenCV's convention, and its cv2.fisheye coefficients
KF_CV = np.array([[402.0, 0.0, 319.2], [0.0, 401.0, 241.7], [0.0, 0.0, 1.0]])
DF = np.array([0.052, -0.013, 0.0041, -0.0007])
KF_OURS = KF_CV + [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]]


def _write_fisheye(tmp_path):
    files = {}
    path = files["opencv_fisheye.yaml"] = tmp_path / "opencv_fisheye.yaml"  # OpenCV's calibration sample, fisheye
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in (("image_width", 640), ("image_height", 480), ("camera_matrix", KF_CV),
                       ("distortion_coefficients", DF.reshape(4, 1)), ("fisheye_model", 1)):  # fmt: skip
        fs.write(key, value)
    fs.release()
    files["ost.yaml"] = tmp_path / "ost.yaml"
    files["ost.yaml"].write_text(
        "image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
        f"  data: {KF_CV.ravel().tolist()}\ndistortion_model: equidistant\ndistortion_coefficients:\n  rows: 1\n"
        f"  cols: 4\n  data: {DF.tolist()}\n"
    )
    files["realsense.json"] = tmp_path / "realsense.json"
    files["realsense.json"].write_text(json.dumps({"width": 640, "height": 480, "fx": 402.0, "fy": 401.0,
                                                   "ppx": 319.2, "ppy": 241.7, "model": "Kannala Brandt4",
                                                   "coeffs": [*DF.tolist(), 0.0]}))  # fmt: skip
    files["cameras.txt"] = tmp_path / "cameras.txt"  # two cameras: the one of the asked size is used
    files["cameras.txt"].write_text(f"1 PINHOLE 320 240 200 200 160 120\n2 OPENCV_FISHEYE 640 480 402 401 319.7 242.2 "
                                    f"{' '.join(map(str, DF))}\n")  # fmt: skip
    files["ours.json"] = tmp_path / "ours.json"
    ours = Camera(KF_OURS, np.eye(4), 640, 480, "", dict(zip(("k1", "k2", "k3", "k4"), DF.tolist(), strict=True)),
                  "fisheye")  # fmt: skip
    files["ours.json"].write_text(json.dumps(ours.to_json()))
    return files


def test_every_format_reads_the_same_fisheye(tmp_path):
    for name, path in _write_fisheye(tmp_path).items():
        cam = load_intrinsics(path, size=(640, 480))
        assert (cam.width, cam.height, cam.distortion_model) == (640, 480, "fisheye"), name
        assert np.allclose(cam.K, KF_OURS), (name, cam.K)
        assert np.allclose(cam.fisheye_distortion(), DF), (name, cam.distortion)
        again = tmp_path / "again.json"  # our JSON keeps the model
        again.write_text(json.dumps(cam.to_json()))
        assert load_intrinsics(again).distortion_model == "fisheye"
    with pytest.raises(CameraFormatError, match="2 cameras"):
        load_intrinsics(tmp_path / "cameras.txt")  # several and no size: which one is not guessed


def _grid(w, h):
    u, v = np.meshgrid(np.linspace(0, w, 33), np.linspace(0, h, 25))  # to the image's very corners
    return np.c_[u.ravel(), v.ravel()]


def test_fisheye_agrees_with_cv2_fisheye_and_inverts():
    cam = Camera(KF_OURS, np.eye(4), 640, 480, "", dict(zip(("k1", "k2", "k3", "k4"), DF.tolist(), strict=True)),
                 "fisheye")  # fmt: skip
    measured = _grid(640, 480)
    ideal = cam.undistort_pixels(measured)
    assert np.isfinite(ideal).all()
    assert np.abs(cam.distort_pixels(ideal) - measured).max() < 1e-4
    rays = np.c_[(ideal[:, 0] - KF_OURS[0, 2]) / 402.0, (ideal[:, 1] - KF_OURS[1, 2]) / 401.0, np.ones(len(ideal))]
    cv_uv, _ = cv2.fisheye.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), KF_CV, DF)
    assert np.abs(cv_uv.reshape(-1, 2) + 0.5 - measured).max() < 1e-4
    # and cv2.fisheye's own undistortion lands where ours does (it iterates less: 1e-2 px)
    cv_ideal = cv2.fisheye.undistortPoints((measured - 0.5).reshape(-1, 1, 2), KF_CV, DF, P=KF_CV).reshape(-1, 2)
    assert np.abs(cv_ideal + 0.5 - ideal).max() < 1e-2
    # a point on the optical axis lands on the principal point, in our convention; project(distort=True) = cv2
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.05, 0.2]
    posed = dataclasses.replace(cam, T_world_cam=T)
    assert np.allclose(posed.project(np.array([[0.1, -0.05, 1.7]]), distort=True)[0], KF_OURS[:2, 2])
    pts = np.random.default_rng(0).uniform([-1.0, -0.8, 1.2], [1.2, 0.8, 2.5], (50, 3))
    uv, z = posed.project(pts, distort=True)
    cv_uv, _ = cv2.fisheye.projectPoints((pts - T[:3, 3]).reshape(-1, 1, 3), np.zeros(3), np.zeros(3), KF_CV, DF)
    assert (z > 0).all() and np.abs(uv - cv_uv.reshape(-1, 2) - 0.5).max() < 1e-6


def test_rational_model_agrees_with_opencv():
    d8 = np.array([0.3, -0.1, 0.001, -0.002, 0.02, 0.25, -0.05, 0.01])
    cam = Camera(KF_OURS, np.eye(4), 640, 480, "", dict(zip(("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), d8,
                                                            strict=True)))  # fmt: skip
    measured = _grid(640, 480)
    ideal = cam.undistort_pixels(measured)
    assert np.abs(cam.distort_pixels(ideal) - measured).max() < 1e-4
    pts = np.c_[(ideal - KF_OURS[:2, 2]) / [402.0, 401.0], np.ones(len(ideal))]
    uv, _ = cam.project(pts, distort=True)
    cv_uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), KF_CV, d8)
    assert np.abs(uv - cv_uv.reshape(-1, 2) - 0.5).max() < 1e-6 and np.abs(uv - measured).max() < 1e-4
    assert np.allclose(cam.project(pts)[0], ideal)  # the default stays the pinhole


def test_realsense_inverse_brown_conrady_is_opencv_where_they_agree(tmp_path):
    # a D455 colour stream's coefficients (librealsense issue 9551): the two formulas differ by 0.02 px
    coeffs = [-0.0565362684428692, 0.068201869726181, 0.0003659751964733, 0.000692575704306364, -0.0218431670218706]
    path = tmp_path / "rs.json"
    path.write_text(json.dumps({"width": 1280, "height": 720, "fx": 640.2, "fy": 639.4, "ppx": 641.3, "ppy": 362.9,
                                "model": "Inverse Brown Conrady", "coeffs": coeffs}))  # fmt: skip
    cam = load_intrinsics(path)
    assert np.allclose(cam.opencv_distortion(), coeffs) and np.allclose(cam.K[:2, 2], [641.8, 363.4])


def test_old_camera_json_reads_unchanged_and_a_lone_k4_must_say_its_model(tmp_path):
    old = {"K": [[400, 0, 320], [0, 400, 240], [0, 0, 1]], "width": 640, "height": 480,
           "T_world_cam": np.eye(4).tolist(), "distortion": {"k1": 0.1, "p1": 0.001}}  # fmt: skip
    cam = Camera.from_json(old)
    assert cam.distortion_model == "opencv" and cam.to_json() == {**old, "K": cam.K.tolist()}
    with pytest.raises(CameraFormatError, match='"fisheye"'):
        Camera.from_json({**old, "distortion": {"k1": 0.1, "k4": 0.01}}).undistort_pixels(np.zeros((1, 2)))
    assert Camera.from_json({**old, "distortion": {"model": "fisheye", "k1": 0.1, "k4": 0.01}}).has_distortion


@pytest.mark.parametrize(
    ("name", "text", "match"),
    [
        ("prism.yaml", "image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [400, 0, 320,"
         " 0, 400, 240, 0, 0, 1]}\ndistortion_model: thin_prism\ndistortion_coefficients: {rows: 1, cols: 4, data: "
         "[0.1, 0.01, 0, 0]}\n", "'thin_prism' is not supported.*undistort"),
        ("fisheye.yaml", "image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [400, 0, 320,"
         " 0, 400, 240, 0, 0, 1]}\ndistortion_model: equidistant\ndistortion_coefficients: {rows: 1, cols: 5, data: "
         "[0.1, 0.01, 0, 0, 0.2]}\n", "fisheye takes 4 coefficients"),
        ("cameras.txt", "1 THIN_PRISM_FISHEYE 640 480 400 400 320 240 0 0 0 0 0 0 0 0\n",
         "THIN_PRISM_FISHEYE is not supported.*undistort"),
        ("cameras.txt", "1 FOV 640 480 400 400 320 240 0.1\n", "FOV is not supported"),
        ("cameras.txt", "1 OPENCV_FISHEYE 640 480 400 400 320 240 0.1\n", "takes 8 parameters, got 5"),
        ("cameras.txt", "1 PINHOLE 640 480 400 400 320 240\n2 PINHOLE 640 480 400 400 320 240\n", "2 cameras"),
        ("rs.json", json.dumps({"width": 640, "height": 480, "fx": 400, "fy": 400, "ppx": 320, "ppy": 240,
                                "model": "Inverse Brown Conrady", "coeffs": [0.1, 0, 0.03, 0.02, 0]}),
         "differ from OpenCV's by up to"),
        ("rs.json", json.dumps({"width": 640, "height": 480, "fx": 400, "fy": 400, "ppx": 320, "ppy": 240,
                                "model": "F-Theta", "coeffs": [0.1, 0, 0, 0, 0]}), "'F-Theta' is not supported"),
        ("ours.json", json.dumps({"K": [[400, 0, 320], [0, 400, 240], [0, 0, 1]], "width": 640, "height": 480,
                                  "distortion": {"k1": 0.1, "k4": 0.2}}), "k4 but no k5"),
        ("ours.json", json.dumps({"K": [[400, 0, 320], [0, 400, 240], [0, 0, 1]], "width": 640, "height": 480,
                                  "distortion": {"model": "fov", "w": 0.2}}), "'fov' is not supported"),
        ("ours.json", json.dumps({"K": [[400, 0, 320], [0, -400, 240], [0, 0, 1]], "width": 640, "height": 480}),
         "K"),
        ("what.json", json.dumps({"focal": 400}), "accepted: our JSON"),
        ("ost.yaml", "image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [400, 0, 320]}\n",
         "must be 9"),
        ("ours.json", json.dumps({"K": [[400, 0, 320], [0, 400, 240], [0, 0, 1]], "width": -1, "height": 480}),
         "width"),
    ],
)
def test_bad_intrinsics_are_named(tmp_path, name, text, match):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(CameraFormatError, match=match) as e:
        load_intrinsics(path)
    assert str(path) in str(e.value) or "width" in str(e.value)


def test_images_of_another_size_are_named():
    cam = Camera(KF_OURS, np.eye(4), 640, 480)
    cam.check_image_size(640, 480, "frame 3")
    with pytest.raises(CameraFormatError, match="frame 3 is 1280x960 but the intrinsics are for 640x480"):
        cam.check_image_size(1280, 960, "frame 3")
