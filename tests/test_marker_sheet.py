"""``shepherd marker sheet``: the rhombus at exact size, found by our own extractor."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from services.vertex_extractor.extractor import RhombusExtractor
from services.vertex_extractor.sheet import MarkerSheet
from tests.conftest import cli_here


def test_the_printed_marker_has_the_mounts_size_and_our_extractor_finds_it(tmp_path: Path):
    out = cli_here("marker", "sheet", "--out", str(tmp_path / "m.png"), "--dpi", "100")
    assert out.returncode == 0, out.stderr
    assert "rhombus 50 x 66 mm" in out.stdout and "the bar is 100 mm" in out.stdout
    data = (tmp_path / "m.png").read_bytes()
    assert b"pHYs" in data[:100]
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None
    px_per_mm = 100 / 25.4
    sheet = MarkerSheet()
    x0, y0 = ((sheet.vertices_mm().min(0) - 10) * px_per_mm).astype(int)
    x1, y1 = ((sheet.vertices_mm().max(0) + 10) * px_per_mm).astype(int)
    crop = np.ascontiguousarray(img[y0:y1, x0:x1])
    det = RhombusExtractor().extract(crop)
    assert det.found and det.vertices_px is not None, det.reason
    left, top, right, bottom = det.vertices_px
    assert abs(np.linalg.norm(right - left) / px_per_mm - 50.0) < 0.3
    assert abs(np.linalg.norm(bottom - top) / px_per_mm - 66.0) < 0.3


def test_the_pdf_draws_the_rhombus_in_magenta_at_exact_size(tmp_path: Path):
    assert cli_here("marker", "sheet", "--out", str(tmp_path / "m.pdf")).returncode == 0
    pdf = (tmp_path / "m.pdf").read_bytes()
    assert pdf.startswith(b"%PDF-1.4") and b"1.0000 0.0000 1.0000 rg" in pdf
    pt = 72 / 25.4
    left_x = (105.0 - 25.0) * pt
    assert f"{left_x:.3f}".encode() in pdf  # the left vertex, 25 mm left of the centre
    bad = cli_here("marker", "sheet", "--out", str(tmp_path / "m.txt"))
    assert bad.returncode == 2 and "expected .pdf, .svg or .png" in bad.stderr


def test_a_marker_as_wide_as_tall_is_printed_with_a_warning(tmp_path: Path):
    """A square or wide rhombus is a shape pink cards take in some view: the sheet is still
    written, with a warning that says which shape to use; the default's is not warned of."""
    deployment = tmp_path / "square.toml"
    deployment.write_text("[geometry]\nmarker_width_m = 0.066\nmarker_height_m = 0.066\n")
    out = cli_here("marker", "sheet", "--file", str(deployment), "--out",
                   str(tmp_path / "m.pdf"))
    assert out.returncode == 0 and (tmp_path / "m.pdf").exists(), out.stderr
    assert "warning: the marker's diagonals (horizontal 1.00 x the vertical)" in out.stderr
    assert "taller than wide" in out.stderr
    plain = cli_here("marker", "sheet", "--out", str(tmp_path / "d.pdf"))
    assert plain.returncode == 0 and "warning" not in plain.stderr


def test_a_narrow_marker_is_warned_of_and_the_usable_shapes_are_not():
    """A marker narrower than 0.70 has corners sharp enough that cast shadows put more than
    1 % of its views over 2 px off: warned of, with the range to use; shapes in that range
    are not warned of, those over 0.85 are (pink cards)."""
    from services.vertex_extractor.extractor import (
        MAX_DISTINCT_RATIO,
        MIN_ROBUST_RATIO,
        shape_warning,
    )
    narrow = shape_warning(0.040 / 0.066)
    assert "corners sharp" in narrow and "0.606 x the vertical" in narrow
    assert "0.697 x" in shape_warning(0.046 / 0.066)  # (1.2 % wrong under the hard shadow)
    assert f"{MIN_ROBUST_RATIO:.2f}-{MAX_DISTINCT_RATIO:.2f}" in narrow
    assert all(shape_warning(r) == "" for r in (0.70, 0.76, 0.85))
    assert "pink cards" in shape_warning(0.86)
