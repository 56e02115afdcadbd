"""Hand-eye calibration: a ChArUco board seen by a camera while the robot moves (Tsai-Lenz by default).

Two mounts:
- ``head`` (eye-to-hand): the camera is fixed in the base frame and the board rides on the gripper;
  the result is ``T_base_headcam``.
- ``wrist`` (eye-in-hand): the camera rides on the gripper and the board is fixed in the world;
  the result is ``T_link_wristcam`` (the camera in the gripper link's frame).

OpenCV's ``calibrateHandEye`` solves the eye-in-hand problem; eye-to-hand is the same problem with
the gripper poses inverted (the base "rides" on the gripper), which gives the camera in the base.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import M2MError
from ..geometry.camera import opencv_K
from ..geometry.rotation import rotation_angle
from ..geometry.sim3 import invert_rigid
from .board import BoardSpec

METHODS = ("tsai", "park", "horaud", "andreff", "daniilidis")


class HandEyeError(M2MError, ValueError):
    """Unusable hand-eye data; the message says what to change."""


@dataclass
class BoardObservation:
    """The board in one image: T_cam_board [4,4] by PnP, the corners used (points_board [M,3], their
    pixels uv [M,2] with our +0.5 convention) and the RMS reprojection error of the PnP pose."""

    T_cam_board: np.ndarray
    points_board: np.ndarray
    uv: np.ndarray
    rms_px: float

    @property
    def n_corners(self) -> int:
        return len(self.uv)


def detect_board_pose(image_rgb: np.ndarray, board: BoardSpec, K: np.ndarray, min_corners: int = 6):
    """ChArUco corners + PnP (IPPE, refined iteratively). K uses pixel centres at +0.5 (ours).
    Returns a BoardObservation, or None when fewer than ``min_corners`` corners are found."""
    import cv2

    gray = cv2.cvtColor(image_rgb, cv2.COLOR_RGB2GRAY) if image_rgb.ndim == 3 else image_rgb
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board.cv_board()).detectBoard(gray)
    if ids is None or len(ids) < min_corners:
        return None
    obj = board.corner_points_board()[ids.ravel()].astype(np.float64)
    img = corners.reshape(-1, 2).astype(np.float64)
    K_cv = opencv_K(K)
    ok, rvec, tvec = cv2.solvePnP(obj, img, K_cv, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        return None
    ok, rvec, tvec = cv2.solvePnP(obj, img, K_cv, None, rvec, tvec, True, cv2.SOLVEPNP_ITERATIVE)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K_cv, None)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))
    return BoardObservation(T, obj, img + 0.5, rms)


def check_motion_diversity(T_base_link: list[np.ndarray], min_angle_deg: float = 2.0) -> None:
    """Raise HandEyeError unless the relative rotations turn about at least two non-parallel axes."""
    import cv2

    axes = []
    for i in range(len(T_base_link)):
        for j in range(i + 1, len(T_base_link)):
            rvec = cv2.Rodrigues(T_base_link[i][:3, :3].T @ T_base_link[j][:3, :3])[0].ravel()
            if np.degrees(np.linalg.norm(rvec)) >= min_angle_deg:
                axes.append(rvec / np.linalg.norm(rvec))
    if len(axes) < 2 or np.linalg.svd(np.asarray(axes), compute_uv=False)[1] < 0.1:
        raise HandEyeError(
            "degenerate hand-eye motions: the gripper rotates about a single axis (or hardly at all) "
            "between views; vary the wrist orientation about at least two different axes"
        )


@dataclass
class HandEyeResult:
    mount: str
    method: str
    T: np.ndarray  # T_base_headcam (head) or T_link_wristcam (wrist)
    T_board: np.ndarray  # T_link_board (head: board on the gripper) or T_base_board (wrist)
    residual_deg: list[float] = field(default_factory=list)  # per view
    residual_mm: list[float] = field(default_factory=list)

    def to_json(self, link: str, views: list[str]) -> dict:
        key = "T_base_headcam" if self.mount == "head" else f"T_{link}_wristcam"
        board_key = f"T_{link}_board" if self.mount == "head" else "T_base_board"
        return {
            "mount": self.mount,
            "method": self.method,
            "link": link,
            key: self.T.tolist(),
            board_key: self.T_board.tolist(),
            "residual_deg_median": float(np.median(self.residual_deg)),
            "residual_mm_median": float(np.median(self.residual_mm)),
            "per_view": [
                {"image": v, "residual_deg": d, "residual_mm": m}
                for v, d, m in zip(views, self.residual_deg, self.residual_mm, strict=True)
            ],
        }


def _average_pose(Ts: list[np.ndarray]) -> np.ndarray:
    """Chordal mean of rigid poses: mean rotation projected onto SO(3), mean translation."""
    U, _, Vt = np.linalg.svd(sum(T[:3, :3] for T in Ts))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.mean([T[:3, 3] for T in Ts], axis=0)
    return T


def _pose_from_vec(v: np.ndarray) -> np.ndarray:
    import cv2

    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cv2.Rodrigues(v[:3])[0], v[3:]
    return T


def _vec_from_pose(T: np.ndarray) -> np.ndarray:
    import cv2

    return np.concatenate([cv2.Rodrigues(T[:3, :3])[0].ravel(), T[:3, 3]])


def refine_reprojection(
    X: np.ndarray, Y: np.ndarray, T_base_link: list[np.ndarray], observations: list[BoardObservation],
    K: np.ndarray, mount: str,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Jointly refine the camera mount X and the board mount Y by minimising the corner reprojection
    error over all views (robust loss). The closed-form solvers fit pose pairs, so each view's PnP
    depth error goes straight into X; fitting the pixels weighs every corner as it was measured."""
    from scipy.optimize import least_squares

    K = np.asarray(K, dtype=np.float64)

    def residuals(params: np.ndarray) -> np.ndarray:
        Xp, Yp = _pose_from_vec(params[:6]), _pose_from_vec(params[6:])
        out = []
        for Tl, obs in zip(T_base_link, observations, strict=True):
            # camera <- board: head: X^-1 Tl Y (board on the link); wrist: X^-1 Tl^-1 Y (board in the base)
            T_cb = invert_rigid(Xp) @ (Tl if mount == "head" else invert_rigid(Tl)) @ Yp
            p = obs.points_board @ T_cb[:3, :3].T + T_cb[:3, 3]
            uv = p @ K.T
            out.append((uv[:, :2] / uv[:, 2:] - obs.uv).ravel())
        return np.concatenate(out)

    x0 = np.concatenate([_vec_from_pose(X), _vec_from_pose(Y)])
    sol = least_squares(residuals, x0, loss="huber", f_scale=1.0, x_scale="jac")
    return _pose_from_vec(sol.x[:6]), _pose_from_vec(sol.x[6:])


