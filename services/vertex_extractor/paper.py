"""The paper's vertex method as published (section 4.1, Tables 1 and 2), for comparison
(``method = "paper"``). Compiled with numba, like ours, so that speeds compare fairly.

Table 1: from the seed P_0, search up and down for the last marker pixels U_k and D_k (whole
pixels); stop when ||U_k D_k|| < MIN_LEN; the next column's start is the chord's midpoint
moved Δx right (then, from P_0 again, left). Table 2: the left line of the U points starts
from the two leftmost, the right line from the two rightmost; each point between, left to
right, joins the nearer line, which is refitted (least squares, y = a x + b, as the paper's
"quadratic error"); the same for the D points; the four lines intersect into the vertices.
Edge points are pixel centres: no sub-pixel step.
"""

from __future__ import annotations

import math

import numpy as np

from services.core.jit import njit
from services.vertex_extractor.colour import is_marker

OK, BORDER, TOO_SHORT = 0, 1, 2


@njit()
def table1(img: np.ndarray, sx: int, sy: int, min_len: int, dx: int, lut: np.ndarray,
           m: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """U and D points (n, 2) px, left to right (U_-N ... U_M), from the marker pixel (sx, sy).
    Status BORDER when a walk reaches the image's edge, TOO_SHORT when P_0's chord is already
    shorter than MIN_LEN."""
    H, W = img.shape[0], img.shape[1]
    cap = W // dx + 2
    right = np.empty((cap, 3), np.int64)  # x, U row, D row
    left = np.empty((cap, 3), np.int64)
    counts = np.zeros(2, np.int64)
    for side in range(2):
        step = dx if side == 0 else -dx
        out = right if side == 0 else left
        x, y = sx, sy
        k = 0
        while 0 <= x < W and 0 <= y < H and is_marker(img, y, x, lut, m):
            u = y
            while u > 0 and is_marker(img, u - 1, x, lut, m):
                u -= 1
            d = y
            while d < H - 1 and is_marker(img, d + 1, x, lut, m):
                d += 1
            if u == 0 or d == H - 1:
                return BORDER, np.empty((0, 2)), np.empty((0, 2))
            if d - u < min_len:  # ||U_k D_k|| < MIN_LEN
                break
            out[k, 0], out[k, 1], out[k, 2] = x, u, d
            k += 1
            y = (u + d) // 2  # P_k+1 = (U_k + D_k) / 2 + [Δx 0]
            x += step
            if x == 0 or x == W - 1:
                return BORDER, np.empty((0, 2)), np.empty((0, 2))
        counts[side] = k
    nr, nl = counts[0], counts[1]
    if nr == 0:
        return TOO_SHORT, np.empty((0, 2)), np.empty((0, 2))
    n = nr + max(nl - 1, 0)  # column 0 is in both searches
    U = np.empty((n, 2))
    D = np.empty((n, 2))
    i = 0
    for k in range(nl - 1, 0, -1):
        U[i, 0], U[i, 1], D[i, 0], D[i, 1] = left[k, 0], left[k, 1], left[k, 0], left[k, 2]
        i += 1
    for k in range(nr):
        U[i, 0], U[i, 1], D[i, 0], D[i, 1] = right[k, 0], right[k, 1], right[k, 0], right[k, 2]
        i += 1
    return OK, U, D


@njit(inline="always")
def _fit(s: np.ndarray) -> tuple[float, float]:
    """Least-squares y = a x + b from sums (n, Σx, Σy, Σxx, Σxy)."""
    det = s[0] * s[3] - s[1] * s[1]
    if abs(det) < 1e-12:
        return 0.0, s[2] / max(s[0], 1.0)
    a = (s[0] * s[4] - s[1] * s[2]) / det
    return a, (s[2] - a * s[1]) / s[0]


@njit(inline="always")
def _add(s: np.ndarray, x: float, y: float) -> None:
    s[0] += 1.0
    s[1] += x
    s[2] += y
    s[3] += x * x
    s[4] += x * y


@njit()
def table2(points: np.ndarray) -> tuple[float, float, float, float, int]:
    """The left and right lines (a_L, b_L, a_R, b_R; y = a x + b) of ordered points, by the
    paper's greedy assignment; the count assigned to the left line (at least 2)."""
    n = points.shape[0]
    sl = np.zeros(5)
    sr = np.zeros(5)
    _add(sl, points[0, 0], points[0, 1])  # U_-N and U_-(N-1)
    _add(sl, points[1, 0], points[1, 1])
    _add(sr, points[n - 1, 0], points[n - 1, 1])  # U_M and U_M-1
    _add(sr, points[n - 2, 0], points[n - 2, 1])
    al, bl = _fit(sl)
    ar, br = _fit(sr)
    for i in range(2, n - 2):  # i = -(N-2) ... M-2
        x, y = points[i, 0], points[i, 1]
        el = abs(al * x - y + bl) / math.sqrt(al * al + 1.0)
        er = abs(ar * x - y + br) / math.sqrt(ar * ar + 1.0)
        if el < er:
            _add(sl, x, y)
            al, bl = _fit(sl)
        else:
            _add(sr, x, y)
            ar, br = _fit(sr)
    return al, bl, ar, br, int(sl[0])


@njit(inline="always")
def _meet(a1: float, b1: float, a2: float, b2: float, out: np.ndarray) -> bool:
    if abs(a1 - a2) < 1e-9:
        return False
    out[0] = (b2 - b1) / (a1 - a2)
    out[1] = a1 * out[0] + b1
    return True


@njit()
def vertices(U: np.ndarray, D: np.ndarray) -> tuple[bool, np.ndarray]:
    """Left, top, right, bottom from the four lines of Table 2 (needs 4 points each)."""
    v = np.zeros((4, 2))
    if U.shape[0] < 4 or D.shape[0] < 4:
        return False, v
    aul, bul, aur, bur, _ = table2(U)
    adl, bdl, adr, bdr, _ = table2(D)
    ok = _meet(aul, bul, adl, bdl, v[0])
    ok &= _meet(aul, bul, aur, bur, v[1])
    ok &= _meet(aur, bur, adr, bdr, v[2])
    ok &= _meet(adl, bdl, adr, bdr, v[3])
    return ok, v
