"""``shepherd calibrate pattern`` and ``shepherd calibrate intrinsics``."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_calibrate_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("calibrate", help="intrinsic calibration (Zhang's method)")
    csub = p.add_subparsers(dest="cal_cmd", required=True)
    pat = csub.add_parser("pattern", help="draw the paper's 9 + 9 line grid to print")
    pat.add_argument("--out", default="grid.pdf", help=".pdf, .svg or .png")
    pat.add_argument("--pitch-mm", type=float, default=20.0, help="from line to line")
    pat.add_argument("--line-mm", type=float, default=2.0, help="line width")
    pat.add_argument("--lines", type=int, default=9, help="lines each way")
    pat.add_argument("--dpi", type=float, default=300.0, help="for PNG")
    pat.set_defaults(func=cmd_pattern)
    intr = csub.add_parser("intrinsics", help="calibrate from images of a pattern")
    intr.add_argument("images", nargs="+", type=Path, help="photographs of the pattern")
    intr.add_argument("--pattern", default="grid:9x9:0.02",
                      help="grid:9x9:0.02 | squares:8x8:0.0127:0.0225778 | chessboard:9x6:0.025")
    intr.add_argument("--out", type=Path, default=Path("camera.toml"),
                      help="the calibration TOML (an OpenCV YAML is written beside it)")
    intr.add_argument("--plots", type=Path, help="folder for a residual PNG per view")
    intr.add_argument("--no-skew", action="store_true", help="assume gamma = 0")
    intr.set_defaults(func=cmd_intrinsics)


def cmd_pattern(args: argparse.Namespace) -> int:
    import sys

    from services.calibration.pattern import GridSheet
    sheet = GridSheet(lines=args.lines, pitch_mm=args.pitch_mm, line_mm=args.line_mm)
    if sheet.span_mm + 2 * sheet.overhang_mm > sheet.page_mm[0] - 10:
        print(f"shepherd: a {args.lines}-line grid at {args.pitch_mm} mm does not fit on A4",
              file=sys.stderr)
        return 2
    from services.tools.marker import save_sheet
    return save_sheet(sheet, Path(args.out), args.dpi)


def cmd_intrinsics(args: argparse.Namespace) -> int:
    from services.calibration.run import main
    return main(args.images, args.pattern, args.out, args.plots, not args.no_skew)