def calibrate_handeye(
    T_base_link: list[np.ndarray],
    T_cam_board: list[np.ndarray],
    mount: str = "head",
    method: str = "tsai",
    observations: list[BoardObservation] | None = None,
    K: np.ndarray | None = None,
) -> HandEyeResult:
    """Solve hand-eye from N >= 3 pairs (gripper link pose in the base, board pose in the camera).
    With ``observations`` and ``K`` the closed-form solution is refined on the corner pixels."""
    import cv2

    if mount not in ("head", "wrist"):
        raise HandEyeError(f"mount must be 'head' or 'wrist', got {mount!r}")
    if method not in METHODS:
        raise HandEyeError(f"unknown hand-eye method {method!r}; choose one of {', '.join(METHODS)}")
    if len(T_base_link) != len(T_cam_board):
        raise HandEyeError(f"{len(T_base_link)} robot poses but {len(T_cam_board)} board poses; they must pair up")
    if len(T_base_link) < 3:
        raise HandEyeError(f"hand-eye needs at least 3 views with the board detected, got {len(T_base_link)}")
    check_motion_diversity(T_base_link)
    # eye-in-hand takes gripper->base; eye-to-hand the same with the gripper poses inverted
    motions = T_base_link if mount == "wrist" else [invert_rigid(T) for T in T_base_link]
    flag = getattr(cv2, f"CALIB_HAND_EYE_{method.upper()}")
    R, t = cv2.calibrateHandEye(
        [T[:3, :3] for T in motions], [T[:3, 3] for T in motions],
        [T[:3, :3] for T in T_cam_board], [T[:3, 3] for T in T_cam_board], method=flag,
    )  # fmt: skip
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, t.ravel()
    # The other unknown (where the board is) and the per-view disagreement of the loop
    # base -> link -> board vs base -> camera -> board (head) / base -> board vs link -> camera -> board (wrist).
    if mount == "head":
        T_board = _average_pose([invert_rigid(Tl) @ X @ Tc for Tl, Tc in zip(T_base_link, T_cam_board, strict=True)])
        pairs = [(X @ Tc, Tl @ T_board) for Tl, Tc in zip(T_base_link, T_cam_board, strict=True)]
    else:
        T_board = _average_pose([Tl @ X @ Tc for Tl, Tc in zip(T_base_link, T_cam_board, strict=True)])
        pairs = [(Tl @ X @ Tc, T_board) for Tl, Tc in zip(T_base_link, T_cam_board, strict=True)]
    if observations is not None and K is not None:
        X, T_board = refine_reprojection(X, T_board, T_base_link, observations, K, mount)
        if mount == "head":
            pairs = [(X @ Tc, Tl @ T_board) for Tl, Tc in zip(T_base_link, T_cam_board, strict=True)]
        else:
            pairs = [(Tl @ X @ Tc, T_board) for Tl, Tc in zip(T_base_link, T_cam_board, strict=True)]
    deg = [float(np.degrees(rotation_angle(A[:3, :3].T @ B[:3, :3]))) for A, B in pairs]
    mm = [float(1000 * np.linalg.norm(A[:3, 3] - B[:3, 3])) for A, B in pairs]
    return HandEyeResult(mount, method, X, T_board, deg, mm)


