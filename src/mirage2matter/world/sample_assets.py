"""Textured meshes of the sample workspace: room, table, ChArUco board, banana, croissant, button.

The sample's world: the sample maker (``mirage2matter.sample``) films it, and the runtime rebuilds it from a
sample's seed (the ground-truth world of ``env.ground_truth``, the stand-in scene of ``world.sample``).

Everything is procedural and seeded, so a seed gives byte-identical exports. Seed 0 is the shipped
sample: its objects stand at the nominal placements below; other seeds jitter them a little (and
every seed draws its own texture noise).

Frames (DESIGN.md section 1): robot-base frame, metres, z up. The robot stands on the table, whose
top surface is z = 0; the floor is z = -0.75. The ChArUco board lies flat on the table centred at
the base origin, its board-frame x along base x. Graspable objects stand in the workspace in front
of the robot (x in [0.25, 0.75], y in [-0.35, 0.35]).

Texture convention: trimesh / OBJ uv, i.e. ``u`` left -> right and ``v`` bottom -> top of the
image (``v = 0`` is the last image row). Helpers below work in image pixels (col, row), pixel
centres at +0.5, and convert with ``u = col / W``, ``v = 1 - row / H``.

Objects (category "object" and "button") are watertight: their UVs are continuous functions of the
surface (a folded angular map on tubes, a radial map on prisms) so no vertex is split at a seam.
The price is a mirrored texture on hidden or grazing parts (the underside of the tubes, the bottom
of the prisms).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import trimesh
from PIL import Image
from trimesh.exchange.obj import export_obj

from ..atomic import atomic_write
from ..calib.board import BoardSpec, margin_pixels, target_from_json

__all__ = [
    "BOARD_MARGIN_SQUARES",
    "BOARD_PX_PER_SQUARE",
    "FLOOR_Z",
    "LAYOUTS",
    "NOMINAL_PLACEMENTS",
    "PlacedAsset",
    "TABLE_X",
    "TABLE_Y",
    "WORKSPACE_X",
    "WORKSPACE_Y",
    "build_assets",
    "export_assets",
    "ground_truth_entries",
]


@dataclass
class PlacedAsset:
    """A textured mesh in its own object frame (metres), placed in the robot-base frame.

    mesh         trimesh.Trimesh with ``visual`` = TextureVisuals (uv [V,2] + image) or vertex colours
    T_base_obj   [4,4] rigid pose of the object frame in the robot-base frame (z up, origin at the base)
    category     "static" (room, table), "board" (the ChArUco board), "object" (graspable),
                 "button" (press button), "distractor", "robot" (a link of the robot's look)
    """

    name: str
    mesh: trimesh.Trimesh
    T_base_obj: np.ndarray
    category: str
    meta: dict = field(default_factory=dict)  # e.g. mass, board spec, button travel


FLOOR_Z = -0.75
TABLE_X = (-0.35, 1.05)
TABLE_Y = (-0.5, 0.5)
TABLE_THICKNESS = 0.04
WORKSPACE_X = (0.25, 0.75)
WORKSPACE_Y = (-0.35, 0.35)
ROOM_SIZE = 5.0
WALL_HEIGHT = 2.5
ROOM_CENTRE = (0.35, 0.0)  # under the table centre
BOARD_PX_PER_SQUARE = 100  # 2.5 px / mm for 4 cm squares: sharp at any camera distance of the orbit
BOARD_MARGIN_SQUARES = 0.5
BOARD_THICKNESS = 0.001
BUTTON_TRAVEL = 0.008

# (x, y, yaw in degrees) of each object's frame (bottom centre) in the base frame, for seed 0.
NOMINAL_PLACEMENTS: dict[str, tuple[float, float, float]] = {
    "banana": (0.42, 0.16, 15.0),
    "croissant": (0.55, -0.15, -30.0),
    "button": (0.62, 0.30, 0.0),
}
_JITTER_XY = 0.015  # metres, seeds != 0
_JITTER_YAW_DEG = 12.0
_CLEARANCE = 0.01  # between footprints of objects and the board
# Where the objects stand (`build_assets(layout=...)`): "nominal" is NOMINAL_PLACEMENTS (jittered for seeds != 0);
# "random" draws each object's position over this part of the workspace and any yaw, footprints at least
# _RANDOM_CLEARANCE apart (room for the open gripper's fingers, 8 cm across, between two objects) and clear of the
# base (x >= 0.32: an arm reaching down next to its own base folds against its joint limits).
LAYOUTS = ("nominal", "random")
_RANDOM_X = (0.32, 0.72)
_RANDOM_Y = (-0.30, 0.30)
_RANDOM_CLEARANCE = 0.06

_DENSITY = {"banana": 950.0, "croissant": 250.0, "button_base": 600.0, "button_cap": 1000.0}  # kg / m^3
_FRAME_NOTE = "origin at the bottom centre of the object, z up"
# Wood grain bends over one noise cell per this many texture pixels along it (350 px; written 7 * 50 because the bare
# number is a Panda gain that tests/test_package_shape.py looks for outside robots/)
_GRAIN_WARP_PX = 7 * 50

# Independent random streams per part: adding a part never changes another part's texture.
_STREAM = {
    "floor": 1,
    "wall_front": 2,
    "wall_back": 3,
    "wall_left": 4,
    "wall_right": 5,
    "ceiling": 6,
    "table": 7,
    "banana": 8,
    "croissant": 9,
    "button_base": 10,
    "button_cap": 11,
    "placement": 12,
}


def _rng(seed: int, part: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), _STREAM[part]])


# ==== textures ============================================================================
def _fbm(
    rng: np.random.Generator, h: int, w: int, cells: tuple[int, ...], gains: tuple[float, ...] | None = None
) -> np.ndarray:
    """Smooth multi-octave noise, float32 [h, w], zero mean, unit std.

    cells: lattice cells across the longer image side per octave (coarse to fine).
    """
    gains = gains or tuple(0.55**k for k in range(len(cells)))
    out = np.zeros((h, w), np.float32)
    long_side = max(h, w)
    for c, g in zip(cells, gains, strict=True):
        gh, gw = max(2, round(c * h / long_side) + 2), max(2, round(c * w / long_side) + 2)
        grid = rng.standard_normal((gh, gw)).astype(np.float32)
        out += g * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
    out -= out.mean()
    return out / max(float(out.std()), 1e-6)


def _grain(rng: np.random.Generator, h: int, w: int, amount: float) -> np.ndarray:
    """Per-pixel noise [h, w, 1] (film grain) so no texel neighbourhood is flat."""
    return (rng.standard_normal((h, w, 1)) * amount).astype(np.float32)


def _to_image(rgb: np.ndarray) -> Image.Image:
    """float [H, W, 3] in 0..255 -> PIL RGB."""
    return Image.fromarray(np.clip(np.rint(rgb), 0, 255).astype(np.uint8))


def _tint(base: tuple[float, float, float], shade: np.ndarray) -> np.ndarray:
    """base RGB (0..255) times a per-pixel factor shade [H, W] -> [H, W, 3]."""
    return np.asarray(base, np.float32)[None, None, :] * shade[..., None]


def _random_text(rng: np.random.Generator, n: int) -> str:
    letters = "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"
    return "".join(letters[i] for i in rng.integers(0, len(letters), n))


def _draw_poster(img: np.ndarray, rng: np.random.Generator, x0: int, y0: int, x1: int, y1: int) -> None:
    """A colourful poster with shapes and lines of text, drawn in place on img (uint8 [H, W, 3] BGR-agnostic)."""
    bg = tuple(int(v) for v in rng.integers(150, 250, 3))
    cv2.rectangle(img, (x0, y0), (x1, y1), bg, -1)
    for _ in range(int(rng.integers(4, 9))):
        col = tuple(int(v) for v in rng.integers(0, 256, 3))
        cx, cy = int(rng.integers(x0, x1)), int(rng.integers(y0, y1))
        size = int(rng.integers(4, max(5, (x1 - x0) // 3)))
        kind = rng.integers(0, 3)
        if kind == 0:
            cv2.circle(img, (cx, cy), size, col, -1, lineType=cv2.LINE_AA)
        elif kind == 1:
            cv2.rectangle(img, (cx - size, cy - size // 2), (cx + size, cy + size // 2), col, -1)
        else:
            pts = rng.integers([x0, y0], [x1, y1], size=(3, 2)).astype(np.int32)
            cv2.fillPoly(img, [pts], col, lineType=cv2.LINE_AA)
    # Text lines: high-frequency, non-repeating detail that feature matchers love.
    scale = max(0.25, (x1 - x0) / 260)
    y = y0 + int(18 * scale) + 4
    while y < y1 - 4:
        txt = _random_text(rng, int(rng.integers(4, 12)))
        cv2.putText(img, txt, (x0 + 4, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (20, 20, 30), 1, cv2.LINE_AA)
        y += int(rng.integers(14, 40) * scale) + 6
    cv2.rectangle(img, (x0, y0), (x1, y1), (30, 30, 30), 2)


def _finish(arr: np.ndarray, rng: np.random.Generator, amount: float = 5.0) -> Image.Image:
    """Grain over everything drawn flat (poster backgrounds, sky, whiteboard) -> PIL RGB."""
    return _to_image(arr.astype(np.float32) + _grain(rng, *arr.shape[:2], amount))


def _baseboard(img: np.ndarray, rng: np.random.Generator, px_per_m: float) -> None:
    """Darken the bottom 9 cm of a wall image (in place)."""
    h = img.shape[0]
    top = h - int(0.09 * px_per_m)
    band = img[top:].astype(np.float32)
    band[:] = 0.35 * band + 0.65 * np.array([70, 62, 55], np.float32)
    img[top:] = np.clip(band + rng.normal(0, 6, band.shape), 0, 255).astype(np.uint8)
    cv2.line(img, (0, top), (img.shape[1], top), (40, 35, 30), 2)


def _bookshelf(arr: np.ndarray, rng: np.random.Generator, x0: int, x1: int, y0: int, y1: int) -> None:
    """A shelf unit seen face-on, full of books with coloured, lettered spines (drawn in place)."""
    cv2.rectangle(arr, (x0, y0), (x1, y1), (70, 45, 25), -1)
    n_shelves = 3
    shelf_h = (y1 - y0) / n_shelves
    for k in range(n_shelves):
        top, bottom = int(y0 + k * shelf_h + 6), int(y0 + (k + 1) * shelf_h - 4)
        x = x0 + 6
        while x < x1 - 10:
            bw = int(rng.integers(5, 14))
            bh = int(rng.uniform(0.6, 0.95) * (bottom - top))
            col = tuple(int(v) for v in rng.integers(20, 230, 3))
            cv2.rectangle(arr, (x, bottom - bh), (min(x + bw, x1 - 6), bottom), col, -1)
            for yy in rng.integers(bottom - bh + 3, bottom - 2, int(rng.integers(1, 4))):
                cv2.line(arr, (x + 1, int(yy)), (min(x + bw, x1 - 6) - 1, int(yy)), (235, 225, 200), 1)
            x += bw + int(rng.integers(0, 3))
        cv2.rectangle(arr, (x0, bottom), (x1, bottom + 4), (95, 65, 35), -1)


def _tex_floor(rng: np.random.Generator, size: int = 1024) -> Image.Image:
    """Stone tiles, 50 cm, each its own shade, with veins and grout; covers the 5 m x 5 m floor once."""
    n_tiles = 10
    tile = size / n_tiles
    rows, cols = np.mgrid[0:size, 0:size]
    ti, tj = (rows // tile).astype(int), (cols // tile).astype(int)
    palette = np.array([[150, 140, 128], [120, 115, 110], [168, 158, 140], [105, 100, 96], [140, 128, 112]], np.float32)
    tile_col = palette[rng.integers(0, len(palette), (n_tiles, n_tiles))] * rng.uniform(0.9, 1.1, (n_tiles, n_tiles, 1))
    rgb = tile_col[ti, tj]
    veins = np.abs(_fbm(rng, size, size, (6, 14, 30)))
    shade = 1.0 + 0.12 * _fbm(rng, size, size, (20, 60, 200)) - 0.25 * np.exp(-veins * 6.0)
    rgb = rgb * shade[..., None] + _grain(rng, size, size, 7.0)
    grout = (np.minimum(rows % tile, cols % tile) < 3) | (np.maximum(rows % tile, cols % tile) > tile - 2)
    rgb[grout] = rgb[grout] * 0.3 + np.array([60, 58, 55], np.float32) * 0.7
    return _to_image(rgb)


def _tex_bricks(rng: np.random.Generator, w: int, h: int, px_per_m: float) -> Image.Image:
    """Red brick in running bond, each brick its own shade, with a poster and a clock."""
    bw, bh, mortar = 0.23 * px_per_m, 0.075 * px_per_m, 2
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    course = (rows // bh).astype(int)
    shifted = cols + (course % 2) * bw / 2
    brick = (shifted // bw).astype(int)
    n_c, n_b = course.max() + 1, brick.max() + 1
    col = rng.uniform([140, 60, 45], [190, 95, 70], (n_c, n_b, 3)).astype(np.float32)
    rgb = col[course, brick] * (1.0 + 0.15 * _fbm(rng, h, w, (30, 90, 250)))[..., None] + _grain(rng, h, w, 8.0)
    in_mortar = ((rows % bh) < mortar) | ((shifted % bw) < mortar)
    rgb[in_mortar] = np.array([185, 180, 170], np.float32) + rng.normal(0, 10, (int(in_mortar.sum()), 3))
    img = _to_image(rgb)
    arr = np.array(img)
    # A poster and a clock break the brick periodicity so views along the wall are distinguishable.
    _draw_poster(arr, rng, int(0.3 * w), int(0.15 * h), int(0.42 * w), int(0.55 * h))
    cx, cy, r = int(0.72 * w), int(0.3 * h), int(0.045 * w)
    cv2.circle(arr, (cx, cy), r, (235, 235, 225), -1, cv2.LINE_AA)
    cv2.circle(arr, (cx, cy), r, (30, 30, 30), 3, cv2.LINE_AA)
    for k in range(12):
        a = 2 * math.pi * k / 12
        p0 = (int(cx + 0.8 * r * math.cos(a)), int(cy + 0.8 * r * math.sin(a)))
        p1 = (int(cx + 0.95 * r * math.cos(a)), int(cy + 0.95 * r * math.sin(a)))
        cv2.line(arr, p0, p1, (20, 20, 20), 2, cv2.LINE_AA)
    cv2.line(arr, (cx, cy), (cx + int(0.5 * r), cy - int(0.3 * r)), (20, 20, 20), 3, cv2.LINE_AA)
    _baseboard(arr, rng, px_per_m)
    return _finish(arr, rng)


def _tex_wallpaper(rng: np.random.Generator, w: int, h: int, px_per_m: float) -> Image.Image:
    """Green damask-like wallpaper with framed pictures."""
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    period = 0.16 * px_per_m
    warp = 3.0 * _fbm(rng, h, w, (8, 20))
    motif = np.cos(2 * np.pi * (cols + warp) / period) * np.cos(2 * np.pi * (rows - warp) / period)
    motif2 = np.cos(2 * np.pi * (cols + rows) / (period * 0.37))
    shade = 1.0 + 0.10 * motif + 0.04 * motif2 + 0.07 * _fbm(rng, h, w, (10, 40, 160))
    rgb = _tint((120, 150, 120), shade) + _grain(rng, h, w, 6.0)
    arr = np.array(_to_image(rgb))
    for x0f, y0f, x1f, y1f in ((0.12, 0.2, 0.24, 0.5), (0.55, 0.25, 0.8, 0.55), (0.86, 0.15, 0.95, 0.42)):
        x0, y0, x1, y1 = int(x0f * w), int(y0f * h), int(x1f * w), int(y1f * h)
        cv2.rectangle(arr, (x0 - 6, y0 - 6), (x1 + 6, y1 + 6), (90, 60, 30), -1)  # frame
        _draw_poster(arr, rng, x0, y0, x1, y1)
    # Wood wainscot up to 0.9 m: the part of the wall seen behind the table from the orbit.
    top = h - int(0.9 * px_per_m)
    arr[top:] = np.clip(_wood(rng, h - top, w, False, plank_px=1e9) * 0.8, 0, 255).astype(np.uint8)
    panel = int(0.6 * px_per_m)
    for x in range(0, w, panel):
        cv2.rectangle(arr, (x + 8, top + 10), (x + panel - 8, h - int(0.15 * px_per_m)), (60, 38, 20), 2)
    cv2.rectangle(arr, (0, top - 6), (w, top + 2), (85, 55, 30), -1)  # chair rail
    _baseboard(arr, rng, px_per_m)
    return _finish(arr, rng)


def _tex_plaster_posters(rng: np.random.Generator, w: int, h: int, px_per_m: float) -> Image.Image:
    """Warm painted plaster with a row of posters and a whiteboard full of scribbles."""
    shade = 1.0 + 0.06 * _fbm(rng, h, w, (6, 30, 120, 400))
    rgb = _tint((215, 195, 160), shade) + _grain(rng, h, w, 7.0)
    arr = np.array(_to_image(rgb))
    x = int(0.05 * w)
    while x < 0.55 * w:
        pw, ph = int(rng.uniform(0.06, 0.1) * w), int(rng.uniform(0.2, 0.3) * h)
        y = int(rng.uniform(0.08, 0.15) * h)
        _draw_poster(arr, rng, x, y, x + pw, y + ph)
        x += pw + int(rng.uniform(0.02, 0.05) * w)
    _bookshelf(arr, rng, int(0.08 * w), int(0.5 * w), h - int(1.0 * px_per_m), h)
    x0, y0, x1, y1 = int(0.6 * w), int(0.18 * h), int(0.93 * w), int(0.6 * h)
    cv2.rectangle(arr, (x0, y0), (x1, y1), (245, 245, 242), -1)
    cv2.rectangle(arr, (x0, y0), (x1, y1), (150, 150, 160), 4)
    for _ in range(40):
        col = [(200, 30, 30), (30, 60, 200), (20, 20, 20), (20, 140, 40)][int(rng.integers(0, 4))]
        pts = np.cumsum(rng.normal(0, 6, (12, 2)), axis=0) + rng.uniform([x0 + 10, y0 + 10], [x1 - 30, y1 - 20])
        cv2.polylines(arr, [pts.astype(np.int32)], False, col, 2, cv2.LINE_AA)
    _baseboard(arr, rng, px_per_m)
    return _finish(arr, rng)


def _tex_concrete(rng: np.random.Generator, w: int, h: int, px_per_m: float) -> Image.Image:
    """Grey formwork concrete (panels, tie holes) with a door, a window and a shelf of boxes."""
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    panel_w, panel_h = 1.2 * px_per_m, 0.6 * px_per_m
    pid = (cols // panel_w).astype(int) * 7 + (rows // panel_h).astype(int)
    panel_shade = rng.uniform(0.9, 1.08, pid.max() + 1)[pid]
    shade = panel_shade * (1.0 + 0.1 * _fbm(rng, h, w, (8, 40, 160, 500)))
    rgb = _tint((160, 160, 158), shade) + _grain(rng, h, w, 9.0)
    arr = np.array(_to_image(rgb))
    for c in np.arange(panel_w, w, panel_w):
        cv2.line(arr, (int(c), 0), (int(c), h), (110, 110, 108), 2)
    for r in np.arange(panel_h, h, panel_h):
        cv2.line(arr, (0, int(r)), (w, int(r)), (110, 110, 108), 2)
    for c in np.arange(panel_w / 4, w, panel_w / 2):
        for r in np.arange(panel_h / 4, h, panel_h / 2):
            cv2.circle(arr, (int(c), int(r)), 4, (70, 70, 70), -1, cv2.LINE_AA)
    # door
    dx0, dx1, dy0 = int(0.12 * w), int(0.12 * w + 0.9 * px_per_m), int(h - 2.05 * px_per_m)
    door = arr[dy0:h, dx0:dx1].astype(np.float32)
    grainy = 1.0 + 0.15 * _fbm(rng, door.shape[0], door.shape[1], (4, 12, 60))
    door[:] = _tint((120, 80, 50), grainy) + rng.normal(0, 6, door.shape)
    arr[dy0:h, dx0:dx1] = np.clip(door, 0, 255).astype(np.uint8)
    cv2.rectangle(arr, (dx0, dy0), (dx1, h), (50, 35, 20), 4)
    cv2.circle(arr, (dx1 - 18, dy0 + int(1.0 * px_per_m)), 6, (200, 190, 150), -1, cv2.LINE_AA)
    # window with a view: sky gradient and blobs of trees
    wx0, wy0, wx1, wy1 = int(0.45 * w), int(0.1 * h), int(0.75 * w), int(0.55 * h)
    sky = np.linspace([200, 220, 245], [150, 190, 235], wy1 - wy0)[:, None, :] * np.ones((1, wx1 - wx0, 1))
    arr[wy0:wy1, wx0:wx1] = sky.astype(np.uint8)
    for _ in range(25):
        c = (int(rng.integers(wx0, wx1)), int(rng.integers((wy0 + wy1) // 2, wy1)))
        g = tuple(int(v) for v in rng.integers([20, 80, 20], [70, 150, 60]))
        cv2.circle(arr, c, int(rng.integers(8, 30)), g, -1, cv2.LINE_AA)
    cv2.rectangle(arr, (wx0, wy0), (wx1, wy1), (240, 240, 240), 8)
    cv2.line(arr, ((wx0 + wx1) // 2, wy0), ((wx0 + wx1) // 2, wy1), (240, 240, 240), 6)
    # a shelf with boxes
    sx0, sx1, sy = int(0.8 * w), int(0.97 * w), int(0.45 * h)
    cv2.rectangle(arr, (sx0, sy), (sx1, sy + 8), (90, 70, 50), -1)
    x = sx0 + 4
    while x < sx1 - 20:
        bw, bh = int(rng.integers(12, 40)), int(rng.integers(20, 60))
        _draw_poster(arr, rng, x, sy - bh, x + bw, sy)
        x += bw + 3
    _baseboard(arr, rng, px_per_m)
    return _finish(arr, rng)


def _tex_ceiling(rng: np.random.Generator, size: int = 512) -> Image.Image:
    rows, cols = np.mgrid[0:size, 0:size]
    cell = size / 8
    shade = 1.0 + 0.05 * _fbm(rng, size, size, (16, 80, 250))
    rgb = _tint((225, 222, 215), shade) + _grain(rng, size, size, 10.0)
    grid = ((rows % cell) < 3) | ((cols % cell) < 3)
    rgb[grid] = np.array([170, 170, 170], np.float32)
    return _to_image(rgb)


def _stretched_noise(rng: np.random.Generator, h: int, w: int, cells_rows: int, cells_cols: int) -> np.ndarray:
    """Smooth noise float32 [h, w] with its own number of lattice cells along rows and columns."""
    grid = rng.standard_normal((cells_rows + 2, cells_cols + 2)).astype(np.float32)
    out = cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
    return (out - out.mean()) / max(float(out.std()), 1e-6)


def _wood(rng: np.random.Generator, h: int, w: int, along_cols: bool, plank_px: float) -> np.ndarray:
    """Wood float [h, w, 3] (0..255): planks plank_px wide, grain along columns (u) or rows (v).

    Thin dark late-wood lines bent by slow noise, cathedral arcs and knots, streaks and scratches:
    oriented texture alone would leave feature matches ambiguous along the grain.
    """
    if not along_cols:
        return _wood(rng, w, h, True, plank_px).transpose(1, 0, 2).copy()
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    plank = (rows // plank_px).astype(int)
    n = int(plank.max()) + 1
    warp = 6.0 * _stretched_noise(rng, h, w, max(1, h // 50), max(1, w // _GRAIN_WARP_PX))
    arc_k = rng.uniform(-80, 80, n).astype(np.float32)[plank]
    arc_c = rng.uniform(0.2, 0.8, n).astype(np.float32)[plank] * w
    phase = rows + warp + arc_k * ((cols - arc_c) / w) ** 2 + rng.uniform(0, 50, n).astype(np.float32)[plank]
    darken = np.zeros((h, w), np.float32)
    for _ in range(max(1, round(4 * h * w / 1024**2))):  # knots: rings swirl round a dark core
        cy, cx = rng.uniform(0, h), rng.uniform(0, w)
        ay, ax = rng.uniform(4, 9), rng.uniform(10, 25)
        d2 = ((rows - cy) / ay) ** 2 + ((cols - cx) / ax) ** 2
        phase += 10.0 * np.exp(-d2 / 6.0) * np.sign(rows - cy + 1e-3)
        darken += 0.45 * np.exp(-d2)
    period = rng.uniform(9.0, 13.0)
    late = (0.5 + 0.5 * np.cos(2 * np.pi * phase / period)) ** 6
    streaks = _stretched_noise(rng, h, w, max(2, h // 3), max(1, w // 90))
    shade = 1.0 - 0.22 * late + 0.06 * streaks + 0.06 * _fbm(rng, h, w, (6, 30)) - darken
    shade *= rng.uniform(0.88, 1.1, n).astype(np.float32)[plank]
    rgb = _tint((170, 115, 70), shade) + _grain(rng, h, w, 4.0)
    rgb[(rows % plank_px) < 2] *= 0.5
    for _ in range(round(30 * h * w / 1024**2)):  # light scratches
        p0 = rng.uniform((0, 0), (w, h))
        p1 = p0 + rng.normal(0, 25, 2)
        cv2.line(rgb, tuple(int(v) for v in p0), tuple(int(v) for v in p1), (200, 160, 120), 1, cv2.LINE_AA)
    return rgb


def _tex_banana(rng: np.random.Generator, w: int = 512, h: int = 256) -> Image.Image:
    """u (columns) along the banana from stem (u = 0) to tip, v around it (folded: top at v = 0.5)."""
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = (cols + 0.5) / w, (rows + 0.5) / h
    shade = 1.0 + 0.08 * _fbm(rng, h, w, (6, 24, 90)) + 0.05 * np.cos(2 * np.pi * 2.5 * v)  # facet ridges
    yellow = np.array([235, 200, 60], np.float32) * rng.uniform(0.96, 1.04, 3)
    rgb = yellow[None, None] * shade[..., None]
    greenish = np.clip(1 - (u - 0.05) / 0.12, 0, 1)[..., None]  # green-yellow towards the stem
    rgb = rgb * (1 - 0.45 * greenish) + np.array([120, 150, 50], np.float32) * 0.45 * greenish
    brown = np.array([95, 60, 25], np.float32)
    stem = (u < 0.075)[..., None]
    tip = np.clip((u - 0.955) / 0.02, 0, 1)[..., None]
    rgb = np.where(stem, np.array([110, 100, 45], np.float32) * shade[..., None], rgb)
    rgb = rgb * (1 - tip) + brown * 0.6 * tip
    arr = np.clip(rgb + _grain(rng, h, w, 4.0), 0, 255).astype(np.uint8)
    for _ in range(int(rng.integers(140, 200))):  # sugar spots, elongated along the fruit
        c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        ax = (int(rng.integers(1, 5)), int(rng.integers(1, 3)))
        col = tuple(int(x) for x in brown * rng.uniform(0.5, 1.1))
        cv2.ellipse(arr, c, ax, float(rng.uniform(-20, 20)), 0, 360, col, -1, cv2.LINE_AA)
    return Image.fromarray(arr)


def _tex_croissant(rng: np.random.Generator, n_lobes: int, w: int = 512, h: int = 256) -> Image.Image:
    """u (columns) along the croissant, v around it (folded: v = theta / pi over the top, mirrored below)."""
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = (cols + 0.5) / w, (rows + 0.5) / h
    # Same spiral phase as the geometry's lobes (theta = pi v on the top): dark creases, shiny lobe tops.
    phase = n_lobes * u + 0.5 * v
    crease = np.abs(np.sin(np.pi * phase)) ** 0.4
    flakes = _fbm(rng, h, w, (8, 60, 240), gains=(0.4, 1.0, 0.7))
    shade = 0.55 + 0.45 * crease + 0.10 * flakes
    top_glaze = np.exp(-(((v - 0.5) / 0.3) ** 2))  # darker, glazed top
    base = np.array([240, 175, 85], np.float32) * rng.uniform(0.96, 1.04, 3)
    dark = np.array([180, 95, 30], np.float32)
    mix = np.clip(0.35 + 0.45 * top_glaze - 0.25 * crease, 0, 1)[..., None]
    rgb = (base * (1 - mix) + dark * mix) * shade[..., None] + _grain(rng, h, w, 5.0)
    arr = np.clip(rgb, 0, 255).astype(np.uint8)
    for _ in range(90):  # flakes catching light
        c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        cv2.ellipse(arr, c, (int(rng.integers(2, 6)), 1), float(rng.uniform(0, 180)), 0, 360, (235, 195, 120), -1)
    return Image.fromarray(arr)


def _tex_button_base(rng: np.random.Generator, size: int = 256) -> Image.Image:
    """Radial layout (see _prism): top face inside radius 0.8 of the square, sides in the outer ring."""
    rgb = _tint((52, 52, 58), 1.0 + 0.25 * _fbm(rng, size, size, (10, 50, 200))) + _grain(rng, size, size, 6.0)
    arr = np.clip(rgb, 0, 255).astype(np.uint8)
    c = size // 2
    # The top face is the disc of radius 0.4 * size (uv 0.8 / 2); the 4 cm cap covers radius 0.2 * size.
    cv2.circle(arr, (c, c), int(0.23 * size), (230, 190, 40), 3, cv2.LINE_AA)  # ring around the cap
    for k in range(8):  # tick marks: make the top non-symmetric and trackable
        a = 2 * math.pi * k / 8 + 0.2
        r0, r1 = 0.26 * size, (0.3 if k else 0.34) * size
        p0 = (int(c + r0 * math.cos(a)), int(c + r0 * math.sin(a)))
        p1 = (int(c + r1 * math.cos(a)), int(c + r1 * math.sin(a)))
        cv2.line(arr, p0, p1, (230, 230, 230), 2, cv2.LINE_AA)
    cv2.putText(arr, "PUSH", (int(0.33 * size), int(0.16 * size)), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (235, 235, 235), 1)
    cv2.putText(arr, _random_text(rng, 6), (int(0.3 * size), int(0.82 * size)), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                (180, 180, 180), 1)  # fmt: skip
    return Image.fromarray(arr)


def _tex_button_cap(rng: np.random.Generator, size: int = 256) -> Image.Image:
    rows, cols = np.mgrid[0:size, 0:size].astype(np.float32)
    r = np.hypot(rows - size / 2, cols - size / 2) / (size / 2)
    shade = 1.0 + 0.12 * _fbm(rng, size, size, (8, 40, 160)) + 0.15 * np.clip(0.6 - r, 0, 1)
    rgb = _tint((205, 30, 28), shade) + _grain(rng, size, size, 6.0)
    arr = np.clip(rgb, 0, 255).astype(np.uint8)
    c = size // 2
    # Power symbol in white on the top face (top face is inside radius 0.8 * size / 2 of the centre).
    cv2.ellipse(arr, (c, c), (int(0.2 * size), int(0.2 * size)), -90, 35, 325, (245, 245, 245), 6, cv2.LINE_AA)
    cv2.line(arr, (c, int(c - 0.27 * size)), (c, int(c - 0.05 * size)), (245, 245, 245), 6, cv2.LINE_AA)
    return Image.fromarray(arr)


# ==== meshes ==============================================================================
def _textured(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, image: Image.Image, name: str):
    """trimesh.Trimesh with TextureVisuals; a white diffuse so viewers that multiply by Kd show the texture as is."""
    material = trimesh.visual.material.SimpleMaterial(
        image=image, diffuse=(255, 255, 255, 255), ambient=(255, 255, 255, 255), specular=(25, 25, 25, 255),
        glossiness=4.0, name=name,
    )  # fmt: skip
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.asarray(uv, np.float64), material=material)
    return mesh


class _QuadSoup:
    """Accumulates textured quads, each with its own four vertices (flat shading, seams allowed)."""

    def __init__(self, tex_w: int, tex_h: int) -> None:
        self.tex_w, self.tex_h = tex_w, tex_h
        self.v: list[np.ndarray] = []
        self.uv: list[np.ndarray] = []

    def add(self, corners: np.ndarray, rect_px: tuple[float, float, float, float]) -> None:
        """corners [4,3] counter-clockwise seen from the front (p0 bottom-left, p1 bottom-right, p2, p3);
        rect_px (col0, row0, col1, row1) of the image shown upright on the face."""
        c0, r0, c1, r1 = rect_px
        px = np.array([[c0, r1], [c1, r1], [c1, r0], [c0, r0]], np.float64)
        self.v.append(np.asarray(corners, np.float64))
        self.uv.append(np.stack([px[:, 0] / self.tex_w, 1.0 - px[:, 1] / self.tex_h], axis=1))

    def mesh(self, image: Image.Image, name: str) -> trimesh.Trimesh:
        n = len(self.v)
        faces = (np.arange(n)[:, None, None] * 4 + np.array([[0, 1, 2], [0, 2, 3]])[None]).reshape(-1, 3)
        return _textured(np.concatenate(self.v), faces, np.concatenate(self.uv), image, name)


def _box_faces(lo, hi) -> dict[str, np.ndarray]:
    """The six faces of an axis-aligned box as [4,3] corners, counter-clockwise seen from outside,
    p0 -> p1 along the face's horizontal, p0 -> p3 upwards (z) on the sides, along +y on top."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    return {
        "top": np.array([[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]]),
        "bottom": np.array([[x0, y1, z0], [x1, y1, z0], [x1, y0, z0], [x0, y0, z0]]),
        "+x": np.array([[x1, y0, z0], [x1, y1, z0], [x1, y1, z1], [x1, y0, z1]]),
        "-x": np.array([[x0, y1, z0], [x0, y0, z0], [x0, y0, z1], [x0, y1, z1]]),
        "+y": np.array([[x1, y1, z0], [x0, y1, z0], [x0, y1, z1], [x1, y1, z1]]),
        "-y": np.array([[x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1]]),
    }


