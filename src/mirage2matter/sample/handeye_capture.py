"""A hand-eye capture as a real arm and a real camera make it: the test bed that calibration is measured on.

Renders, without Genesis, what a camera sees of a ChArUco board while a Panda moves: ``mount="wrist"`` (the
camera on the hand, the board on the table) or ``mount="head"`` (the camera fixed, the board in the gripper).
What makes real data hard is put in on purpose, each with its size in :class:`HandEyeCaptureConfig`:

- a lens with radial-tangential distortion (the intrinsics file holds it, as a factory calibration does);
- sensor noise, defocus blur and a per-image exposure change;
- robot pose error: the joint angles written are not the ones the arm was at (a constant encoder offset per
  joint plus per-pose noise), so the reported hand pose is off by about a millimetre and a tenth of a degree,
  as on a real arm (absolute accuracy, not repeatability).

Images are ray-traced: each pixel's ray (through the lens, 2 x 2 samples per pixel) meets the board plane and
reads the printed board; so the corners' true positions are exact and the errors are only the ones put in.
Ground truth (mount, board pose, true and reported hand poses) goes to ``ground_truth.json``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import atomic_dir
from ..calib.board import BoardSpec, board_frame_to_board_image
from ..errors import M2MError
from ..render.lens import lens_rays
from ..robots import DEFAULT_ROBOT, get_robot
from ..robots.kinematics import RobotKinematics

__all__ = ["HandEyeCaptureConfig", "HandEyeCaptureError", "make_handeye_capture", "render_board_view"]


class HandEyeCaptureError(M2MError, ValueError):
    """Test-bed settings that cannot make a capture."""


@dataclass(frozen=True)
class HandEyeCaptureConfig:
    """The test bed's camera, robot, board and error sizes.

    mount            "wrist" (camera on the hand, board on the table) or "head" (camera fixed, board in the hand)
    views            images (with joint angles) to make
    width, height    image size (px); fx, fy, cx, cy in pixels, pixel centres at +0.5
    distortion       OpenCV radial-tangential coefficients of the lens (k1, k2, p1, p2, k3)
    noise_dn         std of the sensor noise, 8-bit levels
    blur_px          std of the Gaussian defocus blur (px)
    exposure         images are scaled by a gain drawn in [1 - exposure, 1 + exposure]
    joint_offset_rad std of each joint's constant encoder offset (rad)
    joint_noise_rad  std of the per-pose joint error (rad)
    distance         range of camera-to-board distances (m)
    tilt_deg         largest angle between the optical axis and the board normal
    seed             everything random
    """

    mount: str = "wrist"
    views: int = 12
    width: int = 1280
    height: int = 720
    fx: float = 912.0
    fy: float = 911.0
    cx: float = 646.3
    cy: float = 362.8
    distortion: tuple[float, ...] = (0.11, -0.24, 0.0012, -0.0009, 0.12)
    noise_dn: float = 2.0
    blur_px: float = 0.7
    exposure: float = 0.25
    joint_offset_rad: float = 0.0012
    joint_noise_rad: float = 0.0006
    distance: tuple[float, float] = (0.32, 0.52)
    tilt_deg: float = 35.0
    # any calibration target (calib.board): a ChArUco board by default
    board: Any = field(default_factory=lambda: BoardSpec(squares_x=5, squares_y=7, square=0.035, marker=0.026,
                                                         dictionary="DICT_5X5_100"))  # fmt: skip
    seed: int = 0

    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def check(self) -> None:
        if self.mount not in ("wrist", "head"):
            raise HandEyeCaptureError(f"mount must be 'wrist' or 'head', got {self.mount!r}")
        if self.views < 3:
            raise HandEyeCaptureError(f"a hand-eye capture needs at least 3 views, got {self.views}")
        if len(self.distortion) != 5:
            raise HandEyeCaptureError(f"distortion is (k1, k2, p1, p2, k3), got {self.distortion!r}")


# The mounts of the test bed. Wrist: a camera on the hand's side, 7 cm off its axis, 4 cm behind the flange,
# looking along the fingers, tilted 12 degrees towards them; board on the table in front of the robot.
def _rot(axis: str, deg: float) -> np.ndarray:
    import cv2

    v = {"x": [1.0, 0, 0], "y": [0, 1.0, 0], "z": [0, 0, 1.0]}[axis]
    return cv2.Rodrigues(np.radians(deg) * np.asarray(v))[0]


def _T(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def default_mounts(mount: str, board: BoardSpec) -> tuple[np.ndarray, np.ndarray]:
    """(X, Y): wrist: T_hand_cam and T_base_board; head: T_base_headcam and T_hand_board."""
    w, h = board.size
    if mount == "wrist":
        X = _T(_rot("z", 90.0) @ _rot("x", -12.0), [0.07, 0.0, -0.04])
        # board face up, centred at (0.5, 0, 0) in the base; board z (into the board) points down
        Y = _T(np.diag([1.0, -1.0, -1.0]), [0.5 - w / 2, h / 2, 0.0])
        return X, Y
    # head: a camera 1.2 m in front of the robot, 0.55 m up, looking back at the workspace
    from ..geometry.camera import look_at_pose

    X = look_at_pose(np.array([1.25, 0.15, 0.6]), np.array([0.45, 0.0, 0.35]))
    # the board held flat against the fingers' outside, its centre 9 cm beyond the flange
    # board z (into the board) = -hand z: its face looks away from the flange; centre 9 cm beyond it
    Y = _T(np.diag([1.0, -1.0, -1.0]), [-w / 2, h / 2, 0.09])
    return X, Y


# ---- rendering --------------------------------------------------------------------------------------
class _Rays:
    """Normalised ray directions [H*2, W*2, 2] (x/z, y/z) of every sub-pixel of the distorted image."""

    def __init__(self, cfg: HandEyeCaptureConfig, supersample: int = 2) -> None:
        from ..geometry.camera import Camera

        k1, k2, p1, p2, k3 = cfg.distortion
        camera = Camera(cfg.K(), np.eye(4), cfg.width, cfg.height, distortion={"k1": k1, "k2": k2, "p1": p1,
                                                                               "p2": p2, "k3": k3})  # fmt: skip
        self.xy = lens_rays(camera, supersample)
        self.s = supersample


def render_board_view(
    rays: _Rays, T_cam_board: np.ndarray, board: BoardSpec, texture: np.ndarray, px_per_square: int,
    background: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """The board seen by the camera at ``T_cam_board`` [4,4]: float32 [H, W] in [0, 1] before any sensor effect.
    ``texture`` is ``board.render_image(px_per_square)``; outside the printed sheet the ``background`` [H, W]."""
    import cv2

    R, t = T_cam_board[:3, :3], T_cam_board[:3, 3]
    n = R[:, 2]  # board normal in the camera
    d = np.concatenate([rays.xy, np.ones((*rays.xy.shape[:2], 1))], axis=2)  # [h, w, 3]
    denom = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (n @ t) / denom
    p_cam = d * lam[..., None]
    p_board = (p_cam - t) @ R  # board frame (z ~ 0)
    uv = board_frame_to_board_image(p_board, board, px_per_square).astype(np.float32)
    ok = (lam > 0) & np.isfinite(lam)
    uv[~ok] = -1e6
    # texture pixel centres at +0.5: remap wants centres at integers
    sheet = cv2.remap(texture.astype(np.float32) / 255.0, uv[..., 0] - 0.5, uv[..., 1] - 0.5, cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)  # fmt: skip
    s = rays.s
    h, w = sheet.shape[0] // s, sheet.shape[1] // s
    inside = sheet >= 0
    bg = np.repeat(np.repeat(background, s, axis=0), s, axis=1)
    img = np.where(inside, 0.85 * np.clip(sheet, 0, 1) + 0.06, bg)  # paper is not pure white, ink not pure black
    return img.reshape(h, s, w, s).mean(axis=(1, 3)).astype(np.float32)


def _sensor(img: np.ndarray, cfg: HandEyeCaptureConfig, rng: np.random.Generator) -> np.ndarray:
    """Exposure, defocus, noise and 8-bit quantisation -> uint8 [H, W, 3]."""
    import cv2

    gain = 1.0 + rng.uniform(-cfg.exposure, cfg.exposure)
    out = img * gain
    if cfg.blur_px > 0:
        out = cv2.GaussianBlur(out, (0, 0), cfg.blur_px)
    out = out * 255.0 + rng.normal(0.0, cfg.noise_dn, out.shape)
    grey = np.clip(np.round(out), 0, 255).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=2)


def _background(cfg: HandEyeCaptureConfig, rng: np.random.Generator) -> np.ndarray:
    """A table-like grey with low-frequency texture [H, W]."""
    import cv2

    small = rng.uniform(0.25, 0.55, (cfg.height // 40 + 2, cfg.width // 40 + 2)).astype(np.float32)
    return cv2.resize(small, (cfg.width, cfg.height), interpolation=cv2.INTER_CUBIC)


# ---- poses ----------------------------------------------------------------------------------------------
def _random_T_cam_board(cfg: HandEyeCaptureConfig, rng: np.random.Generator) -> np.ndarray:
    """A view of the board: its centre near the optical axis at a distance in ``cfg.distance``, its face towards
    the camera within ``cfg.tilt_deg``, any roll."""
    import cv2

    w, h = cfg.board.size
    dist = rng.uniform(*cfg.distance)
    off = rng.normal(size=2) * 0.06 * dist
    centre = np.array([off[0], off[1], dist])
    axis = rng.normal(size=3)
    axis[2] = 0.0
    axis /= np.linalg.norm(axis)
    tilt = cv2.Rodrigues(axis * np.radians(rng.uniform(10.0, cfg.tilt_deg)))[0]
    roll = _rot("z", rng.uniform(-180.0, 180.0))
    R = tilt @ roll  # board z (into the board) along the optical axis, then tilted
    t = centre - R @ np.array([w / 2, h / 2, 0.0])
    return _T(R, t)


def _visible(cfg: HandEyeCaptureConfig, T_cam_board: np.ndarray, margin_px: float = 25.0) -> bool:
    import cv2

    w, h = cfg.board.size
    m = cfg.board.feature_size * 0.5
    outline = np.array([[-m, -m, 0], [w + m, -m, 0], [w + m, h + m, 0], [-m, h + m, 0]])
    p = outline @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    if np.any(p[:, 2] <= 0.05):
        return False
    K_cv = cfg.K().copy()
    K_cv[:2, 2] -= 0.5
    uv = cv2.projectPoints(p, np.zeros(3), np.zeros(3), K_cv, np.asarray(cfg.distortion, float))[0].reshape(-1, 2)
    return bool(np.all((uv > margin_px) & (uv < np.array([cfg.width, cfg.height]) - margin_px)))


def make_handeye_capture(out_dir: str | Path, cfg: HandEyeCaptureConfig = HandEyeCaptureConfig(), log=print) -> dict:
    """Write the capture into the NEW folder ``out_dir`` (atomically): images/NNNN.png, joints.json (the reported
    joints and the hand poses they give), intrinsics.json (K + distortion), board.json, ground_truth.json.
    Returns the ground truth."""
    from PIL import Image


    cfg.check()
    robot = get_robot(DEFAULT_ROBOT)
    kin = RobotKinematics(robot.model)
    link = robot.ee_link
    n, limits = kin.chain(link)
    rng = np.random.default_rng(cfg.seed)
    X, Y = default_mounts(cfg.mount, cfg.board)
    offsets = rng.normal(0.0, cfg.joint_offset_rad, n)
    q_home = np.r_[np.asarray(robot.home, float), np.zeros(max(0, n - len(robot.home)))][:n]
    ppsq = 160 if cfg.board.kind == "charuco" else 2 * int(round(cfg.board.feature_size * 2500))  # ~5 px / mm
    texture = cfg.board.render_image(ppsq)
    rays = _Rays(cfg)
    views, truth = [], []
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        (tmp / "images").mkdir()
        attempts = 0
        while len(views) < cfg.views:
            attempts += 1
            if attempts > 200 * cfg.views:
                raise HandEyeCaptureError(f"only {len(views)} of {cfg.views} views reachable; widen cfg.distance")
            T_cb = _random_T_cam_board(cfg, rng)
            if not _visible(cfg, T_cb):
                continue
            if cfg.mount == "wrist":  # base <- hand = base <- board . board <- cam . cam <- hand
                T_hand = Y @ np.linalg.inv(T_cb) @ np.linalg.inv(X)
            else:  # base <- board = base <- cam . cam <- board;  base <- hand = that . board <- hand
                T_hand = X @ T_cb @ np.linalg.inv(Y)
            q = kin.inverse(T_hand, link, q_home, margin=0.02)  # room for the reported joints' errors
            if q is None:
                continue
            q_true = q
            q_reported = q_true + offsets + rng.normal(0.0, cfg.joint_noise_rad, n)
            T_hand_true = kin.link_pose(q_true, link)
            name = f"{len(views):04d}.png"
            img = render_board_view(rays, T_cb, cfg.board, texture, ppsq, _background(cfg, rng))
            Image.fromarray(_sensor(img, cfg, rng)).save(tmp / "images" / name)
            T_hand_reported = kin.link_pose(q_reported, link)
            views.append({"image": f"images/{name}", "joints": [float(v) for v in q_reported],
                          "T_base_hand": T_hand_reported.tolist()})  # fmt: skip
            truth.append({"image": f"images/{name}", "joints": [float(v) for v in q_true],
                          "T_base_hand": T_hand_true.tolist(), "T_cam_board": T_cb.tolist()})  # fmt: skip
            log(f"handeye capture: view {len(views)}/{cfg.views}")
        (tmp / "joints.json").write_text(json.dumps({"robot": robot.model, "link": link, "views": views}, indent=1))
        k1, k2, p1, p2, k3 = cfg.distortion
        intr = {"width": cfg.width, "height": cfg.height, "K": cfg.K().tolist(),
                "distortion": {"k1": k1, "k2": k2, "p1": p1, "p2": p2, "k3": k3}}  # fmt: skip
        (tmp / "intrinsics.json").write_text(json.dumps(intr, indent=1))
        cfg.board.save(tmp / "board.json")
        key, board_key = ("T_hand_cam", "T_base_board") if cfg.mount == "wrist" else ("T_base_headcam", "T_hand_board")
        errs = [_pose_error(np.asarray(v["T_base_hand"]), np.asarray(t["T_base_hand"]))
                for v, t in zip(views, truth, strict=True)]  # fmt: skip
        gt = {"mount": cfg.mount, "link": link, key: X.tolist(), board_key: Y.tolist(),
              "joint_offsets": offsets.tolist(), "hand_pose_error_deg": [e[0] for e in errs],
              "hand_pose_error_mm": [e[1] for e in errs],
              "views": truth, "config": {k: v for k, v in asdict(cfg).items() if k != "board"}}  # fmt: skip
        (tmp / "ground_truth.json").write_text(json.dumps(gt, indent=1))
    return gt


def _pose_error(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    from ..geometry.rotation import rotation_angle

    return float(np.degrees(rotation_angle(A[:3, :3].T @ B[:3, :3]))), float(1000 * np.linalg.norm(A[:3, 3] - B[:3, 3]))
