"""The rhombus's four vertices (paper 4.1, Tables 1 and 2): the colour test (``colour``),
the column scan (``scan``), the line fits (``lines``), one seed's scans, fits and tests in
one compiled call (``measure``), the whole extractor (``extractor``);
``service`` turns ``camera/frame`` into ``marker/vertices``."""

from services.vertex_extractor.colour import ColourModel
from services.vertex_extractor.extractor import Detection, ExtractorParams, RhombusExtractor

__all__ = ["ColourModel", "Detection", "ExtractorParams", "RhombusExtractor"]
