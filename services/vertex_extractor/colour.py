"""What the marker looks like to the camera: the per-pixel colour test and the sub-pixel
score (BGR uint8 images), compiled with numba.

Both work in linear light: a 256-entry table undoes the camera's transfer curve (sRGB by
default), because light mixes linearly across an edge and the sRGB values of a mixed pixel do
not. The interior test is an ellipse in the chromaticity plane (r, g) = (R, G) / (R + G + B),
which does not depend on brightness; the score is the pixel's colour along the marker's
chroma direction (orthogonal to grey; measured on each marker's own interior), linear in how
much of the pixel the marker covers.
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from services.core.jit import njit

# Model vector layout for the kernels: ellipse centre (r, g), inverse shape a, b, c
# (q = a dr² + 2 b dr dg + c dg² <= 1 inside), least R + G + B (x 255).
R0, G0, QA, QB, QC, MIN_SUM = range(6)


class ColourModel(BaseModel):
    """The marker's colour in linear-light chromaticity (r, g) = (R, G) / (R + G + B).

    A pixel is marker when its chromaticity lies within ``max_distance`` of ``centre`` in the
    metric of ``covariance`` (Mahalanobis) and its R + G + B (linear, 0-3) is at least
    ``min_sum``. The default covers printed inks from nominal magenta (255, 0, 255) to process
    magenta (about (236, 0, 140)) and bluish magenta cards under white-balanced light, and
    leaves out pinks, purples and reds with any green in them (hot pink, salmon, lilac).
    ``shepherd marker learn`` fits one to a user's own marker and camera.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)
    centre: tuple[float, float] = Field(default=(0.615, 0.02),
                                        description="the marker's chromaticity (r, g)")
    covariance: tuple[tuple[float, float], tuple[float, float]] = Field(
        default=((0.0064, 0.0), (0.0, 0.0004)), description="its spread in (r, g), 2x2")
    max_distance: float = Field(default=3.0, gt=0.0, le=20.0,
                                description="Mahalanobis distance from centre accepted")
    min_sum: float = Field(default=0.05, ge=0.0, le=3.0,
                           description="least R + G + B in linear light (0-3)")
    transfer: Literal["srgb", "gamma", "linear"] = Field(
        default="srgb", description="the camera's transfer curve, undone before the test")
    gamma: float = Field(default=2.2, gt=0.5, le=4.0, description="when transfer = gamma")

    @model_validator(mode="after")
    def _check(self) -> ColourModel:
        (a, b), (b2, c) = self.covariance
        if abs(b - b2) > 1e-12 or a <= 0 or c <= 0 or a * c - b * b <= 0:
            raise ValueError("covariance must be a symmetric positive definite 2 x 2 matrix")
        r, g = self.centre
        if not (0.0 <= r <= 1.0 and -0.1 <= g <= 1.0 and r + g <= 1.0):
            raise ValueError(f"centre {self.centre} is not a chromaticity (r, g >= 0, r + g <= 1)")
        return self

    @cached_property
    def lut(self) -> np.ndarray:
        """Linear light x 255 of each 8-bit value (float64, 256)."""
        v = np.arange(256) / 255.0
        if self.transfer == "srgb":
            lin = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
        elif self.transfer == "gamma":
            lin = v ** self.gamma
        else:
            lin = v
        return np.ascontiguousarray(lin * 255.0)

    @cached_property
    def vector(self) -> np.ndarray:
        """The model as the kernels take it (see the layout constants)."""
        (a, b), (_, c) = self.covariance
        det = a * c - b * b
        k = 1.0 / self.max_distance ** 2
        r, g = self.centre
        return np.array([r, g, k * c / det, -k * b / det, k * a / det, self.min_sum * 255.0])

    @cached_property
    def green_bound(self) -> np.ndarray:
        """For each 8-bit value v, the largest 8-bit green a marker pixel can have when the
        brighter of its red and blue is v (uint8, 256): a necessary condition of the interior
        test, cheap enough to pass over most pixels before it (``grid_mask``).

        Inside the ellipse the green chromaticity is at most c = g0 + sqrt(QA / det), so
        G <= c (R + G + B), G <= c / (1 - c) (R + B) <= 2 c / (1 - c) max(R, B) (linear)."""
        m = self.vector
        c = m[G0] + math.sqrt(m[QA] / (m[QA] * m[QC] - m[QB] * m[QB]))
        if c >= 1.0:
            return np.full(256, 255, np.uint8)
        limit = 2.0 * c / (1.0 - c) * self.lut * (1.0 + 1e-6) + 1e-9  # (a margin for rounding)
        bound = np.searchsorted(self.lut, limit, side="right") - 1
        return np.clip(bound, 0, 255).astype(np.uint8)

    def chroma_distance(self, bgr: np.ndarray) -> np.ndarray:
        """Mahalanobis distance of each pixel's chromaticity from the centre (for tools)."""
        lin = self.lut[np.asarray(bgr, np.uint8)]
        s = np.maximum(lin.sum(-1), 1e-9)
        m = self.vector
        dr, dg = lin[..., 2] / s - m[R0], lin[..., 1] / s - m[G0]
        q = m[QA] * dr * dr + 2 * m[QB] * dr * dg + m[QC] * dg * dg
        return np.sqrt(np.maximum(q, 0.0)) * self.max_distance

    def mask(self, bgr: np.ndarray) -> np.ndarray:
        """The interior test on a whole image (bool H x W; for tools, not the hot path)."""
        return inside_mask(self.lut[np.asarray(bgr, np.uint8)], self.vector)


