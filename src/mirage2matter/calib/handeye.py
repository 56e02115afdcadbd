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
from ..inputs import InputError, check_joints, read_image_rgb, read_json
from ..robots import DEFAULT_ROBOT, get_robot, is_spec_file
from ..robots.kinematics import KinematicsError, RobotKinematics, robot_model_file

METHODS = ("tsai", "park", "horaud", "andreff", "daniilidis")


class HandEyeError(M2MError, ValueError):
    """Unusable hand-eye data; the message says what to change."""


@dataclass
class BoardObservation:
    """The board in one image: T_cam_board [4,4] by PnP, the corners used (points_board [M,3]) and their pixels
    ``uv`` [M,2] in the *ideal pinhole* camera with the same K (lens distortion removed; our +0.5 convention),
    the pixels as measured ``uv_measured`` [M,2], and the RMS reprojection error of the PnP pose."""

    T_cam_board: np.ndarray
    points_board: np.ndarray
    uv: np.ndarray
    rms_px: float
    uv_measured: np.ndarray | None = None

    @property
    def n_corners(self) -> int:
        return len(self.uv)


def ideal_pixels(camera, uv: np.ndarray) -> np.ndarray:
    """Measured pixels [M,2] -> the pixels an ideal pinhole with the same K would see (our +0.5 convention).
    ``camera``: a Camera (its lens is undone) or a bare K [3,3] (no lens)."""
    uv = np.asarray(uv, np.float64)
    return uv if isinstance(camera, np.ndarray) else camera.undistort_pixels(uv)


def _K_of(camera) -> np.ndarray:
    return np.asarray(camera if isinstance(camera, np.ndarray) else camera.K, dtype=np.float64)


def detect_board_pose(image_rgb: np.ndarray, board, camera, min_corners: int | None = None):
    """Target corners + PnP (IPPE, refined iteratively) on lens-corrected corners. ``camera``: a Camera (K and
    lens, pixel centres at +0.5) or a bare K [3,3] (a distortion-free lens).
    Returns a BoardObservation, or None when fewer than ``min_corners`` corners are found (default: 6, or all four
    of a single marker)."""
    import cv2

    gray = cv2.cvtColor(image_rgb, cv2.COLOR_RGB2GRAY) if image_rgb.ndim == 3 else image_rgb
    ids, img_cv = _detect(board, gray)
    if min_corners is None:
        min_corners = min(6, len(board.points_board()))
    if len(ids) < min_corners:
        return None
    obj = np.asarray(board.points_board(ids), np.float64)
    measured = img_cv.reshape(-1, 2).astype(np.float64) + 0.5  # OpenCV centres at integers -> ours
    uv = ideal_pixels(camera, measured)
    K_cv = opencv_K(_K_of(camera))
    img = uv - 0.5
    flag = cv2.SOLVEPNP_IPPE if _coplanar(obj) else cv2.SOLVEPNP_SQPNP
    ok, rvec, tvec = cv2.solvePnP(obj, img, K_cv, None, flags=flag)
    if not ok:
        return None
    ok, rvec, tvec = cv2.solvePnP(obj, img, K_cv, None, rvec, tvec, True, cv2.SOLVEPNP_ITERATIVE)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K_cv, None)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))
    return BoardObservation(T, obj, uv, rms, measured)


def _coplanar(points: np.ndarray) -> bool:
    return bool(np.ptp(points[:, 2]) < 1e-9)


