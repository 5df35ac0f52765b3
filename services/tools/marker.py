"""``shepherd marker sheet``: the rhombus to print; ``shepherd marker learn``: its colour as
your camera sees it."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any


def add_marker_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("marker", help="the marker: a sheet to print, its colour to learn")
    msub = p.add_subparsers(dest="marker_cmd", required=True)
    s = msub.add_parser("sheet", help="the rhombus at exact size with a scale bar")
    s.add_argument("--out", default="marker.pdf", help=".pdf, .svg or .png")
    s.add_argument("--file", help="deployment whose [geometry] gives the size "
                   "(default: the default deployment)")
    s.add_argument("--dpi", type=float, default=300.0, help="for PNG")
    s.set_defaults(func=cmd_sheet)
    learn = msub.add_parser(
        "learn", help="fit the marker's colour to your camera's images (a colour_file)",
        description="Finds the marker in each image (or within --roi, the same for all), fits "
        "a colour model in linear-light chromaticity, prints how well it separates the marker "
        "from the rest of each image, and writes it for [services.vertex_extractor] "
        "colour_file.")
    learn.add_argument("images", nargs="+", help="photographs with the marker in view")
    learn.add_argument("--roi", help="X,Y,W,H: the region (px) where the marker is")
    learn.add_argument("--out", required=True, help="TOML file to write")
    learn.set_defaults(func=cmd_learn)


def _roi(text: str | None) -> tuple[int, int, int, int] | None:
    if text is None:
        return None
    parts = text.split(",")
    if len(parts) != 4 or not all(p.strip().lstrip("-").isdigit() for p in parts):
        raise ValueError(f"--roi {text!r}: expected X,Y,W,H in pixels, e.g. 100,80,200,160")
    x, y, w, h = (int(p) for p in parts)
    if x < 0 or y < 0 or w <= 0 or h <= 0:
        raise ValueError(f"--roi {text!r}: X and Y must be >= 0, W and H > 0")
    return x, y, w, h


def cmd_learn(args: argparse.Namespace) -> int:
    import cv2

    from services.vertex_extractor.colour import ellipse_axes
    from services.vertex_extractor.learn import LearnError, learn, write_colour_file
    try:
        roi = _roi(args.roi)
        images = []
        for name in args.images:
            img = cv2.imread(name, cv2.IMREAD_COLOR)
            if img is None:
                raise ValueError(f"{name}: not an image OpenCV can read")
            images.append((name, img))
        model, report = learn(images, roi)
    except (ValueError, LearnError) as err:
        print(f"shepherd: {err}", file=sys.stderr)
        return 2
    print(f"{'image':40s} {'marker px':>9s} {'marker found':>13s} {'rest taken':>11s}")
    for sep in report:
        print(f"{sep.name[-40:]:40s} {sep.marker_px:9d} {100 * sep.recall:12.1f}% "
              f"{100 * sep.false_rate:10.3f}%")
    major, minor, angle = ellipse_axes(model)
    out = Path(args.out)
    write_colour_file(out, model, f"shepherd marker learn on {len(images)} image(s); "
                      f"chromaticity ellipse {major:.3f} x {minor:.3f} at {angle:.0f} deg.\n"
                      "Use it as [services.vertex_extractor] colour_file = \"" + out.name + "\"")
    print(f"wrote {out}: centre r={model.centre[0]:.3f} g={model.centre[1]:.3f}, "
          f"half-axes {major:.3f} x {minor:.3f}")
    return 0


def cmd_sheet(args: argparse.Namespace) -> int:
    from services.data import DEFAULT_DEPLOYMENT
    from services.runtime.config import ConfigError, load_deployment
    from services.vertex_extractor.extractor import shape_warning
    from services.vertex_extractor.sheet import MarkerSheet
    try:
        g = load_deployment(args.file or DEFAULT_DEPLOYMENT).geometry
    except ConfigError as err:
        print(f"shepherd: {err}", file=sys.stderr)
        return 2
    if warning := shape_warning(g.marker_width_m / g.marker_height_m):
        print(f"shepherd: warning: {warning}", file=sys.stderr)
    sheet = MarkerSheet(width_mm=1000 * g.marker_width_m, height_mm=1000 * g.marker_height_m)
    return save_sheet(sheet, Path(args.out), args.dpi)


def save_sheet(sheet: Any, out: Path, dpi: float) -> int:
    """Write a printable sheet (``write(path, dpi)``, ``caption()``) and say so; exit code 2
    with the reason when it cannot be written."""
    try:
        sheet.write(out, dpi)
    except ValueError as err:
        print(f"shepherd: {err}", file=sys.stderr)
        return 2
    print(f"wrote {out}: {sheet.caption()}")
    return 0
