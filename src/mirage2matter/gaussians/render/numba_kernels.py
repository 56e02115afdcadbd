"""Numba CPU kernels of the tile rasterizer: projection, depth sort, tile binning, forward and backward.

They work on float32 numpy arrays indexed by the global Gaussian id; a Gaussian is culled by giving
it radius 0. Unlike a GPU rasterizer, which evaluates every Gaussian of a tile at every one of the
tile's pixels, each Gaussian here only visits the pixels of its own (opacity-aware, tight) bounding
box inside the tile: on a CPU that is most of the speed. The box contains every pixel where the
Gaussian's alpha can reach ALPHA_MIN, so no contribution is lost relative to the dense reference.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

from ..sh import SH_C0 as _SH_C0
from ..sh import SH_C1 as _SH_C1
from ..sh import SH_C2 as _SH_C2
from ..sh import SH_C3 as _SH_C3
from .conventions import ALPHA_MAX, ALPHA_MIN, EPS2D, FAR_PLANE, FOV_CLAMP, NEAR_PLANE, T_MIN, TILE_SIZE

_LOG_ALPHA_MIN = math.log(ALPHA_MIN)
_EXTEND_MAX = 3.33  # gsplat's cap on the box half-width in standard deviations

# exp(-x) for 0 <= x < 8 as table[x*16] times a 4th-order series of the remainder (< 1/16):
# relative error < 1e-8 at a fraction of libm's cost. Compositing only ever needs x < log(255).
_EXP_STEPS = 16.0
_EXP_TABLE = np.exp(-np.arange(130) / _EXP_STEPS)


# One float32 record of 16 per Gaussian (a cache line): what the rasterizer reads about it.
REC_MEAN_X, REC_MEAN_Y = 0, 1  # pixels
REC_CONIC_A, REC_CONIC_B, REC_CONIC_C = 2, 3, 4  # inverse 2D covariance [[a, b], [b, c]]
REC_OPACITY, REC_SIGMA_MAX, REC_INV_A = 5, 6, 7  # sigma_max: beyond it alpha < ALPHA_MIN; 1/a
REC_R, REC_G, REC_B, REC_DEPTH = 8, 9, 10, 11
REC_RADIUS_X, REC_RADIUS_Y = 12, 13  # box half-widths in pixels; 0 = culled
REC_SIZE = 16


@njit(cache=True, inline="always")
def _exp_neg(x):
    k = int(x * _EXP_STEPS)
    r = x - k / _EXP_STEPS
    return _EXP_TABLE[k] * (1.0 - r * (1.0 - r * (0.5 - r * (1.0 / 6.0 - r * (1.0 / 24.0)))))


@njit(cache=True, inline="always")
def _sh_color(sh, i, degree, x, y, z, out, col):
    """out[i, col:col+3] = max(sum_k sh[i,k] Y_k(x,y,z) + 0.5, 0) for a unit direction; basis order as sh.py."""
    r = 0.5 + _SH_C0 * sh[i, 0, 0]
    g = 0.5 + _SH_C0 * sh[i, 0, 1]
    b = 0.5 + _SH_C0 * sh[i, 0, 2]
    if degree >= 1:
        y1, y2, y3 = -_SH_C1 * y, _SH_C1 * z, -_SH_C1 * x
        r += y1 * sh[i, 1, 0] + y2 * sh[i, 2, 0] + y3 * sh[i, 3, 0]
        g += y1 * sh[i, 1, 1] + y2 * sh[i, 2, 1] + y3 * sh[i, 3, 1]
        b += y1 * sh[i, 1, 2] + y2 * sh[i, 2, 2] + y3 * sh[i, 3, 2]
        if degree >= 2:
            xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
            basis = (
                _SH_C2[0] * xy,
                _SH_C2[1] * yz,
                _SH_C2[2] * (2.0 * zz - xx - yy),
                _SH_C2[3] * xz,
                _SH_C2[4] * (xx - yy),
            )
            for k in range(5):
                r += basis[k] * sh[i, 4 + k, 0]
                g += basis[k] * sh[i, 4 + k, 1]
                b += basis[k] * sh[i, 4 + k, 2]
            if degree >= 3:
                basis3 = (
                    _SH_C3[0] * y * (3.0 * xx - yy),
                    _SH_C3[1] * xy * z,
                    _SH_C3[2] * y * (4.0 * zz - xx - yy),
                    _SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
                    _SH_C3[4] * x * (4.0 * zz - xx - yy),
                    _SH_C3[5] * z * (xx - yy),
                    _SH_C3[6] * x * (xx - 3.0 * yy),
                )
                for k in range(7):
                    r += basis3[k] * sh[i, 9 + k, 0]
                    g += basis3[k] * sh[i, 9 + k, 1]
                    b += basis3[k] * sh[i, 9 + k, 2]
    out[i, col] = max(r, 0.0)
    out[i, col + 1] = max(g, 0.0)
    out[i, col + 2] = max(b, 0.0)


@njit(cache=True, inline="always")
def box_radius(cov_xx, cov_yy, sigma_cut):
    """Opacity-aware half-widths (pixels, integral) of the box holding every pixel with alpha >= ALPHA_MIN,
    given sigma_cut = log(opacity / ALPHA_MIN), the Mahalanobis term where alpha falls to ALPHA_MIN."""
    extend = min(_EXTEND_MAX, math.sqrt(2.0 * sigma_cut))
    return math.ceil(extend * math.sqrt(cov_xx)), math.ceil(extend * math.sqrt(cov_yy))


@njit(cache=True, inline="always")
def _write_record(rec, i, u, v, ca, cb, cc, op, sigma_cut, z, rx, ry):
    rec[i, REC_MEAN_X] = u
    rec[i, REC_MEAN_Y] = v
    rec[i, REC_CONIC_A] = ca
    rec[i, REC_CONIC_B] = cb
    rec[i, REC_CONIC_C] = cc
    rec[i, REC_OPACITY] = op
    rec[i, REC_SIGMA_MAX] = sigma_cut + 1e-4  # the margin keeps rounding on the safe side
    rec[i, REC_INV_A] = 1.0 / ca
    rec[i, REC_DEPTH] = z
    rec[i, REC_RADIUS_X] = rx
    rec[i, REC_RADIUS_Y] = ry


@njit(parallel=True, cache=True)
def project_fused(means, quats, log_scales, logit_opacities, sh, sh_degree, viewmat, K, width, height, rec,
                  antialias=False):
    """Project N Gaussians and evaluate their colour into records rec [N, REC_SIZE] float32.
    Inputs means [N,3], quats [N,4] wxyz, log_scales [N,3], logit_opacities [N], sh [N,K,3];
    viewmat [4,4] world-to-camera, K [3,3] (float64). ``antialias``: each opacity times
    sqrt(det(cov2d) / det(cov2d + EPS2D I)) (gsplat's "antialiased" mode)."""
    n = means.shape[0]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    lim_x_pos = (width - cx) / fx + FOV_CLAMP * 0.5 * width / fx
    lim_x_neg = cx / fx + FOV_CLAMP * 0.5 * width / fx
    lim_y_pos = (height - cy) / fy + FOV_CLAMP * 0.5 * height / fy
    lim_y_neg = cy / fy + FOV_CLAMP * 0.5 * height / fy
    # camera centre in the world: -R^T t
    campos_x = -(viewmat[0, 0] * viewmat[0, 3] + viewmat[1, 0] * viewmat[1, 3] + viewmat[2, 0] * viewmat[2, 3])
    campos_y = -(viewmat[0, 1] * viewmat[0, 3] + viewmat[1, 1] * viewmat[1, 3] + viewmat[2, 1] * viewmat[2, 3])
    campos_z = -(viewmat[0, 2] * viewmat[0, 3] + viewmat[1, 2] * viewmat[1, 3] + viewmat[2, 2] * viewmat[2, 3])
    W = viewmat
    for i in prange(n):
        # culled: radius 0; the mean is zeroed too so callers never see stale memory
        rec[i, REC_MEAN_X] = rec[i, REC_MEAN_Y] = 0.0
        rec[i, REC_RADIUS_X] = rec[i, REC_RADIUS_Y] = 0.0
        mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
        x = W[0, 0] * mx + W[0, 1] * my + W[0, 2] * mz + W[0, 3]
        y = W[1, 0] * mx + W[1, 1] * my + W[1, 2] * mz + W[1, 3]
        z = W[2, 0] * mx + W[2, 1] * my + W[2, 2] * mz + W[2, 3]
        if z <= NEAR_PLANE or z >= FAR_PLANE:
            continue
        op = 1.0 / (1.0 + math.exp(-logit_opacities[i]))
        if op < ALPHA_MIN:
            continue
        # rotation from the (normalised) quaternion, scaled columns M = R diag(s)
        qw, qx, qy, qz = quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3]
        qn = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qw, qx, qy, qz = qw * qn, qx * qn, qy * qn, qz * qn
        s0, s1, s2 = math.exp(log_scales[i, 0]), math.exp(log_scales[i, 1]), math.exp(log_scales[i, 2])
        m00 = (1.0 - 2.0 * (qy * qy + qz * qz)) * s0
        m01 = 2.0 * (qx * qy - qw * qz) * s1
        m02 = 2.0 * (qx * qz + qw * qy) * s2
        m10 = 2.0 * (qx * qy + qw * qz) * s0
        m11 = (1.0 - 2.0 * (qx * qx + qz * qz)) * s1
        m12 = 2.0 * (qy * qz - qw * qx) * s2
        m20 = 2.0 * (qx * qz - qw * qy) * s0
        m21 = 2.0 * (qy * qz + qw * qx) * s1
        m22 = (1.0 - 2.0 * (qx * qx + qy * qy)) * s2
        # camera-frame columns: C = W_rot @ M, so Sigma_c = C C^T
        c00 = W[0, 0] * m00 + W[0, 1] * m10 + W[0, 2] * m20
        c01 = W[0, 0] * m01 + W[0, 1] * m11 + W[0, 2] * m21
        c02 = W[0, 0] * m02 + W[0, 1] * m12 + W[0, 2] * m22
        c10 = W[1, 0] * m00 + W[1, 1] * m10 + W[1, 2] * m20
        c11 = W[1, 0] * m01 + W[1, 1] * m11 + W[1, 2] * m21
        c12 = W[1, 0] * m02 + W[1, 1] * m12 + W[1, 2] * m22
        c20 = W[2, 0] * m00 + W[2, 1] * m10 + W[2, 2] * m20
        c21 = W[2, 0] * m01 + W[2, 1] * m11 + W[2, 2] * m21
        c22 = W[2, 0] * m02 + W[2, 1] * m12 + W[2, 2] * m22
        rz = 1.0 / z
        tx = z * min(lim_x_pos, max(-lim_x_neg, x * rz))
        ty = z * min(lim_y_pos, max(-lim_y_neg, y * rz))
        # rows of J C, J = [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]]
        j00, j02 = fx * rz, -fx * tx * rz * rz
        j11, j12 = fy * rz, -fy * ty * rz * rz
        a0 = j00 * c00 + j02 * c20
        a1 = j00 * c01 + j02 * c21
        a2 = j00 * c02 + j02 * c22
        b0 = j11 * c10 + j12 * c20
        b1 = j11 * c11 + j12 * c21
        b2 = j11 * c12 + j12 * c22
        cov_xx = a0 * a0 + a1 * a1 + a2 * a2 + EPS2D
        cov_xy = a0 * b0 + a1 * b1 + a2 * b2
        cov_yy = b0 * b0 + b1 * b1 + b2 * b2 + EPS2D
        det = cov_xx * cov_yy - cov_xy * cov_xy
        if det <= 0.0:
            continue
        if antialias:  # the low-pass spreads a sub-pixel Gaussian; keep its footprint's energy, not its peak
            det0 = (cov_xx - EPS2D) * (cov_yy - EPS2D) - cov_xy * cov_xy
            op = op * math.sqrt(max(det0, 0.0) / det)
            if op < ALPHA_MIN:
                continue
        sigma_cut = math.log(op) - _LOG_ALPHA_MIN
        rx, ry = box_radius(cov_xx, cov_yy, sigma_cut)
        u = fx * x * rz + cx
        v = fy * y * rz + cy
        if u + rx <= 0 or u - rx >= width or v + ry <= 0 or v - ry >= height:
            continue
        inv_det = 1.0 / det
        _write_record(rec, i, u, v, cov_yy * inv_det, -cov_xy * inv_det, cov_xx * inv_det, op, sigma_cut, z, rx, ry)
        # view-dependent colour, direction from the camera centre to the mean
        dx, dy, dz = mx - campos_x, my - campos_y, mz - campos_z
        dn = 1.0 / max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
        _sh_color(sh, i, sh_degree, dx * dn, dy * dn, dz * dn, rec, REC_R)


