"""The per-pixel colour test for the magenta marker (BGR images), compiled with numba.

``score = (R + B) / 2 - G`` is linear in how much of a pixel the marker covers, so it gives the
sub-pixel edge position; the interior test adds chroma ratios so that pink, red, blue and
purple things are not taken for the marker, at any brightness.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from services.core.jit import njit


class ColourModel(BaseModel):
    """Interior when: (R + B) / 2 - G > ``min_score``, G < ``green_ratio`` min(R, B),
    |R - B| < ``balance`` max(R, B) and min(R, B) > ``min_level`` (grey levels 0-255)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    min_score: float = Field(default=60.0, gt=0)
    green_ratio: float = Field(default=0.35, gt=0, le=1)
    balance: float = Field(default=0.2, gt=0, le=1)
    min_level: int = Field(default=50, ge=0, le=255)

    @property
    def args(self) -> tuple[float, float, float, float]:
        """The thresholds in the order the compiled kernels take them."""
        return (float(self.min_score), float(self.green_ratio), float(self.balance),
                float(self.min_level))


@njit(inline="always")
def is_marker(img: np.ndarray, y: int, x: int, min_score: float, green_ratio: float,
              balance: float, min_level: float) -> bool:
    """The interior test of pixel (x, y) of a BGR uint8 image."""
    b = float(img[y, x, 0])
    g = float(img[y, x, 1])
    r = float(img[y, x, 2])
    lo = min(r, b)
    return (lo > min_level and 0.5 * (r + b) - g > min_score and g < green_ratio * lo
            and abs(r - b) < balance * max(r, b))


@njit(inline="always")
def score(img: np.ndarray, y: int, x: int) -> float:
    """(R + B) / 2 - G of pixel (x, y): linear in the marker's coverage of the pixel."""
    return 0.5 * (float(img[y, x, 0]) + float(img[y, x, 2])) - float(img[y, x, 1])


@njit()
def grid_mask(img: np.ndarray, step: int, offset: int, min_score: float, green_ratio: float,
              balance: float, min_level: float) -> tuple[np.ndarray, int]:
    """Interior mask on the grid (offset + i step, offset + j step), and its count."""
    h = (img.shape[0] - offset + step - 1) // step
    w = (img.shape[1] - offset + step - 1) // step
    out = np.zeros((h, w), np.uint8)
    count = 0
    for i in range(h):
        y = offset + i * step
        for j in range(w):
            if is_marker(img, y, offset + j * step, min_score, green_ratio, balance, min_level):
                out[i, j] = 255
                count += 1
    return out, count
