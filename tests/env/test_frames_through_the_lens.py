"""The world's cameras as calibrated (env.lens): a frame is the camera's own image, lens and principal point
included, cropped about its centre and scaled; checked against OpenCV's projection and its undistortion."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from mirage2matter.env import EnvError
from mirage2matter.env.hybrid import render_K
from mirage2matter.env.lens import frame_camera, lens_plan
from mirage2matter.world import load_world
from mirage2matter.world.config import CameraConfig

# a wide-angle camera as a calibration reports it: barrel distortion, principal point off the centre, fx != fy
K_WIDE = np.array([[430.0, 0.0, 331.0], [0.0, 432.0, 229.0], [0.0, 0.0, 1.0]])
LENS = {"k1": -0.28, "k2": 0.08, "p1": 0.0007, "p2": -0.0005, "k3": 0.0}
SIZE = 96


def _cv_dist() -> np.ndarray:
    return np.array([LENS[k] for k in ("k1", "k2", "p1", "p2", "k3")])


def _cv_K(K: np.ndarray) -> np.ndarray:
    """Our K (pixel centres at +0.5) as OpenCV's (centres at integers)."""
    return K - np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])


def test_a_frame_is_the_camera_s_image_cropped_about_its_centre_and_scaled():
    cam = CameraConfig("base", np.eye(4), K_WIDE, 640, 480, LENS)
    frame = frame_camera(cam, 224, 224)
    # points seen by the whole camera (OpenCV's projection, lens included), then cropped and scaled by hand
    rng = np.random.default_rng(0)
    p = np.c_[rng.uniform(-0.4, 0.4, (50, 2)), np.ones(50)]
    uv = cv2.projectPoints(p, np.zeros(3), np.zeros(3), _cv_K(K_WIDE), _cv_dist())[0].reshape(-1, 2) + 0.5
    s = 224 / 480
    expected = np.c_[(uv[:, 0] - 0.5 * (640 - 224 / s)) * s, uv[:, 1] * s]
    got = cv2.projectPoints(p, np.zeros(3), np.zeros(3), _cv_K(frame.K), _cv_dist())[0].reshape(-1, 2) + 0.5
    np.testing.assert_allclose(got, expected, atol=1e-9)
    # a centred pinhole's frame is the pinhole the renderers draw directly
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    np.testing.assert_allclose(frame_camera(CameraConfig("base", np.eye(4), K, 640, 480), 224, 224).K,
                               render_K(K, 640, 480, 224, 224))  # fmt: skip


def test_zero_coefficients_are_a_pinhole_and_a_bad_lens_is_named(tmp_path):
    from mirage2matter.world.config import WorldConfigError, _lens

    assert CameraConfig("base", np.eye(4), K_WIDE, 640, 480, {"k1": 0.0, "k2": 0.0}).distortion == {}
    assert CameraConfig("base", np.eye(4), K_WIDE, 640, 480, LENS).distortion == LENS
    with pytest.raises(WorldConfigError, match=r"cameras.head.distortion: .*'q9'"):
        _lens({"q9": 0.1}, "cameras.head.distortion")


@pytest.fixture(scope="module")
def world(sample_world_ws):
    return load_world(sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0) / "world")


def test_a_world_of_centred_pinholes_has_no_plan_and_a_fisheye_too_wide_is_refused(world):
    from mirage2matter.env.twin_env import make_config

    assert lens_plan(make_config(world, "grasp banana", size=SIZE)) is None
    wide = world.copy()
    head = wide.cameras["head"]
    wide.cameras["head"] = replace(head, distortion={"model": "fisheye", "k1": 0.0, "k2": 0.0, "k3": 0.0, "k4": 0.0},
                                   K=np.diag([0.3 * head.K[0, 0], 0.3 * head.K[1, 1], 1.0]) @ head.K)  # fmt: skip
    with pytest.raises(EnvError, match="camera 'head': its lens .* sees too wide"):
        lens_plan(make_config(wide, "grasp banana", size=SIZE))


