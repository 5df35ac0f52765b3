"""Calibration targets: specs, model points, and the paper's printable grid.

Specs: ``grid:ROWSxCOLS:PITCH`` (the paper's pattern: rows x columns of *lines*, pitch in m;
9x9 gives 18 lines and 81 points), ``squares:ROWSxCOLS:SIZE:PITCH`` (Zhang's board of
separate squares), ``chessboard:COLSxROWS:SIZE`` (OpenCV inner corners).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from services.core.printing import PT_PER_MM, one_page_pdf, write_sheet


@dataclass(frozen=True)
class PatternSpec:
    kind: str          # grid | squares | chessboard
    rows: int
    cols: int
    size_m: float      # pitch for grid, square size for squares and chessboard
    pitch_m: float = 0.0

    @classmethod
    def parse(cls, text: str) -> PatternSpec:
        """Parse a spec; raises ValueError naming what is wrong."""
        m = re.fullmatch(r"(grid|squares|chessboard):(\d+)x(\d+):([\d.eE+-]+)(?::([\d.eE+-]+))?",
                         text.strip())
        if not m:
            raise ValueError(f"pattern {text!r}: expected grid:9x9:0.02, "
                             "squares:8x8:0.0127:0.0225778 or chessboard:9x6:0.025")
        kind, a, b, size, pitch = m.groups()
        rows, cols = int(a), int(b)
        if kind == "chessboard":
            cols, rows = rows, cols  # OpenCV's (columns, rows) of inner corners
        if float(size) <= 0 or min(rows, cols) < 2:
            raise ValueError(f"pattern {text!r}: sizes must be positive, at least 2x2")
        if kind == "squares" and (pitch is None or float(pitch) <= float(size)):
            raise ValueError(f"pattern {text!r}: squares needs a pitch larger than the size")
        if kind != "squares" and pitch is not None:
            raise ValueError(f"pattern {text!r}: only squares takes a pitch")
        return cls(kind, rows, cols, float(size), float(pitch or 0.0))

    def model_points(self) -> np.ndarray:
        """(N, 2) model points in metres, in the order the detector returns them.

        grid: row-major intersections (x right, y down the sheet). squares: Zhang's order,
        square by square from the bottom row up (y negative upwards, as in his Model.txt),
        corners top-left, top-right, bottom-right, bottom-left. chessboard: OpenCV's order.
        """
        if self.kind == "grid":
            r, c = np.mgrid[0:self.rows, 0:self.cols]
            return np.column_stack([c.ravel(), r.ravel()]) * self.size_m
        if self.kind == "chessboard":
            return np.indices((self.cols, self.rows)).T.reshape(-1, 2) * self.size_m
        s, p = self.size_m, self.pitch_m
        pts = []
        for r in range(self.rows):
            for c in range(self.cols):
                x, y = c * p, -r * p
                pts += [(x, y - s), (x + s, y - s), (x + s, y), (x, y)]
        return np.array(pts)


# -- the printable grid ------------------------------------------------------------------------

@dataclass(frozen=True)
class GridSheet:
    """The paper's pattern on a sheet: ``lines`` x ``lines`` straight lines (mm)."""

    lines: int = 9
    pitch_mm: float = 20.0
    line_mm: float = 2.0
    overhang_mm: float = 10.0
    page_mm: tuple[float, float] = (210.0, 297.0)   # A4 portrait
    scale_bar_mm: float = 100.0

    @property
    def span_mm(self) -> float:
        return (self.lines - 1) * self.pitch_mm

    def origin_mm(self) -> tuple[float, float]:
        """Page position (mm from the top left) of the first intersection."""
        w, _ = self.page_mm
        return (w - self.span_mm) / 2, 30.0 + self.overhang_mm

    def rectangles_mm(self) -> list[tuple[float, float, float, float]]:
        """Black rectangles (x, y, w, h) in mm from the page's top left: lines, scale bar."""
        x0, y0 = self.origin_mm()
        half, ext = self.line_mm / 2, self.span_mm + 2 * self.overhang_mm
        rects = []
        for i in range(self.lines):
            rects.append((x0 - self.overhang_mm, y0 + i * self.pitch_mm - half, ext,
                          self.line_mm))
            rects.append((x0 + i * self.pitch_mm - half, y0 - self.overhang_mm, self.line_mm,
                          ext))
        bx, by = x0, y0 + self.span_mm + self.overhang_mm + 20
        rects.append((bx, by, self.scale_bar_mm, 1.0))
        for k in range(11):
            rects.append((bx + k * self.scale_bar_mm / 10 - 0.15, by - 3, 0.3, 4.0))
        return rects

    def caption(self) -> str:
        return (f"Shepherd grid {self.lines}+{self.lines} lines, pitch {self.pitch_mm:g} mm, "
                f"line {self.line_mm:g} mm. Print at 100%: the bar is "
                f"{self.scale_bar_mm:g} mm.")

    def raster(self, px_per_mm: float, page: bool = True) -> np.ndarray:
        """Greyscale image of the sheet (or of the grid area only), area-antialiased."""
        ss = 4
        W, H = self.page_mm
        x_off = y_off = 0.0
        if not page:
            x0, y0 = self.origin_mm()
            x_off, y_off = x0 - self.overhang_mm - 5, y0 - self.overhang_mm - 5
            W = H = self.span_mm + 2 * self.overhang_mm + 10
        k = px_per_mm * ss
        img = np.full((round(H * k), round(W * k)), 255, np.uint8)
        for x, y, w, h in self.rectangles_mm():
            p1 = (round((x - x_off) * k), round((y - y_off) * k))
            p2 = (round((x + w - x_off) * k) - 1, round((y + h - y_off) * k) - 1)
            cv2.rectangle(img, p1, p2, 0, -1)
        img = cv2.resize(img, (round(W * px_per_mm), round(H * px_per_mm)),
                         interpolation=cv2.INTER_AREA)
        if page:
            _, by = self.origin_mm()
            cv2.putText(img, self.caption(), (round(self.origin_mm()[0] * px_per_mm),
                        round((by + self.span_mm + self.overhang_mm + 32) * px_per_mm)),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.09 * px_per_mm, 0, max(1, round(px_per_mm / 8)),
                        cv2.LINE_AA)
        return img

    def svg(self) -> str:
        W, H = self.page_mm
        rects = "\n".join(f'  <rect x="{x:.3f}" y="{y:.3f}" width="{w:.3f}" height="{h:.3f}"/>'
                          for x, y, w, h in self.rectangles_mm())
        _, by = self.origin_mm()
        ty = by + self.span_mm + self.overhang_mm + 32
        return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}mm" height="{H}mm" '
                f'viewBox="0 0 {W} {H}">\n<rect width="{W}" height="{H}" fill="white"/>\n'
                f'<g fill="black">\n{rects}\n</g>\n<text x="{self.origin_mm()[0]}" y="{ty}" '
                f'font-family="Helvetica" font-size="4">{self.caption()}</text>\n</svg>\n')

    def pdf(self) -> bytes:
        """A one-page vector PDF at exact size (1 pt = 1/72 in)."""
        _, H = self.page_mm
        pt = PT_PER_MM
        ops = ["0 g"]
        for x, y, w, h in self.rectangles_mm():
            ops.append(f"{x * pt:.3f} {(H - y - h) * pt:.3f} {w * pt:.3f} {h * pt:.3f} re f")
        _, by = self.origin_mm()
        ty = H - (by + self.span_mm + self.overhang_mm + 32)
        text = self.caption().replace("(", "[").replace(")", "]")
        ops.append(f"BT /F1 11 Tf {self.origin_mm()[0] * pt:.2f} {ty * pt:.2f} Td ({text}) Tj ET")
        return one_page_pdf("\n".join(ops), self.page_mm)

    def write(self, path: Path, dpi: float = 300.0) -> None:
        """Write PDF, SVG or PNG (with its DPI recorded) by the file's suffix."""
        write_sheet(path, dpi, self.pdf, self.svg, self.raster)
