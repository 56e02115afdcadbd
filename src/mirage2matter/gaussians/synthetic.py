"""The deterministic synthetic scene and cameras `m2m bench render` times (and renderer tests use).

``tabletop_scene`` imitates a trained 3DGS capture of a robot workspace in the robot-base frame
(metres, z up, base at the origin): a tiled floor, three painted walls with a door, a window and
a picture, a cabinet, the robot's pedestal, a wooden table in front of the robot and a few
objects on it (banana, croissant, a push button, a can) next to a ChArUco-like board. Gaussians
are flat discs lying in the surfaces (thin axis along the normal), sized to the budget so the
surfaces are covered, coloured from procedural textures with lighting baked in, as training
would produce. ``orbit_cameras`` gives views of the table.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from ..geometry.camera import look_at_pose
from ..geometry.sim3 import invert_rigid
from .model import Gaussians
from .sh import MAX_SH_DEGREE, rgb_to_sh_dc

# ---- scene layout (metres, robot-base frame) -------------------------------------------------
ROOM_MIN = (-2.4, -2.2, 0.0)
ROOM_MAX = (2.6, 2.2, 2.5)
TABLE_TOP_Z = 0.75
TABLE_MIN_XY = (0.2, -0.6)  # the table top is 0.8 m (x) by 1.2 m (y), its near edge 0.2 m from the base
TABLE_MAX_XY = (1.0, 0.6)
TABLE_THICKNESS = 0.04
# Box holding the table top and everything on it: the region of interest of a workspace capture.
TABLE_ROI_MIN = (0.15, -0.65, 0.70)
TABLE_ROI_MAX = (1.05, 0.65, 1.00)

# Share of the budget per group. A trained scene concentrates Gaussians where the cameras look
# and where the detail is, so the table and its objects get far more than their area would.
_GROUP_SHARES = {"room": 0.336, "table": 0.33, "objects": 0.25, "board": 0.08, "floaters": 0.004}

_LIGHT = np.array([0.35, 0.25, 1.0]) / np.linalg.norm([0.35, 0.25, 1.0])
_SH_BAND_STD = (0.05, 0.035, 0.025)  # view-dependent SH magnitude for bands 1..3

Texture = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]  # (p [m,3], n [m,3], uv [m,2]) -> rgb


# ---- procedural noise ------------------------------------------------------------------------
def _hash01(ix: np.ndarray, iy: np.ndarray, salt: int) -> np.ndarray:
    """Integer lattice -> uniform [0,1), deterministic (murmur-style finaliser on uint32)."""
    h = ix.astype(np.int64).astype(np.uint32) * np.uint32(0x27D4EB2D)
    h ^= iy.astype(np.int64).astype(np.uint32) * np.uint32(0x165667B1)
    h ^= np.uint32((salt * 0x9E3779B9) & 0xFFFFFFFF)
    h ^= h >> np.uint32(15)
    h *= np.uint32(0x85EBCA6B)
    h ^= h >> np.uint32(13)
    h *= np.uint32(0xC2B2AE35)
    h ^= h >> np.uint32(16)
    return h.astype(np.float64) / 4294967296.0


def _value_noise(x: np.ndarray, y: np.ndarray, salt: int) -> np.ndarray:
    """Smooth 2D value noise in [0,1] with unit lattice spacing."""
    ix, iy = np.floor(x), np.floor(y)
    fx, fy = x - ix, y - iy
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    v00, v10 = _hash01(ix, iy, salt), _hash01(ix + 1, iy, salt)
    v01, v11 = _hash01(ix, iy + 1, salt), _hash01(ix + 1, iy + 1, salt)
    return (v00 * (1 - fx) + v10 * fx) * (1 - fy) + (v01 * (1 - fx) + v11 * fx) * fy


def _fbm(x: np.ndarray, y: np.ndarray, salt: int, octaves: int = 4) -> np.ndarray:
    """Fractal sum of value noise, roughly in [0,1], mean 0.5."""
    total, amp, norm = np.zeros_like(x, dtype=np.float64), 1.0, 0.0
    for o in range(octaves):
        f = 2.0**o
        total += amp * _value_noise(x * f, y * f, salt + 101 * o)
        norm += amp
        amp *= 0.5
    return total / norm


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _mix(a, b, t: np.ndarray) -> np.ndarray:
    """Per-point blend of colours a and b ([3] or [m,3]) by t [m]."""
    t = t[:, None]
    return np.asarray(a) * (1 - t) + np.asarray(b) * t


def _const(rgb: tuple[float, float, float]) -> Texture:
    return lambda p, n, uv: np.broadcast_to(np.asarray(rgb, dtype=np.float64), p.shape).copy()


# ---- textures --------------------------------------------------------------------------------
def _floor_tex(p: np.ndarray, n: np.ndarray, uv: np.ndarray) -> np.ndarray:
    tile = 0.6
    tx, ty = np.floor(p[:, 0] / tile), np.floor(p[:, 1] / tile)
    shade = 0.82 + 0.22 * _hash01(tx, ty, 7)  # every tile a slightly different batch
    base = np.array([0.62, 0.58, 0.52]) * shade[:, None]
    base = base * (0.9 + 0.2 * _fbm(p[:, 0] * 9, p[:, 1] * 9, 11))[:, None]  # stone mottling
    fx, fy = p[:, 0] / tile - tx, p[:, 1] / tile - ty
    edge = np.minimum(np.minimum(fx, 1 - fx), np.minimum(fy, 1 - fy)) * tile
    grout = 1 - _smoothstep(0.004, 0.01, edge)
    col = _mix(base, (0.3, 0.29, 0.27), grout)
    # contact shadow of the table and the pedestal: soft darkening under and around them
    dx = np.maximum(np.maximum(TABLE_MIN_XY[0] - p[:, 0], p[:, 0] - TABLE_MAX_XY[0]), 0)
    dy = np.maximum(np.maximum(TABLE_MIN_XY[1] - p[:, 1], p[:, 1] - TABLE_MAX_XY[1]), 0)
    shadow = 1 - 0.45 * (1 - _smoothstep(0.0, 0.35, np.hypot(dx, dy)))
    shadow *= 1 - 0.4 * (1 - _smoothstep(0.1, 0.3, np.hypot(p[:, 0], p[:, 1])))
    return col * shadow[:, None]


def _wall_tex(p: np.ndarray, n: np.ndarray, uv: np.ndarray) -> np.ndarray:
    # along-wall coordinate: y on the x-facing wall, x on the y-facing walls
    s = np.where(np.abs(n[:, 0]) > 0.5, p[:, 1], p[:, 0])
    z = p[:, 2]
    paint = np.array([0.80, 0.78, 0.73])
    col = paint * (0.94 + 0.08 * _fbm(s * 2, z * 2, 21, 3))[:, None] * (0.9 + 0.06 * z / 2.5)[:, None]
    col = np.where((z < 0.09)[:, None], np.array([0.33, 0.31, 0.29]), col)  # baseboard

    front = n[:, 0] < -0.5
    left = n[:, 1] < -0.5  # the wall at y = +2.2
    right = n[:, 1] > 0.5  # the wall at y = -2.2
    # a framed picture on the front wall
    pic = front & (s > -1.0) & (s < 0.3) & (z > 1.1) & (z < 1.9)
    inner = pic & (s > -0.97) & (s < 0.27) & (z > 1.13) & (z < 1.87)
    land = _fbm(s * 3, z * 3, 31)
    sky = _mix((0.45, 0.62, 0.85), (0.85, 0.88, 0.92), land)
    hills = _mix((0.22, 0.42, 0.18), (0.45, 0.55, 0.25), land)
    horizon = 1.4 + 0.12 * (_fbm(s * 2, np.zeros_like(s), 33) - 0.5)
    art = np.where((z > horizon)[:, None], sky, hills)
    col = np.where(pic[:, None], np.array([0.08, 0.07, 0.06]), col)
    col = np.where(inner[:, None], art, col)
    # a wooden door on the right wall
    door = right & (s > 0.8) & (s < 1.7) & (z < 2.05)
    grain = _fbm(s * 30, z * 1.5, 41)
    door_col = _mix((0.50, 0.32, 0.18), (0.36, 0.22, 0.12), grain)
    knob = door & (np.hypot(s - 1.6, z - 1.0) < 0.03)
    col = np.where(door[:, None], door_col, col)
    col = np.where(knob[:, None], np.array([0.75, 0.72, 0.6]), col)
    # a bright window on the left wall
    win = left & (s > -1.6) & (s < 0.0) & (z > 1.0) & (z < 2.0)
    frame = win & ((np.abs(s + 0.8) < 0.02) | (np.abs(z - 1.5) < 0.02) | (s < -1.57) | (s > -0.03) | (z < 1.03))
    glass = _mix((0.92, 0.95, 1.0), (0.7, 0.8, 0.95), _fbm(s * 1.5, z * 1.5, 51))
    col = np.where(win[:, None], glass, col)
    col = np.where(frame[:, None], np.array([0.9, 0.9, 0.88]), col)
    return col


def _ceiling_tex(p: np.ndarray, n: np.ndarray, uv: np.ndarray) -> np.ndarray:
    col = np.array([0.86, 0.86, 0.84]) * (0.95 + 0.05 * _fbm(p[:, 0] * 2, p[:, 1] * 2, 111, 2))[:, None]
    # two rows of light panels
    lamp = (np.abs(p[:, 1]) > 0.5) & (np.abs(p[:, 1]) < 1.1) & (np.abs(p[:, 0] - 0.3) < 0.6)
    return np.where(lamp[:, None], np.array([1.0, 0.99, 0.95]), col * 0.85)


def _wood_tex(salt: int, light=(0.74, 0.55, 0.35), dark=(0.50, 0.32, 0.17)) -> Texture:
    def tex(p: np.ndarray, n: np.ndarray, uv: np.ndarray) -> np.ndarray:
        x, y = p[:, 0], p[:, 1] + 0.3 * p[:, 2]
        # grain runs along y: growth rings are stretched bands in x, warped by low-frequency noise
        warp = 1.5 * _fbm(x * 4, y * 0.6, salt)
        rings = np.sin(2 * np.pi * (x * 18 + warp)) * 0.5 + 0.5
        streak = _fbm(x * 160, y * 3, salt + 5, 3)
        t = np.clip(0.55 * rings**3 + 0.6 * (streak - 0.35), 0, 1)
        col = _mix(light, dark, t)
        plank = (x - TABLE_MIN_XY[0]) / ((TABLE_MAX_XY[0] - TABLE_MIN_XY[0]) / 4)
        seam = np.abs(plank - np.round(plank)) * (TABLE_MAX_XY[0] - TABLE_MIN_XY[0]) / 4
        col *= (1 - 0.5 * (1 - _smoothstep(0.001, 0.003, seam)) * (n[:, 2] > 0.5))[:, None]
        return col

    return tex


def _table_top_tex() -> Texture:
    wood = _wood_tex(61)
    # soft contact shadows of the objects standing on the table (x, y, radius, strength)
    casters = ((0.60, 0.20, 0.08, 0.35), (0.78, -0.18, 0.11, 0.4), (0.42, -0.02, 0.08, 0.45), (0.86, 0.36, 0.06, 0.45))

    def tex(p: np.ndarray, n: np.ndarray, uv: np.ndarray) -> np.ndarray:
        col = wood(p, n, uv)
        shade = np.ones(len(p))
        for cx, cy, r, k in casters:
            d = np.hypot(p[:, 0] - cx, p[:, 1] - cy)
            shade *= 1 - k * (1 - _smoothstep(r * 0.6, r * 1.4, d))
        return col * shade[:, None]

    return tex


_BOARD_ORIGIN = (0.25, -0.52)  # corner of the ChArUco-like board on the table, near the robot
_BOARD_SQUARES = (6, 8)  # squares along x, y
_BOARD_SQUARE = 0.03
_BOARD_MARGIN = 0.01


def _board_tex(p: np.ndarray, n: np.ndarray, uv: np.ndarray) -> np.ndarray:
    u = (p[:, 0] - _BOARD_ORIGIN[0] - _BOARD_MARGIN) / _BOARD_SQUARE
    v = (p[:, 1] - _BOARD_ORIGIN[1] - _BOARD_MARGIN) / _BOARD_SQUARE
    iu, iv = np.floor(u), np.floor(v)
    inside = (iu >= 0) & (iu < _BOARD_SQUARES[0]) & (iv >= 0) & (iv < _BOARD_SQUARES[1])
    black = ((iu + iv) % 2 == 0) & inside
    # white squares carry a 4x4-bit marker inside a black border, as ArUco markers do
    fu, fv = (u - iu - 0.15) / 0.7, (v - iv - 0.15) / 0.7
    in_marker = inside & ~black & (fu > 0) & (fu < 1) & (fv > 0) & (fv < 1)
    bu, bv = np.floor(fu * 6), np.floor(fv * 6)
    border = (bu == 0) | (bu == 5) | (bv == 0) | (bv == 5)
    bit = _hash01(iu * 16 + bu, iv * 16 + bv, 71) < 0.5
    dark = black | (in_marker & (border | bit))
    return np.where(dark[:, None], np.array([0.05, 0.05, 0.06]), np.array([0.93, 0.93, 0.91]))


def _banana_tex(p: np.ndarray, n: np.ndarray, uv: np.ndarray) -> np.ndarray:
    u, v = uv[:, 0], uv[:, 1]
    col = _mix((0.95, 0.80, 0.20), (0.66, 0.72, 0.24), _smoothstep(0.7, 0.9, u))  # green towards the stem
    speck = _fbm(u * 40, v * 6, 81)
    col *= (1 - 0.35 * _smoothstep(0.62, 0.8, speck))[:, None]
    col *= (1 - 0.12 * (np.cos(5 * v) > 0.92))[:, None]  # ridges between the facets
    tip = (u < 0.035) | (u > 0.93)
    return np.where(tip[:, None], np.array([0.32, 0.24, 0.12]), col)


def _croissant_tex(p: np.ndarray, n: np.ndarray, uv: np.ndarray) -> np.ndarray:
    u = uv[:, 0]
    crust = _mix((0.86, 0.62, 0.30), (0.58, 0.33, 0.11), _smoothstep(-0.2, 0.9, n[:, 2]))
    groove = _smoothstep(0.5, 0.9, -np.cos(2 * np.pi * 6 * u))  # paler dough between the rolls
    col = _mix(crust, (0.93, 0.78, 0.52), 0.7 * groove)
    return col * (0.9 + 0.2 * _fbm(u * 30, uv[:, 1] * 4, 91))[:, None]


def _can_tex(p: np.ndarray, n: np.ndarray, uv: np.ndarray) -> np.ndarray:
    z = p[:, 2] - TABLE_TOP_Z
    col = np.where(((z > 0.045) & (z < 0.075))[:, None], np.array([0.92, 0.92, 0.9]), np.array([0.10, 0.25, 0.65]))
    ang = np.arctan2(p[:, 1] - 0.36, p[:, 0] - 0.86)
    logo = (z > 0.05) & (z < 0.07) & (np.abs(np.sin(3 * ang)) < 0.25)
    col = np.where(logo[:, None], np.array([0.8, 0.1, 0.1]), col)
    return np.where((n[:, 2] > 0.5)[:, None], np.array([0.72, 0.73, 0.75]), col)


def _cabinet_tex(p: np.ndarray, n: np.ndarray, uv: np.ndarray) -> np.ndarray:
    col = np.array([0.86, 0.86, 0.83]) * (0.95 + 0.06 * _fbm(p[:, 1] * 5, p[:, 2] * 5, 101, 2))[:, None]
    facing = n[:, 0] < -0.5
    gap = (np.abs(p[:, 2] - 0.3) < 0.004) | (np.abs(p[:, 2] - 0.6) < 0.004) | (np.abs(p[:, 1] - 1.55) < 0.004)
    gap &= facing
    handle = facing & (np.abs(p[:, 1] - 1.55) > 0.08) & (np.abs(p[:, 1] - 1.55) < 0.2)
    handle &= (np.abs(p[:, 2] - 0.52) < 0.01) | (np.abs(p[:, 2] - 0.82) < 0.01) | (np.abs(p[:, 2] - 0.22) < 0.01)
    col = np.where(gap[:, None], np.array([0.3, 0.3, 0.3]), col)
    return np.where(handle[:, None], np.array([0.45, 0.46, 0.5]), col)


# ---- surface primitives ----------------------------------------------------------------------
@dataclass
class _Samples:
    points: np.ndarray  # [m,3]
    normals: np.ndarray  # [m,3] unit, outward
    tangents: np.ndarray  # [m,3] unit, orthogonal to the normal (preferred elongation)
    rgb: np.ndarray  # [m,3]


@dataclass
class _Part:
    name: str
    group: str
    area: float
    sample: Callable[[np.random.Generator, int], _Samples]
    max_sigma: float  # cap on the in-plane scale: a Gaussian may not outgrow its surface
    density: float = 1.0  # weight within the group, per square metre
    aligned: bool = False  # elongate along the sampler's tangent (wood grain) instead of at random


@dataclass
class _Rect:
    origin: np.ndarray  # corner [3]
    eu: np.ndarray  # edge vector [3]
    ev: np.ndarray  # edge vector [3]; normal = eu x ev (outward)
    tex: Texture

    @property
    def area(self) -> float:
        return float(np.linalg.norm(np.cross(self.eu, self.ev)))


def _rect(origin, eu, ev, tex: Texture) -> _Rect:
    return _Rect(np.asarray(origin, float), np.asarray(eu, float), np.asarray(ev, float), tex)


def _box_rects(lo, hi, tex: Texture, bottom: bool = False) -> list[_Rect]:
    """Faces of an axis-aligned box with outward normals (the bottom face only if asked)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
    faces = [
        _rect((x0, y0, z1), (dx, 0, 0), (0, dy, 0), tex),  # +z
        _rect((x1, y0, z0), (0, dy, 0), (0, 0, dz), tex),  # +x
        _rect((x0, y0, z0), (0, 0, dz), (0, dy, 0), tex),  # -x
        _rect((x0, y1, z0), (0, 0, dz), (dx, 0, 0), tex),  # +y
        _rect((x0, y0, z0), (dx, 0, 0), (0, 0, dz), tex),  # -y
    ]
    if bottom:
        faces.append(_rect((x0, y0, z0), (0, dy, 0), (dx, 0, 0), tex))
    return faces