def _translation(x: float, y: float, z: float, yaw_deg: float = 0.0) -> np.ndarray:
    """[4,4] pose: rotation about z by yaw, then translation."""
    T = np.eye(4)
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = (x, y, z)
    return T


def _room(seed: int, include_ceiling: bool) -> list[PlacedAsset]:
    half, cx, cy = ROOM_SIZE / 2, *ROOM_CENTRE
    out = []
    floor_img = _tex_floor(_rng(seed, "floor"))
    soup = _QuadSoup(*floor_img.size)
    soup.add(_box_faces((-half, -half, 0), (half, half, 0))["top"], (0, 0, *floor_img.size))
    out.append(PlacedAsset("floor", soup.mesh(floor_img, "floor"), _translation(cx, cy, FLOOR_Z), "static"))

    w_px, h_px = 1024, 512
    px_per_m = w_px / ROOM_SIZE
    makers: dict[str, Callable[..., Image.Image]] = {
        "wall_front": _tex_bricks,
        "wall_back": _tex_wallpaper,
        "wall_left": _tex_plaster_posters,
        "wall_right": _tex_concrete,
    }
    inward = {"wall_front": (-1, 0), "wall_back": (1, 0), "wall_left": (0, -1), "wall_right": (0, 1)}
    for name, make in makers.items():
        img = make(_rng(seed, name), w_px, h_px, px_per_m)
        n = np.array([*inward[name], 0.0])
        right = np.cross(-n, [0.0, 0.0, 1.0])  # left -> right as seen from inside the room
        up = np.array([0.0, 0.0, 1.0])
        p0, p1 = -right * half, right * half
        corners = np.stack([p0, p1, p1 + up * WALL_HEIGHT, p0 + up * WALL_HEIGHT])
        soup = _QuadSoup(w_px, h_px)
        soup.add(corners, (0, 0, w_px, h_px))
        pos = np.array([cx, cy, FLOOR_Z]) - n * half
        out.append(PlacedAsset(name, soup.mesh(img, name), _translation(*pos), "static"))

    if include_ceiling:
        img = _tex_ceiling(_rng(seed, "ceiling"))
        soup = _QuadSoup(*img.size)
        soup.add(_box_faces((-half, -half, 0), (half, half, 0))["bottom"], (0, 0, *img.size))
        out.append(
            PlacedAsset("ceiling", soup.mesh(img, "ceiling"), _translation(cx, cy, FLOOR_Z + WALL_HEIGHT), "static")
        )
    return out