@njit(parallel=True, cache=True)
def pack_records(mean2d, conic, opacity, color, depth, radius, rec):
    """Records from separately projected quantities (the differentiable torch projection)."""
    for i in prange(mean2d.shape[0]):
        rec[i, REC_MEAN_X] = rec[i, REC_MEAN_Y] = 0.0
        rec[i, REC_RADIUS_X] = rec[i, REC_RADIUS_Y] = 0.0
        if radius[i, 0] <= 0 or opacity[i] < ALPHA_MIN or conic[i, 0] <= 0:
            continue
        sigma_cut = math.log(opacity[i]) - _LOG_ALPHA_MIN
        _write_record(rec, i, mean2d[i, 0], mean2d[i, 1], conic[i, 0], conic[i, 1], conic[i, 2],
                      opacity[i], sigma_cut, depth[i], radius[i, 0], radius[i, 1])  # fmt: skip
        rec[i, REC_R] = color[i, 0]
        rec[i, REC_G] = color[i, 1]
        rec[i, REC_B] = color[i, 2]


@njit(cache=True)
def argsort_by_depth(ids, depth_bits):
    """Stable LSD radix sort of ``ids`` [M] int32 by ``depth_bits`` [N] uint32 (the bits of positive
    float32 depths, which order like the floats). Two 16-bit passes: exact, O(M)."""
    m = ids.shape[0]
    src = ids.copy()
    dst = np.empty_like(ids)
    for shift in (0, 16):
        counts = np.zeros(65537, np.int64)
        for j in range(m):
            counts[((depth_bits[src[j]] >> shift) & 0xFFFF) + 1] += 1
        for b in range(65536):
            counts[b + 1] += counts[b]
        for j in range(m):
            key = (depth_bits[src[j]] >> shift) & 0xFFFF
            dst[counts[key]] = src[j]
            counts[key] += 1
        src, dst = dst, src
    return src


