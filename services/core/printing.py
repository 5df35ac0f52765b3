"""Sheets to print at exact size: a one-page vector PDF and a PNG that records its DPI."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

PT_PER_MM = 72 / 25.4


def one_page_pdf(content: str, page_mm: tuple[float, float]) -> bytes:
    """A PDF of one ``page_mm`` (width, height) page drawn by ``content`` (PDF operators in
    points, origin bottom left), with Helvetica as /F1."""
    W, H = page_mm
    data = content.encode()
    objs = [b"<< /Type /Catalog /Pages 2 0 R >>",
            b"<< /Type /Pages /Kids [3 0 R] /Count 1 >>",
            (f"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {W * PT_PER_MM:.2f} "
             f"{H * PT_PER_MM:.2f}] /Contents 4 0 R /Resources << /Font << /F1 5 0 R >> >> >>"
             ).encode(),
            b"<< /Length %d >>\nstream\n" % len(data) + data + b"\nendstream",
            b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica >>"]
    out = b"%PDF-1.4\n"
    offsets = []
    for i, body in enumerate(objs, 1):
        offsets.append(len(out))
        out += b"%d 0 obj\n" % i + body + b"\nendobj\n"
    xref = len(out)
    out += b"xref\n0 %d\n0000000000 65535 f \n" % (len(objs) + 1)
    out += b"".join(b"%010d 00000 n \n" % o for o in offsets)
    out += b"trailer\n<< /Size %d /Root 1 0 R >>\nstartxref\n%d\n%%%%EOF\n" % (
        len(objs) + 1, xref)
    return out


def png_with_dpi(png: bytes, dpi: float) -> bytes:
    """Insert a pHYs chunk so viewers and printers know the physical size."""
    ppm = round(dpi / 0.0254)
    data = struct.pack(">IIB", ppm, ppm, 1)
    chunk = struct.pack(">I", len(data)) + b"pHYs" + data + struct.pack(
        ">I", zlib.crc32(b"pHYs" + data) & 0xFFFFFFFF)
    end_ihdr = 8 + 4 + 4 + 13 + 4
    return png[:end_ihdr] + chunk + png[end_ihdr:]


def write_sheet(path: Path, dpi: float, pdf: Callable[[], bytes], svg: Callable[[], str],
                raster: Callable[[float], np.ndarray]) -> None:
    """Write a sheet as PDF, SVG or PNG (``raster(px_per_mm)``, its DPI recorded) by the
    file's suffix; raises ValueError for any other."""
    suffix = path.suffix.lower()
    if suffix == ".pdf":
        path.write_bytes(pdf())
    elif suffix == ".svg":
        path.write_text(svg())
    elif suffix == ".png":
        ok, buf = cv2.imencode(".png", raster(dpi / 25.4))
        if not ok:
            raise ValueError("PNG encoding failed")
        path.write_bytes(png_with_dpi(buf.tobytes(), dpi))
    else:
        raise ValueError(f"{path}: expected .pdf, .svg or .png")
