"""The shipped sample (samples/tabletop) and its generator.

The shipped-sample tests check the ground truth against what an independent detector sees in the
rendered pixels: ChArUco corners found by OpenCV must land where the ground-truth camera poses and
board pose project them, and PnP on the hand-eye images must give the ground-truth board pose.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from fixtures import SAMPLE
from mirage2matter.calib.board import BoardSpec
from mirage2matter.sample.make import SampleConfig, SampleError, make_sample, with_robot_in_view
from mirage2matter.video import read_video_frames

REQUIRED = ["scene.mp4", "ground_truth.json", "head_view.png", "board.json", "handeye/joints.json", "contact_sheet.jpg"]


@pytest.fixture(scope="module")
def gt() -> dict:
    if not (SAMPLE / "ground_truth.json").is_file():
        pytest.fail(f"the shipped sample is missing: {SAMPLE} (regenerate with `m2m sample make {SAMPLE}`)")
    return json.loads((SAMPLE / "ground_truth.json").read_text())


def _rigid(T) -> bool:
    T = np.asarray(T)
    R = T[:3, :3]
    return T.shape == (4, 4) and np.allclose(R.T @ R, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(R), 1.0)


def _detect(board: BoardSpec, image_rgb: np.ndarray):
    """ChArUco corners (ids [M], pixels [M,2] with our +0.5 pixel-centre convention) or None."""
    gray = cv2.cvtColor(image_rgb, cv2.COLOR_RGB2GRAY)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board.cv_board()).detectBoard(gray)
    if ids is None or len(ids) < 4:
        return None
    return ids.ravel(), corners.reshape(-1, 2) + 0.5


def _project(K, T_base_cam, points_base) -> np.ndarray:
    T_cam_base = np.linalg.inv(T_base_cam)
    p = points_base @ T_cam_base[:3, :3].T + T_cam_base[:3, 3]
    uv = p @ np.asarray(K).T
    return uv[:, :2] / uv[:, 2:]


def _board_corners_base(gt: dict) -> tuple[BoardSpec, np.ndarray]:
    board = BoardSpec.from_json(gt["board"]["spec"])
    T = np.asarray(gt["board"]["T_base_board"])
    pts = board.corner_points_board()
    return board, pts @ T[:3, :3].T + T[:3, 3]


def test_layout_size_and_conventions(gt):
    for rel in REQUIRED:
        assert (SAMPLE / rel).is_file(), rel
    total = sum(f.stat().st_size for f in SAMPLE.rglob("*") if f.is_file())
    assert total <= 25 * 2**20, f"sample is {total / 2**20:.1f} MB, over the 25 MB budget"
    cam = gt["camera"]
    K = np.asarray(cam["K"])
    assert (cam["width"], cam["height"]) == (640, 480)
    assert np.isclose(K[0, 2], cam["width"] / 2) and np.isclose(K[1, 2], cam["height"] / 2) and K[0, 0] > 0
    assert all(_rigid(f["T_base_cam"]) for f in gt["frames"])
    assert _rigid(gt["head_camera"]["T_base_headcam"]) and _rigid(gt["board"]["T_base_board"])
    for obj in gt["objects"]:
        assert (SAMPLE / obj["mesh"]).is_file() and _rigid(obj["T_base_obj"])
    names = {o["name"] for o in gt["objects"]}
    assert {"banana", "croissant"} <= names and any("button" in n for n in names)
    lo, hi = np.asarray(gt["world_extent"]["min"]), np.asarray(gt["world_extent"]["max"])
    assert np.all(hi - lo > 1.0)
    duration = gt["video"]["n_frames"] / gt["video"]["fps"]
    assert 20 <= duration <= 30


def test_video_matches_the_ground_truth_frames(gt):
    decoded = list(read_video_frames(SAMPLE / "scene.mp4", every=1))
    assert len(decoded) == gt["video"]["n_frames"] == len(gt["frames"])
    h, w = decoded[0][2].shape[:2]
    assert (w, h) == (gt["camera"]["width"], gt["camera"]["height"])
    ts = np.array([t for _, t, _ in decoded])
    assert np.allclose(ts, [f["timestamp"] for f in gt["frames"]], atol=1e-3)


def test_board_is_detected_where_the_ground_truth_puts_it(gt):
    board, corners_base = _board_corners_base(gt)
    K = np.asarray(gt["camera"]["K"])
    n = gt["video"]["n_frames"]
    every = max(1, n // 30)
    seen, errors = 0, []
    frames = list(read_video_frames(SAMPLE / "scene.mp4", every=every))
    for i, _, image in frames:
        found = _detect(board, image)
        if found is None:
            continue
        seen += 1
        ids, uv = found
        expected = _project(K, np.asarray(gt["frames"][i]["T_base_cam"]), corners_base[ids])
        errors.extend(np.linalg.norm(uv - expected, axis=1))
    assert seen >= 0.5 * len(frames), f"board detected in only {seen}/{len(frames)} sampled frames"
    # H.264 and rendering blur corners a little; a wrong pose or axis convention is off by many pixels
    assert np.median(errors) < 1.0 and np.percentile(errors, 95) < 2.5


def test_handeye_images_match_the_ground_truth(gt):
    he = gt["handeye"]
    views = json.loads((SAMPLE / he["joints"]).read_text())["views"]
    assert len(views) >= 15
    board = BoardSpec.from_json(he["board"])
    K = np.asarray(gt["head_camera"]["K"])
    K_cv = K.copy()
    K_cv[:2, 2] -= 0.5  # OpenCV puts pixel centres at integers
    T_base_headcam = np.asarray(gt["head_camera"]["T_base_headcam"])
    T_hand_board = np.asarray(he["T_hand_board"])
    rot_err, trans_err, rotations = [], [], []
    from PIL import Image

    for view in views:
        image = np.asarray(Image.open(SAMPLE / "handeye" / view["image"]).convert("RGB"))
        found = _detect(board, image)
        assert found is not None, f"no board in {view['image']}"
        ids, uv = found
        obj = board.corner_points_board()[ids].astype(np.float64)
        ok, rvec, tvec = cv2.solvePnP(obj, uv - 0.5, K_cv, None, flags=cv2.SOLVEPNP_IPPE)
        assert ok
        ok, rvec, tvec = cv2.solvePnP(obj, uv - 0.5, K_cv, None, rvec, tvec, True, cv2.SOLVEPNP_ITERATIVE)
        T_cam_board = np.eye(4)
        T_cam_board[:3, :3], T_cam_board[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
        T_expected = np.linalg.inv(T_base_headcam) @ np.asarray(view["T_base_hand"]) @ T_hand_board
        dR = T_cam_board[:3, :3].T @ T_expected[:3, :3]
        rot_err.append(np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))))
        trans_err.append(np.linalg.norm(T_cam_board[:3, 3] - T_expected[:3, 3]))
        rotations.append(np.asarray(view["T_base_hand"])[:3, :3])
    assert np.median(rot_err) < 0.3 and np.median(trans_err) < 0.002, (rot_err, trans_err)
    # Tsai-Lenz needs relative rotations about non-parallel axes
    axes = []
    for a, b in zip(rotations[:-1], rotations[1:], strict=True):
        rvec = cv2.Rodrigues(a.T @ b)[0].ravel()
        if np.linalg.norm(rvec) > np.radians(3):
            axes.append(rvec / np.linalg.norm(rvec))
    assert len(axes) >= 5 and np.linalg.svd(np.asarray(axes), compute_uv=False)[1] > 0.3


def test_bad_output_directory_is_refused_and_nothing_is_written(tmp_path):
    full = tmp_path / "full"
    full.mkdir()
    (full / "x.txt").write_text("keep me")
    with pytest.raises(SampleError, match="not an empty directory"):
        make_sample(full)
    with pytest.raises(SampleError, match="does not exist"):
        make_sample(tmp_path / "missing" / "sample")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["full"]
    assert [p.name for p in full.iterdir()] == ["x.txt"]


def _digest(sample_dir: Path) -> tuple[str, str]:
    gt_hash = hashlib.sha256((sample_dir / "ground_truth.json").read_bytes()).hexdigest()
    frames = hashlib.sha256()
    for _, _, image in read_video_frames(sample_dir / "scene.mp4"):
        frames.update(image.tobytes())
    return gt_hash, frames.hexdigest()


def test_regenerated_short_sample_is_deterministic_and_follows_the_shipped_conventions(tmp_path, gt):
    a, b = tmp_path / "a", tmp_path / "b"
    short_config = with_robot_in_view(SampleConfig.short(seed=0), second_pose=True)  # the bundled sample, shorter
    make_sample(a, short_config, log=lambda _msg: None)
    make_sample(b, short_config, log=lambda _msg: None)
    assert _digest(a) == _digest(b)
    short = json.loads((a / "ground_truth.json").read_text())
    assert set(short) == set(gt)
    for key in ("camera", "board", "head_camera", "units", "frame", "camera_convention"):
        assert short[key] == gt[key], key
    # the same robot and poses; it moves half-way through its own, shorter, video
    (frame, moved), (full_frame, full_moved) = short["robot"].pop("capture_moves").popitem(), \
        gt["robot"]["capture_moves"].copy().popitem()  # fmt: skip
    assert moved == full_moved and int(frame) == len(short["frames"]) // 2 and int(full_frame) == len(gt["frames"]) // 2
    assert short["robot"] == {k: v for k, v in gt["robot"].items() if k != "capture_moves"}
    assert [o["name"] for o in short["objects"]] == [o["name"] for o in gt["objects"]]
    # same seed, same scene: the first frame of the short orbit starts where the full one starts
    assert np.allclose(short["frames"][0]["T_base_cam"], gt["frames"][0]["T_base_cam"])


def test_pycolmap_registers_frames_sampled_from_the_video(gt, tmp_path):
    """Smoke test of SfM-friendliness (full SfM is the reconstruction issue's): >= 95% registered."""
    import pycolmap
    from PIL import Image

    images = tmp_path / "images"
    images.mkdir()
    n = gt["video"]["n_frames"]
    every = max(1, n // 36)
    names = []
    for i, _, frame in read_video_frames(SAMPLE / "scene.mp4", every=every):
        names.append(f"{i:05d}.png")
        Image.fromarray(frame).save(images / names[-1])
    db = tmp_path / "db.db"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.sift.max_num_features = 4096
    pycolmap.extract_features(
        db,
        images,
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=pycolmap.ImageReaderOptions(camera_model="PINHOLE"),
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    pycolmap.match_sequential(db, pairing_options=pycolmap.SequentialPairingOptions(overlap=8))
    models = pycolmap.incremental_mapping(db, images, tmp_path / "sparse")
    registered = max((m.num_reg_images() for m in models.values()), default=0)
    assert registered >= 0.95 * len(names), f"registered {registered}/{len(names)} frames"


def test_inspect_sample_reads_the_video_like_a_user_capture(gt, tmp_path):
    from mirage2matter.sample.inspect import inspect_sample

    summary = inspect_sample(SAMPLE, n_checked=12)
    assert summary["video_frames"] == gt["video"]["n_frames"]
    assert summary["board_detected"] >= 0.5 * summary["frames_checked"] >= 6
    assert summary["board_corner_error_px_median"] < 1.0
    with pytest.raises(FileNotFoundError, match="m2m sample make"):
        inspect_sample(tmp_path / "nothing")