@njit(cache=True, inline="always")
def _pixel_range(m, r, size):
    """Pixels p (centre p + 0.5) of [0, size) with |p + 0.5 - m| <= r, as [lo, hi] inclusive."""
    lo = max(0, math.ceil(m - r - 0.5))
    hi = min(size - 1, math.floor(m + r - 0.5))
    return lo, hi


@njit(cache=True, inline="always")
def _box_in_tile(recs, k, px0, py0, tw, th, width, height):
    """Inclusive pixel box x0, x1, y0, y1 of record k inside the tile at (px0, py0) of size tw x th."""
    x0, x1 = _pixel_range(recs[k, REC_MEAN_X], recs[k, REC_RADIUS_X], width)
    y0, y1 = _pixel_range(recs[k, REC_MEAN_Y], recs[k, REC_RADIUS_Y], height)
    return max(x0, px0), min(x1, px0 + tw - 1), max(y0, py0), min(y1, py0 + th - 1)


@njit(cache=True, inline="always")
def _row_span(mx, dy, ca, inv_ca, cb, cc, sigma_max, x0, x1):
    """Pixels px in [x0, x1] of a row at dy = my - (py + 0.5) whose sigma is <= sigma_max: between
    the roots of 0.5 a dx^2 + b dy dx + 0.5 c dy^2 = sigma_max in dx = mx - (px + 0.5)."""
    bdy = cb * dy
    disc = bdy * bdy - ca * (cc * dy * dy - 2.0 * sigma_max)
    if disc < 0.0:
        return 1, 0
    centre = mx - 0.5 + bdy * inv_ca
    half = math.sqrt(disc) * inv_ca
    return max(x0, math.ceil(centre - half)), min(x1, math.floor(centre + half))


