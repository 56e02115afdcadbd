"""The differentiable EWA projection + SH colour of the CPU backend as numba kernels: forward, and a
hand-written backward, one pass over the Gaussians each.

Training used to differentiate the torch projection (``projection.py``) with autograd: ~60 elementwise
ops over [N] tensors forward and as many backward, each a full pass over memory. This computes the same
quantities per Gaussian in registers. ``projection.py`` stays the reference it is tested against (same
clamps, same culling, gradients within float32 rounding).

Per Gaussian (not culled): camera point p = R_cw m + t; C = R_cw R(q/|q|) diag(exp(l)); with J the
projection Jacobian at the FOV-clamped x/z, y/z, rows a = J_0 C, b = J_1 C; 2D covariance
[[a.a + eps, a.b], [a.b, b.b + eps]], conic its inverse; mean2d (fx x/z + cx, fy y/z + cy); depth z;
opacity sigmoid(logit); colour max(SH(d/|d|) + 0.5, 0) with d = m - camera centre. Culled Gaussians
(behind the near plane, degenerate, too faint, or off the image) get radius 0 and zero gradients.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange

from ..sh import SH_C0 as _C0
from ..sh import SH_C1 as _C1
from ..sh import SH_C2 as _C2
from ..sh import SH_C3 as _C3
from .conventions import ALPHA_MIN, EPS2D, FAR_PLANE, FOV_CLAMP, NEAR_PLANE
from .numba_kernels import box_radius

_LOG_ALPHA_MIN = math.log(ALPHA_MIN)


@njit(cache=True, inline="always")
def _sh_basis(x, y, z, degree):
    """(Y_0 .. Y_15)(x, y, z) for a unit direction, zero above ``degree`` (order and constants as sh.py)."""
    y1 = y2 = y3 = y4 = y5 = y6 = y7 = y8 = 0.0
    y9 = y10 = y11 = y12 = y13 = y14 = y15 = 0.0
    if degree >= 1:
        y1, y2, y3 = -_C1 * y, _C1 * z, -_C1 * x
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        y4, y5, y6 = _C2[0] * xy, _C2[1] * yz, _C2[2] * (2.0 * zz - xx - yy)
        y7, y8 = _C2[3] * xz, _C2[4] * (xx - yy)
        if degree >= 3:
            y9 = _C3[0] * y * (3.0 * xx - yy)
            y10 = _C3[1] * xy * z
            y11 = _C3[2] * y * (4.0 * zz - xx - yy)
            y12 = _C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
            y13 = _C3[4] * x * (4.0 * zz - xx - yy)
            y14 = _C3[5] * z * (xx - yy)
            y15 = _C3[6] * x * (xx - 3.0 * yy)
    return (_C0, y1, y2, y3, y4, y5, y6, y7, y8, y9, y10, y11, y12, y13, y14, y15)


@njit(cache=True, inline="always")
def _sh_basis_vjp(x, y, z, degree, sh, i, g0, g1, g2):
    """(gx, gy, gz): the gradient with respect to the (unit) direction of sum_k gY_k Y_k(x, y, z), where
    gY_k = sum_c sh[i, k, c] g_c (the colour's gradient, g0..g2, through the SH coefficients)."""
    gx = gy = gz = 0.0
    if degree >= 1:
        gy -= _C1 * (sh[i, 1, 0] * g0 + sh[i, 1, 1] * g1 + sh[i, 1, 2] * g2)
        gz += _C1 * (sh[i, 2, 0] * g0 + sh[i, 2, 1] * g1 + sh[i, 2, 2] * g2)
        gx -= _C1 * (sh[i, 3, 0] * g0 + sh[i, 3, 1] * g1 + sh[i, 3, 2] * g2)
    if degree >= 2:
        g4 = _C2[0] * (sh[i, 4, 0] * g0 + sh[i, 4, 1] * g1 + sh[i, 4, 2] * g2)
        g5 = _C2[1] * (sh[i, 5, 0] * g0 + sh[i, 5, 1] * g1 + sh[i, 5, 2] * g2)
        g6 = _C2[2] * (sh[i, 6, 0] * g0 + sh[i, 6, 1] * g1 + sh[i, 6, 2] * g2)
        g7 = _C2[3] * (sh[i, 7, 0] * g0 + sh[i, 7, 1] * g1 + sh[i, 7, 2] * g2)
        g8 = _C2[4] * (sh[i, 8, 0] * g0 + sh[i, 8, 1] * g1 + sh[i, 8, 2] * g2)
        gx += g4 * y - 2.0 * g6 * x + g7 * z + 2.0 * g8 * x
        gy += g4 * x + g5 * z - 2.0 * g6 * y - 2.0 * g8 * y
        gz += g5 * y + 4.0 * g6 * z + g7 * x
        if degree >= 3:
            xx, yy, zz = x * x, y * y, z * z
            g9 = _C3[0] * (sh[i, 9, 0] * g0 + sh[i, 9, 1] * g1 + sh[i, 9, 2] * g2)
            g10 = _C3[1] * (sh[i, 10, 0] * g0 + sh[i, 10, 1] * g1 + sh[i, 10, 2] * g2)
            g11 = _C3[2] * (sh[i, 11, 0] * g0 + sh[i, 11, 1] * g1 + sh[i, 11, 2] * g2)
            g12 = _C3[3] * (sh[i, 12, 0] * g0 + sh[i, 12, 1] * g1 + sh[i, 12, 2] * g2)
            g13 = _C3[4] * (sh[i, 13, 0] * g0 + sh[i, 13, 1] * g1 + sh[i, 13, 2] * g2)
            g14 = _C3[5] * (sh[i, 14, 0] * g0 + sh[i, 14, 1] * g1 + sh[i, 14, 2] * g2)
            g15 = _C3[6] * (sh[i, 15, 0] * g0 + sh[i, 15, 1] * g1 + sh[i, 15, 2] * g2)
            gx += (g9 * 6.0 * x * y + g10 * y * z - g11 * 2.0 * x * y - g12 * 6.0 * x * z
                   + g13 * (4.0 * zz - 3.0 * xx - yy) + g14 * 2.0 * x * z + g15 * (3.0 * xx - 3.0 * yy))  # fmt: skip
            gy += (g9 * (3.0 * xx - 3.0 * yy) + g10 * x * z + g11 * (4.0 * zz - xx - 3.0 * yy) - g12 * 6.0 * y * z
                   - g13 * 2.0 * x * y - g14 * 2.0 * y * z - g15 * 6.0 * x * y)  # fmt: skip
            gz += (g10 * x * y + g11 * 8.0 * y * z + g12 * (6.0 * zz - 3.0 * xx - 3.0 * yy) + g13 * 8.0 * x * z
                   + g14 * (xx - yy))  # fmt: skip
    return gx, gy, gz


@njit(cache=True, inline="always")
def _color_grad(basis, sh, i, nb, ch, v, g_sh):
    """Channel ``ch`` of the colour max(sum_k Y_k sh[i, k, ch] + 0.5, 0) with upstream gradient ``v``: writes
    its SH gradient and returns the gradient that reaches the sum (0 where the clamp cut it: clamp_min passes
    it where the value is >= 0)."""
    acc = 0.5
    for k in range(nb):
        acc += basis[k] * sh[i, k, ch]
    if acc < 0.0:
        return 0.0
    for k in range(nb):
        g_sh[i, k, ch] = basis[k] * v
    return v


@njit(cache=True, inline="always")
def _camera_factor(V, r, s0, s1, s2):
    """C = R_cw R diag(s) (row-major, 9 values) from R (row-major) and the scales."""
    return (
        s0 * (V[0, 0] * r[0] + V[0, 1] * r[3] + V[0, 2] * r[6]),
        s1 * (V[0, 0] * r[1] + V[0, 1] * r[4] + V[0, 2] * r[7]),
        s2 * (V[0, 0] * r[2] + V[0, 1] * r[5] + V[0, 2] * r[8]),
        s0 * (V[1, 0] * r[0] + V[1, 1] * r[3] + V[1, 2] * r[6]),
        s1 * (V[1, 0] * r[1] + V[1, 1] * r[4] + V[1, 2] * r[7]),
        s2 * (V[1, 0] * r[2] + V[1, 1] * r[5] + V[1, 2] * r[8]),
        s0 * (V[2, 0] * r[0] + V[2, 1] * r[3] + V[2, 2] * r[6]),
        s1 * (V[2, 0] * r[1] + V[2, 1] * r[4] + V[2, 2] * r[7]),
        s2 * (V[2, 0] * r[2] + V[2, 1] * r[5] + V[2, 2] * r[8]),
    )


@njit(cache=True, inline="always")
def _rt_times(V, g):
    """R_cw^T G for G [3,3] row-major (9 values): the gradient of C = R_cw M with respect to M."""
    return (
        V[0, 0] * g[0] + V[1, 0] * g[3] + V[2, 0] * g[6],
        V[0, 0] * g[1] + V[1, 0] * g[4] + V[2, 0] * g[7],
        V[0, 0] * g[2] + V[1, 0] * g[5] + V[2, 0] * g[8],
        V[0, 1] * g[0] + V[1, 1] * g[3] + V[2, 1] * g[6],
        V[0, 1] * g[1] + V[1, 1] * g[4] + V[2, 1] * g[7],
        V[0, 1] * g[2] + V[1, 1] * g[5] + V[2, 1] * g[8],
        V[0, 2] * g[0] + V[1, 2] * g[3] + V[2, 2] * g[6],
        V[0, 2] * g[1] + V[1, 2] * g[4] + V[2, 2] * g[7],
        V[0, 2] * g[2] + V[1, 2] * g[5] + V[2, 2] * g[8],
    )


@njit(cache=True, inline="always")
def _rotation(qw, qx, qy, qz):
    """R(q) of a unit quaternion (wxyz), row-major as 9 values."""
    return (
        1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy - qw * qz), 2.0 * (qx * qz + qw * qy),
        2.0 * (qx * qy + qw * qz), 1.0 - 2.0 * (qx * qx + qz * qz), 2.0 * (qy * qz - qw * qx),
        2.0 * (qx * qz - qw * qy), 2.0 * (qy * qz + qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy),
    )  # fmt: skip


