"""The marker to print: the rhombus at exact size (the deployment's mounts), with a scale bar.

Nominal magenta (sRGB 255, 0, 255) on white; a printer makes of it what its inks can, which
is why ``shepherd marker learn`` exists. Check the 100 mm bar after printing at 100%.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from services.core.printing import PT_PER_MM, one_page_pdf, write_sheet


@dataclass(frozen=True)
class MarkerSheet:
    """The rhombus (diagonals in mm) centred on an A4 page, a 100 mm bar below it."""

    width_mm: float = 50.0     # the horizontal diagonal (Geometry.marker_width_m)
    height_mm: float = 66.0    # the vertical diagonal (Geometry.marker_height_m)
    rgb: tuple[int, int, int] = (255, 0, 255)
    page_mm: tuple[float, float] = (210.0, 297.0)
    scale_bar_mm: float = 100.0

    def centre_mm(self) -> tuple[float, float]:
        """Centre of the rhombus, mm from the page's top left."""
        return self.page_mm[0] / 2, 40.0 + self.height_mm / 2

    def vertices_mm(self) -> np.ndarray:
        """(4, 2) left, top, right, bottom, mm from the page's top left."""
        cx, cy = self.centre_mm()
        w, h = self.width_mm / 2, self.height_mm / 2
        return np.array([[cx - w, cy], [cx, cy - h], [cx + w, cy], [cx, cy + h]])

    def _bar_mm(self) -> tuple[float, float]:
        return self.page_mm[0] / 2 - self.scale_bar_mm / 2, 60.0 + self.height_mm

    def caption(self) -> str:
        return (f"Shepherd marker: rhombus {self.width_mm:g} x {self.height_mm:g} mm "
                f"(diagonals). Print at 100%: the bar is {self.scale_bar_mm:g} mm.")

    def pdf(self) -> bytes:
        _, H = self.page_mm
        pt = PT_PER_MM
        r, g, b = (c / 255 for c in self.rgb)
        v = self.vertices_mm()
        path = " ".join(f"{x * pt:.3f} {(H - y) * pt:.3f} {'m' if i == 0 else 'l'}"
                        for i, (x, y) in enumerate(v))
        bx, by = self._bar_mm()
        ops = [f"{r:.4f} {g:.4f} {b:.4f} rg", f"{path} h f", "0 g",
               f"{bx * pt:.3f} {(H - by - 1.0) * pt:.3f} {self.scale_bar_mm * pt:.3f} "
               f"{1.0 * pt:.3f} re f"]
        ops += [f"{(bx + k * self.scale_bar_mm / 10 - 0.15) * pt:.3f} {(H - by - 1.0) * pt:.3f} "
                f"{0.3 * pt:.3f} {4.0 * pt:.3f} re f" for k in range(11)]
        ops.append(f"BT /F1 8 Tf {bx * pt:.2f} {(H - by - 14) * pt:.2f} Td "
                   f"({self.caption()}) Tj ET")
        return one_page_pdf("\n".join(ops), self.page_mm)

    def svg(self) -> str:
        W, H = self.page_mm
        points = " ".join(f"{x:.3f},{y:.3f}" for x, y in self.vertices_mm())
        bx, by = self._bar_mm()
        ticks = "\n".join(f'  <rect x="{bx + k * self.scale_bar_mm / 10 - 0.15:.3f}" '
                          f'y="{by - 3:.3f}" width="0.3" height="4"/>' for k in range(11))
        r, g, b = self.rgb
        return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}mm" height="{H}mm" '
                f'viewBox="0 0 {W} {H}">\n<rect width="{W}" height="{H}" fill="white"/>\n'
                f'<polygon points="{points}" fill="rgb({r},{g},{b})"/>\n<g fill="black">\n'
                f'  <rect x="{bx:.3f}" y="{by:.3f}" width="{self.scale_bar_mm}" height="1"/>\n'
                f'{ticks}\n</g>\n<text x="{bx}" y="{by + 14}" font-family="Helvetica" '
                f'font-size="4">{self.caption()}</text>\n</svg>\n')

    def raster(self, px_per_mm: float) -> np.ndarray:
        """BGR image of the page, the rhombus area-antialiased."""
        ss = 4
        W, H = self.page_mm
        k = px_per_mm * ss
        img = np.full((round(H * k), round(W * k), 3), 255, np.uint8)
        poly = np.round(self.vertices_mm() * k).astype(np.int32)
        r, g, b = self.rgb
        cv2.fillPoly(img, [poly], (b, g, r))
        bx, by = self._bar_mm()
        cv2.rectangle(img, (round(bx * k), round(by * k)),
                      (round((bx + self.scale_bar_mm) * k), round((by + 1) * k)), (0, 0, 0), -1)
        return cv2.resize(img, (round(W * px_per_mm), round(H * px_per_mm)),
                          interpolation=cv2.INTER_AREA)

    def write(self, path: Path, dpi: float = 300.0) -> None:
        """Write PDF, SVG or PNG (with its DPI recorded) by the file's suffix."""
        write_sheet(path, dpi, self.pdf, self.svg, self.raster)