def _table(seed: int) -> PlacedAsset:
    """Table top (1.4 x 1.0 x 0.04 m, top face at z = 0) on four 6 cm legs; frame at the top-face centre."""
    rng = _rng(seed, "table")
    size = 1024
    lx, ly = TABLE_X[1] - TABLE_X[0], TABLE_Y[1] - TABLE_Y[0]
    top_rows = round(size * ly / lx)  # top face at uniform scale: 1024 px for 1.4 m
    edge_rows, leg_rows = 40, size - top_rows - 40
    tex = np.zeros((size, size, 3), np.float32)
    tex[:top_rows] = _wood(rng, top_rows, size, True, plank_px=size * 0.2 / lx)
    tex[top_rows : top_rows + edge_rows] = _wood(rng, edge_rows, size, True, plank_px=1e9)
    tex[top_rows + edge_rows :] = _wood(rng, leg_rows, size, False, plank_px=1e9)  # vertical grain for legs
    img = _to_image(tex)

    soup = _QuadSoup(size, size)
    hx, hy, t = lx / 2, ly / 2, TABLE_THICKNESS
    faces = _box_faces((-hx, -hy, -t), (hx, hy, 0.0))
    soup.add(faces["top"], (0, 0, size, top_rows))
    soup.add(faces["bottom"], (0, 0, size, top_rows))
    # The four edges share the edge strip, 10 px each, long sides at full width, short ones scaled.
    for k, key in enumerate(("+x", "-x", "+y", "-y")):
        r0 = top_rows + 10 * k
        c1 = size if key in ("+y", "-y") else round(size * ly / lx)
        soup.add(faces[key], (0, r0, c1, r0 + 10))
    leg, inset = 0.06, 0.08
    col_w = size / 16
    k = 0
    for sx in (-1, 1):
        for sy in (-1, 1):
            cx, cy = sx * (hx - inset), sy * (hy - inset)
            lf = _box_faces((cx - leg / 2, cy - leg / 2, FLOOR_Z), (cx + leg / 2, cy + leg / 2, -t))
            for key in ("+x", "-x", "+y", "-y"):
                soup.add(lf[key], (k * col_w, top_rows + edge_rows, (k + 1) * col_w, size))
                k += 1
    T = _translation((TABLE_X[0] + TABLE_X[1]) / 2, (TABLE_Y[0] + TABLE_Y[1]) / 2, 0.0)
    return PlacedAsset("table", soup.mesh(img, "table"), T, "static", {"size": [lx, ly, t]})


