"""Intrinsic calibration (paper 2.1, 3): the printed 9 + 9 line grid (``pattern``), its
target points found with the Hough transform (``detect``), Zhang's method (``zhang``), the
``shepherd calibrate intrinsics`` run (``run``), synthetic views (``synthetic``); ``service``
serves an intrinsics file on ``camera/intrinsics``."""

from services.calibration.detect import DetectionError, detect, detect_grid
from services.calibration.pattern import GridSheet, PatternSpec
from services.calibration.zhang import Calibration, CalibrationError, calibrate

__all__ = ["Calibration", "CalibrationError", "DetectionError", "GridSheet", "PatternSpec",
           "calibrate", "detect", "detect_grid"]
