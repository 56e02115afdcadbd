"""``m2m board``: a printable ChArUco board at true scale (PDF + PNG) and its JSON spec."""

from __future__ import annotations

import argparse

from .args import CliError, int_at_least, positive_float, show


def register(sub: argparse._SubParsersAction) -> None:
    bd = sub.add_parser("board", help="a printable ChArUco board at true scale (PDF + PNG) and its JSON spec")
    bd.add_argument("--out", required=True, metavar="PDF", help="output .pdf (a .png and .json go beside it)")
    bd.add_argument("--squares", default="5x7", help="squares across x down (default 5x7)")
    bd.add_argument("--square", type=positive_float, default=0.04, metavar="M", help="square side, metres (0.04)")
    bd.add_argument("--marker", type=positive_float, default=0.03, metavar="M", help="marker side, metres (0.03)")
    bd.add_argument("--dict", default="5X5_100", help="ArUco dictionary (default 5X5_100)")
    bd.add_argument("--dpi", type=int_at_least(72), default=300, help="print resolution (default 300)")
    bd.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..calib.board import BoardSpec, write_printable

    try:
        sx, sy = (int(v) for v in args.squares.lower().split("x"))
    except ValueError:
        raise CliError(f"--squares must look like 5x7, got {args.squares!r}") from None
    spec = BoardSpec(sx, sy, args.square, args.marker, f"DICT_{args.dict.upper().removeprefix('DICT_')}")
    out = write_printable(spec, args.out, dpi=args.dpi)
    w, h = out["size_mm"]
    print(
        f"wrote {show(out['pdf'])}, {show(out['png'])} and {show(out['json'])}: {sx}x{sy} squares of "
        f"{args.square * 1000:g} mm, sheet {w:.0f} x {h:.0f} mm. Print at 100% (no fit-to-page) and measure "
        "one square: it must be exactly that size"
    )
    return 0
