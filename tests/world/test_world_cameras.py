"""The calibrated head camera as the world, the head-view check and train-scene --head-photo all read it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mirage2matter.world.cameras import calibrated_head_camera


def _head() -> dict:
    T = np.eye(4)
    T[:3, 3] = [0.6, 0.1, 0.5]
    return {"mount": "head", "T_base_headcam": T.tolist(), "K": [[500.0, 0, 321.5], [0, 502.0, 239.0], [0, 0, 1]],
            "width": 640, "height": 480, "distortion": {"k1": -0.1, "k2": 0.02, "p1": 0.0, "p2": 0.0, "k3": 0.0}}


def test_the_head_camera_keeps_its_calibration_and_lens():
    he = _head()
    cam, why = calibrated_head_camera(json.loads(json.dumps(he)))
    assert why == "" and (cam.width, cam.height) == (640, 480)
    np.testing.assert_array_equal(cam.K, np.asarray(he["K"]))
    np.testing.assert_array_equal(cam.T_world_cam, np.asarray(he["T_base_headcam"]))
    assert cam.has_distortion and cam.distortion["k1"] == -0.1
    # a calibration with no image size takes a photo's, and says it needs one otherwise
    del he["width"], he["height"]
    assert calibrated_head_camera(he, (800, 600))[0].width == 800
    cam, why = calibrated_head_camera(he)
    assert cam is None and why == "it records no image size"


@pytest.mark.parametrize(("change", "words"), [
    ({"mount": "wrist"}, "its mount is 'wrist', not a head camera"),
    ({"K": None}, "it records no K"),
    ({"T_base_headcam": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "T_base_headcam must be 4x4"),
])  # fmt: skip
def test_a_calibration_that_is_no_head_camera_says_why(change, words):
    he = {k: v for k, v in {**_head(), **change}.items() if v is not None}
    cam, why = calibrated_head_camera(he)
    assert cam is None and words in why