def _r2(rng: np.random.Generator, k: int) -> np.ndarray:
    """k well-spread points in the unit square [k,2] (R2 low-discrepancy sequence, random shift).

    Densification leaves a trained scene's Gaussians far more evenly spread than independent
    uniform draws would, so surfaces are covered without holes at a modest Gaussian size.
    """
    g = 1.32471795724474602596  # plastic number
    alpha = np.array([1 / g, 1 / g**2])
    return (rng.random(2) + np.arange(1, k + 1)[:, None] * alpha) % 1.0


def _split_by_area(rng: np.random.Generator, areas: list[float], m: int) -> np.ndarray:
    return rng.multinomial(m, np.asarray(areas) / np.sum(areas))


def _rects_part(name: str, group: str, rects: list[_Rect], max_sigma: float, **kw) -> _Part:
    def sample(rng: np.random.Generator, m: int) -> _Samples:
        out = []
        for r, k in zip(rects, _split_by_area(rng, [r.area for r in rects], m), strict=True):
            ab = _r2(rng, k)
            p = r.origin + ab[:, :1] * r.eu + ab[:, 1:] * r.ev
            nrm = np.broadcast_to(np.cross(r.eu, r.ev) / r.area, (k, 3))
            tan = np.broadcast_to(r.ev / np.linalg.norm(r.ev), (k, 3))
            uv = ab * [np.linalg.norm(r.eu), np.linalg.norm(r.ev)]
            out.append(_Samples(p, nrm.copy(), tan.copy(), r.tex(p, nrm, uv)))
        return _cat_samples(out)

    return _Part(name, group, sum(r.area for r in rects), sample, max_sigma, **kw)


