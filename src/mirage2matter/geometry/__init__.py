"""Geometry: similarity transforms, rotations, Umeyama, cameras. Imports nothing else of ours."""

from .camera import Camera, CameraFormatError, camera_from_transforms_frame, load_camera_json, load_transforms_json
from .sim3 import Sim3
from .umeyama import umeyama

__all__ = [
    "Camera",
    "CameraFormatError",
    "Sim3",
    "camera_from_transforms_frame",
    "load_camera_json",
    "load_transforms_json",
    "umeyama",
]