@njit(inline="always")
def _inside(b: float, g: float, r: float, m: np.ndarray) -> bool:
    """The interior test of a linear colour (x 255)."""
    s = r + g + b
    if s < m[MIN_SUM] or s <= 0.0:
        return False
    dr = r - m[R0] * s  # the chromaticity offsets times s: no division
    dg = g - m[G0] * s
    return m[QA] * dr * dr + 2.0 * m[QB] * dr * dg + m[QC] * dg * dg <= s * s


@njit(inline="always")
def is_marker(img: np.ndarray, y: int, x: int, lut: np.ndarray, m: np.ndarray) -> bool:
    """The interior test of pixel (x, y) of a BGR uint8 image."""
    return _inside(lut[img[y, x, 0]], lut[img[y, x, 1]], lut[img[y, x, 2]], m)


#: a highlight's halo: white light at least this share of the pixel's brightest channel,
HALO_MIN_WHITE = 0.15
#: and a channel at or above this (linear x 255; sRGB 250) is clipped: it has lost chroma
HALO_CLIPPED = 243.0
#: the halo keeps most of the marker's chroma (a blurred fringe over a bright surround, the
#: marker mixed with grey, keeps only its share of it): at least this share of the seed's,
HALO_MIN_CHROMA = 0.85
#: or of it where a channel clips (clipping takes chroma away as the light grows)
HALO_MIN_CHROMA_CLIPPED = 0.25


@njit(inline="always")
def chroma_amount(img: np.ndarray, y: int, x: int, lut: np.ndarray) -> float:
    """Pixel (x, y)'s linear colour less its grey part (R + G + B - 3 min, x 255)."""
    b = lut[img[y, x, 0]]
    g = lut[img[y, x, 1]]
    r = lut[img[y, x, 2]]
    return b + g + r - 3.0 * min(min(b, g), r)


@njit(inline="always")
def is_lit_marker(img: np.ndarray, y: int, x: int, lut: np.ndarray, m: np.ndarray,
                  min_chroma: float, unclipped: bool) -> bool:
    """The interior test, or the marker under a glossy print's highlight: the marker's
    colour plus white light (in linear light the pixel less its smallest channel passes the
    test with at least ``min_chroma`` of chroma (``chroma_amount``), and the white is at
    least ``HALO_MIN_WHITE`` of the brightest channel). The walk goes on through such pixels
    instead of ending its run at the halo; ``unclipped``: only where no channel clips
    (adding white moves no chroma score, so these still measure an edge; clipping does)."""
    b = lut[img[y, x, 0]]
    g = lut[img[y, x, 1]]
    r = lut[img[y, x, 2]]
    if _inside(b, g, r, m):
        return True
    lo = min(min(b, g), r)
    hi = max(max(b, g), r)
    clipped = hi >= HALO_CLIPPED
    if lo < HALO_MIN_WHITE * hi or (unclipped and clipped):
        return False
    least = min_chroma * (HALO_MIN_CHROMA_CLIPPED / HALO_MIN_CHROMA if clipped else 1.0)
    if b + g + r - 3.0 * lo < least:
        return False
    return _inside(b - lo, g - lo, r - lo, m)


