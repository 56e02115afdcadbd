"""The ChArUco calibration board: its specification, geometry, and a printable image.

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

from ..atomic import atomic_write
from ..errors import M2MError
from ..inputs import InputError, read_json

__all__ = ["BoardError", "BoardSpec", "board_frame_to_board_image", "board_image_to_board_frame", "margin_pixels"]

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
    xy = (px - m) * (spec.square / px_per_square)
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
    return p[..., :2] * (px_per_square / spec.square) + m


def write_printable(spec: BoardSpec, pdf_path: str | os.PathLike, dpi: int = 300, margin_squares: float = 0.5) -> dict:
    """Write the board as a PDF and a PNG at true scale (``dpi``; print at 100%, no "fit to page"),
    and its spec as JSON beside them (same stem). Returns {"pdf", "png", "json", "size_mm", "px_per_square"}."""
    from PIL import Image

    from mirage2matter.atomic import atomic_path

    pdf_path = Path(pdf_path)
    if pdf_path.suffix.lower() != ".pdf":
        raise BoardError(f"{pdf_path}: the printable board is written as .pdf (a .png and .json go beside it)")
    # Whole pixels per square at this dpi; the dpi written into the files is adjusted so that the
    # square prints at exactly its size.
    px_per_square = max(8, int(round(spec.square / 0.0254 * dpi)))
    px_per_square += px_per_square % 2  # keeps a half-square margin whole
    true_dpi = px_per_square / (spec.square / 0.0254)
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
