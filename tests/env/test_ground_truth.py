"""The "ground_truth" observation renderer: the sample's own world, rendered as its video was.

One renderer (with the robot) for the module: Genesis builds it in ~25 s warm (~2 min with cold kernel caches).
The slow tests re-encode all 720 video frames (~3 min) and drive the renderer from the physics twin.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import trimesh

from mirage2matter.env.ground_truth import GroundTruthError, GroundTruthRenderer, render_intrinsics
from mirage2matter.errors import EpisodeStalled, M2MError
from mirage2matter.video import read_video_frames, write_video

pytest.importorskip("genesis")

N_PSNR_FRAMES = 8  # spread over the video


# ---- helpers -------------------------------------------------------------------------------------
def _twin_render_K(K: np.ndarray, height: int, out_w: int, out_h: int) -> np.ndarray:
    """The twin's K of a camera rendered at another size (``sim.scene.render_K``, ``Twin.camera``):
    vertical field of view kept, square pixels, principal point centred."""
    f = K[1, 1] * out_h / height
    return np.array([[f, 0.0, out_w / 2], [0.0, f, out_h / 2], [0.0, 0.0, 1.0]])


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)
    return float("inf") if mse == 0 else float(10.0 * np.log10(255.0**2 / mse))


def _luma(rgb: np.ndarray) -> np.ndarray:
    """BT.601 luma (the Y a video codec's PSNR is quoted on)."""
    x = np.asarray(rgb, np.float64)
    return 0.299 * x[..., 0] + 0.587 * x[..., 1] + 0.114 * x[..., 2]


def _half(rgb: np.ndarray) -> np.ndarray:
    """2x2 box average (compression noise averages out; a wrong pose or shading does not)."""
    h, w = rgb.shape[:2]
    return np.asarray(rgb, np.float64).reshape(h // 2, 2, w // 2, 2, -1).mean(axis=(1, 3))


def _rigid(x: float, y: float, z: float, yaw_deg: float) -> np.ndarray:
    a = np.radians(yaw_deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = (x, y, z)
    return T


def _project(K: np.ndarray, T_base_cam: np.ndarray, X: np.ndarray) -> np.ndarray:
    V = np.linalg.inv(T_base_cam)
    Xc = X @ V[:3, :3].T + V[:3, 3]
    uv = Xc @ K.T
    return uv[:, :2] / uv[:, 2:3]


def _silhouette(mesh: trimesh.Trimesh, T_base_obj: np.ndarray, K, T_base_cam, width: int, height: int) -> np.ndarray:
    """bool [H,W]: pixels whose centre (+0.5) lies inside one of the mesh's projected triangles."""
    X = mesh.vertices @ T_base_obj[:3, :3].T + T_base_obj[:3, 3]
    uv = _project(K, T_base_cam, X)
    out = np.zeros((height, width), dtype=bool)
    for tri in uv[mesh.faces]:
        lo = np.clip(np.floor(tri.min(0) - 0.5).astype(int), 0, [width, height])
        hi = np.clip(np.ceil(tri.max(0) - 0.5).astype(int) + 1, 0, [width, height])
        if np.any(hi <= lo):
            continue
        u, v = np.meshgrid(np.arange(lo[0], hi[0]) + 0.5, np.arange(lo[1], hi[1]) + 0.5)
        e = [
            (q[0] - p[0]) * (v - p[1]) - (q[1] - p[1]) * (u - p[0])
            for p, q in zip(tri, np.roll(tri, -1, 0), strict=True)
        ]
        inside = (np.minimum.reduce(e) >= 0) | (np.maximum.reduce(e) <= 0)
        out[lo[1] : hi[1], lo[0] : hi[0]] |= inside
    return out


def _centroid(mask: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(mask)
    return np.array([u.mean(), v.mean()])


def _dilate(mask: np.ndarray, r: int) -> np.ndarray:
    out = mask.copy()
    for dv in range(-r, r + 1, max(1, r // 4)):
        for du in range(-r, r + 1, max(1, r // 4)):
            out |= np.roll(mask, (dv, du), axis=(0, 1))
    return out


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


# ---- fixtures ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def gt(sample_dir: Path) -> dict:
    return json.loads((sample_dir / "ground_truth.json").read_text())


@pytest.fixture(scope="module")
def cameras(gt: dict) -> dict:
    """The video camera (640x480) and the head camera at the policy's 224x224 (as the twin renders it)."""
    c, h = gt["camera"], gt["head_camera"]
    return {
        "video": (np.asarray(c["K"]), c["width"], c["height"]),
        "head224": (_twin_render_K(np.asarray(h["K"]), h["height"], 224, 224), 224, 224),
    }


@pytest.fixture(scope="module")
def renderer(sample_dir: Path, cameras: dict) -> Iterator[GroundTruthRenderer]:
    t = time.perf_counter()
    with GroundTruthRenderer(sample_dir, cameras, with_robot=True) as r:
        print(f"\nGroundTruthRenderer build: {time.perf_counter() - t:.1f} s")
        yield r


@pytest.fixture(scope="module")
def video_frames(sample_dir: Path, gt: dict) -> dict[int, np.ndarray]:
    n = len(gt["frames"])
    pick = set(np.linspace(0, n - 1, N_PSNR_FRAMES).round().astype(int).tolist())
    return {i: f for i, _, f in read_video_frames(sample_dir / "scene.mp4") if i in pick}


def _T_head(gt: dict) -> np.ndarray:
    return np.asarray(gt["head_camera"]["T_base_headcam"], dtype=np.float64)


# ---- bad input (no Genesis needed) ---------------------------------------------------------------
def test_a_capture_without_ground_truth_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "scene.mp4").write_bytes(b"")  # a user's capture: a video, no ground truth
    K = np.array([[200.0, 0, 112], [0, 200.0, 112], [0, 0, 1]])
    with pytest.raises(GroundTruthError, match="ground_truth rendering needs a sample's ground_truth.json") as e:
        GroundTruthRenderer(tmp_path, {"head": (K, 224, 224)})
    assert isinstance(e.value, M2MError) and "hybrid" in str(e.value)
    (tmp_path / "ground_truth.json").write_text("{not json")
    with pytest.raises(GroundTruthError, match="not readable JSON"):
        GroundTruthRenderer(tmp_path, {"head": (K, 224, 224)})
    (tmp_path / "ground_truth.json").write_text(json.dumps({"version": 99, "seed": 0, "board": {}, "objects": []}))
    with pytest.raises(GroundTruthError, match="version 99"):
        GroundTruthRenderer(tmp_path, {"head": (K, 224, 224)})


def test_an_unknown_texture_filter_is_a_clear_error(sample_dir: Path) -> None:
    K = np.array([[200.0, 0, 112], [0, 200.0, 112], [0, 0, 1]])
    with pytest.raises(GroundTruthError, match="texture_filter: one of .*'trilinear'.*, got 'bilinear'"):
        GroundTruthRenderer(sample_dir, {"head": (K, 224, 224)}, texture_filter="bilinear")


@pytest.mark.slow
def test_trilinear_textures_render_at_once_where_anisotropic_filtering_stalls(sample_dir: Path, gt: dict,
                                                                               tmp_path: Path) -> None:  # fmt: skip
    """llvmpipe's anisotropic filter (Genesis sets the most the driver offers on every texture; the sample's video was
    rendered so) can hold one frame for minutes at exact camera poses. Here: a 128-px camera 4 cm beside a banana
    triangle, 0.04 mm off its plane, measured 24-37 s. ``texture_filter="trilinear"`` (the env's frames) renders it at
    once, the same picture up to the filtering; its exported meshes go under ``tmp_dir`` and leave with close()."""
    from mirage2matter.world.sample_assets import assets_of_sample

    banana = next(a for a in assets_of_sample(gt) if a.name == "banana")
    V = banana.mesh.vertices @ banana.T_base_obj[:3, :3].T + banana.T_base_obj[:3, 3]
    a, b, c = V[banana.mesh.faces[3357]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    centre = (a + b + c) / 3
    away = centre - V.mean(0)
    away -= n * (away @ n)
    eye = centre + 0.04 * away / np.linalg.norm(away) + 4e-5 * n
    z = (centre - eye) / np.linalg.norm(centre - eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T_cam = np.eye(4)
    T_cam[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T_cam[:3, 3] = eye
    K = np.array([[100.0, 0.0, 64.0], [0.0, 100.0, 64.0], [0.0, 0.0, 1.0]])
    seconds, images = {}, {}
    for texture_filter in ("trilinear", "anisotropic"):
        with GroundTruthRenderer(sample_dir, {"c": (K, 128, 128)}, with_robot=False, texture_filter=texture_filter,
                                 tmp_dir=tmp_path) as r:  # fmt: skip
            assert r._workdir.parent == tmp_path
            r.render({"c": T_cam @ _rigid(0.0, 0.0, -0.01, 0.0)})  # a first render elsewhere (shaders compile)
            t0 = time.perf_counter()
            images[texture_filter] = r.render({"c": T_cam})["c"]
            seconds[texture_filter] = time.perf_counter() - t0
        assert not any(tmp_path.iterdir())  # the exported meshes went with close()
    print(f"\nrender at the pose: {seconds}; PSNR trilinear vs anisotropic {_psnr(*images.values()):.1f} dB")
    assert seconds["trilinear"] < 2.0
    assert _psnr(images["trilinear"], images["anisotropic"]) > 25.0
    if seconds["anisotropic"] < 5.0:
        pytest.skip(f"this llvmpipe rendered the anisotropic frame in {seconds['anisotropic']:.1f} s (measured 24-37 s "
                    "with Debian 12's Mesa 22.3): the stall this setting avoids did not happen here")


def test_a_stalled_render_is_stopped_and_retried_with_the_cameras_moved_back() -> None:
    """llvmpipe can hang on one exact camera pose (HTL1's seed 1000196: one wrist render held for 460 s; 0.1 mm off
    it renders in 0.04 s): GroundTruthFrames stops a render past its time limit and retries with every camera
    moved back along its axis, 0.2 mm then 1 mm, counting stalls; three stalls on one state are a clear error."""
    from mirage2matter.env.ground_truth import STALL_NUDGES_M, GroundTruthFrames
    from mirage2matter.processes import WorkerTimeout

    T_cam = np.eye(4)
    T_cam[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]  # its +z (optical axis) is base +y
    T_cam[:3, 3] = [0.1, 0.2, 0.3]

    class Twin:
        def camera(self, name: str):
            return T_cam, None

        def robot_state(self):
            return np.zeros(9)

        def object_poses(self):
            return {"banana": np.eye(4)}

    class StallingWorker:  # stands in for the TimedWorker holding the renderer
        def __init__(self, stalls: int):
            self.stalls, self.seen = stalls, []

        def call(self, method, views, *, timeout_s, **state):
            self.seen.append(views["head"])
            if len(self.seen) <= self.stalls:
                raise WorkerTimeout("stalled")
            return {"head": np.zeros((2, 2, 3), np.uint8)}

    frames = object.__new__(GroundTruthFrames)
    frames.twin, frames.cameras, frames.timeout_s = Twin(), ("head",), 60.0
    frames.T_body_asset = {"banana": np.eye(4)}
    frames.start_episode(None)
    frames.renderer = StallingWorker(stalls=0)
    frames.render()
    assert np.array_equal(frames.renderer.seen[0], T_cam) and frames.timings["ground_truth_stalls"] == 0
    frames.renderer = StallingWorker(stalls=2)
    with pytest.warns(UserWarning, match="llvmpipe stall"):
        assert frames.render()["head"].shape == (2, 2, 3)
    seen = frames.renderer.seen
    assert [round(float(T[1, 3] - 0.2), 6) for T in seen] == [0.0, -STALL_NUDGES_M[0], -STALL_NUDGES_M[1]]
    assert all(np.array_equal(T[:3, :3], T_cam[:3, :3]) and np.allclose(T[[0, 2], 3], [0.1, 0.3]) for T in seen)
    assert frames.timings["ground_truth_stalls"] == 2
    frames.start_episode(None)
    frames.renderer = StallingWorker(stalls=3)
    with pytest.warns(UserWarning), pytest.raises(GroundTruthError, match="stalled 3 times on one state") as err:
        frames.render()
    # the episode cannot go on, the evaluation can: evaluation.run_episode counts it a failure cut short
    assert isinstance(err.value, EpisodeStalled) and frames.timings["ground_truth_stalls"] == 3


def test_intrinsics_genesis_cannot_render_are_refused_or_approximated_as_the_twin_does(sample_dir: Path) -> None:
    ok = np.array([[200.0, 0, 112], [0, 200.0, 112], [0, 0, 1]])
    assert np.array_equal(render_intrinsics(ok, 224, 224), ok)
    off_centre = np.array([[200.0, 0, 115.3], [0, 200.0, 110.0], [0, 0, 1]])
    not_square = np.array([[205.0, 0, 112], [0, 200.0, 112], [0, 0, 1]])
    for K in (off_centre, not_square):
        with pytest.raises(GroundTruthError, match="intrinsics='twin'"):
            render_intrinsics(K, 224, 224)
        with pytest.raises(GroundTruthError, match="principal point at the image centre"):
            GroundTruthRenderer(sample_dir, {"head": (K, 224, 224)})  # refused before Genesis starts
        assert np.allclose(render_intrinsics(K, 224, 224, "twin"), _twin_render_K(K, 224, 224, 224))
    for bad in ((np.eye(3), 0, 10), (np.zeros((2, 2)), 10, 10), (np.diag([-1.0, 1.0, 1.0]), 10, 10)):
        with pytest.raises(GroundTruthError):
            render_intrinsics(*bad)
    with pytest.raises(GroundTruthError, match="intrinsics must be one of"):
        GroundTruthRenderer(sample_dir, {"head": (ok, 224, 224)}, intrinsics="closest")
    with pytest.raises(GroundTruthError, match="at least one camera"):
        GroundTruthRenderer(sample_dir, {})


# ---- the sample's own frames ---------------------------------------------------------------------
def test_renders_at_the_videos_camera_poses_are_the_video(
    renderer: GroundTruthRenderer, gt: dict, video_frames: dict[int, np.ndarray]
) -> None:
    """The robot at the joint state each frame was filmed at (ground_truth.json robot.capture_joints, then its move
    half-way: capture_moves) in the sample's own look, objects at their ground-truth poses. RGB PSNR against the
    decoded H.264 (CRF 23, yuv420p) frames is what
    the codec leaves of the source frames (the slow test shows the renders ARE the source frames); on luma and at
    half resolution every frame is >= 35 dB."""
    from mirage2matter.robots.capture_poses import CapturePoses

    poses = CapturePoses.from_json(gt["robot"])
    assert len(poses) == 2 and {poses.index_at(i) for i in video_frames} == {0, 1}  # both poses among the frames
    rows = []
    try:
        for i, frame in sorted(video_frames.items()):
            renderer.set_state(robot_q=poses.joints[poses.index_at(i)], object_poses=renderer.ground_truth_poses())
            img = renderer.render({"video": np.asarray(gt["frames"][i]["T_base_cam"])})["video"]
            rows.append((i, _psnr(img, frame), _psnr(_luma(img), _luma(frame)), _psnr(_half(img), _half(frame))))
    finally:
        renderer.set_state(robot_q=renderer.spec.home_q())  # the module's other tests start from home
    print("\nframe  PSNR RGB  PSNR Y  PSNR RGB at 1/2 res (dB)")
    for i, rgb, y, half in rows:
        print(f"{i:5d}  {rgb:8.2f}  {y:6.2f}  {half:8.2f}")
    rgb, y, half = (np.array(c) for c in list(zip(*rows, strict=True))[1:])
    print(f"mean   {rgb.mean():8.2f}  {y.mean():6.2f}  {half.mean():8.2f}")
    assert len(rows) == N_PSNR_FRAMES
    # measured on the sample with the robot in view: luma 35.6-38.8, half size 36.0-38.6, RGB mean 35.0
    assert y.min() >= 35.0 and half.min() >= 35.0 and rgb.mean() >= 34.5, rows
    assert rgb.min() >= 33.0, rows  # the codec's floor on this video (the source frames score the same)


def test_hidden_robot_renders_as_no_robot_and_shows_again(renderer: GroundTruthRenderer, gt: dict) -> None:
    T = _T_head(gt)
    shown = renderer.segmentation({"head224": T})["head224"]
    assert renderer.mask(shown, "robot").sum() > 500  # the head camera sees the arm at home
    renderer.set_state(robot_visible=False)
    assert not renderer.robot_visible
    assert not renderer.mask(renderer.segmentation({"head224": T})["head224"], "robot").any()
    renderer.set_state(robot_visible=True)
    assert np.array_equal(renderer.segmentation({"head224": T})["head224"], shown)


# ---- moving things -------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("name", "mesh", "new_pose"),
    [
        ("banana", "banana", _rigid(0.50, -0.02, 0.0, 100.0)),
        ("croissant", "croissant", _rigid(0.38, 0.22, 0.0, 30.0)),
        ("button/cap", "button_cap", _rigid(0.48, -0.30, 0.0, 0.0)),  # the twin's name of the button's cap
    ],
)
def test_moving_an_object_moves_it_in_the_render(
    renderer: GroundTruthRenderer, sample_dir: Path, gt: dict, cameras: dict, name: str, mesh: str, new_pose: np.ndarray
) -> None:
    """Its mask goes where its mesh projects at the new pose (silhouette IoU, centroid), and leaves the old place."""
    K, w, h = cameras["video"]
    T_cam = _T_head(gt)
    m = trimesh.load(sample_dir / "gt" / f"{mesh}.obj", force="mesh", process=False)
    old_pose = renderer.ground_truth_poses()[name]
    renderer.reset_objects()
    before = renderer.segmentation({"video": T_cam})["video"]
    try:
        after = renderer.segmentation({"video": T_cam}, object_poses={name: new_pose})["video"]
        assert np.allclose(renderer.object_poses()[name], new_pose)
        rgb_after = renderer.render({"video": T_cam})["video"]
    finally:
        renderer.reset_objects()
    old_sil, new_sil = (_silhouette(m, T, K, T_cam, w, h) for T in (old_pose, new_pose))
    mask_before, mask_after = renderer.mask(before, name), renderer.mask(after, name)
    shift = _centroid(new_sil) - _centroid(old_sil)
    print(f"\n{name}: predicted centroid shift {shift.round(1)} px; mask IoU with the projected mesh "
          f"{_iou(mask_before, old_sil):.3f} before, {_iou(mask_after, new_sil):.3f} after")  # fmt: skip
    assert np.linalg.norm(shift) > 40
    for mask, sil in ((mask_before, old_sil), (mask_after, new_sil)):
        assert _iou(mask, sil) > 0.98  # measured 0.999-1.000: pixel-exact
        assert np.linalg.norm(_centroid(mask) - _centroid(sil)) < 0.5
    assert (mask_after & old_sil & ~new_sil).sum() == 0  # gone from where it was
    rgb_before = renderer.render({"video": T_cam})["video"]
    # the colour image changed there too (not just the labels); a croissant on wood changes it least
    diff = np.abs(rgb_after.astype(int) - rgb_before.astype(int)).sum(-1)
    near = _dilate(old_sil | new_sil, 25)  # the objects and their shadows
    print(f"{name}: mean |RGB change| {diff[new_sil].mean():.1f} where it went, {diff[~near].mean():.3f} elsewhere")
    assert diff[new_sil].mean() > 20 and diff[~near].max() == 0
    # back at the ground truth, the pictures are the same as before the move
    assert np.array_equal(renderer.segmentation({"video": T_cam})["video"], before)


def test_robot_joints_move_the_robot(renderer: GroundTruthRenderer, gt: dict, cameras: dict) -> None:
    """The arm is drawn where its forward kinematics put it: the hand projects into the robot's mask, and a
    turn of the base joint moves mask and hand the same way."""
    K, _, _ = cameras["head224"]
    T_cam = _T_head(gt)
    home = renderer.spec.home_q()
    turned = home.copy()
    turned[0] += 0.7
    centroids, hands = [], []
    try:
        for q in (home, turned):
            seg = renderer.segmentation({"head224": T_cam}, robot_q=q)["head224"]
            mask = renderer.mask(seg, "robot")
            hand = renderer.robot_link_pose()[:3, 3]
            uv = _project(K, T_cam, hand[None])[0]
            u, v = int(uv[0]), int(uv[1])
            assert mask[max(v - 3, 0) : v + 4, max(u - 3, 0) : u + 4].any(), (q, uv)
            centroids.append(_centroid(mask))
            hands.append(uv)
    finally:
        renderer.set_state(robot_q=renderer.spec.home_q())  # the module's other tests start from home
    d_mask, d_hand = centroids[1] - centroids[0], hands[1] - hands[0]
    assert np.linalg.norm(d_hand) > 10 and d_mask @ d_hand > 0
    with pytest.raises(GroundTruthError, match="9 finite joint positions"):
        renderer.render({"head224": T_cam}, robot_q=home[:7])


def test_bad_state_changes_nothing(renderer: GroundTruthRenderer, gt: dict) -> None:
    T = _T_head(gt)
    poses = renderer.object_poses()
    assert set(poses) == {"banana", "croissant", "button", "button/cap"}
    assert {"button_base", "button_cap"} <= set(renderer.object_names)
    not_rigid = np.diag([2.0, 1.0, 1.0, 1.0])
    for kwargs, match in (
        ({"object_poses": {"teapot": np.eye(4)}}, "unknown object 'teapot'"),
        ({"object_poses": {"banana": _rigid(0.5, 0, 0, 0), "croissant": not_rigid}}, "not a rigid transform"),
        ({"object_poses": {"banana": np.full((4, 4), np.nan)}}, "finite 4x4"),
        ({"robot_q": np.zeros(3)}, "joint positions"),
    ):
        with pytest.raises(GroundTruthError, match=match):
            renderer.render({"head224": T}, **kwargs)
    with pytest.raises(GroundTruthError, match="no camera 'wrist'"):
        renderer.render({"wrist": T}, object_poses={"banana": _rigid(0.5, 0, 0, 0)})
    with pytest.raises(GroundTruthError, match="T_base_cams"):
        renderer.render({"head224": np.eye(3)})
    after = renderer.object_poses()
    assert all(np.array_equal(after[n], poses[n]) for n in poses)


def test_render_timing(renderer: GroundTruthRenderer, gt: dict) -> None:
    """Per frame, robot in view, an object moved every frame (what the env does at each step)."""
    T = _T_head(gt)
    q = renderer.spec.home_q()
    timings = {}
    try:
        for cam in ("head224", "video"):
            renderer.render({cam: T})  # first render at a size allocates its buffers
            ts = []
            for k in range(5):
                pose = _rigid(0.42 + 0.01 * k, 0.16, 0.0, 15.0)
                t = time.perf_counter()
                out = renderer.render({cam: T}, robot_q=q, object_poses={"banana": pose})
                ts.append(time.perf_counter() - t)
            w, h = renderer.size(cam)
            assert out[cam].shape == (h, w, 3) and out[cam].dtype == np.uint8
            timings[f"{w}x{h}"] = float(np.median(ts))
    finally:
        renderer.reset_objects()
    print(
        "\nground-truth render per frame (median of 5): "
        + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in timings.items())
    )
    assert max(timings.values()) < 3.0


# ---- slow --------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_reencoded_renders_are_the_sample_video(sample_dir: Path, gt: dict, tmp_path: Path) -> None:
    """All 720 frames rendered (the robot at each frame's joints, in the sample's look) and encoded with the sample's
    own settings decode to the shipped video's frames (~3 min). On the empty table this was bit for bit; with the
    robot in view it is not (2026-12-05: 0 of 720 frames identical, worst 36.6 dB): something of the robot's look is
    drawn differently from the sample maker's scene, not found yet. The bar is what H.264 leaves (>= 35 dB)."""
    from mirage2matter.robots.capture_poses import CapturePoses

    c = gt["camera"]
    poses = CapturePoses.from_json(gt["robot"])  # the robot moved once while filming (capture_moves)
    t = time.perf_counter()
    with GroundTruthRenderer(sample_dir, {"video": (np.asarray(c["K"]), c["width"], c["height"])}) as r:

        def frames() -> Iterator[np.ndarray]:
            for i, f in enumerate(gt["frames"]):
                yield r.render({"video": np.asarray(f["T_base_cam"])}, robot_q=poses.joints[poses.index_at(i)])["video"]

        n = write_video(tmp_path / "again.mp4", frames(), fps=gt["video"]["fps"], crf=gt["video"]["crf"])
    elapsed = time.perf_counter() - t
    assert n == len(gt["frames"])
    identical, worst = 0, float("inf")
    shipped = read_video_frames(sample_dir / "scene.mp4")
    for (_, _, a), (_, _, b) in zip(shipped, read_video_frames(tmp_path / "again.mp4"), strict=True):
        identical += int(np.array_equal(a, b))
        worst = min(worst, _psnr(a, b))
    same_bytes = (tmp_path / "again.mp4").read_bytes() == (sample_dir / "scene.mp4").read_bytes()
    print(f"\n{n} frames rendered + encoded in {elapsed:.0f} s; decoded frames identical: {identical}/{n}, "
          f"worst PSNR {worst:.1f} dB; same MP4 bytes: {same_bytes}")  # fmt: skip
    assert worst >= 35.0


@pytest.mark.slow
def test_the_twins_state_drives_the_renderer(renderer: GroundTruthRenderer, sample_world_ws, gt: dict) -> None:
    """``Twin.object_poses()`` and ``Twin.robot_state()`` go straight in: same names, same frames (at rest the
    twin's poses are the ground truth's), and after a randomised reset the objects are drawn where physics put
    them. The twin and the renderer live side by side in one process, as in the env."""
    from mirage2matter.sim.twin import Twin, TwinOptions
    from mirage2matter.world import load_world

    ws = sample_world_ws(gaussians_per_object=3000, scene_density_per_m2=4000.0)
    twin = Twin.build(load_world(ws / "world"), TwinOptions(render=False))
    try:
        twin.reset(seed=0, randomize=False)
        poses = twin.object_poses()
        gt_poses = renderer.ground_truth_poses()
        assert set(poses) == set(gt_poses)
        for name, T in poses.items():
            G = gt_poses[name]
            angle = np.degrees(np.arccos(np.clip((np.trace(G[:3, :3].T @ T[:3, :3]) - 1) / 2, -1, 1)))
            dist = np.linalg.norm(T[:3, 3] - G[:3, 3])
            print(f"\ntwin at rest vs ground truth: {name} {dist * 1e3:.1f} mm, {angle:.1f} deg")
            assert dist < 1e-2, name  # same frame origin (the bottom centre)
            if name.startswith("button"):  # fixed base, cap on its slider: the same frames exactly
                assert angle < 0.5, name
        twin.reset(seed=3, randomize=True)
        poses, q = twin.object_poses(), twin.robot_state()
        T_cam = _T_head(gt)
        K, w, h = renderer.K("video"), *renderer.size("video")
        seg = renderer.segmentation({"video": T_cam}, robot_q=q, object_poses=poses)["video"]
        for name in ("banana", "croissant"):
            mesh = trimesh.load(renderer.sample_dir / "gt" / f"{name}.obj", force="mesh", process=False)
            sil = _silhouette(mesh, poses[name], K, T_cam, w, h)
            mask = renderer.mask(seg, name)
            visible = mask.sum() / max(sil.sum(), 1)
            if visible > 0.5:  # not hidden behind the arm
                assert np.linalg.norm(_centroid(mask) - _centroid(sil)) < 10.0, name
            assert (mask & ~sil).sum() < 0.05 * max(mask.sum(), 1), name
        assert np.allclose(renderer.robot_link_pose(), twin.T_base_link(), atol=1e-4)
    finally:
        twin.close()
        renderer.reset_objects()
        renderer.set_state(robot_q=renderer.spec.home_q())