def _cylinder_part(
    name: str,
    group: str,
    cx: float,
    cy: float,
    z0: float,
    z1: float,
    radius: float,
    side: Texture,
    cap: Texture,
    max_sigma: float,
    **kw,
) -> _Part:
    """Vertical cylinder: side wall plus the top disc."""
    a_side, a_cap = 2 * math.pi * radius * (z1 - z0), math.pi * radius**2

    def sample(rng: np.random.Generator, m: int) -> _Samples:
        k_side, k_cap = _split_by_area(rng, [a_side, a_cap], m)
        ab = _r2(rng, k_side)
        th, z = 2 * math.pi * ab[:, 0], z0 + (z1 - z0) * ab[:, 1]
        nrm = np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], 1)
        p = np.stack([cx + radius * nrm[:, 0], cy + radius * nrm[:, 1], z], 1)
        tan = np.broadcast_to([0.0, 0.0, 1.0], (k_side, 3)).copy()
        s_side = _Samples(p, nrm, tan, side(p, nrm, np.stack([th * radius, z], 1)))
        ab = _r2(rng, k_cap)
        r, th = radius * np.sqrt(ab[:, 0]), 2 * math.pi * ab[:, 1]
        p = np.stack([cx + r * np.cos(th), cy + r * np.sin(th), np.full(k_cap, z1)], 1)
        nrm = np.broadcast_to([0.0, 0.0, 1.0], (k_cap, 3)).copy()
        tan = np.stack([-np.sin(th), np.cos(th), np.zeros_like(th)], 1)
        s_cap = _Samples(p, nrm, tan, cap(p, nrm, np.stack([r, th], 1)))
        return _cat_samples([s_side, s_cap])

    return _Part(name, group, a_side + a_cap, sample, max_sigma, **kw)


