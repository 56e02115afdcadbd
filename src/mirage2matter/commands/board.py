"""``m2m board``: a printable calibration target at true scale (PDF + PNG) and its JSON spec: a ChArUco board, a
single ArUco marker, an AprilTag or an ArUco grid."""

from __future__ import annotations

import argparse

from .args import CliError, int_at_least, positive_float, show

_DEFAULT_DICT = {"charuco": "5X5_100", "aruco": "6X6_250", "apriltag": "APRILTAG_36h11", "aruco_grid": "4X4_50"}


def register(sub: argparse._SubParsersAction) -> None:
    bd = sub.add_parser(
        "board", help="a printable calibration target at true scale (PDF + PNG) and its JSON spec",
        description="Write a calibration target to print: a ChArUco board (the default; the most accurate), a "
        "single ArUco marker or AprilTag (what many labs already have taped down), or an ArUco grid. Sizes in "
        "metres; a marker's size is the outer edge of its black border. Print at 100% and measure it.",
    )  # fmt: skip
    bd.add_argument("--out", required=True, metavar="PDF", help="output .pdf (a .png and .json go beside it)")
    bd.add_argument("--type", choices=tuple(_DEFAULT_DICT), default="charuco", help="the kind of target (charuco)")
    bd.add_argument("--squares", default="5x7", help="charuco: squares across x down (default 5x7)")
    bd.add_argument("--square", type=positive_float, default=0.04, metavar="M", help="charuco: square side (0.04)")
    bd.add_argument("--marker", type=positive_float, default=None, metavar="M",
                    help="charuco: marker side (0.03); aruco_grid: marker side (0.04)")
    bd.add_argument("--size", type=positive_float, default=0.15, metavar="M",
                    help="aruco / apriltag: the marker's side, outer edge of the black border (0.15)")
    bd.add_argument("--id", type=int_at_least(0), default=0, help="aruco / apriltag: the marker's id (0)")
    bd.add_argument("--markers", default="4x5", help="aruco_grid: markers across x down (default 4x5)")
    bd.add_argument("--separation", type=positive_float, default=0.01, metavar="M",
                    help="aruco_grid: gap between markers (0.01)")
    bd.add_argument("--first-id", type=int_at_least(0), default=0, help="aruco_grid: id of the top-left marker (0)")
    bd.add_argument("--dict", default=None,
                    help="dictionary (default: 5X5_100 charuco, 6X6_250 aruco, APRILTAG_36h11 apriltag, 4X4_50 grid)")
    bd.add_argument("--dpi", type=int_at_least(72), default=300, help="print resolution (default 300)")
    bd.set_defaults(func=run)


def _pair(text: str, flag: str) -> tuple[int, int]:
    try:
        a, b = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise CliError(f"{flag} must look like 5x7, got {text!r}") from None
    return a, b


def run(args: argparse.Namespace) -> int:
    from ..calib.board import BoardSpec, GridSpec, MarkerSpec, write_printable

    dictionary = f"DICT_{(args.dict or _DEFAULT_DICT[args.type]).upper().removeprefix('DICT_')}"
    if args.type == "charuco":
        sx, sy = _pair(args.squares, "--squares")
        spec = BoardSpec(sx, sy, args.square, args.marker or 0.03, dictionary)
    elif args.type == "aruco_grid":
        mx, my = _pair(args.markers, "--markers")
        spec = GridSpec(mx, my, args.marker or 0.04, args.separation, dictionary, args.first_id)
    else:
        spec = MarkerSpec(args.size, args.id, dictionary, args.type)
    out = write_printable(spec, args.out, dpi=args.dpi)
    w, h = out["size_mm"]
    unit = "one square" if args.type == "charuco" else "a marker's black square"
    print(
        f"wrote {show(out['pdf'])}, {show(out['png'])} and {show(out['json'])}: {spec.describe()}, sheet {w:.0f} x "
        f"{h:.0f} mm. Print at 100% (no fit-to-page) and measure {unit}: it must be exactly "
        f"{spec.feature_size * 1000:g} mm"
    )
    return 0