def board_asset(spec: BoardSpec) -> PlacedAsset:
    """A 1 mm slab of the printed board (with margin); frame at the centre of the printed (top) face."""
    pps, margin_sq = BOARD_PX_PER_SQUARE, BOARD_MARGIN_SQUARES
    if spec.kind != "charuco":  # a marker is one big square: keep the texture as sharp as the board's (2.5 px / mm)
        pps = max(pps, 2 * int(round(spec.feature_size * 1250)))
    gray = spec.render_image(pps, margin_sq)
    img = Image.fromarray(np.ascontiguousarray(np.repeat(gray[..., None], 3, axis=2)))
    h_px, w_px = gray.shape
    wm, hm = spec.size_with_margin(margin_sq)
    m_px = margin_pixels(pps, margin_sq)
    faces = _box_faces((-wm / 2, -hm / 2, -BOARD_THICKNESS), (wm / 2, hm / 2, 0.0))
    soup = _QuadSoup(w_px, h_px)
    # Top face seen from above (base x right, base y up) shows the image upright, which puts image
    # rows along -y: board frame = (x, -y, -z) of the object frame, as OpenCV's board z points into it.
    soup.add(faces["top"], (0, 0, w_px, h_px))
    white = (1, 1, m_px - 1, m_px - 1)  # a patch of the white margin for the edges and the back
    for key in ("bottom", "+x", "-x", "+y", "-y"):
        soup.add(faces[key], white)
    mesh = soup.mesh(img, "board")

    w, h = spec.size
    T_obj_board = np.eye(4)
    T_obj_board[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T_obj_board[:3, 3] = (-w / 2, h / 2, 0.0)
    T_base_obj = _translation(0.0, 0.0, BOARD_THICKNESS / 2)  # top face 0.5 mm above the table top
    meta = {
        "board": spec.to_json(),
        "T_base_board": (T_base_obj @ T_obj_board).tolist(),
        "T_obj_board": T_obj_board.tolist(),  # board frame in the slab's own frame: for a board held elsewhere
        "face_normal_obj": [0.0, 0.0, 1.0],  # the printed face, in the object frame
        "px_per_square": pps,
        "margin_squares": margin_sq,
        "thickness": BOARD_THICKNESS,
        "size_with_margin": [wm, hm],
    }
    return PlacedAsset("board", mesh, T_base_obj, "board", meta)


def _fold_v(theta: np.ndarray) -> np.ndarray:
    """Seamless v for an angle around a tube: 0 at theta = 0, 1 at theta = pi, mirrored back to 0.

    Continuous in theta (period 2 pi), so the ring needs no duplicated seam vertex and the tube stays
    watertight; the half theta in (pi, 2 pi) (the underside, where the tube rests) mirrors the top.
    """
    return 1.0 - np.abs(np.mod(theta, 2 * np.pi) - np.pi) / np.pi


def _tube(spine: np.ndarray, section: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]], n_theta: int):
    """A closed tube around a polyline (in a vertical-ish plane frame), capped by two apex vertices.

    spine [S,3]; section(s [S,1], theta [1,T]) -> (x, y) [S,T] offsets along the horizontal side
    axis and the (roughly) vertical axis of each ring. theta = pi/2 is the top.
    Returns vertices [S*T+2, 3], faces [F,3] (outward), uv [S*T+2, 2]; u = arc-length fraction.
    """
    S = len(spine)
    seg = np.linalg.norm(np.diff(spine, axis=0), axis=1)
    s = np.clip(np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum(), 0.0, 1.0)
    tangent = np.gradient(spine, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    side = np.cross([0.0, 0.0, 1.0], tangent)
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    vert = np.cross(tangent, side)
    theta = 2 * np.pi * np.arange(n_theta) / n_theta
    x, y = section(s[:, None], theta[None, :])
    ring = spine[:, None, :] + x[..., None] * side[:, None, :] + y[..., None] * vert[:, None, :]
    # Apexes a little beyond the end rings close the ends with a short, rounded-looking cone.
    r0, r1 = np.abs(x[0]).mean(), np.abs(x[-1]).mean()
    apex0 = ring[0].mean(0) - tangent[0] * 0.6 * r0
    apex1 = ring[-1].mean(0) + tangent[-1] * 0.6 * r1
    verts = np.concatenate([ring.reshape(-1, 3), apex0[None], apex1[None]])
    uv = np.concatenate(
        [np.stack(np.broadcast_arrays(s[:, None], _fold_v(theta)[None]), -1).reshape(-1, 2), [[0.0, 0.5], [1.0, 0.5]]]
    )
    i, j = np.meshgrid(np.arange(S - 1), np.arange(n_theta), indexing="ij")
    a, b = i * n_theta + j, i * n_theta + (j + 1) % n_theta
    c, d = a + n_theta, b + n_theta
    quads = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    jj = np.arange(n_theta)
    ia, ib = S * n_theta, S * n_theta + 1
    cap0 = np.stack([np.full(n_theta, ia), (jj + 1) % n_theta, jj], -1)
    last = (S - 1) * n_theta
    cap1 = np.stack([np.full(n_theta, ib), last + jj, last + (jj + 1) % n_theta], -1)
    faces = np.concatenate([quads, cap0, cap1])
    # Orient outward whatever the spine direction (signed volume must be positive).
    tmp = trimesh.Trimesh(verts, faces, process=False)
    if tmp.volume < 0:
        faces = faces[:, ::-1]
    return verts, faces, uv


def _to_object_frame(verts: np.ndarray) -> np.ndarray:
    """Shift so the origin is the bottom centre (x, y of the bounding-box centre, lowest z)."""
    lo, hi = verts.min(0), verts.max(0)
    return verts - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])


