"""The per-pixel colour test for the magenta marker (BGR images).

``score = (R + B) / 2 - G`` is linear in how much of a pixel the marker covers, so it gives the
sub-pixel edge position; the interior test adds chroma ratios so that pink, red, blue and
purple things are not taken for the marker, at any brightness.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class ColourModel:
    """Interior when: (R + B) / 2 - G > ``min_score``, G < ``green_ratio`` min(R, B),
    |R - B| < ``balance`` max(R, B) and min(R, B) > ``min_level`` (grey levels 0-255)."""

    min_score: float = 60.0
    green_ratio: float = 0.35
    balance: float = 0.2
    min_level: int = 50

    def mask(self, bgr: np.ndarray) -> np.ndarray:
        """Interior mask of an H x W x 3 uint8 BGR image: uint8, 255 inside, 0 outside."""
        b, g, r = cv2.split(bgr)
        lo, hi = cv2.min(r, b), cv2.max(r, b)
        m = cv2.compare(lo, self.min_level, cv2.CMP_GT)
        half_sum = cv2.addWeighted(r, 0.5, b, 0.5, 0.0)
        m &= cv2.compare(cv2.subtract(half_sum, g), self.min_score, cv2.CMP_GT)
        m &= cv2.compare(g, cv2.multiply(lo, self.green_ratio, dtype=cv2.CV_8U), cv2.CMP_LT)
        m &= cv2.compare(cv2.absdiff(r, b), cv2.multiply(hi, self.balance, dtype=cv2.CV_8U),
                         cv2.CMP_LT)
        return m

    @staticmethod
    def score(bgr: np.ndarray) -> np.ndarray:
        """(R + B) / 2 - G as float32 (linear in the marker's coverage of a pixel)."""
        f = bgr.astype(np.float32)
        return 0.5 * (f[..., 0] + f[..., 2]) - f[..., 1]