@njit(cache=True, inline="always")
def _screen_covariance(c, fx, fy, rz, uc, vc):
    """The projection Jacobian's rows times the camera factor c [9] (a = J_x C, b = J_y C, with x/z, y/z clamped to
    uc, vc) and the 2D covariance (cxx, cxy, cyy) they give, with gsplat's eps2d on the diagonal."""
    a0, a1, a2 = fx * rz * (c[0] - uc * c[6]), fx * rz * (c[1] - uc * c[7]), fx * rz * (c[2] - uc * c[8])
    b0, b1, b2 = fy * rz * (c[3] - vc * c[6]), fy * rz * (c[4] - vc * c[7]), fy * rz * (c[5] - vc * c[8])
    cxx = a0 * a0 + a1 * a1 + a2 * a2 + EPS2D
    cxy = a0 * b0 + a1 * b1 + a2 * b2
    cyy = b0 * b0 + b1 * b1 + b2 * b2 + EPS2D
    return a0, a1, a2, b0, b1, b2, cxx, cxy, cyy


@njit(cache=True, inline="always")
def _view_constants(V, K, width, height):
    """The clamp limits of x/z and y/z (positive and negative sides, gsplat's FOV clamp) and the camera centre in
    the world (-R^T t) of world-to-camera V [4,4] and intrinsics K [3,3]."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    lim_xp = (width - cx) / fx + FOV_CLAMP * 0.5 * width / fx
    lim_xn = cx / fx + FOV_CLAMP * 0.5 * width / fx
    lim_yp = (height - cy) / fy + FOV_CLAMP * 0.5 * height / fy
    lim_yn = cy / fy + FOV_CLAMP * 0.5 * height / fy
    camx = -(V[0, 0] * V[0, 3] + V[1, 0] * V[1, 3] + V[2, 0] * V[2, 3])
    camy = -(V[0, 1] * V[0, 3] + V[1, 1] * V[1, 3] + V[2, 1] * V[2, 3])
    camz = -(V[0, 2] * V[0, 3] + V[1, 2] * V[1, 3] + V[2, 2] * V[2, 3])
    return lim_xp, lim_xn, lim_yp, lim_yn, camx, camy, camz


@njit(parallel=True, cache=True)
def project_forward(means, quats, log_scales, logit_opacities, sh, degree, V, K, width, height,
                    mean2d, conic, depth, opacity, color, radius):  # fmt: skip
    """Inputs float32 [N,3], [N,4], [N,3], [N], [N,K,3] (K >= (degree+1)^2), V [4,4] world-to-camera and K
    [3,3] float64. Writes mean2d [N,2], conic [N,3], depth [N], opacity [N], color [N,3], radius [N,2]
    (float32; culled: radius 0, conic (1, 0, 1), the rest 0)."""
    n = means.shape[0]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    lim_xp, lim_xn, lim_yp, lim_yn, camx, camy, camz = _view_constants(V, K, width, height)
    nb = (degree + 1) * (degree + 1)
    for i in prange(n):
        mean2d[i, 0] = mean2d[i, 1] = depth[i] = opacity[i] = 0.0
        color[i, 0] = color[i, 1] = color[i, 2] = 0.0
        conic[i, 0], conic[i, 1], conic[i, 2] = 1.0, 0.0, 1.0
        radius[i, 0] = radius[i, 1] = 0.0
        mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
        x = V[0, 0] * mx + V[0, 1] * my + V[0, 2] * mz + V[0, 3]
        y = V[1, 0] * mx + V[1, 1] * my + V[1, 2] * mz + V[1, 3]
        z = V[2, 0] * mx + V[2, 1] * my + V[2, 2] * mz + V[2, 3]
        if z <= NEAR_PLANE or z >= FAR_PLANE:
            continue
        op = 1.0 / (1.0 + math.exp(-logit_opacities[i]))
        if op < ALPHA_MIN:
            continue
        qw, qx, qy, qz = quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3]
        qn = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        r = _rotation(qw * qn, qx * qn, qy * qn, qz * qn)
        s0, s1, s2 = math.exp(log_scales[i, 0]), math.exp(log_scales[i, 1]), math.exp(log_scales[i, 2])
        c = _camera_factor(V, r, s0, s1, s2)
        rz = 1.0 / z
        uc = min(lim_xp, max(-lim_xn, x * rz))
        vc = min(lim_yp, max(-lim_yn, y * rz))
        a0, a1, a2, b0, b1, b2, cxx, cxy, cyy = _screen_covariance(c, fx, fy, rz, uc, vc)
        det = cxx * cyy - cxy * cxy
        if det <= 0.0:
            continue
        rx, ry = box_radius(cxx, cyy, math.log(op) - _LOG_ALPHA_MIN)
        u, v = fx * x * rz + cx, fy * y * rz + cy
        if u + rx <= 0 or u - rx >= width or v + ry <= 0 or v - ry >= height:
            continue
        mean2d[i, 0], mean2d[i, 1] = u, v
        conic[i, 0], conic[i, 1], conic[i, 2] = cyy / det, -cxy / det, cxx / det
        depth[i], opacity[i] = z, op
        radius[i, 0], radius[i, 1] = rx, ry
        dx, dy, dz = mx - camx, my - camy, mz - camz
        dn = 1.0 / max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
        basis = _sh_basis(dx * dn, dy * dn, dz * dn, degree)
        for ch in range(3):
            acc = 0.5
            for k in range(nb):
                acc += basis[k] * sh[i, k, ch]
            color[i, ch] = max(acc, 0.0)


@njit(parallel=True, cache=True)
def project_backward(means, quats, log_scales, logit_opacities, sh, degree, V, K, width, height, radius,
                     v_mean2d, v_conic, v_depth, v_opacity, v_color,
                     g_means, g_quats, g_log_scales, g_logit_opacities, g_sh):  # fmt: skip
    """Gradients of the forward's outputs' loss (v_*, float32 like the outputs) with respect to its inputs,
    written to g_* (zeros for culled Gaussians). Recomputes the forward per Gaussian (cheaper than storing
    it)."""
    n = means.shape[0]
    fx, fy = K[0, 0], K[1, 1]
    lim_xp, lim_xn, lim_yp, lim_yn, camx, camy, camz = _view_constants(V, K, width, height)
    nb = (degree + 1) * (degree + 1)
    kk = sh.shape[1]
    for i in prange(n):
        for j in range(3):
            g_means[i, j] = g_log_scales[i, j] = 0.0
        for j in range(4):
            g_quats[i, j] = 0.0
        g_logit_opacities[i] = 0.0
        for k in range(kk):
            g_sh[i, k, 0] = g_sh[i, k, 1] = g_sh[i, k, 2] = 0.0
        if radius[i, 0] <= 0.0 and radius[i, 1] <= 0.0:
            continue
        mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
        x = V[0, 0] * mx + V[0, 1] * my + V[0, 2] * mz + V[0, 3]
        y = V[1, 0] * mx + V[1, 1] * my + V[1, 2] * mz + V[1, 3]
        z = V[2, 0] * mx + V[2, 1] * my + V[2, 2] * mz + V[2, 3]
        op = 1.0 / (1.0 + math.exp(-logit_opacities[i]))
        qw0, qx0, qy0, qz0 = quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3]
        qnorm = math.sqrt(qw0 * qw0 + qx0 * qx0 + qy0 * qy0 + qz0 * qz0)
        qw, qx, qy, qz = qw0 / qnorm, qx0 / qnorm, qy0 / qnorm, qz0 / qnorm
        r = _rotation(qw, qx, qy, qz)
        s = (math.exp(log_scales[i, 0]), math.exp(log_scales[i, 1]), math.exp(log_scales[i, 2]))
        c = _camera_factor(V, r, s[0], s[1], s[2])
        rz = 1.0 / z
        xr, yr = x * rz, y * rz
        uc = min(lim_xp, max(-lim_xn, xr))
        vc = min(lim_yp, max(-lim_yn, yr))
        a0, a1, a2, b0, b1, b2, cxx, cxy, cyy = _screen_covariance(c, fx, fy, rz, uc, vc)
        det = cxx * cyy - cxy * cxy
        # conic (cyy, -cxy, cxx) / det -> covariance entries
        gA, gB, gC = v_conic[i, 0], v_conic[i, 1], v_conic[i, 2]
        id2 = 1.0 / (det * det)
        g_det = -(gA * cyy - gB * cxy + gC * cxx) * id2
        g_cxx = gC / det + g_det * cyy
        g_cyy = gA / det + g_det * cxx
        g_cxy = -gB / det - 2.0 * g_det * cxy
        # covariance -> rows a, b
        ga0, ga1, ga2 = 2.0 * g_cxx * a0 + g_cxy * b0, 2.0 * g_cxx * a1 + g_cxy * b1, 2.0 * g_cxx * a2 + g_cxy * b2
        gb0, gb1, gb2 = 2.0 * g_cyy * b0 + g_cxy * a0, 2.0 * g_cyy * b1 + g_cxy * a1, 2.0 * g_cyy * b2 + g_cxy * a2
        # rows -> C, the clamped x/z, y/z, and 1/z
        kx, ky = fx * rz, fy * rz
        gc = (kx * ga0, kx * ga1, kx * ga2, ky * gb0, ky * gb1, ky * gb2, -kx * uc * ga0 - ky * vc * gb0,
              -kx * uc * ga1 - ky * vc * gb1, -kx * uc * ga2 - ky * vc * gb2)  # fmt: skip
        g_uc = -kx * (ga0 * c[6] + ga1 * c[7] + ga2 * c[8])
        g_vc = -ky * (gb0 * c[6] + gb1 * c[7] + gb2 * c[8])
        g_rz = (ga0 * a0 + ga1 * a1 + ga2 * a2 + gb0 * b0 + gb1 * b1 + gb2 * b2) * z
        g_x = g_y = 0.0
        if -lim_xn <= xr <= lim_xp:  # torch.clamp passes the gradient on the closed interval
            g_x += g_uc * rz
            g_rz += g_uc * x
        if -lim_yn <= yr <= lim_yp:
            g_y += g_vc * rz
            g_rz += g_vc * y
        # mean2d and depth
        g_x += fx * rz * v_mean2d[i, 0]
        g_y += fy * rz * v_mean2d[i, 1]
        g_rz += fx * x * v_mean2d[i, 0] + fy * y * v_mean2d[i, 1]
        g_z = v_depth[i] - g_rz * rz * rz
        # camera point -> mean: R_cw^T (g_x, g_y, g_z)
        gmx = V[0, 0] * g_x + V[1, 0] * g_y + V[2, 0] * g_z
        gmy = V[0, 1] * g_x + V[1, 1] * g_y + V[2, 1] * g_z
        gmz = V[0, 2] * g_x + V[1, 2] * g_y + V[2, 2] * g_z
        # C = R_cw M, M = R diag(s): g_M = R_cw^T g_C; g_R[:, j] = g_M[:, j] s_j; g_s_j = g_M[:, j] . R[:, j]
        gm = _rt_times(V, gc)
        for col in range(3):
            g_log_scales[i, col] = s[col] * (gm[col] * r[col] + gm[3 + col] * r[3 + col] + gm[6 + col] * r[6 + col])
        gr = (gm[0] * s[0], gm[1] * s[1], gm[2] * s[2], gm[3] * s[0], gm[4] * s[1], gm[5] * s[2],
              gm[6] * s[0], gm[7] * s[1], gm[8] * s[2])  # fmt: skip
        # R(q) -> the unit quaternion, then through the normalisation
        gqw = 2.0 * (-qz * gr[1] + qy * gr[2] + qz * gr[3] - qx * gr[5] - qy * gr[6] + qx * gr[7])
        gqx = 2.0 * (qy * gr[1] + qz * gr[2] + qy * gr[3] - 2.0 * qx * gr[4] - qw * gr[5] + qz * gr[6]
                     + qw * gr[7] - 2.0 * qx * gr[8])  # fmt: skip
        gqy = 2.0 * (-2.0 * qy * gr[0] + qx * gr[1] + qw * gr[2] + qx * gr[3] + qz * gr[5] - qw * gr[6]
                     + qz * gr[7] - 2.0 * qy * gr[8])  # fmt: skip
        gqz = 2.0 * (-2.0 * qz * gr[0] - qw * gr[1] + qx * gr[2] + qw * gr[3] - 2.0 * qz * gr[4] + qy * gr[5]
                     + qx * gr[6] + qy * gr[7])  # fmt: skip
        dot = qw * gqw + qx * gqx + qy * gqy + qz * gqz
        g_quats[i, 0] = (gqw - qw * dot) / qnorm
        g_quats[i, 1] = (gqx - qx * dot) / qnorm
        g_quats[i, 2] = (gqy - qy * dot) / qnorm
        g_quats[i, 3] = (gqz - qz * dot) / qnorm
        g_logit_opacities[i] = v_opacity[i] * op * (1.0 - op)
        # colour: max(SH(d/|d|) + 0.5, 0), d = m - camera centre
        dx, dy, dz = mx - camx, my - camy, mz - camz
        dlen = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
        ux, uy, uz = dx / dlen, dy / dlen, dz / dlen
        basis = _sh_basis(ux, uy, uz, degree)
        g0 = _color_grad(basis, sh, i, nb, 0, v_color[i, 0], g_sh)
        g1 = _color_grad(basis, sh, i, nb, 1, v_color[i, 1], g_sh)
        g2 = _color_grad(basis, sh, i, nb, 2, v_color[i, 2], g_sh)
        gux, guy, guz = _sh_basis_vjp(ux, uy, uz, degree, sh, i, g0, g1, g2)
        dot = ux * gux + uy * guy + uz * guz
        g_means[i, 0] = gmx + (gux - ux * dot) / dlen
        g_means[i, 1] = gmy + (guy - uy * dot) / dlen
        g_means[i, 2] = gmz + (guz - uz * dot) / dlen


def _np32(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).numpy())


class ProjectNumba(torch.autograd.Function):
    """(means, quats, log_scales, logit_opacities, sh) -> (mean2d [N,2], conic [N,3], depth [N], opacity [N],
    color [N,3], radius [N,2]) for the camera ``viewmat`` / ``K`` (float64 numpy); radius has no gradient."""

    @staticmethod
    def forward(ctx, means, quats, log_scales, logit_opacities, sh, viewmat, K, width, height):
        n = means.shape[0]
        ins = [_np32(t) for t in (means, quats, log_scales, logit_opacities, sh)]
        degree = int(round(math.sqrt(sh.shape[1]))) - 1
        outs = [np.empty(s, np.float32) for s in ((n, 2), (n, 3), (n,), (n,), (n, 3), (n, 2))]
        project_forward(*ins, degree, viewmat, K, width, height, *outs)
        ctx.saved = (ins, degree, viewmat, K, width, height, outs[5])
        ctx.dtypes = [t.dtype for t in (means, quats, log_scales, logit_opacities, sh)]
        ctx.mark_non_differentiable(radius := torch.from_numpy(outs[5]))
        return (*(torch.from_numpy(a) for a in outs[:5]), radius)

    @staticmethod
    def backward(ctx, v_mean2d, v_conic, v_depth, v_opacity, v_color, _v_radius):
        ins, degree, viewmat, K, width, height, radius = ctx.saved
        grads = [np.empty_like(a) for a in ins]
        vs = []
        for v, shape in zip((v_mean2d, v_conic, v_depth, v_opacity, v_color), ((2,), (3,), (), (), (3,)), strict=True):
            vs.append(np.zeros((radius.shape[0], *shape), np.float32) if v is None else _np32(v))
        project_backward(*ins, degree, viewmat, K, width, height, radius, *vs, *grads)
        out = [torch.from_numpy(g).to(dt) for g, dt in zip(grads, ctx.dtypes, strict=True)]
        return (*out, None, None, None, None)