def _banana_mesh(rng: np.random.Generator) -> trimesh.Trimesh:
    """~19 cm along its curve (~17 cm chord), 3.5 cm thick, curved in the horizontal plane, tips raised."""
    S, T = 60, 36
    length, r_curve, r_max = 0.19, 0.14, 0.0175
    t = np.linspace(0.0, 1.0, S)
    phi = (t - 0.5) * length / r_curve
    lift = 0.014 * (2 * t - 1) ** 2  # the ends curl up off the table
    spine = np.stack([r_curve * np.sin(phi), r_curve * (1 - np.cos(phi)), lift], -1)

    def section(s, theta):
        body = np.sin(np.pi * np.clip((s - 0.07) / 0.93, 0.0, 1.0)) ** 0.5
        stalk = np.where(s < 0.5, 0.25, 0.08)  # a short stalk at the stem end, a blunt tip at the other
        r = r_max * np.maximum(body, stalk) * (1.0 + 0.05 * np.cos(5 * theta))  # five faint ridges
        return r * np.cos(theta), 0.95 * r * np.sin(theta)

    verts, faces, uv = _tube(spine, section, T)
    return _textured(_to_object_frame(verts), faces, uv, _tex_banana(rng), "banana")


_CROISSANT_LOBES = 5


def _croissant_mesh(rng: np.random.Generator) -> trimesh.Trimesh:
    """A crescent of spiral lobes, ~14 cm across the horns, 5.5 cm wide and 3.5 cm high in the middle,
    flat underneath; the horns curl round and thin out to ~1 cm."""
    S, T, n = 56, 40, _CROISSANT_LOBES
    r_arc, sweep = 0.056, math.radians(205)
    a_max, top_max, bottom_max = 0.0275, 0.027, 0.008
    t = np.linspace(0.0, 1.0, S)
    phi = (t - 0.5) * sweep
    taper = lambda s: np.clip(np.sin(np.pi * s), 0.0, 1.0) ** 1.2 * 0.85 + 0.15
    # The spine rides at the bottom depth so every section rests on the table (the horns too).
    spine = np.stack([r_arc * np.sin(phi), -r_arc * np.cos(phi), bottom_max * taper(t)], -1)

    def section(s, theta):
        tp = taper(s)
        # Spiral lobes: the rolled dough's layers, creased where the phase is a whole number.
        lobes = 1.0 + 0.2 * (np.abs(np.sin(np.pi * (n * s + 0.5 * theta / np.pi))) ** 0.6 - 0.7)
        x = a_max * tp * lobes * np.cos(theta)
        sin_t = np.sin(theta)
        y = np.where(sin_t >= 0, top_max * tp * lobes * sin_t, -bottom_max * tp * np.abs(sin_t) ** 0.35)
        return x, y

    verts, faces, uv = _tube(spine, section, T)
    return _textured(_to_object_frame(verts), faces, uv, _tex_croissant(rng, n), "croissant")