def calibrate_from_files(
    images_dir: str | Path,
    joints_file: str | Path,
    board: BoardSpec,
    K: np.ndarray,
    mount: str = "head",
    method: str = "tsai",
    robot: str | None = None,
    link: str | None = None,
    refine: bool = True,
) -> tuple[HandEyeResult, dict]:
    """Detect the board in every image of ``joints_file`` (``{"robot", "link", "views": [{"image",
    "joints"}]}``, image paths relative to ``images_dir``), run forward kinematics, solve.
    Returns the result and its JSON (with the images used and those skipped)."""
    from ..inputs import InputError, check_joints, read_image_rgb, read_json
    from ..robots import DEFAULT_ROBOT, get_robot
    from .kinematics import RobotKinematics

    joints_file, images_dir = Path(joints_file), Path(images_dir)
    try:
        spec = read_json(joints_file, "joints file")
    except InputError as e:
        raise HandEyeError(str(e)) from None
    views = spec.get("views")
    if not isinstance(views, list) or not all(isinstance(v, dict) and "image" in v and "joints" in v for v in views):
        raise HandEyeError(f"{joints_file}: expected {{'views': [{{'image': NAME, 'joints': [...]}}, ...]}} (joint "
                           "angles in radians, one list per image)")  # fmt: skip
    if not images_dir.is_dir():
        raise HandEyeError(f"{images_dir}: not a folder of board images")
    images = sorted(p for p in images_dir.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    if len(images) != len(views):
        raise HandEyeError(
            f"{images_dir} holds {len(images)} images but {joints_file} lists {len(views)} joint sets; "
            "give one joint set per image"
        )
    default = get_robot(DEFAULT_ROBOT)
    kin = RobotKinematics(robot or spec.get("robot", default.model))
    link = link or spec.get("link", default.ee_link)
    n_chain, limits = kin.chain(link)
    used, skipped, T_links, observations = [], [], [], []
    for i, view in enumerate(views):
        name = Path(str(view["image"])).name
        path = images_dir / name
        if not path.is_file():
            raise HandEyeError(f"{joints_file} names image {name}, which is not in {images_dir}")
        q = view["joints"]
        try:  # the joints that move the link: a view missing some is a different pose, not a rounding
            if isinstance(q, list) and len(q) >= n_chain:
                q = q[:n_chain]
            check_joints(q, tuple(f"{k + 1}" for k in range(n_chain)), limits, f"{joints_file}: views[{i}] ({name})")
        except InputError as e:
            raise HandEyeError(f"{e}; {link} is moved by the first {n_chain} joints of {kin.path.name}") from None
        obs = detect_board_pose(read_image_rgb(path, "board image"), board, K)
        if obs is None:
            skipped.append(name)
            continue
        used.append(name)
        T_links.append(kin.link_pose(view["joints"], link))
        observations.append(obs)
    if len(used) < 3:
        raise HandEyeError(
            f"the board ({board.squares_x}x{board.squares_y}, {board.square * 100:g} cm squares, {board.dictionary}) "
            f"was found in only {len(used)} of {len(views)} images in {images_dir}; tried: "
            f"{', '.join(skipped[:8])}{' ...' if len(skipped) > 8 else ''}. Check the board spec and lighting"
        )
    T_cams = [o.T_cam_board for o in observations]
    result = calibrate_handeye(T_links, T_cams, mount, method, observations=observations if refine else None, K=K)
    out = result.to_json(link, used)
    out.update(robot=str(kin.path), skipped=skipped, board=board.to_json(), K=np.asarray(K).tolist(), refined=refine)
    return result, out
