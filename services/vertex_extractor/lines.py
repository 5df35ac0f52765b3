"""Table 2 made optimal and robust: the best two-line split, Huber line fits, the vertices
and their plausibility. Compiled with numba.

A line is ``(nx, ny, d)`` with unit normal (nx, ny): points (x, y) on it satisfy
nx x + ny y = d (pixels). The best split of an ordered point list comes from one pass of
prefix moments; each side is then fitted by total least squares with Huber weights
(c = 1.345 px, as OpenCV's ``fitLine(DIST_HUBER)``), by iteratively reweighted least squares.
"""

from __future__ import annotations

import math

import numpy as np

from services.core.jit import njit

FIT_OK, TOO_FEW_POINTS, PARALLEL = 0, 1, 2
MIN_SCALE_PX = 0.03  # least robust residual scale (px) for Huber's threshold
PLAUSIBLE, NOT_FINITE, OUTSIDE, NOT_CONVEX, BAD_ANGLES, NOT_STRAIGHT, AREA_MISMATCH = range(7)


@njit(inline="always")
def _tls_sse(n: float, sx: float, sy: float, sxx: float, syy: float, sxy: float) -> float:
    """Least total squared distance of points to one line, from their moments."""
    a = sxx - sx * sx / n
    c = syy - sy * sy / n
    b = sxy - sx * sy / n
    return 0.5 * (a + c) - math.sqrt(max(0.25 * (a - c) ** 2 + b * b, 0.0))


@njit()
def best_split(points: np.ndarray, min_points: int) -> int:
    """Index k splitting ordered points (N, 2) into two lines [:k] and [k:] with the least
    total TLS residual: the optimal version of the paper's greedy Table 2."""
    n = points.shape[0]
    cx = points[:, 0].mean()
    cy = points[:, 1].mean()  # moments about the centre: well conditioned
    tot = np.zeros(5)
    for i in range(n):
        x, y = points[i, 0] - cx, points[i, 1] - cy
        tot[0] += x
        tot[1] += y
        tot[2] += x * x
        tot[3] += y * y
        tot[4] += x * y
    pre = np.zeros(5)
    best, best_k = np.inf, min_points
    for k in range(1, n - min_points + 1):
        x, y = points[k - 1, 0] - cx, points[k - 1, 1] - cy
        pre[0] += x
        pre[1] += y
        pre[2] += x * x
        pre[3] += y * y
        pre[4] += x * y
        if k < min_points:
            continue
        cost = _tls_sse(k, pre[0], pre[1], pre[2], pre[3], pre[4]) + _tls_sse(
            n - k, tot[0] - pre[0], tot[1] - pre[1], tot[2] - pre[2], tot[3] - pre[3],
            tot[4] - pre[4])
        if cost < best:
            best, best_k = cost, k
    return best_k


@njit()
def huber_line(points: np.ndarray, c: float = 1.345, iterations: int = 10,
               scaled: bool = True) -> tuple[float, float, float, float, int]:
    """Huber-weighted TLS line through points (N >= 2, 2) px by IRLS.

    Returns (nx, ny, d, sum of squared distances of the inliers, inlier count); inliers are
    within 3 robust sigmas (at least 0.25 px) of the line, for the residual figure.
    """
    n = points.shape[0]
    w = np.ones(n)
    r = np.zeros(n)
    nx = ny = d = 0.0
    scale = 1.0
    for it in range(iterations):
        sw = mx = my = 0.0
        for i in range(n):
            sw += w[i]
            mx += w[i] * points[i, 0]
            my += w[i] * points[i, 1]
        mx /= sw
        my /= sw
        sxx = syy = sxy = 0.0
        for i in range(n):
            ex, ey = points[i, 0] - mx, points[i, 1] - my
            sxx += w[i] * ex * ex
            syy += w[i] * ey * ey
            sxy += w[i] * ex * ey
        theta = 0.5 * math.atan2(2.0 * sxy, sxx - syy)  # direction of the major axis
        nx_new, ny_new = -math.sin(theta), math.cos(theta)
        moved = abs(nx_new - nx) + abs(ny_new - ny)
        nx, ny = nx_new, ny_new
        d = nx * mx + ny * my
        for i in range(n):
            r[i] = nx * points[i, 0] + ny * points[i, 1] - d
        if it == 0 and scaled:  # Huber's threshold in units of the first fit's robust
            scale = max(1.4826 * np.median(np.abs(r)), MIN_SCALE_PX)  # scale (MAD), floored
        for i in range(n):
            a = abs(r[i])
            w[i] = 1.0 if a <= c * scale else c * scale / a
        if it > 0 and moved < 1e-9:
            break
    r2 = r * r
    limit = max(9.0 * 1.4826 ** 2 * np.median(r2), 0.0625)
    sq, count = 0.0, 0
    for i in range(n):
        if r2[i] <= limit:
            sq += r2[i]
            count += 1
    return nx, ny, d, sq, count