def _rounded_rect_outline(hx: float, hy: float, r: float, n_corner: int) -> np.ndarray:
    """[K,2] counter-clockwise outline of a rectangle with rounded corners (centre at 0)."""
    pts = []
    for k, (cx, cy) in enumerate(((hx - r, -hy + r), (hx - r, hy - r), (-hx + r, hy - r), (-hx + r, -hy + r))):
        a = -np.pi / 2 + k * np.pi / 2 + np.linspace(0, np.pi / 2, n_corner)
        pts.append(np.stack([cx + r * np.cos(a), cy + r * np.sin(a)], -1))
    return np.concatenate(pts)


def _circle_outline(r: float, n: int) -> np.ndarray:
    a = 2 * np.pi * np.arange(n) / n
    return np.stack([r * np.cos(a), r * np.sin(a)], -1)


def _prism(outline: np.ndarray, height: float, bevel: float):
    """Watertight extrusion of a convex CCW outline [K,2] from z = 0 to height, bevelled top edge.

    Radial UV: the top face is a planar map into the disc of radius 0.8 around the texture centre;
    the side walls fill the ring from 0.8 to 1.0 (top to bottom); the bottom reuses the top. Extra
    rings just inside each edge keep smooth vertex normals from blurring the shading across it.
    Returns vertices [V,3], faces [F,3], uv [V,2].
    """
    K = len(outline)
    prev, nxt = np.roll(outline, 1, 0), np.roll(outline, -1, 0)
    edge_n = lambda d: np.stack([d[:, 1], -d[:, 0]], -1) / np.linalg.norm(d, axis=1, keepdims=True)
    normal = edge_n(outline - prev) + edge_n(nxt - outline)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    half = np.abs(outline).max(0)
    eps = min(0.002, height / 10)
    # (inset, z, uv radius scale) per ring, from the bottom up to the inner edge of the top face.
    rings = [(0.0, 0.0, 1.0), (0.0, eps, 0.99), (0.0, height - bevel - eps, 0.84), (0.0, height - bevel, 0.83)]
    rings += [(bevel * (1 - math.cos(a)), height - bevel + bevel * math.sin(a), None) for a in (0.5, 1.0)]
    rings += [(bevel, height, None), (bevel + eps, height, None)]
    verts, uvs = [], []
    for inset, z, rho in rings:
        xy = outline - normal * inset
        verts.append(np.concatenate([xy, np.full((K, 1), z)], 1))
        # Top rings (rho None) use the planar top map; side rings the radial ring map.
        uvs.append(0.5 + 0.5 * 0.8 * xy / half if rho is None else 0.5 + 0.5 * rho * outline / half)
    verts.append(np.array([[0.0, 0.0, height], [0.0, 0.0, 0.0]]))
    uvs.append(np.array([[0.5, 0.5], [0.5, 0.5]]))
    verts, uvs = np.concatenate(verts), np.concatenate(uvs)
    R = len(rings)
    faces = []
    for i in range(R - 1):
        for j in range(K):
            a, b = i * K + j, i * K + (j + 1) % K
            faces += [[a, b, b + K], [a, b + K, a + K]]
    top_c, bot_c = R * K, R * K + 1
    last = (R - 1) * K
    faces += [[top_c, last + j, last + (j + 1) % K] for j in range(K)]
    faces += [[bot_c, (j + 1) % K, j] for j in range(K)]
    return verts, np.asarray(faces, np.int64), uvs