def _tube_part(
    name: str,
    group: str,
    centre: Callable[[np.ndarray], np.ndarray],
    radius: Callable[[np.ndarray], np.ndarray],
    tex: Texture,
    max_sigma: float,
    squash: float = 1.0,
    **kw,
) -> _Part:
    """Generalised cylinder around the curve ``centre(u)`` [m]->[m,3], u in [0,1], radius ``radius(u)``.

    The cross-section is an ellipse, ``squash`` times as high (towards +z) as it is wide.
    """
    ug = np.linspace(0.0, 1.0, 2049)
    speed = np.linalg.norm(np.gradient(centre(ug), ug, axis=0), axis=1)
    dens = radius(ug) * speed * (1 + squash) / 2  # area element per du, over 2 pi
    cdf = np.concatenate([[0.0], np.cumsum((dens[1:] + dens[:-1]) / 2 * np.diff(ug))])
    area = float(2 * math.pi * cdf[-1])

    def sample(rng: np.random.Generator, m: int) -> _Samples:
        ab = _r2(rng, m)
        u = np.interp(ab[:, 0] * cdf[-1], cdf, ug)  # inverse CDF: uniform over the area
        v = 2 * math.pi * ab[:, 1]
        c = centre(u)
        h = 1e-4
        t = centre(np.clip(u + h, 0, 1)) - centre(np.clip(u - h, 0, 1))
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        up = np.array([0.0, 0.0, 1.0])
        e1 = up - (t @ up)[:, None] * t
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        e2 = np.cross(t, e1)
        r = radius(u)[:, None]
        cv, sv = np.cos(v)[:, None], np.sin(v)[:, None]
        p = c + r * (squash * cv * e1 + sv * e2)
        nrm = cv * e1 + squash * sv * e2  # normal of the ellipse (a cos, b sin) is (b cos, a sin)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        return _Samples(p, nrm, t, tex(p, nrm, np.stack([u, v], 1)))

    return _Part(name, group, area, sample, max_sigma, **kw)