@njit(inline="always")
def _intersect(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> bool:
    det = a[0] * b[1] - a[1] * b[0]
    if abs(det) < 1e-9:
        return False
    out[0] = (a[2] * b[1] - b[2] * a[1]) / det
    out[1] = (a[0] * b[2] - b[0] * a[2]) / det
    return True


@njit()
def fit_rhombus(u: np.ndarray, d: np.ndarray, min_points: int, drop: int
                ) -> tuple[int, np.ndarray, float]:
    """Four vertices (left, top, right, bottom) px from the upper points U and lower points
    D (each ordered by x): split each at its vertex, drop ``drop`` points each side of the
    split (their window straddles the vertex), fit the four lines, intersect.

    Returns (status, vertices (4, 2), RMS line residual px).
    """
    v = np.zeros((4, 2))
    lines = np.zeros((4, 3))  # left-upper, right-upper, left-lower, right-lower
    sq, count = 0.0, 0
    for s in range(2):
        pts = u if s == 0 else d
        k = best_split(pts, min_points)
        for side in range(2):
            part = pts[:max(k - drop, 0)] if side == 0 else pts[k + drop:]
            if part.shape[0] < min_points:
                return TOO_FEW_POINTS, v, 0.0
            nx, ny, dd, q, c = huber_line(part)
            lines[2 * s + side, 0] = nx
            lines[2 * s + side, 1] = ny
            lines[2 * s + side, 2] = dd
            sq += q
            count += c
    ok = _intersect(lines[0], lines[2], v[0])  # left = upper-left x lower-left
    ok &= _intersect(lines[0], lines[1], v[1])
    ok &= _intersect(lines[1], lines[3], v[2])
    ok &= _intersect(lines[2], lines[3], v[3])
    if not ok:
        return PARALLEL, v, 0.0
    return FIT_OK, v, math.sqrt(sq / count)


@njit()
def check_rhombus(v: np.ndarray, residual: float, blob_area: float, width: int, height: int,
                  min_angle_deg: float, max_residual: float
                  ) -> tuple[int, float, float, float]:
    """Is the quadrilateral v (left, top, right, bottom) px the marker? Returns (verdict,
    area px², smallest and largest corner angle deg); area is checked against the blob's
    with a tolerance of 15% + 2 sqrt(area)."""
    for i in range(4):
        if not (math.isfinite(v[i, 0]) and math.isfinite(v[i, 1])):
            return NOT_FINITE, 0.0, 0.0, 0.0
    for i in range(4):
        if v[i, 0] < -0.5 or v[i, 1] < -0.5 or v[i, 0] > width - 0.5 or \
                v[i, 1] > height - 0.5:
            return OUTSIDE, 0.0, 0.0, 0.0
    positive = negative = 0
    amin, amax = 180.0, 0.0
    area2 = 0.0
    for i in range(4):
        j, k = (i + 1) % 4, (i + 3) % 4
        ex, ey = v[j, 0] - v[i, 0], v[j, 1] - v[i, 1]       # edge leaving vertex i
        px, py = v[i, 0] - v[k, 0], v[i, 1] - v[k, 1]       # edge arriving at vertex i
        cross = px * ey - py * ex
        positive += cross > 0
        negative += cross < 0
        cosang = -(px * ex + py * ey) / (math.hypot(px, py) * math.hypot(ex, ey))
        ang = math.degrees(math.acos(min(max(cosang, -1.0), 1.0)))
        amin, amax = min(amin, ang), max(amax, ang)
        area2 += v[i, 0] * v[j, 1] - v[i, 1] * v[j, 0]
    area = 0.5 * abs(area2)
    if positive != 4 and negative != 4:
        return NOT_CONVEX, area, amin, amax
    if amin < min_angle_deg or amax > 180.0 - min_angle_deg:
        return BAD_ANGLES, area, amin, amax
    if residual > max_residual:
        return NOT_STRAIGHT, area, amin, amax
    if abs(area - blob_area) > 0.15 * area + 2.0 * math.sqrt(area):
        return AREA_MISMATCH, area, amin, amax
    return PLAUSIBLE, area, amin, amax