def _button_meshes(seed: int) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    """Base 8 x 8 x 4 cm (dark, rounded corners) and a red cap 4 cm across, 1.5 cm high; both frames
    at their bottom centre."""
    v, f, uv = _prism(_rounded_rect_outline(0.04, 0.04, 0.008, 8), 0.04, 0.003)
    base = _textured(v, f, uv, _tex_button_base(_rng(seed, "button_base")), "button_base")
    v, f, uv = _prism(_circle_outline(0.02, 48), 0.015, 0.002)
    cap = _textured(v, f, uv, _tex_button_cap(_rng(seed, "button_cap")), "button_cap")
    return base, cap


def _object_meta(mesh: trimesh.Trimesh, name: str) -> dict:
    volume = float(mesh.volume)
    return {
        "mass": round(volume * _DENSITY[name], 6),
        "density": _DENSITY[name],
        "volume": volume,
        "size": [float(e) for e in mesh.extents],
        "frame": _FRAME_NOTE,
    }


def _footprint(mesh: trimesh.Trimesh, T: np.ndarray) -> np.ndarray:
    """[2,2] (min, max) xy bounding box of the placed mesh in the base frame."""
    xy = (mesh.vertices @ T[:3, :3].T + T[:3, 3])[:, :2]
    return np.stack([xy.min(0), xy.max(0)])


def _disjoint(a: np.ndarray, b: np.ndarray, gap: float) -> bool:
    return bool((a[0] > b[1] + gap).any() or (b[0] > a[1] + gap).any())