def _cat_samples(parts: list[_Samples]) -> _Samples:
    return _Samples(*(np.concatenate([getattr(s, f) for s in parts]) for f in ("points", "normals", "tangents", "rgb")))


# ---- the scene -------------------------------------------------------------------------------
def _banana_centre(u: np.ndarray) -> np.ndarray:
    a = np.pi / 2 + (u - 0.5) * 1.3  # an arc of radius 0.17 m, concave towards -y
    lift = 0.012 * (2 * u - 1) ** 2  # tips curl up off the table
    return np.stack([0.60 + 0.17 * np.cos(a), 0.03 + 0.17 * np.sin(a), TABLE_TOP_Z + 0.018 + lift], 1)


def _banana_radius(u: np.ndarray) -> np.ndarray:
    body = 0.018 * np.clip(np.sin(np.pi * np.clip(u / 0.93, 0, 1)), 0, 1) ** 0.45
    return np.where(u > 0.9, 0.005, np.maximum(body, 0.003))  # thin stem at the end


def _croissant_centre(u: np.ndarray) -> np.ndarray:
    a = -np.pi / 2 + (u - 0.5) * 4.4  # open towards -x, tips curling in
    r = 0.06 * (1 - 0.3 * (2 * u - 1) ** 2)
    return np.stack([0.78 + r * np.cos(a), -0.18 + r * np.sin(a) + 0.03, np.full_like(u, TABLE_TOP_Z + 0.021)], 1)


