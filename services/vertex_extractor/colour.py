"""The per-pixel colour test for the magenta marker (BGR images).

``score = (R + B) / 2 - G`` is linear in how much of a pixel the marker covers, so it gives the
sub-pixel edge position; the interior test adds chroma ratios so that pink, red, blue and
purple things are not taken for the marker, at any brightness.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ColourModel:
    """Interior when: score > ``min_score``, G < ``green_ratio`` min(R, B), |R - B| <
    ``balance`` max(R, B) and min(R, B) > ``min_level`` (grey levels 0-255)."""

    min_score: float = 60.0
    green_ratio: float = 0.45
    balance: float = 0.3
    min_level: int = 50

    def mask(self, bgr: np.ndarray) -> np.ndarray:
        """Boolean interior mask of an H x W x 3 uint8 BGR image."""
        b = bgr[..., 0].astype(np.int16)
        g = bgr[..., 1].astype(np.int16)
        r = bgr[..., 2].astype(np.int16)
        lo = np.minimum(r, b)
        hi = np.maximum(r, b)
        return ((lo > self.min_level) & ((r + b) - 2 * g > 2 * self.min_score)
                & (g < self.green_ratio * lo) & (np.abs(r - b) < self.balance * hi))

    @staticmethod
    def score(bgr: np.ndarray) -> np.ndarray:
        """(R + B) / 2 - G as float32 (linear in the marker's coverage of a pixel)."""
        f = bgr.astype(np.float32)
        return 0.5 * (f[..., 0] + f[..., 2]) - f[..., 1]