@njit(parallel=True, cache=True)
def tile_rects(rec, width, height, rect):
    """rect [N,4] int32: inclusive tile range x0, x1, y0, y1 each Gaussian's box touches (x0 > x1: none)."""
    for g in prange(rec.shape[0]):
        rect[g, 0], rect[g, 1], rect[g, 2], rect[g, 3] = 1, 0, 1, 0
        if rec[g, REC_RADIUS_X] <= 0:
            continue
        x0, x1 = _pixel_range(rec[g, REC_MEAN_X], rec[g, REC_RADIUS_X], width)
        y0, y1 = _pixel_range(rec[g, REC_MEAN_Y], rec[g, REC_RADIUS_Y], height)
        if x0 > x1 or y0 > y1:
            continue
        rect[g, 0], rect[g, 1] = x0 // TILE_SIZE, x1 // TILE_SIZE
        rect[g, 2], rect[g, 3] = y0 // TILE_SIZE, y1 // TILE_SIZE


@njit(parallel=True, cache=True)
def bin_tiles(sorted_ids, rect, width, height, n_chunks):
    """Per-tile lists of Gaussians, each front to back. Returns offsets [n_tiles+1] int64 and
    ids [n_isect] int32: tile t owns ids[offsets[t]:offsets[t+1]].
    Parallel: each chunk of the depth-sorted ids gets its own slot range in every tile, after the
    slots of the chunks in front of it, so the lists stay sorted."""
    tiles_x = (width + TILE_SIZE - 1) // TILE_SIZE
    n_tiles = tiles_x * ((height + TILE_SIZE - 1) // TILE_SIZE)
    m = sorted_ids.shape[0]
    counts = np.zeros((n_chunks, n_tiles), np.int64)
    for c in prange(n_chunks):
        for j in range(m * c // n_chunks, m * (c + 1) // n_chunks):
            g = sorted_ids[j]
            for ty in range(rect[g, 2], rect[g, 3] + 1):
                for tx in range(rect[g, 0], rect[g, 1] + 1):
                    counts[c, ty * tiles_x + tx] += 1
    offsets = np.empty(n_tiles + 1, np.int64)
    pos = 0
    for t in range(n_tiles):
        offsets[t] = pos
        for c in range(n_chunks):
            n_c = counts[c, t]
            counts[c, t] = pos  # becomes this chunk's write cursor in tile t
            pos += n_c
    offsets[n_tiles] = pos
    ids = np.empty(pos, np.int32)
    for c in prange(n_chunks):
        for j in range(m * c // n_chunks, m * (c + 1) // n_chunks):
            g = sorted_ids[j]
            for ty in range(rect[g, 2], rect[g, 3] + 1):
                for tx in range(rect[g, 0], rect[g, 1] + 1):
                    k = counts[c, ty * tiles_x + tx]
                    counts[c, ty * tiles_x + tx] = k + 1
                    ids[k] = g
    return offsets, ids


@njit(parallel=True, cache=True)
def gather_records(ids, rec, out):
    """out[k] = rec[ids[k]]: the records in tile order, so the rasterizer streams through memory.
    Pass the float32 records viewed as complex128 ([N, REC_SIZE // 4]): the copy is then 4 moves
    per record instead of 16, which keeps ~3x more of these cache-missing loads in flight."""
    for k in prange(ids.shape[0]):
        g = ids[k]
        for j in range(rec.shape[1]):
            out[k, j] = rec[g, j]


@njit(parallel=True, cache=True)
def rasterize_forward(offsets, recs, width, height, out_rgb, out_depth, out_T, out_last):
    """Front-to-back alpha compositing per tile over recs [n_isect, REC_SIZE] (tile t owns
    recs[offsets[t]:offsets[t+1]], front to back). Outputs [H,W(,3)]: out_rgb = sum w c (no
    background), out_depth = sum w z, out_T final transmittance, out_last the index k of the last
    record composited into the pixel (-1: none), where the backward pass starts."""
    tiles_x = (width + TILE_SIZE - 1) // TILE_SIZE
    for t in prange(offsets.shape[0] - 1):
        px0 = (t % tiles_x) * TILE_SIZE
        py0 = (t // tiles_x) * TILE_SIZE
        tw = min(TILE_SIZE, width - px0)
        th = min(TILE_SIZE, height - py0)
        T = np.ones(TILE_SIZE * TILE_SIZE)
        acc = np.zeros((TILE_SIZE * TILE_SIZE, 4))
        done = np.zeros(TILE_SIZE * TILE_SIZE, np.bool_)
        last = np.full(TILE_SIZE * TILE_SIZE, -1, np.int32)
        n_done = 0
        for k in range(offsets[t], offsets[t + 1]):
            mx, my = recs[k, REC_MEAN_X], recs[k, REC_MEAN_Y]
            x0, x1, y0, y1 = _box_in_tile(recs, k, px0, py0, tw, th, width, height)
            ca, cb, cc = recs[k, REC_CONIC_A], recs[k, REC_CONIC_B], recs[k, REC_CONIC_C]
            op, smax, inv_ca = recs[k, REC_OPACITY], recs[k, REC_SIGMA_MAX], recs[k, REC_INV_A]
            cr, cg, cbl, z = recs[k, REC_R], recs[k, REC_G], recs[k, REC_B], recs[k, REC_DEPTH]
            for py in range(y0, y1 + 1):
                dy = my - (py + 0.5)
                row = (py - py0) * TILE_SIZE - px0
                sx0, sx1 = _row_span(mx, dy, ca, inv_ca, cb, cc, smax, x0, x1)
                for px in range(sx0, sx1 + 1):
                    p = row + px
                    if done[p]:
                        continue
                    dx = mx - (px + 0.5)
                    sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                    if sigma < 0.0:
                        continue
                    alpha = min(ALPHA_MAX, op * _exp_neg(sigma))
                    if alpha < ALPHA_MIN:
                        continue
                    next_T = T[p] * (1.0 - alpha)
                    if next_T <= T_MIN:  # gsplat's rule: this Gaussian is left out and the pixel stops
                        done[p] = True
                        n_done += 1
                        continue
                    w = alpha * T[p]
                    acc[p, 0] += w * cr
                    acc[p, 1] += w * cg
                    acc[p, 2] += w * cbl
                    acc[p, 3] += w * z
                    T[p] = next_T
                    last[p] = k
            if n_done == tw * th:
                break
        for ly in range(th):
            for lx in range(tw):
                p = ly * TILE_SIZE + lx
                out_rgb[py0 + ly, px0 + lx, 0] = acc[p, 0]
                out_rgb[py0 + ly, px0 + lx, 1] = acc[p, 1]
                out_rgb[py0 + ly, px0 + lx, 2] = acc[p, 2]
                out_depth[py0 + ly, px0 + lx] = acc[p, 3]
                out_T[py0 + ly, px0 + lx] = T[p]
                out_last[py0 + ly, px0 + lx] = last[p]


@njit(cache=True, inline="always")
def _record_levels(out_A, lev, T, px0, py0, tw, th):
    for ly in range(th):
        for lx in range(tw):
            out_A[lev, py0 + ly, px0 + lx] = 1.0 - T[ly * TILE_SIZE + lx]


@njit(parallel=True, cache=True)
def opacity_levels(offsets, recs, width, height, levels, out_A, out_T):
    """The opacity each pixel accumulates from the records in front of each depth of ``levels`` [L] (ascending,
    metres): out_A [L,H,W] = 1 - T just before the first record whose depth is at or behind the level, composited
    by ``rasterize_forward``'s rules (same offsets/recs, front to back); out_T [H,W] the final transmittance. One
    pass gives what one render per level (the Gaussians in front of it alone) gives.
    Its compositing loop repeats rasterize_forward's on purpose: reading the levels inside rasterize_forward (an
    optional array) made every render slower (no-grad, 100k Gaussians at 224 px, seven interleaved runs on an idle
    2-core host: median 52.1 -> 54.2 ms, slower in 5 of 7), and that loop is the training's hot path."""
    tiles_x = (width + TILE_SIZE - 1) // TILE_SIZE
    n_levels = levels.shape[0]
    for t in prange(offsets.shape[0] - 1):
        px0 = (t % tiles_x) * TILE_SIZE
        py0 = (t // tiles_x) * TILE_SIZE
        tw = min(TILE_SIZE, width - px0)
        th = min(TILE_SIZE, height - py0)
        T = np.ones(TILE_SIZE * TILE_SIZE)
        done = np.zeros(TILE_SIZE * TILE_SIZE, np.bool_)
        n_done, lev = 0, 0
        for k in range(offsets[t], offsets[t + 1]):
            while lev < n_levels and recs[k, REC_DEPTH] >= levels[lev]:
                _record_levels(out_A, lev, T, px0, py0, tw, th)
                lev += 1
            mx, my = recs[k, REC_MEAN_X], recs[k, REC_MEAN_Y]
            x0, x1, y0, y1 = _box_in_tile(recs, k, px0, py0, tw, th, width, height)
            ca, cb, cc = recs[k, REC_CONIC_A], recs[k, REC_CONIC_B], recs[k, REC_CONIC_C]
            op, smax, inv_ca = recs[k, REC_OPACITY], recs[k, REC_SIGMA_MAX], recs[k, REC_INV_A]
            for py in range(y0, y1 + 1):
                dy = my - (py + 0.5)
                row = (py - py0) * TILE_SIZE - px0
                sx0, sx1 = _row_span(mx, dy, ca, inv_ca, cb, cc, smax, x0, x1)
                for px in range(sx0, sx1 + 1):
                    p = row + px
                    if done[p]:
                        continue
                    dx = mx - (px + 0.5)
                    sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                    if sigma < 0.0:
                        continue
                    alpha = min(ALPHA_MAX, op * _exp_neg(sigma))
                    if alpha < ALPHA_MIN:
                        continue
                    if T[p] * (1.0 - alpha) <= T_MIN:  # as rasterize_forward: left out, and the pixel stops
                        done[p] = True
                        n_done += 1
                        continue
                    T[p] *= 1.0 - alpha
            if n_done == tw * th:
                break
        while lev < n_levels:  # the levels behind every record (or behind the pixels' stop)
            _record_levels(out_A, lev, T, px0, py0, tw, th)
            lev += 1
        for ly in range(th):
            for lx in range(tw):
                out_T[py0 + ly, px0 + lx] = T[ly * TILE_SIZE + lx]


@njit(parallel=True, cache=True)
def rasterize_backward(offsets, ids, recs, width, height, T_final, last, v_rgb, v_depth, v_T, n_chunks,
                       g_mean2d, g_conic, g_opacity, g_color, g_depth, g_mean2d_abs):  # fmt: skip
    """Back-to-front gradient pass of ``rasterize_forward`` (same offsets/recs; ids [n_isect] maps a
    record to its Gaussian). v_rgb [H,W,3], v_depth [H,W], v_T [H,W] are the loss gradients w.r.t.
    its outputs. Gradients go per chunk of tiles into g_* [n_chunks, N, ...] (no two threads write
    the same row), for the caller to sum. g_mean2d_abs sums |dL/dmean2d| per pixel (3DGS's
    densification statistic)."""
    tiles_x = (width + TILE_SIZE - 1) // TILE_SIZE
    n_tiles = offsets.shape[0] - 1
    for c in prange(n_chunks):
        for t in range(c, n_tiles, n_chunks):
            px0 = (t % tiles_x) * TILE_SIZE
            py0 = (t // tiles_x) * TILE_SIZE
            tw = min(TILE_SIZE, width - px0)
            th = min(TILE_SIZE, height - py0)
            T = np.empty(TILE_SIZE * TILE_SIZE)
            # The pixel's loss gradients (rgb, depth) read once into the tile, and S: their dot product with
            # everything composited behind the current record, plus v_T * T_final (what occluding it costs).
            V = np.zeros((TILE_SIZE * TILE_SIZE, 4))
            S = np.zeros(TILE_SIZE * TILE_SIZE)
            lastp = np.full(TILE_SIZE * TILE_SIZE, -1, np.int32)
            k_max = -1
            for ly in range(th):
                for lx in range(tw):
                    p = ly * TILE_SIZE + lx
                    py, px = py0 + ly, px0 + lx
                    T[p] = T_final[py, px]
                    lastp[p] = last[py, px]
                    k_max = max(k_max, lastp[p])
                    V[p, 0], V[p, 1], V[p, 2] = v_rgb[py, px, 0], v_rgb[py, px, 1], v_rgb[py, px, 2]
                    V[p, 3] = v_depth[py, px]
                    S[p] = v_T[py, px] * T_final[py, px]
            for k in range(k_max, offsets[t] - 1, -1):
                mx, my = recs[k, REC_MEAN_X], recs[k, REC_MEAN_Y]
                x0, x1, y0, y1 = _box_in_tile(recs, k, px0, py0, tw, th, width, height)
                ca, cb, cc = recs[k, REC_CONIC_A], recs[k, REC_CONIC_B], recs[k, REC_CONIC_C]
                op, smax, inv_ca = recs[k, REC_OPACITY], recs[k, REC_SIGMA_MAX], recs[k, REC_INV_A]
                cr, cg, cbl, z = recs[k, REC_R], recs[k, REC_G], recs[k, REC_B], recs[k, REC_DEPTH]
                gm0 = gm1 = ga = gb = gc = go = gr = gg = gbl = gz = gabs0 = gabs1 = 0.0
                for py in range(y0, y1 + 1):
                    dy = my - (py + 0.5)
                    row = (py - py0) * TILE_SIZE - px0
                    sx0, sx1 = _row_span(mx, dy, ca, inv_ca, cb, cc, smax, x0, x1)
                    for px in range(sx0, sx1 + 1):
                        p = row + px
                        if k > lastp[p]:
                            continue
                        dx = mx - (px + 0.5)
                        sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                        if sigma < 0.0:
                            continue
                        vis = _exp_neg(sigma)
                        alpha = min(ALPHA_MAX, op * vis)
                        if alpha < ALPHA_MIN:
                            continue
                        inv_1ma = 1.0 / (1.0 - alpha)
                        T_i = T[p] * inv_1ma
                        w = alpha * T_i
                        vr, vg, vb, vd = V[p, 0], V[p, 1], V[p, 2], V[p, 3]
                        gr += w * vr
                        gg += w * vg
                        gbl += w * vb
                        gz += w * vd
                        v_c = vr * cr + vg * cg + vb * cbl + vd * z
                        # dL/dalpha: own weight, minus the share of everything behind it and of T_final
                        v_alpha = T_i * v_c - S[p] * inv_1ma
                        S[p] += w * v_c
                        T[p] = T_i
                        if op * vis <= ALPHA_MAX:  # the clamp passes no gradient
                            go += vis * v_alpha
                            v_sigma = -alpha * v_alpha
                            ga += 0.5 * dx * dx * v_sigma
                            gb += dx * dy * v_sigma
                            gc += 0.5 * dy * dy * v_sigma
                            d0 = (ca * dx + cb * dy) * v_sigma
                            d1 = (cc * dy + cb * dx) * v_sigma
                            gm0 += d0
                            gm1 += d1
                            gabs0 += abs(d0)
                            gabs1 += abs(d1)
                g = ids[k]
                g_mean2d[c, g, 0] += gm0
                g_mean2d[c, g, 1] += gm1
                g_mean2d_abs[c, g, 0] += gabs0
                g_mean2d_abs[c, g, 1] += gabs1
                g_conic[c, g, 0] += ga
                g_conic[c, g, 1] += gb
                g_conic[c, g, 2] += gc
                g_opacity[c, g] += go
                g_color[c, g, 0] += gr
                g_color[c, g, 1] += gg
                g_color[c, g, 2] += gbl
                g_depth[c, g] += gz


def num_threads() -> int:
    return numba.get_num_threads()