def _croissant_radius(u: np.ndarray) -> np.ndarray:
    return 0.03 * (0.25 + 0.75 * np.sin(np.pi * u) ** 0.9) * (1 + 0.1 * np.cos(2 * np.pi * 6 * u))


def _scene_parts() -> list[_Part]:
    x0, y0, z0 = ROOM_MIN
    x1, y1, z1 = ROOM_MAX
    tx0, ty0 = TABLE_MIN_XY
    tx1, ty1 = TABLE_MAX_XY
    top, bot = TABLE_TOP_Z, TABLE_TOP_Z - TABLE_THICKNESS
    legs = []
    for lx in (tx0 + 0.05, tx1 - 0.1):
        for ly in (ty0 + 0.05, ty1 - 0.1):
            legs += _box_rects((lx, ly, 0.0), (lx + 0.05, ly + 0.05, bot), _const((0.16, 0.16, 0.18)))
    slab = _box_rects((tx0, ty0, bot), (tx1, ty1, top), _wood_tex(63, (0.6, 0.42, 0.26), (0.42, 0.27, 0.14)))[1:]
    button_box = _box_rects((0.375, -0.065, top), (0.465, 0.025, top + 0.035), _const((0.92, 0.76, 0.10)))
    bw, bh = (k * _BOARD_SQUARE + 2 * _BOARD_MARGIN for k in _BOARD_SQUARES)
    return [
        _rects_part(
            "floor", "room", [_rect((x0, y0, z0), (x1 - x0, 0, 0), (0, y1 - y0, 0), _floor_tex)], 0.3, density=1.6
        ),
        _rects_part(
            "walls",
            "room",
            [
                _rect((x1, y1, z0), (0, y0 - y1, 0), (0, 0, z1 - z0), _wall_tex),  # front, facing -x
                _rect((x0, y1, z0), (x1 - x0, 0, 0), (0, 0, z1 - z0), _wall_tex),  # y = +2.2, facing -y
                _rect((x1, y0, z0), (x0 - x1, 0, 0), (0, 0, z1 - z0), _wall_tex),  # y = -2.2, facing +y
            ],
            0.3,
        ),
        _rects_part(
            "ceiling", "room", [_rect((x0, y0, z1), (0, y1 - y0, 0), (x1 - x0, 0, 0), _ceiling_tex)], 0.3, density=0.35
        ),
        _rects_part("cabinet", "room", _box_rects((2.1, 1.1, 0.0), (2.55, 2.0, 0.9), _cabinet_tex), 0.1, density=3.0),
        _cylinder_part(
            "pedestal",
            "room",
            0.0,
            0.0,
            0.0,
            top,
            0.1,
            _const((0.24, 0.25, 0.27)),
            _const((0.55, 0.56, 0.58)),
            0.04,
            density=6.0,
        ),
        _rects_part(
            "table_top",
            "table",
            [_rect((tx0, ty0, top), (tx1 - tx0, 0, 0), (0, ty1 - ty0, 0), _table_top_tex())],
            0.1,
            aligned=True,
        ),
        _rects_part("table_frame", "table", slab + legs, 0.012, density=0.6),
        _rects_part(
            "board",
            "board",
            [_rect((_BOARD_ORIGIN[0], _BOARD_ORIGIN[1], top + 0.001), (bw, 0, 0), (0, bh, 0), _board_tex)],
            0.02,
        ),
        _tube_part("banana", "objects", _banana_centre, _banana_radius, _banana_tex, 0.008, squash=0.9),
        _tube_part(
            "croissant", "objects", _croissant_centre, _croissant_radius, _croissant_tex, 0.01, squash=0.7, density=1.2
        ),
        _rects_part("button_box", "objects", button_box, 0.015),
        _cylinder_part(
            "button_cap",
            "objects",
            0.42,
            -0.02,
            top + 0.035,
            top + 0.055,
            0.026,
            _const((0.80, 0.08, 0.06)),
            _const((0.88, 0.12, 0.08)),
            0.008,
            density=2.0,
        ),
        _cylinder_part(
            "can", "objects", 0.86, 0.36, top, top + 0.12, 0.033, _can_tex, _const((0.72, 0.73, 0.75)), 0.012
        ),
    ]