def _detect(board, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ids [M], uv [M,2] OpenCV convention) of the target's points found in ``gray``."""
    ids, uv = board.detect(gray)
    return np.asarray(ids, np.int64).ravel(), np.asarray(uv, np.float64).reshape(-1, 2)


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
    """The camera mount ``T`` (T_base_headcam for head, T_link_wristcam for wrist), the board's mount ``T_board``
    (T_link_board for head, T_base_board for wrist), the loop residuals per view, and the quality figure: each
    view's leave-one-out corner error (px: the view's board corners predicted from the other views' calibration
    and the view's robot pose, against where they were seen)."""

    mount: str
    method: str
    T: np.ndarray
    T_board: np.ndarray
    residual_deg: list[float] = field(default_factory=list)  # per view
    residual_mm: list[float] = field(default_factory=list)
    refine: str = "none"  # the variant that produced T
    loo_px: list[float] = field(default_factory=list)  # per view, of the chosen variant (empty: not computed)
    candidates: dict[str, dict] = field(default_factory=dict)  # variant -> {"loo_px_median", "loo_px_p90"}
    outliers: list[int] = field(default_factory=list)  # views whose leave-one-out error stands out

    @property
    def loo_px_median(self) -> float | None:
        return float(np.median(self.loo_px)) if self.loo_px else None

    def to_json(self, link: str, views: list[str]) -> dict:
        key = "T_base_headcam" if self.mount == "head" else f"T_{link}_wristcam"
        board_key = f"T_{link}_board" if self.mount == "head" else "T_base_board"
        loo = self.loo_px or [None] * len(views)
        return {
            "mount": self.mount,
            "method": self.method,
            "refine": self.refine,
            "link": link,
            key: self.T.tolist(),
            board_key: self.T_board.tolist(),
            "loo_px_median": self.loo_px_median,
            "loo_px_p90": float(np.percentile(self.loo_px, 90)) if self.loo_px else None,
            "candidates": self.candidates,
            "outlier_views": [views[i] for i in self.outliers],
            "residual_deg_median": float(np.median(self.residual_deg)),
            "residual_mm_median": float(np.median(self.residual_mm)),
            "per_view": [
                {"image": v, "residual_deg": d, "residual_mm": m, "loo_px": e}
                for v, d, m, e in zip(views, self.residual_deg, self.residual_mm, loo, strict=True)
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


def _T_cam_board(X: np.ndarray, T_link: np.ndarray, Y: np.ndarray, mount: str) -> np.ndarray:
    """camera <- board: head: X^-1 Tl Y (board on the link); wrist: X^-1 Tl^-1 Y (board in the base)."""
    return invert_rigid(X) @ (T_link if mount == "head" else invert_rigid(T_link)) @ Y


def _project(K: np.ndarray, T_cb: np.ndarray, points_board: np.ndarray) -> np.ndarray:
    p = points_board @ T_cb[:3, :3].T + T_cb[:3, 3]
    uv = p @ K.T
    return uv[:, :2] / uv[:, 2:]


def refine_reprojection(
    X: np.ndarray, Y: np.ndarray, T_base_link: list[np.ndarray], observations: list[BoardObservation],
    K: np.ndarray, mount: str,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Jointly refine the camera mount X and the board mount Y by minimising the corner reprojection
    error over all views (robust loss), taking the robot's poses as exact ("exact" variant).

    On a real arm this is the wrong model: each view's pose error shows as an image shift, and the joint fit of
    X and Y has a nearly flat direction it slides along to absorb those shifts (measured on a real wrist camera:
    18 mm from an independent calibration, against 1.3 mm for the closed form on the same corners). Kept for
    comparison; :func:`refine_with_pose_error` models the error."""
    from scipy.optimize import least_squares

    K = np.asarray(K, dtype=np.float64)

    def residuals(params: np.ndarray) -> np.ndarray:
        Xp, Yp = X @ _pose_from_vec(params[:6]), Y @ _pose_from_vec(params[6:])
        return np.concatenate([(_project(K, _T_cam_board(Xp, Tl, Yp, mount), o.points_board) - o.uv).ravel()
                               for Tl, o in zip(T_base_link, observations, strict=True)])  # fmt: skip

    # increments on the start (a rotation vector of the pose itself is singular near a half turn)
    sol = least_squares(residuals, np.zeros(12), loss="huber", f_scale=1.0, x_scale="jac")
    return X @ _pose_from_vec(sol.x[:6]), Y @ _pose_from_vec(sol.x[6:])


# The robot's pose error the robust refinement expects (1 sigma, per view): absolute accuracy of a calibrated
# industrial/cobot arm is about a millimetre and a tenth of a degree at the flange (repeatability is 10x better,
# but the error that matters here is the model's: joint offsets, link lengths, compliance).
POSE_SIGMA_MM = 1.0
POSE_SIGMA_DEG = 0.1
PIXEL_SIGMA = 0.5  # corner detection noise (px)


def refine_with_pose_error(
    X: np.ndarray, Y: np.ndarray, T_base_link: list[np.ndarray], observations: list[BoardObservation],
    K: np.ndarray, mount: str, sigma_mm: float = POSE_SIGMA_MM, sigma_deg: float = POSE_SIGMA_DEG,
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:  # fmt: skip
    """Refine X and Y on the corner pixels with each view's robot pose error E_i modelled (the arm was at
    T_i E_i, not at T_i): a maximum a posteriori fit with a Gaussian prior of ``sigma_mm`` / ``sigma_deg`` on each
    E_i and a robust (Huber) loss on the pixels. A view's shift is explained by its own pose error, so it no longer
    drags X and Y along their nearly flat direction. Returns (X, Y, [E_i])."""
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    K = np.asarray(K, dtype=np.float64)
    n = len(observations)
    w_rot, w_t = 1.0 / np.radians(sigma_deg), 1.0 / (sigma_mm / 1000.0)
    sizes = [2 * o.n_corners for o in observations]

    def residuals(params: np.ndarray) -> np.ndarray:
        Xp, Yp = X @ _pose_from_vec(params[:6]), Y @ _pose_from_vec(params[6:12])
        out = []
        for i, (Tl, o) in enumerate(zip(T_base_link, observations, strict=True)):
            e = params[12 + 6 * i : 18 + 6 * i]
            T_true = Tl @ _pose_from_vec(e)
            out.append((_project(K, _T_cam_board(Xp, T_true, Yp, mount), o.points_board) - o.uv).ravel() / PIXEL_SIGMA)
        priors = params[12:].reshape(n, 6) * np.array([w_rot] * 3 + [w_t] * 3)
        return np.concatenate([*out, priors.ravel()])

    # each view's pixels depend on X, Y and its own E only: a sparse Jacobian keeps this fast for many views
    rows = sum(sizes) + 6 * n
    sparsity = lil_matrix((rows, 12 + 6 * n), dtype=int)
    r0 = 0
    for i, m in enumerate(sizes):
        sparsity[r0 : r0 + m, :12] = 1
        sparsity[r0 : r0 + m, 12 + 6 * i : 18 + 6 * i] = 1
        r0 += m
    for i in range(n):
        sparsity[r0 + 6 * i : r0 + 6 * i + 6, 12 + 6 * i : 18 + 6 * i] = 1
    # X and Y as increments on the start (a rotation vector of the pose itself is singular near a half turn).
    # A plain least-squares loss: with each view's error modelled the residuals are detection noise; a robust loss
    # with Jacobian scaling crawled along the flat direction (200+ evaluations against 6). Outlying views are named
    # by their leave-one-out error instead.
    sol = least_squares(residuals, np.zeros(12 + 6 * n), jac_sparsity=sparsity, method="trf")
    E = [_pose_from_vec(sol.x[12 + 6 * i : 18 + 6 * i]) for i in range(n)]
    return X @ _pose_from_vec(sol.x[:6]), Y @ _pose_from_vec(sol.x[6:12]), E


def _closed_form(T_base_link: list[np.ndarray], T_cam_board: list[np.ndarray], mount: str, method: str):
    """OpenCV's closed-form solver -> (X, Y)."""
    import cv2

    # eye-in-hand takes gripper->base; eye-to-hand the same with the gripper poses inverted
    motions = T_base_link if mount == "wrist" else [invert_rigid(T) for T in T_base_link]
    flag = getattr(cv2, f"CALIB_HAND_EYE_{method.upper()}")
    R, t = cv2.calibrateHandEye(
        [T[:3, :3] for T in motions], [T[:3, 3] for T in motions],
        [T[:3, :3] for T in T_cam_board], [T[:3, 3] for T in T_cam_board], method=flag,
    )  # fmt: skip
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, t.ravel()
    # the other unknown (where the board is): the mean over views of the loop's prediction
    if mount == "head":
        Y = _average_pose([invert_rigid(Tl) @ X @ Tc for Tl, Tc in zip(T_base_link, T_cam_board, strict=True)])
    else:
        Y = _average_pose([Tl @ X @ Tc for Tl, Tc in zip(T_base_link, T_cam_board, strict=True)])
    return X, Y


REFINE_VARIANTS = ("auto", "pose_error", "exact", "none")


def _solve(T_base_link, observations, T_cam_board, mount, method, variant, K, x0=None):
    if x0 is None:
        X, Y = _closed_form(T_base_link, T_cam_board, mount, method)
    else:
        X, Y = x0
    if variant == "pose_error":
        X, Y, _ = refine_with_pose_error(X, Y, T_base_link, observations, K, mount)
    elif variant == "exact":
        X, Y = refine_reprojection(X, Y, T_base_link, observations, K, mount)
    return X, Y


def leave_one_out(
    T_base_link: list[np.ndarray], observations: list[BoardObservation], mount: str, method: str, variant: str,
    K: np.ndarray, start: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[float]:  # fmt: skip
    """Each view's RMS corner error (px) predicted from a calibration on the other views and the view's robot
    pose: the error a user meets when the calibration places the camera in a new pose."""
    out = []
    for k in range(len(observations)):
        keep = [i for i in range(len(observations)) if i != k]
        Tl = [T_base_link[i] for i in keep]
        obs = [observations[i] for i in keep]
        x0 = start if variant != "none" else None  # refinements start at the full fit: same minimum, faster
        X, Y = _solve(Tl, obs, [o.T_cam_board for o in obs], mount, method, variant, K, x0)
        o = observations[k]
        uv = _project(K, _T_cam_board(X, T_base_link[k], Y, mount), o.points_board)
        out.append(float(np.sqrt(np.mean(np.sum((uv - o.uv) ** 2, axis=1)))))
    return out


def _loop_residuals(X, Y, T_base_link, T_cam_board, mount) -> tuple[list[float], list[float]]:
    """Per view, the disagreement of base -> link -> board with base -> camera -> board (degrees, mm)."""
    if mount == "head":
        pairs = [(X @ Tc, Tl @ Y) for Tl, Tc in zip(T_base_link, T_cam_board, strict=True)]
    else:
        pairs = [(Tl @ X @ Tc, Y) for Tl, Tc in zip(T_base_link, T_cam_board, strict=True)]
    deg = [float(np.degrees(rotation_angle(A[:3, :3].T @ B[:3, :3]))) for A, B in pairs]
    mm = [float(1000 * np.linalg.norm(A[:3, 3] - B[:3, 3])) for A, B in pairs]
    return deg, mm


# What a mount can physically be: a wrist camera sits on the hand, a head camera and a table board within a
# room's reach of the base, a held board near the hand; and the loop closes to about a centimetre and a degree.
MAX_WRIST_OFFSET_M = 0.3
MAX_BASE_DISTANCE_M = 4.0
MAX_HELD_BOARD_M = 0.5
MAX_LOOP_MM = 15.0
MAX_LOOP_DEG = 2.0


def implausibility(X, Y, residual_deg, residual_mm, mount) -> str | None:
    """Why a calibration cannot be physical (None when it can)."""
    loop_mm, loop_deg = float(np.median(residual_mm)), float(np.median(residual_deg))
    if loop_mm > MAX_LOOP_MM or loop_deg > MAX_LOOP_DEG:
        return f"the views disagree by {loop_deg:.1f} deg / {loop_mm:.0f} mm (median; good: < 1 deg, 5 mm)"
    cam, board = float(np.linalg.norm(X[:3, 3])), float(np.linalg.norm(Y[:3, 3]))
    if mount == "wrist" and cam > MAX_WRIST_OFFSET_M:
        return f"the camera would sit {cam:.2f} m from the hand"
    if mount == "wrist" and board > MAX_BASE_DISTANCE_M:
        return f"the board would lie {board:.1f} m from the robot base"
    if mount == "head" and cam > MAX_BASE_DISTANCE_M:
        return f"the camera would stand {cam:.1f} m from the robot base"
    if mount == "head" and board > MAX_HELD_BOARD_M:
        return f"the held board would be {board:.2f} m from the hand"
    return None


def calibrate_handeye(
    T_base_link: list[np.ndarray],
    T_cam_board: list[np.ndarray],
    mount: str = "head",
    method: str = "tsai",
    observations: list[BoardObservation] | None = None,
    K: np.ndarray | None = None,
    refine: str = "auto",
) -> HandEyeResult:
    """Solve hand-eye from N >= 3 pairs (gripper link pose in the base, board pose in the camera).

    With ``observations`` and ``K`` the corner pixels are used too (``refine``):
    - "pose_error": the closed form refined on the pixels with each view's robot pose error modelled;
    - "exact": refined taking the robot poses as exact (the former default; see :func:`refine_reprojection`);
    - "none": the closed form alone;
    - "auto" (default): "pose_error" or "none", whichever predicts held-out views better (leave-one-out corner
      error): a wrong error model shows there, and it is the error users meet.
    The leave-one-out error of the chosen variant is reported per view; views whose error stands out are named.
    """
    if mount not in ("head", "wrist"):
        raise HandEyeError(f"mount must be 'head' or 'wrist', got {mount!r}")
    if method not in METHODS:
        raise HandEyeError(f"unknown hand-eye method {method!r}; choose one of {', '.join(METHODS)}")
    if refine not in REFINE_VARIANTS:
        raise HandEyeError(f"unknown refinement {refine!r}; choose one of {', '.join(REFINE_VARIANTS)}")
    if len(T_base_link) != len(T_cam_board):
        raise HandEyeError(f"{len(T_base_link)} robot poses but {len(T_cam_board)} board poses; they must pair up")
    if len(T_base_link) < 3:
        raise HandEyeError(f"hand-eye needs at least 3 views with the board detected, got {len(T_base_link)}")
    check_motion_diversity(T_base_link)
    X0, Y0 = _closed_form(T_base_link, T_cam_board, mount, method)
    pixels = observations is not None and K is not None
    variant = refine if pixels else "none"
    why = implausibility(X0, Y0, *_loop_residuals(X0, Y0, T_base_link, T_cam_board, mount), mount)
    if why is not None:
        _explain_implausible(why, T_base_link, T_cam_board, mount, method)
    candidates: dict[str, dict] = {}
    loo: list[float] = []
    if variant == "auto":
        results = {}
        for v in ("none", "pose_error"):
            X, Y = (X0, Y0) if v == "none" else _solve(T_base_link, observations, T_cam_board, mount, method, v, K,
                                                       (X0, Y0))  # fmt: skip
            errs = leave_one_out(T_base_link, observations, mount, method, v, K, start=(X, Y))
            results[v] = (X, Y, errs)
            candidates[v] = {"loo_px_median": float(np.median(errs)), "loo_px_p90": float(np.percentile(errs, 90))}
        # the modelled refinement unless the closed form predicts held-out views clearly better (5 %)
        variant = "none" if candidates["none"]["loo_px_median"] < 0.95 * candidates["pose_error"]["loo_px_median"] \
            else "pose_error"  # fmt: skip
        X, Y, loo = results[variant]
    else:
        X, Y = (X0, Y0) if variant == "none" else _solve(T_base_link, observations, T_cam_board, mount, method,
                                                          variant, K, (X0, Y0))  # fmt: skip
        if pixels:
            loo = leave_one_out(T_base_link, observations, mount, method, variant, K, start=(X, Y))
            candidates[variant] = {"loo_px_median": float(np.median(loo)), "loo_px_p90": float(np.percentile(loo, 90))}
    deg, mm = _loop_residuals(X, Y, T_base_link, T_cam_board, mount)
    outliers = []
    if loo:
        med = float(np.median(loo))
        outliers = [i for i, e in enumerate(loo) if e > max(3.0 * med, med + 3.0)]
    return HandEyeResult(mount, method, X, Y, deg, mm, variant, loo, candidates, outliers)


def disagreeing_view(T_base_link: list[np.ndarray], T_cam_board: list[np.ndarray], mount: str,
                     method: str) -> int | None:  # fmt: skip
    """The one view whose robot pose disagrees with the rest: the index of the view without which the closed form is
    plausible with the smallest loop residual, when the whole set is not; None when no single view explains it."""
    if len(T_base_link) < 5:  # too few to outvote one
        return None
    best, best_deg = None, np.inf
    for i in range(len(T_base_link)):
        Ts, Cs = T_base_link[:i] + T_base_link[i + 1 :], T_cam_board[:i] + T_cam_board[i + 1 :]
        X, Y = _closed_form(Ts, Cs, mount, method)
        deg, mm = _loop_residuals(X, Y, Ts, Cs, mount)
        if implausibility(X, Y, deg, mm, mount) is None and float(np.median(deg)) < best_deg:
            best, best_deg = i, float(np.median(deg))
    return best


def _explain_implausible(why: str, T_base_link, T_cam_board, mount: str, method: str) -> None:
    """Raise the HandEyeError for an unphysical closed-form result, naming the likelier mount when it fits."""
    other = "wrist" if mount == "head" else "head"
    X, Y = _closed_form(T_base_link, T_cam_board, other, method)
    if implausibility(X, Y, *_loop_residuals(X, Y, T_base_link, T_cam_board, other), other) is None:
        raise HandEyeError(
            f"as a {mount} camera the calibration is not physical: {why}. The data fit a {other} camera "
            f"({'camera on the hand, board fixed' if other == 'wrist' else 'camera fixed, board on the hand'}): "
            f"rerun with --mount {other}"
        )
    raise HandEyeError(
        f"the calibration is not physical as a {mount} camera ({why}), nor as a {other} camera. Check that the "
        "joint angles (or hand poses) are listed in the images' order and in the stated units, that the link is "
        "the one holding the camera or board, and the board spec"
    )


POSES_HELP = (
    "a JSON {'robot': ROBOT (optional: a robot name, a robot spec file or a model file), 'link': LINK (optional), "
    "'units': {'position': 'm'|'mm', 'rotation': 'rad'|'deg', 'joints': 'rad'|'deg'} (optional; default m, rad, "
    "rad), 'views': [one per image: {'image': NAME, "
    "and either 'joints': [angles] (forward kinematics of the robot model), or the link's pose in the base: "
    "'T_base_link' (or 'T_base_<link>') 4x4, or 'position' [x, y, z] with 'quaternion_xyzw' or 'quaternion_wxyz' "
    "[4] or 'rpy' [roll, pitch, yaw] (fixed axes x, y, z: R = Rz(yaw) Ry(pitch) Rx(roll), as ROS) or "
    "'rotation_vector' [rx, ry, rz] (axis times angle, as UR's controller)}], 'base_frame': FRAME (optional: the frame "
    "the poses are in, a link or named frame fixed to the base, e.g. the UR5e's ur_base; default the model's base)}"
)


def _units(spec: dict, where: str) -> dict[str, str]:
    units = {"position": "m", "rotation": "rad", "joints": "rad"}
    given = spec.get("units", {})
    if not isinstance(given, dict):
        raise HandEyeError(f"{where}: units must be an object like {{'position': 'mm', 'rotation': 'deg'}}")
    allowed = {"position": ("m", "mm"), "rotation": ("rad", "deg"), "joints": ("rad", "deg")}
    for k, v in given.items():
        if k not in allowed or v not in allowed[k]:
            raise HandEyeError(f"{where}: units.{k} = {v!r}; allowed: " +
                               "; ".join(f"{a}: {'|'.join(b)}" for a, b in allowed.items()))  # fmt: skip
        units[k] = v
    return units


def _numbers(value, n: int, where: str, name: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (n,) or not np.isfinite(a).all():
        raise HandEyeError(f"{where}: {name} must be {n} finite numbers, got {value!r}")
    return a


def hand_pose_from_view(view: dict, link: str, units: dict[str, str], where: str) -> np.ndarray | None:
    """T_base_link [4,4] from a view's end-effector pose fields, in metres and radians (None: the view has none)."""
    from scipy.spatial.transform import Rotation

    scale = 0.001 if units["position"] == "mm" else 1.0
    for key in ("T_base_link", f"T_base_{link}"):
        if key in view:
            try:
                T = np.asarray(view[key], dtype=np.float64)
            except (TypeError, ValueError):
                T = None
            if T is None or T.shape != (4, 4) or not np.isfinite(T).all():
                raise HandEyeError(f"{where}: {key} must be a 4x4 matrix of numbers")
            R = T[:3, :3]
            if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
                raise HandEyeError(f"{where}: {key} is not a rigid transform (its rotation is not orthonormal)")
            T = T.copy()
            T[:3, 3] *= scale
            return _checked_position(T, units, where)
    if "position" not in view:
        return None
    p = _numbers(view["position"], 3, where, "position") * scale
    rot_keys = [k for k in ("quaternion_xyzw", "quaternion_wxyz", "rpy", "rotation_vector", "quaternion") if k in view]
    if len(rot_keys) != 1:
        raise HandEyeError(f"{where}: a position needs exactly one of quaternion_xyzw, quaternion_wxyz, rpy or "
                           f"rotation_vector (found {rot_keys or 'none'})")  # fmt: skip
    key = rot_keys[0]
    if key == "quaternion":
        raise HandEyeError(f"{where}: 'quaternion' is ambiguous (x, y, z, w as ROS and scipy, or w, x, y, z as "
                           "Eigen and MuJoCo); name it quaternion_xyzw or quaternion_wxyz")  # fmt: skip
    if key == "rpy":
        rpy = _numbers(view["rpy"], 3, where, "rpy")
        if units["rotation"] == "rad" and np.abs(rpy).max() > 2 * np.pi + 1e-6:
            raise HandEyeError(f"{where}: rpy {rpy.tolist()} exceeds 2 pi: degrees? set units.rotation to 'deg'")
        R = Rotation.from_euler("xyz", rpy, degrees=units["rotation"] == "deg").as_matrix()
    elif key == "rotation_vector":
        rv = _numbers(view[key], 3, where, key)
        if units["rotation"] == "rad" and np.linalg.norm(rv) > 2 * np.pi + 1e-6:
            raise HandEyeError(f"{where}: rotation_vector {rv.tolist()} turns more than 2 pi: degrees? set "
                               "units.rotation to 'deg'")  # fmt: skip
        R = Rotation.from_rotvec(rv, degrees=units["rotation"] == "deg").as_matrix()
    else:
        q = _numbers(view[key], 4, where, key)
        if abs(np.linalg.norm(q) - 1.0) > 1e-2:
            raise HandEyeError(f"{where}: {key} has norm {np.linalg.norm(q):.3f}, not a unit quaternion")
        R = Rotation.from_quat(q if key == "quaternion_xyzw" else np.roll(q, -1)).as_matrix()
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return _checked_position(T, units, where)


def _checked_position(T: np.ndarray, units: dict[str, str], where: str) -> np.ndarray:
    d = float(np.linalg.norm(T[:3, 3]))
    if d > MAX_BASE_DISTANCE_M:  # no arm reaches 4 m: the numbers are millimetres
        raise HandEyeError(
            f"{where}: the hand would be {d:.1f} m from the base; are the positions in millimetres? set "
            "units.position to 'mm'" if units["position"] == "m" else f"{where}: the hand would be {d:.1f} m from "
            "the base; check the positions' units"
        )
    return T


def _read_poses_file(joints_file: str | Path) -> tuple[dict, list[dict], dict]:
    """(the robot poses file, its views, its units), its shape checked (see :data:`POSES_HELP`)."""
    try:
        spec = read_json(joints_file, "robot poses file")
    except InputError as e:
        raise HandEyeError(str(e)) from None
    views = spec.get("views")
    if not isinstance(views, list) or not views or not all(isinstance(v, dict) and "image" in v for v in views):
        raise HandEyeError(f"{joints_file}: expected {POSES_HELP}")
    return spec, views, _units(spec, str(joints_file))


def check_poses_file(joints_file: str | Path) -> None:
    """The robot poses file's shape and values without its images or the robot (what ``m2m init`` checks before
    anything runs): views, units, and every number of every view finite (JSON readers take NaN)."""
    _, views, units = _read_poses_file(joints_file)
    for i, view in enumerate(views):
        where = f"{joints_file}: views[{i}] ({view['image']})"
        if "joints" in view:
            q = view["joints"]
            if not isinstance(q, list) or not q:
                raise HandEyeError(f"{where}: joints must be a list of numbers, got {q!r}")
            _numbers(q, len(q), where, "joints" + (" (degrees)" if units["joints"] == "deg" else ""))
        for key in [k for k in view
                    if k == "position" or str(k).startswith(("T_base_", "quaternion", "rpy", "rotation_vector"))]:
            try:
                ok = np.isfinite(np.asarray(view[key], dtype=np.float64)).all()
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise HandEyeError(f"{where}: {key} must be finite numbers, got {view[key]!r}")


def _robot_link_joints(spec: dict, views: list[dict], robot: str | None, link: str | None,
                       poses: str) -> tuple[str, str, bool]:
    """(the robot, the link, whether the views' joint angles are used) as the settings and the poses file decide: the
    given robot, else the file's, else the default robot (a name, a spec file or a model file); the given link, else
    the file's, else the robot's end-effector link; joint angles when ``poses`` says so, or ("auto") when every view
    has them."""
    robot = robot or spec.get("robot") or DEFAULT_ROBOT
    names_robot = is_spec_file(robot) or not Path(str(robot)).suffix
    link = link or spec.get("link") or get_robot(robot if names_robot else DEFAULT_ROBOT).ee_link
    return robot, link, poses == "joints" or (poses == "auto" and all("joints" in v for v in views))


def base_frame_pose(robot: str, spec: dict, where: str) -> np.ndarray | None:
    """T_base_frame [4,4] of the poses file's ``base_frame`` (the frame its end-effector poses are in; a robot's
    controller may report them in its own base frame, as UR's does), or None when the file names none. It must be a
    link or a named frame that no joint moves (HandEyeError naming it otherwise)."""
    name = spec.get("base_frame")
    if name is None:
        return None
    if not isinstance(name, str) or not name:
        raise HandEyeError(f"{where}: base_frame must be the name of a frame, got {name!r}")
    kin = RobotKinematics(robot)
    try:
        T_base_frame = kin.fixed_pose(name)
    except KinematicsError as e:
        raise HandEyeError(f"{where}: base_frame: {e}") from None
    if T_base_frame is None:
        n = kin.chain(name)[0]
        raise HandEyeError(f"{where}: base_frame {name!r} moves with the first {n} joints; the poses' frame must be "
                           "fixed to the robot's base (a controller's base frame, such as the UR5e's ur_base)")
    return T_base_frame


def check_poses_link(joints_file: str | Path, robot: str | None = None, link: str | None = None,
                     poses: str = "auto") -> None:
    """Where the views give joint angles (``poses``, as :func:`calibrate_from_files` decides), the link forward
    kinematics reaches (``link``, else the file's, else the robot's end-effector link) must be a link of the robot's
    model or a frame its spec names: what ``m2m init`` checks before anything runs (the stage would fail after the
    capture's stages). HandEyeError naming both otherwise; a file that does not read is :func:`check_poses_file`'s to
    name."""
    try:
        spec, views, _ = _read_poses_file(joints_file)
    except HandEyeError:
        return
    robot, link, use_joints = _robot_link_joints(spec, views, robot, link, poses)
    if not use_joints:
        base_frame_pose(robot, spec, str(joints_file))
        return  # end-effector poses: any frame calibrates (the world says where it can mount it)
    try:
        RobotKinematics(robot).frame(str(link))
    except KinematicsError as e:
        raise HandEyeError(f"{joints_file}: the views give joint angles, so forward kinematics must reach the link: "
                           f"{e}; set the file's \"link\" or --handeye.link") from None  # fmt: skip


def calibrate_from_files(
    images_dir: str | Path,
    joints_file: str | Path,
    board,
    camera,
    mount: str = "head",
    method: str = "tsai",
    robot: str | None = None,
    link: str | None = None,
    refine: str = "auto",
    poses: str = "auto",
) -> tuple[HandEyeResult, dict]:
    """Detect the board in every image of ``joints_file`` (see :data:`POSES_HELP`; image paths relative to
    ``images_dir``), take each view's hand pose from its joints (forward kinematics) or its end-effector pose
    (``poses``: "joints", "ee", or "auto": joints when every view has them), solve.
    ``camera``: a Camera (K + lens) or a bare K [3,3]. Returns the result and its JSON."""

    if refine is True or refine is False:  # the former boolean option
        refine = "exact" if refine else "none"
    if poses not in ("auto", "joints", "ee"):
        raise HandEyeError(f"poses must be auto, joints or ee, got {poses!r}")
    joints_file, images_dir = Path(joints_file), Path(images_dir)
    spec, views, units = _read_poses_file(joints_file)
    if not images_dir.is_dir():
        raise HandEyeError(f"{images_dir}: not a folder of board images")
    images = sorted(p for p in images_dir.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    if len(images) != len(views):
        raise HandEyeError(
            f"{images_dir} holds {len(images)} images but {joints_file} lists {len(views)} robot poses; "
            "give one pose per image"
        )
    named = spec.get("robot")
    if robot and named and robot_model_file(robot) != robot_model_file(named):
        # the pipeline's robot is a setting with a default: a joints file of another robot is a mistake to name, not
        # one to calibrate through (the wrong arm's kinematics give a wrong mount and no error)
        raise HandEyeError(f"{joints_file} names the robot {named!r} but the calibration was given {robot!r}; give "
                           f"the robot the images show (`--robot`, or m2m.yaml's top-level robot)")  # fmt: skip
    robot, link, use_joints = _robot_link_joints(spec, views, robot, link, poses)
    if use_joints and not all("joints" in v for v in views):
        missing = next(i for i, v in enumerate(views) if "joints" not in v)
        raise HandEyeError(f"{joints_file}: views[{missing}] has no 'joints'; give joints for every view or "
                           "end-effector poses (poses: ee)")  # fmt: skip
    kin, T_base_frame = None, None
    if use_joints:
        kin = RobotKinematics(robot)
        n_chain, limits = kin.chain(link)
    else:
        T_base_frame = base_frame_pose(robot, spec, str(joints_file))
    w, h = _image_size(camera)
    used, skipped, T_links, observations = [], [], [], []
    for i, view in enumerate(views):
        name = Path(str(view["image"])).name
        where = f"{joints_file}: views[{i}] ({name})"
        path = images_dir / name
        if not path.is_file():
            raise HandEyeError(f"{joints_file} names image {name}, which is not in {images_dir}")
        if use_joints:
            q = view["joints"]
            if isinstance(q, list) and units["joints"] == "deg":
                q = [np.radians(v) if isinstance(v, int | float) and not isinstance(v, bool) else v for v in q]
            try:  # the joints that move the link: a view missing some is a different pose, not a rounding
                if isinstance(q, list) and len(q) >= n_chain:
                    q = q[:n_chain]
                check_joints(q, tuple(f"{k + 1}" for k in range(n_chain)), limits, where)
            except InputError as e:
                hint = " (degrees? set units.joints to 'deg')" if "outside its limits" in str(e) else ""
                raise HandEyeError(f"{e}{hint}; {link} is moved by the first {n_chain} joints of {kin.path.name}") \
                    from None  # fmt: skip
            T_link = kin.link_pose(q, link)
        else:
            T_link = hand_pose_from_view(view, link, units, where)
            if T_link is None:
                other = sorted(k for k in view if str(k).startswith("T_base_"))
                hint = (f" ({', '.join(other)} is another link's pose: set the file's \"link\" or --link to "
                        f"{other[0].removeprefix('T_base_')!r})" if other else "")  # fmt: skip
                raise HandEyeError(f"{where}: no pose of link {link!r}{hint}; expected {POSES_HELP}")
            if T_base_frame is not None:
                T_link = T_base_frame @ T_link
        image = read_image_rgb(path, "board image")
        if w is not None and image.shape[:2] != (h, w):
            raise HandEyeError(f"{path} is {image.shape[1]}x{image.shape[0]} but the intrinsics are for {w}x{h}; give "
                               "the intrinsics of the images' own resolution")  # fmt: skip
        obs = detect_board_pose(image, board, camera)
        if obs is None:
            skipped.append(name)
            continue
        used.append(name)
        T_links.append(T_link)
        observations.append(obs)
    if len(used) < 3:
        raise HandEyeError(
            f"the board ({board.describe()}) was found in only {len(used)} of {len(views)} images in {images_dir}; "
            f"tried: {', '.join(skipped[:8])}{' ...' if len(skipped) > 8 else ''}. Check the board spec and lighting"
        )
    K = _K_of(camera)
    T_cams = [o.T_cam_board for o in observations]
    try:
        result = calibrate_handeye(T_links, T_cams, mount, method, observations=observations, K=K, refine=refine)
    except HandEyeError as e:
        odd = disagreeing_view(T_links, T_cams, mount, method)
        if odd is None:
            raise
        raise HandEyeError(f"view {used[odd]} disagrees with the rest: without it the {len(used) - 1} others fit one "
                           f"camera mount ({e}). Check that view's robot pose in {joints_file} (a joint mistyped or "
                           "logged at another moment), or remove the view from both") from None  # fmt: skip
    out = result.to_json(link, used)
    out.update(robot=str(kin.path) if kin is not None else robot_model_file(robot),
               poses="joints" if use_joints else "ee", base_frame=None if use_joints else spec.get("base_frame"),
               skipped=skipped, board=board.to_json(), K=K.tolist(),
               lens_corrected=bool(not isinstance(camera, np.ndarray) and camera.has_distortion))  # fmt: skip
    return result, out


def _image_size(camera) -> tuple[int | None, int | None]:
    if isinstance(camera, np.ndarray):
        return None, None
    return camera.width, camera.height