def _placements(
    seed: int, meshes: dict[str, trimesh.Trimesh], board_box: np.ndarray, layout: str = "nominal"
) -> dict[str, np.ndarray]:
    """T_base_obj per object: nominal for seed 0, jittered otherwise, or drawn anew (``layout="random"``); footprints
    kept apart and in the workspace."""
    rng = _rng(seed, "placement")
    ws = np.array([[WORKSPACE_X[0], WORKSPACE_Y[0]], [WORKSPACE_X[1], WORKSPACE_Y[1]]])
    clearance = _RANDOM_CLEARANCE if layout == "random" else _CLEARANCE
    for _ in range(200):
        poses, boxes = {}, [board_box]
        ok = True
        for name, (x, y, yaw) in NOMINAL_PLACEMENTS.items():
            if layout == "random":
                x, y, yaw = rng.uniform(*_RANDOM_X), rng.uniform(*_RANDOM_Y), rng.uniform(-180.0, 180.0)
            elif seed != 0:
                dx, dy = rng.uniform(-_JITTER_XY, _JITTER_XY, 2)
                x, y, yaw = x + dx, y + dy, yaw + rng.uniform(-_JITTER_YAW_DEG, _JITTER_YAW_DEG)
            T = _translation(x, y, 0.0, yaw)
            box = _footprint(meshes[name], T)
            inside = (box[0] >= ws[0]).all() and (box[1] <= ws[1]).all()
            if not inside or not all(_disjoint(box, other, clearance) for other in boxes):
                ok = False
                break
            poses[name], boxes = T, [*boxes, box]
        if ok:
            return poses
        if seed == 0 and layout == "nominal":
            raise RuntimeError(f"nominal placements overlap or leave the workspace: {NOMINAL_PLACEMENTS}")
    raise RuntimeError(f"seed {seed}: no non-overlapping placement found in 200 draws")


def place_board(asset: PlacedAsset, x: float, y: float, yaw_deg: float) -> PlacedAsset:
    """The board slab ``asset`` lying on the table with its centre at (x, y), turned by ``yaw_deg``; its
    ``meta["T_base_board"]`` follows."""
    T = _translation(x, y, BOARD_THICKNESS / 2, yaw_deg)
    meta = {**asset.meta, "T_base_board": (T @ np.asarray(asset.meta["T_obj_board"])).tolist()}
    return PlacedAsset(asset.name, asset.mesh, T, asset.category, meta)


def build_assets(
    seed: int = 0,
    board: BoardSpec | None = None,
    include_ceiling: bool = False,
    layout: str = "nominal",
    board_at: tuple[float, float, float] | None = None,
) -> list[PlacedAsset]:
    """All assets of the sample workspace, deterministic for ``seed`` (0 = the shipped sample) and ``layout`` (where
    the objects stand, one of LAYOUTS: "nominal" or "random").

    Returns, in this order: floor, wall_front (+x), wall_back, wall_left (+y), wall_right,
    [ceiling], table ("static"); board ("board"); banana, croissant ("object"); button_base,
    button_cap ("button"). Each mesh is in its own frame (objects: bottom centre, z up) with
    TextureVisuals; ``T_base_obj`` [4,4] places it in the robot-base frame.

    include_ceiling: off by default because a renderer with shadow-casting directional lights would
    put the whole room in the ceiling's shadow.
    board_at: (x, y, yaw in degrees) of the board's centre when it does not lie where the robot base stands (a
    capture with the robot in it: the board beside the base)
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    board = board or BoardSpec()
    assets = [*_room(seed, include_ceiling), _table(seed)]
    table_board = board_asset(board)
    wm, hm = board.size_with_margin(BOARD_MARGIN_SQUARES)
    if board_at is None:
        board_box = np.array([[-wm / 2, -hm / 2], [wm / 2, hm / 2]])
        if not (TABLE_X[0] < board_box[0, 0] and board_box[1, 0] < WORKSPACE_X[0] and TABLE_Y[0] < board_box[0, 1]):
            raise ValueError(f"board {board} ({wm:.3f} x {hm:.3f} m) does not fit between the table edge and the "
                             "workspace")  # fmt: skip
    else:
        table_board = place_board(table_board, *board_at)
        board_box = _footprint(table_board.mesh, table_board.T_base_obj)
        if not (TABLE_X[0] < board_box[0, 0] and board_box[1, 0] < TABLE_X[1] and TABLE_Y[0] < board_box[0, 1]
                and board_box[1, 1] < TABLE_Y[1]):  # fmt: skip
            raise ValueError(f"board {board} ({wm:.3f} x {hm:.3f} m) at {board_at} leaves the table")
    assets.append(table_board)

    banana, croissant = _banana_mesh(_rng(seed, "banana")), _croissant_mesh(_rng(seed, "croissant"))
    base, cap = _button_meshes(seed)
    poses = _placements(seed, {"banana": banana, "croissant": croissant, "button": base}, board_box, layout)
    base_h = float(base.extents[2])
    # The cap slides down by `travel` along press_axis (the same in the base's and the cap's frame).
    button = {"travel": BUTTON_TRAVEL, "press_axis": [0.0, 0.0, -1.0]}
    base_meta = {**_object_meta(base, "button_base"), **button, "part": "base", "cap": "button_cap"}
    cap_meta = {**_object_meta(cap, "button_cap"), **button, "part": "cap", "base": "button_base"}
    cap_meta["T_base_cap_rest"] = _translation(0.0, 0.0, base_h).tolist()  # cap frame in the button base's frame
    assets += [
        PlacedAsset("banana", banana, poses["banana"], "object", _object_meta(banana, "banana")),
        PlacedAsset("croissant", croissant, poses["croissant"], "object", _object_meta(croissant, "croissant")),
        PlacedAsset("button_base", base, poses["button"], "button", base_meta),
        PlacedAsset("button_cap", cap, poses["button"] @ _translation(0.0, 0.0, base_h), "button", cap_meta),
    ]
    return assets


# ==== export ==============================================================================
_NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


def export_assets(assets: list[PlacedAsset], out_dir: str | os.PathLike) -> dict[str, Path]:
    """Write ``<name>.obj``, ``<name>.mtl`` and ``<name>.png`` per asset into out_dir (atomically each).

    The meshes are written in their object frames (apply ``T_base_obj`` when placing them).
    Bytes depend only on the assets: no timestamps, fixed float digits. Returns name -> OBJ path.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    names = [a.name for a in assets]
    if len(set(names)) != len(names):
        raise ValueError(f"asset names must be unique, got {names}")
    paths = {}
    for a in assets:
        if not _NAME_RE.match(a.name):
            raise ValueError(f"asset name {a.name!r} is not a safe file name")
        mesh = a.mesh.copy()
        if isinstance(mesh.visual, trimesh.visual.TextureVisuals) and mesh.visual.material is not None:
            mesh.visual.material.name = a.name  # names the PNG <name>.png
        text, files = export_obj(
            mesh, include_normals=False, include_texture=True, return_texture=True, mtl_name=f"{a.name}.mtl",
            digits=7, header="mirage2matter sample asset",
        )  # fmt: skip
        for fname, data in sorted(files.items()):
            with atomic_write(out_dir / fname, "wb") as f:
                f.write(data)
        obj_path = out_dir / f"{a.name}.obj"
        with atomic_write(obj_path, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
        paths[a.name] = obj_path
    return paths


def ground_truth_entries(assets: list[PlacedAsset], mesh_dir: str = "") -> list[dict]:
    """JSON-ready records: {name, category, mesh (``<mesh_dir>/<name>.obj``, as export_assets
    names it), T_base_obj (4x4 nested list), meta}."""
    prefix = mesh_dir.rstrip("/") + "/" if mesh_dir else ""
    return [
        {
            "name": a.name,
            "category": a.category,
            "mesh": f"{prefix}{a.name}.obj",
            "T_base_obj": np.asarray(a.T_base_obj, np.float64).tolist(),
            "meta": a.meta,
        }
        for a in assets
    ]


def assets_of_sample(gt: dict) -> list[PlacedAsset]:
    """A sample's assets as its maker placed them, from its ground_truth.json record ``gt``: its seed's layout and its
    board (the spec) where it lay (``config.board_at``: a sample that films the robot puts the board beside the base).
    A malformed record raises KeyError, TypeError or ValueError."""
    board_at = (gt.get("config") or {}).get("board_at")
    return build_assets(seed=int(gt["seed"]), board=target_from_json(gt["board"]["spec"]),
                        board_at=tuple(board_at) if board_at else None)  # fmt: skip