def _allocate(parts: list[_Part], n: int) -> tuple[list[int], int]:
    """Counts per part (each at least one) plus a count of floaters, summing to exactly ``n``."""
    target = []
    for p in parts:
        group = [q for q in parts if q.group == p.group]
        w = sum(q.area * q.density for q in group)
        target.append(_GROUP_SHARES[p.group] * n * p.area * p.density / w)
    target.append(_GROUP_SHARES["floaters"] * n)
    counts = np.maximum(np.floor(target).astype(int), [1] * len(parts) + [0])
    short = n - int(counts.sum())
    order = np.argsort(-(np.asarray(target) - np.floor(target)), kind="stable")
    counts[order[:short]] += 1  # largest remainders first
    while counts.sum() > n:  # only when the minimum of one per part overshoots
        counts[int(np.argmax(counts))] -= 1
    return counts[:-1].tolist(), int(counts[-1])


def _frames_to_quats(normals: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """Quaternions (wxyz) of rotations whose columns are (tangent, normal x tangent, normal). [m,3]x2 -> [m,4]"""
    t2 = np.cross(normals, tangents)
    return _matrix_to_quat(np.stack([tangents, t2, normals], axis=2))


def _matrix_to_quat(r: np.ndarray) -> np.ndarray:
    """Rotation matrices [m,3,3] -> unit quaternions [m,4] wxyz, using the best-conditioned branch."""
    m00, m01, m02 = r[:, 0, 0], r[:, 0, 1], r[:, 0, 2]
    m10, m11, m12 = r[:, 1, 0], r[:, 1, 1], r[:, 1, 2]
    m20, m21, m22 = r[:, 2, 0], r[:, 2, 1], r[:, 2, 2]
    d = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], 1)
    s = 0.5 * np.sqrt(np.maximum(d, 1e-12))
    f = 0.25 / s
    cands = np.stack(
        [
            np.stack([s[:, 0], (m21 - m12) * f[:, 0], (m02 - m20) * f[:, 0], (m10 - m01) * f[:, 0]], 1),
            np.stack([(m21 - m12) * f[:, 1], s[:, 1], (m01 + m10) * f[:, 1], (m02 + m20) * f[:, 1]], 1),
            np.stack([(m02 - m20) * f[:, 2], (m01 + m10) * f[:, 2], s[:, 2], (m12 + m21) * f[:, 2]], 1),
            np.stack([(m10 - m01) * f[:, 3], (m02 + m20) * f[:, 3], (m12 + m21) * f[:, 3], s[:, 3]], 1),
        ],
        1,
    )
    q = cands[np.arange(len(r)), np.argmax(d, axis=1)]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _random_quats(rng: np.random.Generator, m: int) -> np.ndarray:
    q = rng.normal(size=(m, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _opacities(rng: np.random.Generator, m: int) -> np.ndarray:
    """Mostly near-opaque with a tail of faint ones, as after training."""
    high = 0.99 - 0.39 * rng.random(m) ** 2
    low = rng.uniform(0.05, 0.6, m)
    return np.where(rng.random(m) < 0.85, high, low)


def _higher_sh(rng: np.random.Generator, m: int, degree: int) -> np.ndarray:
    """Small random view-dependent coefficients [m, K-1, 3] for bands 1..degree."""
    bands = [rng.normal(0.0, _SH_BAND_STD[b - 1], (m, 2 * b + 1, 3)) for b in range(1, degree + 1)]
    return np.concatenate(bands, axis=1) if bands else np.zeros((m, 0, 3))


def _check(n: int, sh_degree: int, n_min: int) -> None:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < n_min:
        raise ValueError(f"number of Gaussians must be an integer >= {n_min}, got {n!r}")
    if not 0 <= sh_degree <= MAX_SH_DEGREE:
        raise ValueError(f"sh_degree must be in 0..{MAX_SH_DEGREE}, got {sh_degree}")


def _to_gaussians(means, quats, scales, opacities, rgb, sh_rest) -> Gaussians:
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))
    sh = np.concatenate([rgb_to_sh_dc(t(rgb)).numpy()[:, None, :], sh_rest], axis=1)
    return Gaussians.from_activated(t(means), t(quats), t(scales), t(opacities), sh=t(sh))


