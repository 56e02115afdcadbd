"""COLMAP camera models <-> our lens models: imported reconstructions and the intrinsics we hand COLMAP."""

from __future__ import annotations

import dataclasses

import numpy as np
import pycolmap
import pytest

from mirage2matter.geometry.camera import Camera
from mirage2matter.sfm.colmap import SfMError, _camera_from_colmap
from mirage2matter.sfm.known_poses import colmap_camera_params

K = np.array([[402.0, 0.0, 319.7], [0.0, 401.0, 242.2], [0.0, 0.0, 1.0]])


class _Image:  # what _camera_from_colmap reads of a pycolmap.Image
    name = "0001.png"

    def __init__(self, cam_from_world: pycolmap.Rigid3d) -> None:
        self._pose = cam_from_world

    def cam_from_world(self) -> pycolmap.Rigid3d:
        return self._pose


@pytest.mark.parametrize(
    ("model", "params", "ours"),
    [
        ("SIMPLE_RADIAL", [402.0, 319.7, 242.2, -0.08], "opencv"),
        ("RADIAL", [402.0, 319.7, 242.2, -0.08, 0.01], "opencv"),
        ("OPENCV", [402.0, 401.0, 319.7, 242.2, -0.08, 0.01, 0.001, -0.002], "opencv"),
        ("FULL_OPENCV", [402.0, 401.0, 319.7, 242.2, 0.3, -0.1, 0.001, -0.002, 0.02, 0.25, -0.05, 0.01], "opencv"),
        ("OPENCV_FISHEYE", [402.0, 401.0, 319.7, 242.2, 0.05, -0.02, 0.004, -0.001], "fisheye"),
        ("RADIAL_FISHEYE", [402.0, 319.7, 242.2, 0.05, -0.02], "fisheye"),
        ("SIMPLE_RADIAL_FISHEYE", [402.0, 319.7, 242.2, 0.05], "fisheye"),
        ("FISHEYE", [402.0, 401.0, 319.7, 242.2], "fisheye"),
    ],
)
def test_imported_cameras_project_as_colmap_does(model, params, ours):
    cam_c = pycolmap.Camera(model=model, width=640, height=480, params=params)
    R = pycolmap.Rotation3d(np.array([0.05, -0.1, 0.02, 1.0]) / np.linalg.norm([0.05, -0.1, 0.02, 1.0]))
    pose = pycolmap.Rigid3d(R, np.array([0.1, -0.2, 0.5]))
    cam = _camera_from_colmap(_Image(pose), cam_c)
    assert cam.distortion_model == ours
    pts = np.random.default_rng(1).uniform([-1.0, -0.8, 1.5], [1.0, 0.8, 3.0], (40, 3))  # world points in view
    p_cam = pts @ pose.matrix()[:, :3].T + pose.matrix()[:, 3]
    uv, z = cam.project(pts, distort=True)
    assert (z > 0).all()
    assert np.abs(uv - cam_c.img_from_cam(p_cam)).max() < 1e-6, model  # COLMAP's own projection, +0.5 both
    # and handing the camera back to COLMAP keeps it: the model we give projects the same
    back_model, back_params = colmap_camera_params(cam)
    back = pycolmap.Camera(model=back_model, width=640, height=480, params=back_params)
    assert np.abs(back.img_from_cam(p_cam) - uv).max() < 1e-6, (model, back_model)


def test_models_we_cannot_take_are_named():
    cam_c = pycolmap.Camera(model="FOV", width=640, height=480, params=[402.0, 401.0, 319.7, 242.2, 0.9])
    with pytest.raises(SfMError, match="FOV is not supported.*undistort"):
        _camera_from_colmap(_Image(pycolmap.Rigid3d()), cam_c)


def test_known_intrinsics_pick_the_colmap_model():
    base = Camera(K, np.eye(4), 640, 480, "c")
    assert colmap_camera_params(base) == ("PINHOLE", [402.0, 401.0, 319.7, 242.2])
    assert colmap_camera_params(dataclasses.replace(base, distortion={"k1": 0.1, "p2": 0.01}))[0] == "OPENCV"
    assert colmap_camera_params(dataclasses.replace(base, distortion={"k1": 0.1, "k3": 0.01}))[0] == "FULL_OPENCV"
    fish = dataclasses.replace(base, distortion={"k1": 0.05, "k4": -0.001}, distortion_model="fisheye")
    assert colmap_camera_params(fish) == ("OPENCV_FISHEYE", [402.0, 401.0, 319.7, 242.2, 0.05, 0.0, 0.0, -0.001])
    with pytest.raises(SfMError, match="k4 but no k5"):  # k1..k4 without the model: a fisheye? not guessed
        colmap_camera_params(dataclasses.replace(base, distortion={"k1": 0.05, "k4": -0.001}))