def inside_mask(lin: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``_inside`` over an H x W x 3 array of linear B, G, R (x 255): bool H x W (numpy, in
    the array's float type; for the fits outside the kernels)."""
    r0, g0, qa, qb, qc, min_sum = (float(m[k]) for k in (R0, G0, QA, QB, QC, MIN_SUM))
    s = lin.sum(axis=2)
    dr, dg = lin[..., 2] - r0 * s, lin[..., 1] - g0 * s
    return (s >= min_sum) & (s > 0.0) & (qa * dr * dr + 2.0 * qb * dr * dg + qc * dg * dg
                                         <= s * s)


def lit_marker_mask(lin: np.ndarray, m: np.ndarray, min_chroma: float,
                    unclipped: bool = False) -> np.ndarray:
    """``is_lit_marker`` over an H x W x 3 array of linear B, G, R (x 255): bool H x W
    (numpy, in the array's float type; for the fits outside the kernels)."""
    lo, hi = lin.min(axis=2), lin.max(axis=2)
    clipped = hi >= HALO_CLIPPED
    least = np.where(clipped, min_chroma * (HALO_MIN_CHROMA_CLIPPED / HALO_MIN_CHROMA),
                     min_chroma)
    lit = (lo >= HALO_MIN_WHITE * hi) & (lin.sum(axis=2) - 3.0 * lo >= least) & \
        inside_mask(lin - lo[..., None], m)
    if unclipped:
        lit &= ~clipped
    return inside_mask(lin, m) | lit


@njit(inline="always")
def score(img: np.ndarray, y: int, x: int, lut: np.ndarray, w: np.ndarray) -> float:
    """Pixel (x, y)'s linear colour (x 255) along the chroma direction ``w`` (B, G, R weights,
    orthogonal to grey): linear in the marker's coverage of the pixel, 0 on grey."""
    return w[0] * lut[img[y, x, 0]] + w[1] * lut[img[y, x, 1]] + w[2] * lut[img[y, x, 2]]


@njit(inline="always")
def chroma_direction(b: float, g: float, r: float) -> np.ndarray:
    """Unit B, G, R weights along the chroma of colour (b, g, r), orthogonal to grey."""
    mean = (b + g + r) / 3.0
    w = np.array([b - mean, g - mean, r - mean])
    norm = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    if norm > 1e-9:
        w /= norm
    return w


@njit()
def grid_mask(img: np.ndarray, step: int, offset: int, lut: np.ndarray, m: np.ndarray,
              green_bound: np.ndarray) -> tuple[np.ndarray, int, tuple[int, int, int, int]]:
    """Interior mask on the grid (offset + i step, offset + j step), its count, and the
    bounding box (i0, i1, j0, j1) of the marked cells, inclusive (empty: i0 > i1).
    ``green_bound``: ``ColourModel.green_bound``, which passes over most pixels cheaply."""
    h = (img.shape[0] - offset + step - 1) // step
    w = (img.shape[1] - offset + step - 1) // step
    out = np.zeros((h, w), np.uint8)
    count = 0
    i0, i1, j0, j1 = h, -1, w, -1
    for i in range(h):
        y = offset + i * step
        for j in range(w):
            x = offset + j * step
            if img[y, x, 1] > green_bound[max(img[y, x, 0], img[y, x, 2])]:
                continue  # too green to be the marker
            if is_marker(img, y, x, lut, m):
                out[i, j] = 255
                count += 1
                i0, i1, j0, j1 = min(i0, i), max(i1, i), min(j0, j), max(j1, j)
    return out, count, (i0, i1, j0, j1)


def ellipse_axes(model: ColourModel) -> tuple[float, float, float]:
    """Half-axes of the acceptance ellipse in chromaticity units and its angle (deg)."""
    cov = np.array(model.covariance)
    vals, vecs = np.linalg.eigh(cov)
    k = model.max_distance
    angle = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))
    return k * math.sqrt(vals[1]), k * math.sqrt(vals[0]), angle