@pytest.mark.parametrize("renderer", ["hybrid", pytest.param("ground_truth", marks=pytest.mark.slow)])
def test_frames_through_the_lens_are_the_wide_pinhole_read_where_opencv_puts_each_ray(world, tmp_path, renderer,
                                                                                     sample_dir):  # fmt: skip
    """The head camera made a calibrated wide-angle one (K_WIDE, LENS): its frames against an independent
    reference, a centred pinhole frame of the same focal length rendered directly, twice as wide, read where OpenCV's
    undistortion puts each frame pixel's ray. The frames the renderers drew before (the centred pinhole of the same
    vertical field of view) are far from it. Both renderers: the hybrid one and the sample's ground truth."""
    from mirage2matter.env.config import Randomization
    from mirage2matter.env.twin_env import TwinEnv
    from mirage2matter.world.config import save_world

    calibrated = world.copy()
    head = calibrated.cameras["head"]
    calibrated.cameras["head"] = replace(head, K=K_WIDE, width=640, height=480, distortion=LENS)
    save_world(calibrated, tmp_path / "world.yaml")  # and read back: the lens survives world.yaml
    calibrated = load_world(tmp_path)
    assert calibrated.cameras["head"].distortion == LENS
    f = K_WIDE[1, 1] * SIZE / 480
    wide_size = 2 * SIZE
    reference_world = world.copy()
    reference_world.cameras["head"] = replace(head, K=np.array([[f, 0, SIZE], [0, f, SIZE], [0, 0, 1.0]]),
                                              width=wide_size, height=wide_size)  # fmt: skip
    still = Randomization(camera_deg=0.0, camera_m=0.0)

    def first_frame(w, size):
        truth = sample_dir if renderer == "ground_truth" else None
        env = TwinEnv(w, "grasp banana", size=size, cameras=("head",), randomization=still, renderer=renderer,
                      ground_truth=truth)  # fmt: skip
        try:
            return env.reset(seed=3)[0]["observation.images.head"]
        finally:
            env.close()

    frame = first_frame(calibrated, SIZE)
    wide = first_frame(reference_world, wide_size).astype(np.float64)
    K_frame = frame_camera(calibrated.cameras["head"], SIZE, SIZE).K
    u, v = np.meshgrid(np.arange(SIZE, dtype=np.float64), np.arange(SIZE, dtype=np.float64))
    xy = cv2.undistortPoints(np.c_[u.ravel(), v.ravel()][:, None], _cv_K(K_frame), _cv_dist()).reshape(-1, 2)
    rows, cols = f * xy[:, 1] + SIZE - 0.5, f * xy[:, 0] + SIZE - 0.5
    reference = np.stack([map_coordinates(wide[..., i], [rows, cols], order=1) for i in range(3)], -1)
    reference = reference.reshape(SIZE, SIZE, 3)
    inner = np.s_[2:-2, 2:-2]

    def psnr(a):
        return 10 * np.log10(255.0**2 / np.mean((a[inner].astype(np.float64) - reference[inner]) ** 2))

    pinhole = world.copy()  # what the renderers drew for this camera before: the centred pinhole of its height
    pinhole.cameras["head"] = replace(head, K=np.array([[432.0, 0, 320], [0, 432.0, 240], [0, 0, 1]]), width=640,
                                      height=480)  # fmt: skip
    before = first_frame(pinhole, SIZE)
    print(f"\nlens frame vs reference {psnr(frame):.1f} dB; centred pinhole vs reference {psnr(before):.1f} dB")
    assert frame.shape == (SIZE, SIZE, 3) and frame.dtype == np.uint8
    assert psnr(frame) > 35.0
    assert psnr(before) < psnr(frame) - 10.0


def test_a_second_renderer_of_the_same_twin_draws_through_the_same_plan(world):
    """bench policy-gap draws the truth beside the env's hybrid frames: through the same lens when the env has one."""
    from mirage2matter.env.lens import LensFrames
    from mirage2matter.env.twin_env import make_config

    calibrated = world.copy()
    calibrated.cameras["head"] = replace(calibrated.cameras["head"], K=K_WIDE, width=640, height=480, distortion=LENS)
    plan = lens_plan(make_config(calibrated, "grasp banana", size=SIZE, cameras=("head",)))
    W, H = plan.render_size
    assert W > SIZE and H > SIZE and (W - SIZE) % 2 == 0 and (H - SIZE) % 2 == 0

    class Flat:  # a renderer drawing one grey level per column of whatever size it was made for
        def __init__(self, size):
            self.size, self.timings = size, {}

        def render(self):
            w, h = self.size
            return {"head": np.broadcast_to(np.arange(w, dtype=np.uint8)[None, :, None], (h, w, 3)).copy()}

    made = LensFrames.like(LensFrames(Flat(plan.render_size), plan), (SIZE, SIZE), Flat)
    assert isinstance(made, LensFrames) and made.inner.size == (W, H)
    frame = made.render()["head"]
    assert frame.shape == (SIZE, SIZE, 3)
    # read from the wide render: the barrel lens's left edge sees further out than the pinhole crop's first column
    assert frame[SIZE // 2, 0, 0] < (W - SIZE) // 2
    assert LensFrames.like(Flat((SIZE, SIZE)), (SIZE, SIZE), Flat).size == (SIZE, SIZE)  # no lens: the frame size
