"""One intrinsics reader for the files calibration tools write, and the lens model every stage uses."""

from __future__ import annotations

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


@pytest.mark.parametrize(
    ("name", "text", "match"),
    [
        ("fisheye.yaml", "image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [400, 0, 320,"
         " 0, 400, 240, 0, 0, 1]}\ndistortion_model: equidistant\ndistortion_coefficients: {rows: 1, cols: 4, data: "
         "[0.1, 0.01, 0, 0]}\n", "equidistant fisheye"),
        ("cameras.txt", "1 OPENCV_FISHEYE 640 480 400 400 320 240 0.1 0 0 0\n", "OPENCV_FISHEYE is not supported"),
        ("cameras.txt", "1 FOV 640 480 400 400 320 240 0.1\n", "FOV is not supported"),
        ("cameras.txt", "1 PINHOLE 640 480 400 400 320 240\n2 PINHOLE 640 480 400 400 320 240\n", "2 cameras"),
        ("rs.json", json.dumps({"width": 640, "height": 480, "fx": 400, "fy": 400, "ppx": 320, "ppy": 240,
                                "model": "Inverse Brown Conrady", "coeffs": [0.1, 0, 0, 0, 0]}), "no OpenCV equal"),
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
