"""``m2m board``: a printable calibration target at true scale (PDF + PNG) and its JSON spec: a ChArUco board, a
single ArUco marker, an AprilTag or an ArUco grid."""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from typing import Literal

from ..calib.board import PRINT_DPI
from ..configs import add_flags, from_flags, ranged
from .args import CliError, show

_DEFAULT_DICT = {"charuco": "5X5_100", "aruco": "6X6_250", "apriltag": "APRILTAG_36h11", "aruco_grid": "4X4_50"}


@dataclass
class BoardConfig:
    """m2m board settings (sizes in metres).

    type        the kind of target
    squares     charuco: squares across x down
    square      charuco: square side
    marker      the marker's side (default: charuco 0.03, aruco_grid 0.04)
    size        aruco / apriltag: the marker's side, outer edge of the black border
    id          aruco / apriltag: the marker's id
    markers     aruco_grid: markers across x down
    separation  aruco_grid: gap between markers
    first_id    aruco_grid: id of the top-left marker
    dict        dictionary (default: 5X5_100 charuco, 6X6_250 aruco, APRILTAG_36h11 apriltag, 4X4_50 grid)
    dpi         print resolution
    """

    type: Literal["charuco", "aruco", "apriltag", "aruco_grid"] = "charuco"
    squares: str = "5x7"
    square: float = ranged(0.04, gt=0, metadata={"metavar": "M"})
    marker: float | None = ranged(None, gt=0, metadata={"metavar": "M"})
    size: float = ranged(0.15, gt=0, metadata={"metavar": "M"})
    id: int = ranged(0, ge=0)
    markers: str = "4x5"
    separation: float = ranged(0.01, gt=0, metadata={"metavar": "M"})
    first_id: int = ranged(0, ge=0)
    dict: str | None = field(default=None, metadata={"metavar": "DICT"})
    dpi: int = ranged(PRINT_DPI, ge=72)


def register(sub: argparse._SubParsersAction) -> None:
    bd = sub.add_parser(
        "board", help="a printable calibration target at true scale (PDF + PNG) and its JSON spec",
        description="Write a calibration target to print: a ChArUco board (the default; the most accurate), a "
        "single ArUco marker or AprilTag (what many labs already have taped down), or an ArUco grid. Sizes in "
        "metres; a marker's size is the outer edge of its black border. Print at 100% and measure it.",
    )  # fmt: skip
    bd.add_argument("--out", required=True, metavar="PDF", help="output .pdf (a .png and .json go beside it)")
    add_flags(bd, BoardConfig)
    bd.set_defaults(func=run)


def _pair(text: str, flag: str) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise CliError(f"{flag} must look like 5x7, got {text!r}") from None
    return a, b


def run(args: argparse.Namespace) -> int:
    from ..calib.board import BoardSpec, GridSpec, MarkerSpec, write_printable

    out_pdf, args = args.out, from_flags(BoardConfig, args)
    dictionary = f"DICT_{(args.dict or _DEFAULT_DICT[args.type]).upper().removeprefix('DICT_')}"
    if args.type == "charuco":
        sx, sy = _pair(args.squares, "--squares")
        spec = BoardSpec(sx, sy, args.square, args.marker or 0.03, dictionary)
    elif args.type == "aruco_grid":
        mx, my = _pair(args.markers, "--markers")
        spec = GridSpec(mx, my, args.marker or 0.04, args.separation, dictionary, args.first_id)
    else:
        spec = MarkerSpec(args.size, args.id, dictionary, args.type)
    out = write_printable(spec, out_pdf, dpi=args.dpi)
    w, h = out["size_mm"]
    unit = "one square" if args.type == "charuco" else "a marker's black square"
    print(
        f"wrote {show(out['pdf'])}, {show(out['png'])} and {show(out['json'])}: {spec.describe()}, sheet {w:.0f} x "
        f"{h:.0f} mm. Print at 100% (no fit-to-page) and measure {unit}: it must be exactly "
        f"{spec.feature_size * 1000:g} mm"
    )
    return 0
