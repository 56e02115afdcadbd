"""Lens distortion on normalised image coordinates (x = X / Z, y = Y / Z), the two models OpenCV calibrates.

- ``"opencv"``: radial-tangential (Brown-Conrady), OpenCV's ``k1 k2 p1 p2 k3`` and its rational ``k4 k5 k6``:
  radial = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6),
  x_d = x radial + 2 p1 x y + p2 (r^2 + 2 x^2), y_d = y radial + p1 (r^2 + 2 y^2) + 2 p2 x y.
- ``"fisheye"``: equidistant (Kannala-Brandt, ``cv2.fisheye``; COLMAP OPENCV_FISHEYE, ROS ``equidistant``,
  RealSense "Kannala Brandt4"): theta = atan(r), theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 +
  k4 theta^8), (x_d, y_d) = theta_d / r (x, y).

Arrays are [N, 2] float64. Pixels and K are the caller's business (:class:`~.camera.Camera`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["FISHEYE_KEYS", "MODELS", "RADTAN_KEYS", "distort", "fisheye_theta", "undistort"]

MODELS = ("opencv", "fisheye")
RADTAN_KEYS = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")  # OpenCV's coefficient order
FISHEYE_KEYS = ("k1", "k2", "k3", "k4")  # cv2.fisheye's order


def _radtan(xy: np.ndarray, c: np.ndarray) -> np.ndarray:
    k1, k2, p1, p2, k3, k4, k5, k6 = np.r_[c, np.zeros(8 - len(c))]
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    x_d = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    return np.c_[x_d, y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y]


def _theta_d(theta: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """theta_d(theta) and its derivative."""
    t2 = theta * theta
    poly = 1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))
    slope = 1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
    return theta * poly, slope


def _scale(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """num / den, 1 where both vanish (the optical axis: no distortion there)."""
    out = np.ones_like(den)
    nz = den > 1e-300
    out[nz] = num[nz] / den[nz]
    return out


def fisheye_theta(coeffs: np.ndarray, theta_d: np.ndarray) -> np.ndarray:
    """The angle from the optical axis [N] (rad) of the rays a fisheye images at distorted radius ``theta_d`` [N]
    (normalised units); beyond 90 deg too. NaN where the polynomial has no such angle (past its fold)."""
    c = np.asarray(coeffs, dtype=np.float64)
    theta_d = np.asarray(theta_d, dtype=np.float64)
    theta = theta_d.copy()
    for _ in range(50):  # Newton on theta_d(theta) = measured; the polynomial is monotonic over a real lens
        value, slope = _theta_d(theta, c)
        step = (value - theta_d) / np.where(slope > 1e-9, slope, np.nan)
        theta = theta - step
        if not np.nanmax(np.abs(step), initial=0.0) > 1e-15:
            break
    value, slope = _theta_d(theta, c)
    theta[~(np.abs(value - theta_d) < 1e-10) | ~(slope > 0) | ~(theta >= 0)] = np.nan
    return theta


def distort(model: str, coeffs: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Ideal (pinhole) normalised coordinates [N, 2] -> where the lens images them [N, 2]."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(coeffs, dtype=np.float64)
    if model == "opencv":
        return _radtan(xy, c)
    if model == "fisheye":
        r = np.hypot(xy[:, 0], xy[:, 1])
        theta_d, _ = _theta_d(np.arctan(r), c)
        return xy * _scale(theta_d, r)[:, None]
    raise ValueError(f"unknown distortion model {model!r}; known: {', '.join(MODELS)}")


def undistort(model: str, coeffs: np.ndarray, xy_d: np.ndarray) -> np.ndarray:
    """Distorted normalised coordinates [N, 2] -> the ideal pinhole ones [N, 2] that ``distort`` maps onto them
    (to ~1e-12). Fisheye rays at 90 deg or more from the axis have no pinhole image: NaN."""
    xy_d = np.asarray(xy_d, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(coeffs, dtype=np.float64)
    if model == "opencv":
        import cv2

        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
        xy = cv2.undistortPointsIter(xy_d.reshape(-1, 1, 2), np.eye(3), c, None, None, criteria).reshape(-1, 2)
        # OpenCV's fixed-point iteration stops early where distortion is strong (image corners); Newton steps on
        # the forward model finish the job (its 2x2 Jacobian by central differences).
        for _ in range(4):
            res = _radtan(xy, c) - xy_d
            if not np.abs(res).max(initial=0.0) > 1e-14:
                break
            h = 1e-7
            jx = (_radtan(xy + [h, 0], c) - _radtan(xy - [h, 0], c)) / (2 * h)
            jy = (_radtan(xy + [0, h], c) - _radtan(xy - [0, h], c)) / (2 * h)
            det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
            ok = np.abs(det) > 1e-12
            step = np.zeros_like(xy)
            step[ok, 0] = (jy[ok, 1] * res[ok, 0] - jy[ok, 0] * res[ok, 1]) / det[ok]
            step[ok, 1] = (jx[ok, 0] * res[ok, 1] - jx[ok, 1] * res[ok, 0]) / det[ok]
            xy = xy - step
        return xy
    if model == "fisheye":
        theta_d = np.hypot(xy_d[:, 0], xy_d[:, 1])
        theta = fisheye_theta(c, theta_d)
        out = xy_d * _scale(np.tan(theta), theta_d)[:, None]
        out[~(theta < np.pi / 2 - 1e-9)] = np.nan  # no pinhole image at 90 deg or more (NaN stays NaN)
        return out
    raise ValueError(f"unknown distortion model {model!r}; known: {', '.join(MODELS)}")
