"""Table 1 of the paper: the column scan from a seed pixel, with sub-pixel edge points.

Compiled with numba: the scan visits a few pixels per column, so its cost is the marker's
width, not its area or the frame's size. Each column's run of marker pixels is found from the
previous column's (walking up or down from its ends), which is Table 1's walk made
incremental; a one-pixel gap is bridged so that image noise inside the marker does not end
a run early.

Edge points are sub-pixel: the colour score is linear in the marker's coverage of a pixel, so
the sum of coverages over a window of rows across the edge gives the edge's distance from the
window's end, exactly on area-sampled images.
"""

from __future__ import annotations

import numpy as np

from services.core.jit import njit
from services.vertex_extractor.colour import is_marker, score

OK, BORDER, LOW_CONTRAST = 0, 1, 2


@njit(inline="always")
def _run_up(img, x, y, c0, c1, c2, c3):  # type: ignore[no-untyped-def]
    """Topmost row of the run of marker pixels containing (x, y), bridging 1-px gaps."""
    while y > 0:
        if is_marker(img, y - 1, x, c0, c1, c2, c3):
            y -= 1
        elif y > 1 and is_marker(img, y - 2, x, c0, c1, c2, c3):
            y -= 2
        else:
            break
    return y


@njit(inline="always")
def _run_down(img, x, y, c0, c1, c2, c3):  # type: ignore[no-untyped-def]
    """Bottom row of the run of marker pixels containing (x, y), bridging 1-px gaps."""
    last = img.shape[0] - 1
    while y < last:
        if is_marker(img, y + 1, x, c0, c1, c2, c3):
            y += 1
        elif y < last - 1 and is_marker(img, y + 2, x, c0, c1, c2, c3):
            y += 2
        else:
            break
    return y


@njit(inline="always")
def _column(img, x, prev_top, prev_bottom, c0, c1, c2, c3):  # type: ignore[no-untyped-def]
    """(top, bottom) rows of column x's run overlapping the previous column's run
    [prev_top, prev_bottom]; (-1, -1) when the column has none."""
    y = prev_top
    if is_marker(img, y, x, c0, c1, c2, c3):
        top = _run_up(img, x, y, c0, c1, c2, c3)
    else:
        y += 1
        while y <= prev_bottom and not is_marker(img, y, x, c0, c1, c2, c3):
            y += 1
        if y > prev_bottom:
            return -1, -1
        top = y
    y = prev_bottom
    if is_marker(img, y, x, c0, c1, c2, c3):
        bottom = _run_down(img, x, y, c0, c1, c2, c3)
    else:
        y -= 1
        while y > top and not is_marker(img, y, x, c0, c1, c2, c3):
            y -= 1
        bottom = y
    return top, bottom


@njit()
def find_seed(img: np.ndarray, sx: int, sy: int, radius: int, c0: float, c1: float,
              c2: float, c3: float) -> tuple[int, int]:
    """A marker pixel at or near (sx, sy): along the seed's column, then its row, out to
    ``radius`` px; (-1, -1) when there is none."""
    H, W = img.shape[0], img.shape[1]
    if sx < 0 or sy < 0 or sx >= W or sy >= H:
        return -1, -1
    for k in range(radius + 1):
        for y in (sy - k, sy + k):
            if 0 <= y < H and is_marker(img, y, sx, c0, c1, c2, c3):
                return sx, y
        for x in (sx - k, sx + k):
            if 0 <= x < W and is_marker(img, sy, x, c0, c1, c2, c3):
                return x, sy
    return -1, -1


@njit()
def scan(img: np.ndarray, sx: int, sy: int, min_len: int, dx: int, window: int,
         c0: float, c1: float, c2: float, c3: float
         ) -> tuple[int, int, int, float, np.ndarray, np.ndarray]:
    """Walk the marker's columns from the marker pixel (sx, sy) and measure its edges.

    Returns (status, blob area px, usable columns, contrast grey levels, U points (n, 2),
    D points (n, 2)), points in pixels (x, y) on columns Δx = ``dx`` apart, over the widest
    column and its neighbours whose run is at least ``min_len`` px long (Table 1's stop).
    Status: OK, BORDER (the marker reaches the image border or the edge windows would),
    LOW_CONTRAST (fewer than 20 grey levels between inside and outside).
    """
    H, W = img.shape[0], img.shape[1]
    empty = np.empty((0, 2))
    top = np.full(W, -1, np.int64)
    bottom = np.full(W, -1, np.int64)
    top[sx] = _run_up(img, sx, sy, c0, c1, c2, c3)
    bottom[sx] = _run_down(img, sx, sy, c0, c1, c2, c3)
    lo, hi = sx, sx + 1  # walked columns [lo, hi)
    for step in (1, -1):
        t, b = top[sx], bottom[sx]
        x = sx + step
        while 0 <= x < W:
            t, b = _column(img, x, t, b, c0, c1, c2, c3)
            if t < 0:
                break
            top[x], bottom[x] = t, b
            x += step
        if step == 1:
            hi = x
        else:
            lo = x + 1
    area = 0
    widest = sx
    touches = lo == 0 or hi == W
    for x in range(lo, hi):
        area += bottom[x] - top[x] + 1
        touches = touches or top[x] == 0 or bottom[x] == H - 1
        if bottom[x] - top[x] > bottom[widest] - top[widest]:
            widest = x
    if touches:
        return BORDER, area, 0, 0.0, empty, empty
    a = widest  # Table 1: from the widest column right and left until a run < MIN_LEN
    while a > lo and bottom[a - 1] - top[a - 1] + 1 >= min_len:
        a -= 1
    z = widest + 1
    while z < hi and bottom[z] - top[z] + 1 >= min_len:
        z += 1
    if bottom[widest] - top[widest] + 1 < min_len:
        return OK, area, 0, 0.0, empty, empty
    n = (z - a + dx - 1) // dx
    gap = window + 2
    s_in = 0.0
    outside = np.empty(2 * n)
    for i in range(n):
        x = a + i * dx
        if top[x] < gap or bottom[x] + gap > H - 1:
            return BORDER, area, n, 0.0, empty, empty
        s_in += score(img, (top[x] + bottom[x]) // 2, x)
        outside[2 * i] = score(img, top[x] - gap, x)
        outside[2 * i + 1] = score(img, bottom[x] + gap, x)
    s_in /= n
    s_out = np.median(outside)
    contrast = s_in - s_out
    if contrast < 20.0:
        return LOW_CONTRAST, area, n, contrast, empty, empty
    inv = 1.0 / contrast
    u = np.empty((n, 2))
    d = np.empty((n, 2))
    for i in range(n):
        x = a + i * dx
        su = 0.0
        sd = 0.0
        for o in range(-window, window):
            su += min(max((score(img, top[x] + o, x) - s_out) * inv, -0.5), 1.5)
            sd += min(max((score(img, bottom[x] + 1 + o, x) - s_out) * inv, -0.5), 1.5)
        u[i, 0] = x
        u[i, 1] = top[x] + window - 0.5 - su
        d[i, 0] = x
        d[i, 1] = bottom[x] - window + 0.5 + sd
    return OK, area, n, contrast, u, d
