"""Calibration targets: a ChArUco board (:class:`BoardSpec`), a single ArUco marker or AprilTag
(:class:`MarkerSpec`) and an ArUco grid (:class:`GridSpec`): their specification, geometry, detection and a
printable image. All share one interface (``kind``, ``size``, ``feature_size``, ``describe()``,
``points_board(ids)``, ``detect(gray)``, ``render_image``, ``to_json``); :func:`load_target` reads any of them
(a JSON without ``"type"`` is a ChArUco board).

Point ids: a ChArUco board's are its inner-corner ids; a marker's are ``marker_id * 4 + corner`` with OpenCV's
corner order (top-left, top-right, bottom-right, bottom-left of the printed marker).

Board frame (OpenCV's, as ``cv2.aruco.CharucoBoard.getChessboardCorners()`` returns it):
origin at the top-left *outer* corner of the chessboard (the corner of the first square, not of
the white margin), x along the ``squares_x`` columns (right in the printed image), y along the
``squares_y`` rows (down in the printed image), z = x × y, i.e. pointing *into* the board, away
from a viewer of the printed face. The printed face is z = 0. Metres.

Image convention of :meth:`BoardSpec.render_image`: continuous pixel coordinates ``(col, row)``
with pixel centres at +0.5 (DESIGN.md section 1), so the image spans ``[0, W] x [0, H]`` and a
square edge lies exactly on a pixel boundary. OpenCV reports detections with pixel centres at
integers: add 0.5 before using :func:`board_image_to_board_frame`.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from mirage2matter.atomic import atomic_path

from ..atomic import atomic_write
from ..errors import M2MError
from ..inputs import InputError, read_json

__all__ = ["BoardError", "BoardSpec", "GridSpec", "MarkerSpec", "TARGET_KINDS", "board_frame_to_board_image",
           "board_image_to_board_frame", "load_target", "margin_pixels", "target_from_json", "target_plane"]

_FIELDS = ("squares_x", "squares_y", "square", "marker", "dictionary")


class BoardError(M2MError, ValueError):
    """A board spec (or board file) that cannot be used; the message names the field or file."""


def _dictionary_id(name: str) -> int:
    """cv2.aruco constant of a predefined dictionary name such as "DICT_5X5_100"."""
    value = getattr(cv2.aruco, name, None) if isinstance(name, str) and name.startswith("DICT_") else None
    if not isinstance(value, int):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise BoardError(f"BoardSpec.dictionary {name!r} is not a cv2.aruco predefined dictionary; known: {known}")
    return value


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: ``squares_x`` x ``squares_y`` chessboard squares of side ``square`` metres,
    ArUco markers of side ``marker`` metres (from ``dictionary``) in the white squares.

    The top-left square is black (OpenCV's layout); marker ids run row by row from 0. The defaults
    are the board of the sample and of FIELD_NOTES.md (5 x 7, 4 cm squares, 3 cm markers).
    """

    squares_x: int = 5
    squares_y: int = 7
    square: float = 0.04
    marker: float = 0.03
    dictionary: str = "DICT_5X5_100"

    def __post_init__(self) -> None:
        for name in ("squares_x", "squares_y"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 2:
                raise BoardError(f"BoardSpec.{name} must be an integer >= 2 (a board needs inner corners), got {v!r}")
            object.__setattr__(self, name, int(v))
        for name in ("square", "marker"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float | np.floating | np.integer):
                raise BoardError(f"BoardSpec.{name} must be a number (metres), got {v!r}")
            if not (math.isfinite(v) and v > 0):
                raise BoardError(f"BoardSpec.{name} must be finite and > 0 metres, got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.marker >= self.square:
            raise BoardError(
                f"BoardSpec.marker ({self.marker} m) must be smaller than BoardSpec.square ({self.square} m): "
                "the marker sits inside a white square"
            )
        dict_size = int(cv2.aruco.getPredefinedDictionary(_dictionary_id(self.dictionary)).bytesList.shape[0])
        needed = self.n_markers
        if needed > dict_size:
            raise BoardError(
                f"a {self.squares_x} x {self.squares_y} board needs {needed} markers but {self.dictionary} "
                f"has only {dict_size}"
            )

    # ---- geometry -----------------------------------------------------------------------
    @property
    def size(self) -> tuple[float, float]:
        """(width, height) of the chessboard in metres, without any margin: along board x, board y."""
        return (self.squares_x * self.square, self.squares_y * self.square)

    @property
    def n_corners(self) -> int:
        """Number of ChArUco (inner chessboard) corners: (squares_x - 1) * (squares_y - 1)."""
        return (self.squares_x - 1) * (self.squares_y - 1)

    @property
    def n_markers(self) -> int:
        """Number of ArUco markers, one per white square."""
        return self.squares_x * self.squares_y // 2

    def corner_points_board(self) -> np.ndarray:
        """[M, 3] float64 inner-corner positions in the board frame, M = n_corners, in ChArUco id order.

        Corner id ``k = i * (squares_x - 1) + j`` sits at ``((j + 1) * square, (i + 1) * square, 0)``
        (row by row, x fastest) — identical to ``cv_board().getChessboardCorners()``.
        """
        j, i = np.meshgrid(np.arange(1, self.squares_x), np.arange(1, self.squares_y))
        pts = np.stack([j.ravel() * self.square, i.ravel() * self.square, np.zeros(j.size)], axis=1)
        return pts.astype(np.float64)

    def size_with_margin(self, margin_squares: float = 0.5) -> tuple[float, float]:
        """(width, height) in metres of the printed sheet with a white margin of ``margin_squares`` squares."""
        m = 2.0 * margin_squares * self.square
        return (self.size[0] + m, self.size[1] + m)

    # ---- the target interface -----------------------------------------------------------
    kind = "charuco"

    @property
    def feature_size(self) -> float:
        """The pattern's unit (metres): the square side. Tolerances and printing scale with it."""
        return self.square

    def describe(self) -> str:
        return f"ChArUco {self.squares_x}x{self.squares_y}, {self.square * 100:g} cm squares, {self.dictionary}"

    def points_board(self, ids: np.ndarray | None = None) -> np.ndarray:
        """[M, 3] board-frame points of the inner-corner ``ids`` (all when None)."""
        pts = self.corner_points_board()
        return pts if ids is None else pts[np.asarray(ids, dtype=np.int64)]

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ids [M] int64, uv [M, 2] float64, OpenCV's pixel convention: centres at integers) of the inner
        corners found in ``gray`` (uint8 [H, W]); empty arrays when none."""
        corners, ids, _, _ = cv2.aruco.CharucoDetector(self.cv_board()).detectBoard(gray)
        if ids is None:
            return np.zeros(0, np.int64), np.zeros((0, 2))
        return ids.ravel().astype(np.int64), corners.reshape(-1, 2).astype(np.float64)

    # ---- OpenCV -------------------------------------------------------------------------
    def cv_dictionary(self) -> cv2.aruco.Dictionary:
        return cv2.aruco.getPredefinedDictionary(_dictionary_id(self.dictionary))

    def cv_board(self) -> cv2.aruco.CharucoBoard:
        """The ``cv2.aruco.CharucoBoard`` (OpenCV >= 4.6 layout, not the legacy one)."""
        board = cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square, self.marker, self.cv_dictionary())
        # Explicit, so a change of OpenCV's default cannot silently move markers on boards with even squares_y.
        board.setLegacyPattern(False)
        return board

    def render_image(self, px_per_square: int = 100, margin_squares: float = 0.5) -> np.ndarray:
        """The printable board, uint8 [H, W] (0 black, 255 white), with a white margin.

        W = squares_x * px_per_square + 2 * margin_px, H = squares_y * px_per_square + 2 * margin_px,
        margin_px = margin_squares * px_per_square (must be a whole number of pixels). Square edges
        fall exactly on pixel boundaries; :func:`board_image_to_board_frame` maps pixels to the board
        frame. The image is upright: rows run along board +y, columns along board +x.
        """
        pps = _check_px_per_square(px_per_square)
        m = margin_pixels(px_per_square, margin_squares)
        w, h = self.squares_x * pps + 2 * m, self.squares_y * pps + 2 * m
        # With the output size an exact multiple of the squares, generateImage draws at exactly pps per square.
        img = self.cv_board().generateImage((w, h), marginSize=m, borderBits=1)
        if img.shape != (h, w) or img.dtype != np.uint8:
            raise RuntimeError(f"cv2 generateImage returned {img.shape} {img.dtype}, expected ({h}, {w}) uint8")
        return img

    # ---- serialisation ------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        """``{"squares_x", "squares_y", "square", "marker", "dictionary"}``."""
        return {name: getattr(self, name) for name in _FIELDS}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> BoardSpec:
        if not isinstance(data, dict):
            raise BoardError(f"BoardSpec JSON must be an object, got {type(data).__name__}")
        unknown = set(data) - set(_FIELDS)
        if unknown:
            raise BoardError(f"BoardSpec JSON has unknown keys {sorted(unknown)}; expected {list(_FIELDS)}")
        missing = set(_FIELDS) - set(data)
        if missing:
            raise BoardError(f"BoardSpec JSON lacks {sorted(missing)}; expected {list(_FIELDS)}")
        return cls(**{name: data[name] for name in _FIELDS})

    def save(self, path: str | os.PathLike) -> None:
        """Write JSON atomically (temporary file in the same folder, then os.replace)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_write(path, "w", encoding="utf-8") as f:
            json.dump(self.to_json(), f, indent=2)
            f.write("\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> BoardSpec:
        try:
            data = read_json(path, "board spec")
        except InputError as e:
            raise BoardError(str(e)) from None
        try:
            return cls.from_json(data)
        except ValueError as e:
            raise BoardError(f"{path}: {e}") from e


def _positive_length(cls: str, name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float | np.floating | np.integer):
        raise BoardError(f"{cls}.{name} must be a number (metres), got {v!r}")
    if not (math.isfinite(v) and 0 < v < 10):
        raise BoardError(f"{cls}.{name} must be finite, > 0 and < 10 metres, got {v!r}")
    return float(v)


def _marker_id(cls: str, name: str, v: Any, dictionary: str, count: int = 1) -> int:
    size = int(cv2.aruco.getPredefinedDictionary(_dictionary_id(dictionary)).bytesList.shape[0])
    if isinstance(v, bool) or not isinstance(v, int | np.integer) or not 0 <= v or v + count > size:
        last = f"..{v + count - 1}" if count > 1 and isinstance(v, int) else ""
        raise BoardError(f"{cls}.{name} {v!r}{last} is not in {dictionary}, which has ids 0..{size - 1}")
    return int(v)


def _marker_detector(dictionary: str, apriltag: bool) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    # sub-pixel corners: a marker's four corners are all the geometry there is
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG if apriltag else cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(_dictionary_id(dictionary)), params)


def _marker_points(ids: np.ndarray, origins: dict[int, np.ndarray], side: float) -> np.ndarray:
    """[M, 3] corner points of point ids ``marker * 4 + corner`` given each marker's top-left corner [2]."""
    corner_xy = np.array([[0.0, 0.0], [side, 0.0], [side, side], [0.0, side]])  # OpenCV's corner order
    out = []
    for pid in np.asarray(ids, dtype=np.int64).ravel():
        marker, corner = int(pid) // 4, int(pid) % 4
        if marker not in origins:
            raise BoardError(f"point id {pid}: marker {marker} is not on this target")
        out.append([*(origins[marker] + corner_xy[corner]), 0.0])
    return np.asarray(out, dtype=np.float64).reshape(-1, 3)


def refine_marker_corners(gray: np.ndarray, quad: np.ndarray, bits: int) -> np.ndarray:
    """Corners [4, 2] (OpenCV convention) of a square marker, re-measured from its four edges.

    OpenCV's marker corners sit 0.2-0.7 px inside the true ones (every refinement method; measured on renders
    warped by a known homography), which shrinks the marker and biases its distance by as much. Here each edge is
    located where the image crosses halfway between the black border and the white margin along the edge's normal
    (a symmetric blur leaves that point on the edge), a line is fitted to those points, and the corners are the
    lines' intersections. ``bits``: cells across the marker, border included."""
    img = gray.astype(np.float32)
    quad = np.asarray(quad, dtype=np.float64).reshape(4, 2)
    centre = quad.mean(axis=0)
    lines = []
    for k in range(4):
        a, b = quad[k], quad[(k + 1) % 4]
        length = float(np.linalg.norm(b - a))
        t = (b - a) / max(length, 1e-9)
        n = np.array([-t[1], t[0]])
        if n @ (centre - a) > 0:
            n = -n  # outward
        r = float(np.clip(0.45 * length / bits, 1.5, 6.0))
        s = np.linspace(0.15, 0.85, max(8, int(length / 2)))
        offsets = np.arange(-r, r + 1e-9, 0.1)
        pts = a + s[:, None] * (b - a)
        xy = pts[:, None, :] + offsets[None, :, None] * n
        prof = cv2.remap(img, xy[..., 0].astype(np.float32), xy[..., 1].astype(np.float32), cv2.INTER_LINEAR)
        lo, hi = prof[:, :5].mean(axis=1, keepdims=True), prof[:, -5:].mean(axis=1, keepdims=True)
        ok = (hi - lo).ravel() > 20  # a visible step
        above = prof >= (lo + hi) / 2
        first = np.argmax(above, axis=1)
        ok &= first > 0
        if ok.sum() < 4:
            return quad
        i = np.arange(len(prof))[ok]
        j = first[ok]
        y0, y1 = prof[i, j - 1], prof[i, j]
        level = ((lo + hi) / 2).ravel()[ok]
        frac = (level - y0) / np.maximum(y1 - y0, 1e-6)
        o = offsets[j - 1] + 0.1 * frac
        edge = pts[ok] + o[:, None] * n
        c = edge.mean(axis=0)
        direction = np.linalg.svd(edge - c)[2][0]
        lines.append((c, direction))
    out = np.empty((4, 2))
    for k in range(4):  # corner k joins edge k-1 (into it) and edge k (out of it)
        (p, d), (q, e) = lines[k - 1], lines[k]
        A = np.array([d, -e]).T
        if abs(np.linalg.det(A)) < 1e-9:
            return quad
        lam = np.linalg.solve(A, q - p)
        out[k] = p + lam[0] * d
    if np.abs(out - quad).max() > 3.0:  # a refinement that wanders off is not one
        return quad
    return out


def _detect_markers(detector: cv2.aruco.ArucoDetector, gray: np.ndarray, wanted: set[int]):
    corners, ids, _ = detector.detectMarkers(gray)
    if ids is None:
        return np.zeros(0, np.int64), np.zeros((0, 2))
    bits = int(detector.getDictionary().markerSize) + 2
    pid, uv = [], []
    for c, m in zip(corners, ids.ravel(), strict=True):
        if int(m) in wanted:
            pid += [int(m) * 4 + k for k in range(4)]
            uv.append(refine_marker_corners(gray, c.reshape(4, 2), bits))
    if not pid:
        return np.zeros(0, np.int64), np.zeros((0, 2))
    return np.asarray(pid, np.int64), np.concatenate(uv).astype(np.float64)


@dataclass(frozen=True)
class MarkerSpec:
    """One square fiducial: an ArUco marker (``kind="aruco"``) or an AprilTag (``kind="apriltag"``, an OpenCV
    DICT_APRILTAG_* dictionary), ``size`` metres along the outer edge of its black border, id ``id``.
    Board frame: origin at the marker's top-left outer corner, x right, y down the print, z into it."""

    size_m: float
    id: int = 0
    dictionary: str = "DICT_6X6_250"
    kind: str = "aruco"

    def __post_init__(self) -> None:
        name = "MarkerSpec"
        if self.kind not in ("aruco", "apriltag"):
            raise BoardError(f"{name}.kind must be 'aruco' or 'apriltag', got {self.kind!r}")
        apriltag = str(self.dictionary).startswith("DICT_APRILTAG")
        if apriltag != (self.kind == "apriltag"):
            need = "a DICT_APRILTAG_*" if self.kind == "apriltag" else "an ArUco (not AprilTag)"
            raise BoardError(f"{name}: an {self.kind} marker needs {need} dictionary, got {self.dictionary!r}")
        object.__setattr__(self, "size_m", _positive_length(name, "size", self.size_m))
        object.__setattr__(self, "id", _marker_id(name, "id", self.id, self.dictionary))

    @property
    def size(self) -> tuple[float, float]:
        return (self.size_m, self.size_m)

    @property
    def feature_size(self) -> float:
        return self.size_m

    @property
    def n_points(self) -> int:
        return 4

    def describe(self) -> str:
        what = "AprilTag" if self.kind == "apriltag" else "ArUco marker"
        return f"{what} id {self.id}, {self.size_m * 100:g} cm, {self.dictionary}"

    def points_board(self, ids: np.ndarray | None = None) -> np.ndarray:
        ids = np.arange(4) + 4 * self.id if ids is None else ids
        return _marker_points(ids, {self.id: np.zeros(2)}, self.size_m)

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _detect_markers(_marker_detector(self.dictionary, self.kind == "apriltag"), gray, {self.id})

    def size_with_margin(self, margin_squares: float = 0.5) -> tuple[float, float]:
        m = 2.0 * margin_squares * self.size_m
        return (self.size_m + m, self.size_m + m)

    def render_image(self, px_per_square: int = 100, margin_squares: float = 0.5) -> np.ndarray:
        """uint8 [H, W]: the marker ``px_per_square`` px wide (its black border's outer edge) with a white margin of
        ``margin_squares`` marker sides (the quiet zone detection needs)."""
        pps = _check_px_per_square(px_per_square)
        m = margin_pixels(px_per_square, margin_squares)
        marker = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(_dictionary_id(self.dictionary)),
                                               self.id, pps, borderBits=1)  # fmt: skip
        return np.pad(marker, m, constant_values=255)

    def to_json(self) -> dict[str, Any]:
        return {"type": self.kind, "size": self.size_m, "id": self.id, "dictionary": self.dictionary}

    def save(self, path: str | os.PathLike) -> None:
        _save_json(self.to_json(), path)


@dataclass(frozen=True)
class GridSpec:
    """An ArUco grid board (OpenCV's GridBoard): ``markers_x`` x ``markers_y`` markers of side ``marker`` metres,
    ``separation`` metres apart, ids ``first_id``, ``first_id + 1``, ... row by row from the top-left.
    Board frame: origin at the top-left marker's outer corner, x right, y down the print, z into it."""

    markers_x: int = 4
    markers_y: int = 5
    marker: float = 0.04
    separation: float = 0.01
    dictionary: str = "DICT_4X4_50"
    first_id: int = 0
    kind = "aruco_grid"

    def __post_init__(self) -> None:
        name = "GridSpec"
        for f in ("markers_x", "markers_y"):
            v = getattr(self, f)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or not 1 <= v <= 100:
                raise BoardError(f"{name}.{f} must be an integer in [1, 100], got {v!r}")
        if self.markers_x * self.markers_y < 2:
            raise BoardError(f"{name}: a grid has at least 2 markers (one marker: use type 'aruco')")
        object.__setattr__(self, "marker", _positive_length(name, "marker", self.marker))
        object.__setattr__(self, "separation", _positive_length(name, "separation", self.separation))
        object.__setattr__(self, "first_id", _marker_id(name, "first_id", self.first_id, self.dictionary,
                                                        self.markers_x * self.markers_y))  # fmt: skip

    @property
    def size(self) -> tuple[float, float]:
        step = self.marker + self.separation
        return (self.markers_x * step - self.separation, self.markers_y * step - self.separation)

    @property
    def feature_size(self) -> float:
        return self.marker

    def _origins(self) -> dict[int, np.ndarray]:
        step = self.marker + self.separation
        return {self.first_id + r * self.markers_x + c: np.array([c * step, r * step])
                for r in range(self.markers_y) for c in range(self.markers_x)}  # fmt: skip

    def describe(self) -> str:
        return (f"ArUco grid {self.markers_x}x{self.markers_y}, {self.marker * 100:g} cm markers "
                f"{self.separation * 100:g} cm apart, {self.dictionary} from id {self.first_id}")  # fmt: skip

    def points_board(self, ids: np.ndarray | None = None) -> np.ndarray:
        if ids is None:
            ids = np.array([4 * m + k for m in sorted(self._origins()) for k in range(4)])
        return _marker_points(ids, self._origins(), self.marker)

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _detect_markers(_marker_detector(self.dictionary, False), gray, set(self._origins()))

    def size_with_margin(self, margin_squares: float = 0.5) -> tuple[float, float]:
        m = 2.0 * margin_squares * self.marker
        return (self.size[0] + m, self.size[1] + m)

    def render_image(self, px_per_square: int = 100, margin_squares: float = 0.5) -> np.ndarray:
        """uint8 [H, W] with ``px_per_square`` px per marker side; the separation must come out whole pixels."""
        pps = _check_px_per_square(px_per_square)
        m = margin_pixels(px_per_square, margin_squares)
        sep = self.separation / self.marker * pps
        if abs(sep - round(sep)) > 1e-6:
            raise ValueError(f"separation {self.separation} m is {sep:g} px at {pps} px per marker; choose "
                             "px_per_square so that it is whole")  # fmt: skip
        sep = int(round(sep))
        d = cv2.aruco.getPredefinedDictionary(_dictionary_id(self.dictionary))
        w, h = self.markers_x * (pps + sep) - sep, self.markers_y * (pps + sep) - sep
        img = np.full((h, w), 255, np.uint8)
        for mid, (x, y) in self._origins().items():
            c, r = int(round(x / self.marker * pps)), int(round(y / self.marker * pps))
            img[r : r + pps, c : c + pps] = cv2.aruco.generateImageMarker(d, mid, pps, borderBits=1)
        return np.pad(img, m, constant_values=255)

    def to_json(self) -> dict[str, Any]:
        return {"type": self.kind, "markers_x": self.markers_x, "markers_y": self.markers_y, "marker": self.marker,
                "separation": self.separation, "dictionary": self.dictionary, "first_id": self.first_id}  # fmt: skip

    def save(self, path: str | os.PathLike) -> None:
        _save_json(self.to_json(), path)


TARGET_KINDS = ("charuco", "aruco", "apriltag", "aruco_grid")


def on_target(points_base: np.ndarray, target: Any, T_base_target: np.ndarray, height: float = 0.03) -> np.ndarray:
    """bool [N]: the points [N,3] (base frame) lying on the calibration target's sheet: within its features' outline
    grown by 1.5 of its feature size (a ChArUco's outer squares and white margin), at most ``height`` metres off its
    plane. SfM puts a few noisy points over a board's repeated pattern, and beside the robot they clump into an
    "object" otherwise."""
    points_base = np.asarray(points_base, np.float64).reshape(-1, 3)
    T = np.asarray(T_base_target, np.float64)
    local = (points_base - T[:3, 3]) @ T[:3, :3]  # into the target's frame
    corners = target.points_board()[:, :2]
    grow = 1.5 * target.feature_size
    lo, hi = corners.min(axis=0) - grow, corners.max(axis=0) + grow
    return np.all((local[:, :2] >= lo) & (local[:, :2] <= hi), axis=1) & (np.abs(local[:, 2]) <= height)


def target_plane(target: Any, T_base_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre [3], up normal [3]) of the target's printed face in the base frame: the middle of its features' outline
    and its z axis, turned up."""
    T = np.asarray(T_base_target, np.float64)
    local = target.points_board()
    centre = T[:3, :3] @ ((local.min(axis=0) + local.max(axis=0)) / 2) + T[:3, 3]
    return centre, (T[:3, 2] if T[2, 2] > 0 else -T[:3, 2])


def target_from_json(data: Any, where: str = "target JSON"):
    """Any calibration target from its JSON (``"type"``: charuco (the default), aruco, apriltag, aruco_grid)."""
    if not isinstance(data, dict):
        raise BoardError(f"{where}: expected a JSON object, got {type(data).__name__}")
    kind = data.get("type", "charuco")
    if kind not in TARGET_KINDS:
        raise BoardError(f"{where}: type {kind!r} is not one of {', '.join(TARGET_KINDS)}")
    rest = {k: v for k, v in data.items() if k != "type"}
    if kind == "charuco":
        return BoardSpec.from_json(rest)
    single = ("size", "id", "dictionary")
    grid = ("markers_x", "markers_y", "marker", "separation", "dictionary", "first_id")
    fields = grid if kind == "aruco_grid" else single
    unknown = set(rest) - set(fields)
    if unknown:
        raise BoardError(f"{where}: unknown keys {sorted(unknown)} for a {kind} target; expected {list(fields)}")
    if kind == "aruco_grid":
        return GridSpec(**rest)
    if "size" not in rest:
        raise BoardError(f"{where}: a {kind} target needs its size (metres, the outer edge of the black border)")
    default = "DICT_APRILTAG_36h11" if kind == "apriltag" else "DICT_6X6_250"
    return MarkerSpec(rest["size"], rest.get("id", 0), rest.get("dictionary", default), kind)


def load_target(path: str | os.PathLike):
    """Any calibration target from a JSON file (BoardError naming the file when it cannot be used)."""
    try:
        data = read_json(path, "calibration target")
    except InputError as e:
        raise BoardError(str(e)) from None
    try:
        return target_from_json(data, str(path))
    except (ValueError, TypeError) as e:
        raise BoardError(f"{path}: {e}") from e


def _save_json(data: dict, path: str | os.PathLike) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "w", encoding="utf-8") as f:
        json.dump(data, f, indent=2)
        f.write("\n")


def _check_px_per_square(px_per_square: int) -> int:
    if isinstance(px_per_square, bool) or not isinstance(px_per_square, int | np.integer) or px_per_square < 8:
        raise ValueError(f"px_per_square must be an integer >= 8, got {px_per_square!r}")
    return int(px_per_square)


def margin_pixels(px_per_square: int, margin_squares: float) -> int:
    """White margin of :meth:`BoardSpec.render_image` in pixels; it must be a whole, non-negative number."""
    pps = _check_px_per_square(px_per_square)
    m = margin_squares * pps
    if not (math.isfinite(m) and m >= 0) or abs(m - round(m)) > 1e-9:
        raise ValueError(
            f"margin_squares * px_per_square must be a whole number of pixels >= 0, got {margin_squares} * {pps} = {m}"
        )
    return int(round(m))


def board_image_to_board_frame(
    pixels: np.ndarray, spec: BoardSpec, px_per_square: int = 100, margin_squares: float = 0.5
) -> np.ndarray:
    """Pixel coordinates in ``spec.render_image(px_per_square, margin_squares)`` -> board frame.

    pixels [..., 2] as (col, row) with pixel centres at +0.5 (the image spans [0, W] x [0, H]).
    Returns [..., 3] board-frame points (metres, z = 0): ``x = (col - margin_px) * square / px_per_square``,
    ``y = (row - margin_px) * square / px_per_square``.
    """
    m = margin_pixels(px_per_square, margin_squares)
    px = np.asarray(pixels, dtype=np.float64)
    if px.shape[-1] != 2:
        raise ValueError(f"pixels must have shape [..., 2] (col, row), got {px.shape}")
    xy = (px - m) * (spec.feature_size / px_per_square)
    return np.concatenate([xy, np.zeros((*xy.shape[:-1], 1))], axis=-1)


def board_frame_to_board_image(
    points: np.ndarray, spec: BoardSpec, px_per_square: int = 100, margin_squares: float = 0.5
) -> np.ndarray:
    """Inverse of :func:`board_image_to_board_frame`: board-frame points [..., 2 or 3] (z ignored)
    -> (col, row) [..., 2], pixel centres at +0.5."""
    m = margin_pixels(px_per_square, margin_squares)
    p = np.asarray(points, dtype=np.float64)
    if p.shape[-1] not in (2, 3):
        raise ValueError(f"points must have shape [..., 2] or [..., 3], got {p.shape}")
    return p[..., :2] * (px_per_square / spec.feature_size) + m


PRINT_DPI = 300  # a laser printer's native resolution


def write_printable(spec, pdf_path: str | os.PathLike, dpi: int = PRINT_DPI, margin_squares: float = 0.5) -> dict:
    """Write the board as a PDF and a PNG at true scale (``dpi``; print at 100%, no "fit to page"),
    and its spec as JSON beside them (same stem). Returns {"pdf", "png", "json", "size_mm", "px_per_square"}."""
    from PIL import Image

    pdf_path = Path(pdf_path)
    if pdf_path.suffix.lower() != ".pdf":
        raise BoardError(f"{pdf_path}: the printable board is written as .pdf (a .png and .json go beside it)")
    # Whole pixels per square at this dpi; the dpi written into the files is adjusted so that the
    # square prints at exactly its size.
    px_per_square = max(8, int(round(spec.feature_size / 0.0254 * dpi)))
    px_per_square += px_per_square % 2  # keeps a half-square margin whole
    if isinstance(spec, GridSpec):  # the gaps between markers must come out whole pixels too
        ratio = spec.separation / spec.marker
        fits = [p for p in range(px_per_square, 2 * px_per_square, 2) if abs(ratio * p - round(ratio * p)) < 1e-6]
        if not fits:
            raise BoardError(f"{spec.describe()}: the separation / marker ratio {ratio:g} cannot be printed in whole "
                             "pixels; choose a simpler ratio (e.g. separation = marker / 4)")  # fmt: skip
        px_per_square = fits[0]
    true_dpi = px_per_square / (spec.feature_size / 0.0254)
    image = Image.fromarray(spec.render_image(px_per_square, margin_squares))
    png_path, json_path = pdf_path.with_suffix(".png"), pdf_path.with_suffix(".json")
    with atomic_path(pdf_path) as tmp:
        image.convert("RGB").save(tmp, format="PDF", resolution=true_dpi)
    with atomic_path(png_path) as tmp:
        image.save(tmp, format="PNG", dpi=(true_dpi, true_dpi))
    spec.save(json_path)
    w, h = spec.size_with_margin(margin_squares)
    return {"pdf": pdf_path, "png": png_path, "json": json_path, "size_mm": (w * 1000, h * 1000),
            "px_per_square": px_per_square}  # fmt: skip
