"""``shepherd marker sheet``: the rhombus to print."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_marker_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("marker", help="the marker: a sheet to print")
    msub = p.add_subparsers(dest="marker_cmd", required=True)
    s = msub.add_parser("sheet", help="the rhombus at exact size with a scale bar")
    s.add_argument("--out", default="marker.pdf", help=".pdf, .svg or .png")
    s.add_argument("--file", help="deployment whose [geometry] gives the size "
                   "(default: the default deployment)")
    s.add_argument("--dpi", type=float, default=300.0, help="for PNG")
    s.set_defaults(func=cmd_sheet)


def cmd_sheet(args: argparse.Namespace) -> int:
    from services.data import DEFAULT_DEPLOYMENT
    from services.runtime.config import ConfigError, load_deployment
    from services.vertex_extractor.sheet import MarkerSheet
    try:
        g = load_deployment(args.file or DEFAULT_DEPLOYMENT).geometry
    except ConfigError as err:
        print(f"shepherd: {err}", file=sys.stderr)
        return 2
    sheet = MarkerSheet(width_mm=1000 * g.marker_width_m, height_mm=1000 * g.marker_height_m)
    out = Path(args.out)
    try:
        sheet.write(out, args.dpi)
    except ValueError as err:
        print(f"shepherd: {err}", file=sys.stderr)
        return 2
    print(f"wrote {out}: {sheet.caption()}")
    return 0