def tabletop_scene(n: int, sh_degree: int = 3, seed: int = 0) -> Gaussians:
    """A workspace-like scene of exactly ``n`` Gaussians (float32, CPU), deterministic for ``seed``.

    Layout (robot-base frame, metres, z up): room ``ROOM_MIN``..``ROOM_MAX`` with floor and three
    walls, robot pedestal at the origin, a 0.8 x 1.2 m table with its top at z = 0.75 spanning
    ``TABLE_MIN_XY``..``TABLE_MAX_XY``, objects and a checker board on it. The seed changes the
    sampling, not the layout or textures. Returns Gaussians with ``sh`` of shape [n, (sh_degree+1)^2, 3].
    """
    _check(n, sh_degree, 100)
    rng = np.random.default_rng(seed)
    parts = _scene_parts()
    counts, n_float = _allocate(parts, n)
    means, quats, scales, rgbs = [], [], [], []
    for part, m in zip(parts, counts, strict=True):
        s = part.sample(rng, m)
        # in-plane size from the area each Gaussian must cover, varied like a trained scene's
        sigma = 0.75 * math.sqrt(part.area / m) * rng.lognormal(0.0, 0.25, m)
        sigma = np.minimum(sigma, part.max_sigma * rng.uniform(0.7, 1.0, m))
        aniso = np.exp(np.abs(rng.normal(0.0, 0.6 if part.aligned else 0.35, m)))
        s1, s2 = sigma * np.sqrt(aniso), sigma / np.sqrt(aniso)
        s3 = np.maximum(0.1 * s2 * rng.lognormal(0.0, 0.3, m), 1e-4)  # thin along the normal
        phi = rng.normal(0.0, 0.1, m) if part.aligned else rng.uniform(0, np.pi, m)
        nrm, tan = s.normals, s.tangents
        tan = np.cos(phi)[:, None] * tan + np.sin(phi)[:, None] * np.cross(nrm, tan)
        means.append(s.points + nrm * rng.normal(0.0, 0.5, (m, 1)) * s3[:, None])  # not exactly on the plane
        quats.append(_frames_to_quats(nrm, tan))
        scales.append(np.stack([s1, s2, s3], 1))
        # bake in lighting (training does): a key light from above, plus ambient
        shade = 0.72 + 0.3 * np.clip(nrm @ _LIGHT, 0, None)
        rgbs.append(np.clip(s.rgb * shade[:, None] + rng.normal(0, 0.015, (m, 3)), 0.0, 1.0))
    # floaters: faint blobs in free space, the usual residue of training
    lo, hi = np.asarray(ROOM_MIN) + 0.1, np.asarray(ROOM_MAX) - 0.1
    means.append(rng.uniform(lo, hi, (n_float, 3)))
    quats.append(_random_quats(rng, n_float))
    scales.append(rng.uniform(0.005, 0.03, (n_float, 3)))
    rgbs.append(rng.uniform(0.3, 0.7, (n_float, 1)) * np.ones((1, 3)))
    opac = np.concatenate([_opacities(rng, n - n_float), rng.uniform(0.03, 0.2, n_float)])
    mean = np.clip(np.concatenate(means), ROOM_MIN, ROOM_MAX)
    return _to_gaussians(
        mean, np.concatenate(quats), np.concatenate(scales), opac, np.concatenate(rgbs), _higher_sh(rng, n, sh_degree)
    )


# ---- cameras ---------------------------------------------------------------------------------
def orbit_cameras(
    n_views: int,
    width: int,
    height: int,
    radius: float = 1.6,
    height_range: tuple[float, float] = (1.1, 1.6),
    target: tuple[float, float, float] = (0.55, 0.0, 0.8),
    fov_deg: float = 60.0,
    seed: int = 0,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Cameras on an arc around the table, all looking at ``target``.

    The arc spans azimuths 110..250 degrees about ``target`` (the robot's side of the table, so
    the back wall is behind the table), at horizontal distance ``radius`` and heights (absolute z)
    drawn from ``height_range``; ``seed`` jitters heights and azimuths. Returns ``n_views`` pairs
    (viewmat [4,4] float64 world-to-camera, OpenCV axes; K [3,3] float64 with fx = fy from the
    horizontal ``fov_deg`` and principal point (width/2, height/2), pixel centres at +0.5).
    """
    if n_views < 1 or width < 1 or height < 1:
        raise ValueError(f"need n_views, width, height >= 1, got {n_views}, {width}, {height}")
    if not 0.0 < fov_deg < 180.0:
        raise ValueError(f"fov_deg must be in (0, 180), got {fov_deg}")
    rng = np.random.default_rng(seed)
    tgt = np.asarray(target, dtype=np.float64)
    lo, hi = np.radians(110.0), np.radians(250.0)
    az = np.full(1, np.pi) if n_views == 1 else np.linspace(lo, hi, n_views)
    az = az + rng.uniform(-0.25, 0.25, n_views) * (hi - lo) / max(n_views, 2)
    zs = rng.uniform(height_range[0], height_range[1], n_views)
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    k = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
    cams = []
    for a, z in zip(az, zs, strict=True):
        eye = np.array([tgt[0] + radius * math.cos(a), tgt[1] + radius * math.sin(a), z])
        cams.append((invert_rigid(look_at_pose(eye, tgt)), k.copy()))
    return cams
