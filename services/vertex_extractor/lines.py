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
from services.core.order import median_in_place

FIT_OK, TOO_FEW_POINTS, PARALLEL = 0, 1, 2
MIN_SCALE_PX = 0.03  # least robust residual scale (px) for Huber's threshold
PLAUSIBLE, NOT_FINITE, OUTSIDE, NOT_CONVEX, BAD_ANGLES, NOT_STRAIGHT, AREA_MISMATCH = range(7)


@njit(inline="always")
def largest_variance(a: float, b: float, c: float) -> float:
    """The larger eigenvalue of the symmetric 2 x 2 matrix [[a, b], [b, c]] (a covariance's
    variance along its long axis)."""
    return 0.5 * (a + c) + math.sqrt(max(0.25 * (a - c) ** 2 + b * b, 0.0))


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
               scaled: bool = True, inliers: bool = True
               ) -> tuple[float, float, float, float, int]:
    """Huber-weighted TLS line through points (N >= 2, 2) px by IRLS.

    Returns (nx, ny, d, sum of squared distances of the inliers, inlier count); inliers are
    within 3 robust sigmas (at least 0.25 px) of the line, for the residual figure (0, 0
    where not ``inliers``: a caller that judges the line itself skips their median).
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
            for i in range(n):  # scale (MAD), floored (the weights are w's scratch till then)
                w[i] = abs(r[i])
            scale = max(1.4826 * median_in_place(w, n), MIN_SCALE_PX)
        for i in range(n):
            a = abs(r[i])
            w[i] = 1.0 if a <= c * scale else c * scale / a
        if it > 0 and moved < 1e-9:
            break
    if not inliers:
        return nx, ny, d, 0.0, 0
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


#: how much more than the quadrilateral the blob may cover, in units of sqrt(area) px²: a
#: band about a quarter of this wide (px) round the outline (a small marker's blurred fringe
#: passes the colour test: 4.5-9 on 25-40 px markers through the webcam)
BLOB_FRINGE = 10.0


@njit()
def check_rhombus(v: np.ndarray, residual: float, blob_area: float, width: int, height: int,
                  min_angle_deg: float, max_residual: float
                  ) -> tuple[int, float, float, float]:
    """Is the quadrilateral v (left, top, right, bottom) px the marker? Returns (verdict,
    area px², smallest and largest corner angle deg); the blob's area may exceed the
    quadrilateral's by 15% + BLOB_FRINGE sqrt(area) (a blurred fringe), and fall short of it by
    30% + 2 sqrt(area) (part of the marker hidden, its vertex given by the visible lines)."""
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
    if blob_area - area > 0.15 * area + BLOB_FRINGE * math.sqrt(area) or \
            area - blob_area > 0.3 * area + 2.0 * math.sqrt(area):
        return AREA_MISMATCH, area, amin, amax
    return PLAUSIBLE, area, amin, amax


TUKEY_C = 4.685        # Tukey biweight constant, in robust sigmas
INLIER_SIGMAS = 3.0    # a point within this many robust sigmas of its line is an inlier
MIN_SIGMA_PX = 0.05    # least robust residual scale (px)
MIN_INLIER_SHARE = 0.5  # a line with fewer inliers is not measured (hidden, or not an edge)
#: a bowed edge (a lens's barrel distortion, a curled print): the quadratic through its inliers'
#: residuals, carried to the vertex, departs from the line by a bias the points' noise does
#: not average out; its square, less BOW_SIGMAS² times its own noise variance, is added to
#: the vertex's variance along the line's normal (``_bow``). 1: the fitted departure's square
#: less its noise variance is the unbiased estimate of the bias's square (2 under-added it:
#: NEES 3.6 on barrel-distorted views, 2.95 with 1; the other conditions 0.04-0.23 lower)
BOW_SIGMAS = 1.0
FAST_SIGMAS, FAST_PX = 5.0, 0.6  # no point further than these from the Huber line: it stands


@njit(inline="always")
def _tls(points: np.ndarray, w: np.ndarray) -> tuple[float, float, float]:
    sw = mx = my = 0.0
    for i in range(points.shape[0]):
        sw += w[i]
        mx += w[i] * points[i, 0]
        my += w[i] * points[i, 1]
    if sw <= 0:
        return 0.0, 1.0, 0.0
    mx /= sw
    my /= sw
    sxx = syy = sxy = 0.0
    for i in range(points.shape[0]):
        ex, ey = points[i, 0] - mx, points[i, 1] - my
        sxx += w[i] * ex * ex
        syy += w[i] * ey * ey
        sxy += w[i] * ex * ey
    theta = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    nx, ny = -math.sin(theta), math.cos(theta)
    return nx, ny, nx * mx + ny * my


@njit(inline="always")
def _trimmed_cost(points: np.ndarray, nx: float, ny: float, d: float, r: np.ndarray) -> float:
    """Sum of the smallest 60 % squared residuals (a least-trimmed-squares score)."""
    n = points.shape[0]
    for i in range(n):
        r[i] = (nx * points[i, 0] + ny * points[i, 1] - d) ** 2
    s = np.sort(r)
    k = max(int(0.6 * n), 2)
    return s[:k].sum()


@njit()
def robust_line(points: np.ndarray) -> tuple[float, float, float, float, int, float, float,
                                              float, float, int, int]:
    """A line through points (N >= 4, 2) px that ignores a minority of them wholesale (an
    occluder's boundary, a highlight's halo, a stretch of marker-coloured surround): the
    better (by trimmed squares) of the Huber fit and the fit to the middle half, refined by
    Tukey's biweight.

    Returns (nx, ny, d, robust sigma px, inliers, inlier centroid x, y, spread along the line
    Σ t² px², inlier sum of squared residuals, outliers on the normal's side, outliers on
    the other side).
    """
    n = points.shape[0]
    r = np.empty(n)
    w = np.ones(n)
    nx, ny, d, _, _ = huber_line(points, 1.345, 10, True, False)
    for i in range(n):
        r[i] = abs(nx * points[i, 0] + ny * points[i, 1] - d)
    top = r.max()
    if top <= FAST_PX:  # (r is scratch from here on)
        sigma = max(1.4826 * median_in_place(r, n), MIN_SIGMA_PX)
        if top <= max(FAST_SIGMAS * sigma, 0.25):  # no gross outliers: the Huber fit stands
            return _line_stats(points, nx, ny, d, sigma)
    best = _trimmed_cost(points, nx, ny, d, r)
    q = n // 4
    for i in range(n):
        w[i] = 1.0 if q <= i < n - q else 0.0
    mx, my, md = _tls(points, w)
    cost = _trimmed_cost(points, mx, my, md, r)
    if cost < best:
        nx, ny, d = mx, my, md
    sigma = 1.0
    for it in range(8):
        for i in range(n):
            r[i] = nx * points[i, 0] + ny * points[i, 1] - d
        if it < 2:  # (w is scratch until the weights below)
            for i in range(n):
                w[i] = abs(r[i])
            sigma = max(1.4826 * median_in_place(w, n), MIN_SIGMA_PX)
        c = TUKEY_C * sigma
        for i in range(n):
            a = r[i] / c
            w[i] = (1.0 - a * a) ** 2 if abs(a) < 1.0 else 0.0
        onx, ony = nx, ny
        nx, ny, d = _tls(points, w)
        if abs(onx - nx) + abs(ony - ny) < 1e-10 and it > 2:
            break
    return _line_stats(points, nx, ny, d, -1.0)


@njit(inline="always")
def _line_stats(points: np.ndarray, nx: float, ny: float, d: float, sigma: float
                ) -> tuple[float, float, float, float, int, float, float, float, float, int,
                           int]:
    """``robust_line``'s result for the line (nx, ny, d), whose robust sigma (px) is
    ``sigma`` where known (else negative)."""
    n = points.shape[0]
    r = np.empty(n)
    for i in range(n):
        r[i] = nx * points[i, 0] + ny * points[i, 1] - d
    if sigma < 0.0:
        scratch = np.empty(n)
        for i in range(n):
            scratch[i] = abs(r[i])
        sigma = max(1.4826 * median_in_place(scratch, n), MIN_SIGMA_PX)
    band = max(INLIER_SIGMAS * sigma, 0.25)
    count = 0
    cx = cy = sq = 0.0
    pos = neg = 0
    for i in range(n):
        if abs(r[i]) <= band:
            count += 1
            cx += points[i, 0]
            cy += points[i, 1]
            sq += r[i] * r[i]
        elif r[i] > 0:
            pos += 1
        else:
            neg += 1
    if count == 0:
        return nx, ny, d, sigma, 0, 0.0, 0.0, 0.0, 0.0, pos, neg
    cx /= count
    cy /= count
    spread = 0.0
    for i in range(n):
        if abs(r[i]) <= band:
            t = -ny * (points[i, 0] - cx) + nx * (points[i, 1] - cy)
            spread += t * t
    rms = math.sqrt(sq / count)
    return nx, ny, d, max(rms, MIN_SIGMA_PX), count, cx, cy, spread, sq, pos, neg


#: splits whose cost is within this share of the least (and of band²) are ties
#: (``robust_split``)
TIE = 1e-9


@njit()
def robust_split(points: np.ndarray, k: int, a: np.ndarray, b: np.ndarray, band: float) -> int:
    """The split index (points [:k] on line a, [k:] on line b) with the least truncated
    squared residual (min(r², band²)): the vertex's place once both lines are known.

    Points beyond the band from both lines (a rounded or shaded vertex, an occluder's
    boundary) cost band² on either, so the cost is flat across them: among the splits within
    ``TIE`` of the least, the one nearest the lines' crossing along the chain (x; points
    (N, 2) sorted by x). Rounding alone used to pick one: a change of 1e-14 px in one point
    moved a shadowed marker's vertex 0.34 px."""
    n = points.shape[0]
    pre = np.zeros(n + 1)
    post = np.zeros(n + 1)
    b2 = band * band
    for i in range(n):
        ra = a[0] * points[i, 0] + a[1] * points[i, 1] - a[2]
        pre[i + 1] = pre[i] + min(ra * ra, b2)
    for i in range(n - 1, -1, -1):
        rb = b[0] * points[i, 0] + b[1] * points[i, 1] - b[2]
        post[i] = post[i + 1] + min(rb * rb, b2)
    best, best_k = np.inf, k
    for j in range(n + 1):
        if pre[j] + post[j] < best:
            best, best_k = pre[j] + post[j], j
    det = a[0] * b[1] - a[1] * b[0]
    if abs(det) < 1e-9 or n == 0:
        return best_k
    crossing = (a[2] * b[1] - b[2] * a[1]) / det  # its x
    near = np.inf
    limit = best + TIE * (best + b2)
    for j in range(n + 1):
        if pre[j] + post[j] <= limit:
            x = points[j - 1, 0] if j == n else (
                points[0, 0] if j == 0 else 0.5 * (points[j - 1, 0] + points[j, 0]))
            if abs(x - crossing) < near:
                near, best_k = abs(x - crossing), j
    return best_k


HIDDEN_EDGE, OUTSIDE_POINTS = 3, 4  # further fit statuses


@njit()
def fit_rhombus_robust(u: np.ndarray, d: np.ndarray, min_points: int, drop: int,
                       centre_x: float, centre_y: float, max_outside_share: float,
                       cov_scale: float = 1.0, cov_floor: float = 0.0
                       ) -> tuple[int, np.ndarray, float, np.ndarray, float]:
    """``fit_rhombus`` that survives a hidden vertex or part of an edge: each of the four
    lines by ``robust_line``, the splits moved to where the two lines meet, and the per-vertex
    covariance of the intersections. (centre_x, centre_y): a point inside the marker.

    Returns (status, vertices (4, 2), RMS inlier residual px, vertex covariances (4, 2, 2)
    px², the largest vertex sigma px). The covariance treats the points as independent with
    their line's RMS residual, times ``cov_scale``, plus ``cov_floor`` px² on the diagonal.
    Status FIT_OK, TOO_FEW_POINTS, PARALLEL, HIDDEN_EDGE (a line with too
    few inliers), OUTSIDE_POINTS (more than ``max_outside_share`` of a line's points beyond
    it, outside the quadrilateral: it is not the whole marker's edge).
    """
    v = np.zeros((4, 2))
    cov = np.zeros((4, 2, 2))
    lines = np.zeros((4, 20))
    for s in range(2):
        pts = u if s == 0 else d
        k = best_split(pts, min_points)
        for rnd in range(3):
            for side in range(2):
                part = pts[:max(k - drop, 0)] if side == 0 else pts[k + drop:]
                if part.shape[0] < min_points:
                    return TOO_FEW_POINTS, v, 0.0, cov, 0.0
                nx, ny, dd, sg, cnt, cx, cy, spread, sq, pos, neg = robust_line(part)
                if nx * centre_x + ny * centre_y - dd > 0:  # orient the normal outward
                    nx, ny, dd, pos, neg = -nx, -ny, -dd, neg, pos
                row = lines[2 * s + side]
                row[0], row[1], row[2], row[3], row[4] = nx, ny, dd, sg, cnt
                row[5], row[6], row[7], row[8] = cx, cy, spread, sq
                row[9], row[10] = pos, part.shape[0]
            if rnd == 2 or (lines[2 * s, 9] == 0 and lines[2 * s + 1, 9] == 0 and
                            lines[2 * s, 4] == lines[2 * s, 10] and
                            lines[2 * s + 1, 4] == lines[2 * s + 1, 10]):
                break  # (every point an inlier: the split stands)
            band = INLIER_SIGMAS * max(lines[2 * s, 3], lines[2 * s + 1, 3])
            k2 = robust_split(pts, k, lines[2 * s], lines[2 * s + 1], max(band, 0.5))
            k2 = min(max(k2, min_points + drop), pts.shape[0] - min_points - drop)
            if k2 == k:
                break
            k = k2
        for side in range(2):  # (the lines as last fitted: on the split k)
            _bow(pts[:max(k - drop, 0)] if side == 0 else pts[k + drop:], lines[2 * s + side])
    return _quad(lines, min_points, max_outside_share, cov_scale, cov_floor)


@njit()
def _bow(points: np.ndarray, row: np.ndarray) -> None:
    """The quadratic a0 + a1 t + a2 t² (t px along the line from its centroid) through the
    residuals of ``points`` (n, 2) px from the line in ``row`` (``fit_rhombus_robust``'s
    columns 0-8), its inliers only (within ``INLIER_SIGMAS`` sigmas), into ``row[11:14]``,
    and the inverse of its normal matrix's upper triangle into ``row[14:20]`` (the
    coefficients' covariance over sigma²; ``_bow_variance``); zeros with fewer than 6."""
    nx, ny, d, sigma, cx, cy = row[0], row[1], row[2], row[3], row[5], row[6]
    band = max(INLIER_SIGMAS * sigma, 0.25)
    n = s1 = s2 = s3 = s4 = r0 = r1 = r2 = 0.0
    for i in range(points.shape[0]):
        r = nx * points[i, 0] + ny * points[i, 1] - d
        if abs(r) > band:
            continue
        t = -ny * (points[i, 0] - cx) + nx * (points[i, 1] - cy)
        t2 = t * t
        n += 1.0
        s1 += t
        s2 += t2
        s3 += t * t2
        s4 += t2 * t2
        r0 += r
        r1 += r * t
        r2 += r * t2
    for c in range(11, 20):
        row[c] = 0.0
    # the normal matrix [[n, s1, s2], [s1, s2, s3], [s2, s3, s4]], inverted by cofactors
    c00, c01, c02 = s2 * s4 - s3 * s3, s2 * s3 - s1 * s4, s1 * s3 - s2 * s2
    c11, c12, c22 = n * s4 - s2 * s2, s1 * s2 - n * s3, n * s2 - s1 * s1
    det = n * c00 + s1 * c01 + s2 * c02
    if n < 6.0 or det <= 1e-9 * n * s2 * s4:
        return  # (too few, or the points bunched: no curvature to tell)
    i00, i01, i02, i11, i12, i22 = c00 / det, c01 / det, c02 / det, c11 / det, c12 / det, \
        c22 / det
    row[11] = i00 * r0 + i01 * r1 + i02 * r2
    row[12] = i01 * r0 + i11 * r1 + i12 * r2
    row[13] = i02 * r0 + i12 * r1 + i22 * r2
    row[14], row[15], row[16], row[17], row[18], row[19] = i00, i01, i02, i11, i12, i22


@njit(inline="always")
def _bow_variance(row: np.ndarray, s: float, cov_scale: float) -> float:
    """The square of the line's departure from its bowed edge at s px along it from its
    centroid (``_bow``'s quadratic there), less ``BOW_SIGMAS``² times that departure's noise
    variance (the line's sigma² g' inv g, g = (1, s, s²), times ``cov_scale``: neighbouring
    points share pixels); 0 where within its noise."""
    s2 = s * s
    bias = row[11] + row[12] * s + row[13] * s2
    gig = (row[14] + 2.0 * row[15] * s + 2.0 * row[16] * s2 + row[17] * s2
           + 2.0 * row[18] * s * s2 + row[19] * s2 * s2)
    return max(bias * bias - BOW_SIGMAS * BOW_SIGMAS * cov_scale * row[3] * row[3] * gig,
               0.0)


@njit()
def _quad(lines: np.ndarray, min_points: int, max_outside_share: float, cov_scale: float,
          cov_floor: float) -> tuple[int, np.ndarray, float, np.ndarray, float]:
    """The four fitted lines (rows: upper left, upper right, lower left, lower right; columns
    as ``fit_rhombus_robust`` fills them) tested and intersected into the vertices and their
    covariance (``fit_rhombus_robust``'s return)."""
    v = np.zeros((4, 2))
    cov = np.zeros((4, 2, 2))
    sq_all, count = 0.0, 0
    for i in range(4):
        if lines[i, 4] < min_points or lines[i, 4] < MIN_INLIER_SHARE * lines[i, 10]:
            return HIDDEN_EDGE, v, 0.0, cov, 0.0
        if lines[i, 9] > max_outside_share * lines[i, 10]:
            return OUTSIDE_POINTS, v, 0.0, cov, 0.0
        sq_all += lines[i, 8]
        count += int(lines[i, 4])
    sigma_max = 0.0
    for vi in range(4):  # left = 0 x 2, top = 0 x 1, right = 1 x 3, bottom = 2 x 3
        i = 0 if vi < 2 else (1 if vi == 2 else 2)
        j = 2 if vi == 0 else (1 if vi == 1 else 3)
        a, b = lines[i], lines[j]
        det = a[0] * b[1] - a[1] * b[0]
        if abs(det) < 1e-9:
            return PARALLEL, v, 0.0, cov, 0.0
        x = (a[2] * b[1] - b[2] * a[1]) / det
        y = (a[0] * b[2] - b[0] * a[2]) / det
        v[vi, 0], v[vi, 1] = x, y
        # N^-1 = [[b1, -a1], [-b0, a0]] / det; each line's offset (var sigma²/n) and its
        # angle about its centroid (var sigma²/spread, lever: the vertex's distance along it)
        sa = -a[1] * (x - a[5]) + a[0] * (y - a[6])
        sb = -b[1] * (x - b[5]) + b[0] * (y - b[6])
        va = a[3] ** 2 * (1.0 / a[4] + sa * sa / max(a[7], 1e-9))
        vb = b[3] ** 2 * (1.0 / b[4] + sb * sb / max(b[7], 1e-9))
        j00, j01 = b[1] / det, -a[1] / det
        j10, j11 = -b[0] / det, a[0] / det
        cxx = cov_scale * (j00 * j00 * va + j01 * j01 * vb) + cov_floor
        cxy = cov_scale * (j00 * j10 * va + j01 * j11 * vb)
        cyy = cov_scale * (j10 * j10 * va + j11 * j11 * vb) + cov_floor
        # the largest sigma, which refuses a marker too uncertain, from the points' noise
        # alone: with the bow, a row scan bent by a shadow's boundary was refused and left
        # the column scan unchecked
        sigma_max = max(sigma_max, math.sqrt(largest_variance(cxx, cxy, cyy)))
        # the covariance with a bowed edge's bias at the vertex, not scaled (the points'
        # sharing does not make it, and their number does not average it out)
        ba, bb = _bow_variance(a, sa, cov_scale), _bow_variance(b, sb, cov_scale)
        cxx += j00 * j00 * ba + j01 * j01 * bb
        cxy += j00 * j10 * ba + j01 * j11 * bb
        cyy += j10 * j10 * ba + j11 * j11 * bb
        cov[vi, 0, 0], cov[vi, 0, 1], cov[vi, 1, 0], cov[vi, 1, 1] = cxx, cxy, cxy, cyy
    return FIT_OK, v, math.sqrt(sq_all / max(count, 1)), cov, sigma_max


@njit()
def fit_joint(u: np.ndarray, d: np.ndarray, left: np.ndarray, right: np.ndarray,
              v0: np.ndarray, drop_px: float, min_points: int, centre_x: float,
              centre_y: float, max_outside_share: float, cov_scale: float = 1.0,
              cov_floor: float = 0.0) -> tuple[int, np.ndarray, float, np.ndarray, float]:
    """The four lines fitted to the column scan's upper and lower chains (u, d) and the row
    scan's left and right ones together, all (n, 2) px in the image: each point goes to the
    edge its chain has on its side of the vertices ``v0`` (left, top, right, bottom), those
    within ``drop_px`` of a vertex to none, and the vertices the lines give split the chains
    again (``fit_rhombus_robust``'s return)."""
    v = v0.copy()
    lines = np.zeros((4, 20))  # (no bow: columns 11-19 zero)
    status, res, cov, sigma = FIT_OK, 0.0, np.zeros((4, 2, 2)), 0.0
    chains = (u, d, left, right)
    for _ in range(3):
        for line in range(4):
            count = 0
            for c in range(4):
                count += _joint_count(chains[c], c, line, v, drop_px)
            pts = np.empty((count, 2))
            k = 0
            for c in range(4):
                k = _joint_fill(chains[c], c, line, v, drop_px, pts, k)
            if count < min_points:
                return TOO_FEW_POINTS, v, 0.0, cov, 0.0
            nx, ny, dd, sg, cnt, cx, cy, spread, sq, pos, neg = robust_line(pts)
            if nx * centre_x + ny * centre_y - dd > 0:  # orient the normal outward
                nx, ny, dd, pos, neg = -nx, -ny, -dd, neg, pos
            row = lines[line]
            row[0], row[1], row[2], row[3], row[4] = nx, ny, dd, sg, cnt
            row[5], row[6], row[7], row[8] = cx, cy, spread, sq
            row[9], row[10] = pos, count
        status, v2, res, cov, sigma = _quad(lines, min_points, max_outside_share, cov_scale,
                                            cov_floor)
        if status != FIT_OK:
            return status, v2, res, cov, sigma
        moved = np.abs(v2 - v).max()
        v = v2
        if moved < 0.05:
            break
    return status, v, res, cov, sigma


#: (chain, line) -> which vertex splits the chain (and -1 / +1: the line lies before / after
#: it along the chain's coordinate), 0 for a chain that has no point on the line. Chains:
#: upper, lower (columns: x), left, right (rows: y); lines: upper left, upper right, lower
#: left, lower right
_JOINT_SIDE = ((-1, 1, 0, 0), (0, 0, -1, 1), (-1, 0, 1, 0), (0, -1, 0, 1))
_JOINT_VERTEX = (1, 3, 0, 2)  # the vertex that splits each chain: top, bottom, left, right


@njit(inline="always")
def _joint_side(p: np.ndarray, i: int, chain: int, line: int, v: np.ndarray, drop_px: float
                ) -> bool:
    side = _JOINT_SIDE[chain][line]
    if side == 0:
        return False
    axis = 0 if chain < 2 else 1
    t = p[i, axis] - v[_JOINT_VERTEX[chain], axis]
    return t < -drop_px if side < 0 else t > drop_px


@njit(inline="always")
def _joint_count(p: np.ndarray, chain: int, line: int, v: np.ndarray, drop_px: float) -> int:
    n = 0
    for i in range(p.shape[0]):
        n += _joint_side(p, i, chain, line, v, drop_px)
    return n


@njit(inline="always")
def _joint_fill(p: np.ndarray, chain: int, line: int, v: np.ndarray, drop_px: float,
                out: np.ndarray, k: int) -> int:
    for i in range(p.shape[0]):
        if _joint_side(p, i, chain, line, v, drop_px):
            out[k, 0], out[k, 1] = p[i, 0], p[i, 1]
            k += 1
    return k


@njit()
def weak_view(v: np.ndarray, diagonal_ratio: float) -> tuple[float, float, float, float]:
    """The view under which the quadrilateral v (left, top, right, bottom) px is the marker
    (a rhombus whose horizontal diagonal is ``diagonal_ratio`` times its vertical one), by
    weak perspective: the affine map A from the marker's plane (vertical half-diagonal = 1)
    to the image, A = s Q P (Q a rotation: the roll; P symmetric with eigenvalues 1 and
    cos tilt). Returns (tilt off the normal, |roll|, the vertical diagonal's foreshortening
    as an angle (turning about a horizontal axis), scale px) in degrees.
    """
    a00 = (v[2, 0] - v[0, 0]) / (2.0 * diagonal_ratio)
    a10 = (v[2, 1] - v[0, 1]) / (2.0 * diagonal_ratio)
    a01 = (v[3, 0] - v[1, 0]) / 2.0
    a11 = (v[3, 1] - v[1, 1]) / 2.0
    # singular values of a 2 x 2 matrix, and the rotation of its polar decomposition
    e = 0.5 * (a00 + a11)
    f = 0.5 * (a00 - a11)
    g = 0.5 * (a10 + a01)
    h = 0.5 * (a10 - a01)
    q = math.hypot(e, h)
    r = math.hypot(f, g)
    s1, s2 = q + r, q - r
    if s2 <= 0 or s1 <= 0:
        return 90.0, 180.0, 90.0, 0.0
    tilt = math.degrees(math.acos(min(s2 / s1, 1.0)))
    roll = abs(math.degrees(math.atan2(h, e)))
    vertical = math.hypot(a01, a11) / s1
    pitch = math.degrees(math.acos(min(vertical, 1.0)))
    return tilt, roll, pitch, s1


@njit()
def diagonal_shift(v: np.ndarray) -> float:
    """How far the quadrilateral v's (left, top, right, bottom) px diagonals cross from their
    midpoints, as a share of each diagonal (the larger of the two; 1 where they do not cross
    within both). A plane's segment whose ends lie at depths Z - δ and Z + δ has its midpoint
    imaged at (Z + δ) / 2Z along it: a shift of δ / 2Z, at most h / 2Z for a rhombus of
    longer half-diagonal h seen from Z, however it is turned. A quadrilateral whose
    diagonals cross further off is no view of the marker from that far (a vertex cut off
    by an occluder's boundary)."""
    rx, ry = v[2, 0] - v[0, 0], v[2, 1] - v[0, 1]  # L -> R
    bx, by = v[3, 0] - v[1, 0], v[3, 1] - v[1, 1]  # T -> B
    det = -rx * by + ry * bx
    if abs(det) < 1e-12:
        return 1.0
    tx, ty = v[1, 0] - v[0, 0], v[1, 1] - v[0, 1]  # L + a (R - L) = T + b (B - T)
    a = (-tx * by + ty * bx) / det
    b = (rx * ty - ry * tx) / det
    if not (0.0 < a < 1.0 and 0.0 < b < 1.0):
        return 1.0
    return max(abs(a - 0.5), abs(b - 0.5))


@njit()
def finite_points(u: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """U and D points without the unmeasured ones (NaN rows), and their centre (x, y)."""
    out = []
    cx = cy = 0.0
    for pts in (u, d):
        keep = np.isfinite(pts[:, 1])
        kept = pts[keep]
        if kept.shape[0] > 0:
            cx += 0.5 * kept[:, 0].mean()
            cy += 0.5 * kept[:, 1].mean()
        out.append(kept)
    return out[0], out[1], cx, cy


#: an edge point further than this inside its chain's convex hull is left out (px): the marker
#: is convex, so a notch in its outline is something in front of it (an arm across an edge),
#: whose boundary must never be fitted as the marker's edge
HULL_TOLERANCE_PX = 1.0
HULL_SUPPORT = 3  # points on the hull needed each side of a notch
HULL_NOTCH_PX = 3.0  # and its least depth (shallower: an outlier outward bridged by the hull)
HULL_RIM_PX = 0.3  # a notch's rim: the points next to it deeper than this, and
HULL_RIM_POINTS = 1  # this many more (their edge windows reach into the notch)


@njit()
def on_hull(points: np.ndarray, upper: bool, tol: float) -> np.ndarray:
    """Which of the points (N, 2) px, ordered by x, lie within ``tol`` px of their chain's
    convex hull on the outer side (upper: towards smaller y, the U points; else larger y, the
    D points). The points of a notch (an occluder crossing an edge) lie inside it."""
    n = points.shape[0]
    keep = np.ones(n, np.bool_)
    if n < 3:
        return keep
    depth = np.zeros(n)  # how far inside the hull (px)
    s = -1.0 if upper else 1.0  # z = s y grows outward
    hull = np.empty(n, np.int64)
    h = 0
    for i in range(n):
        while h >= 2:
            a, b = hull[h - 2], hull[h - 1]
            cross = ((points[b, 0] - points[a, 0]) * s * (points[i, 1] - points[a, 1])
                     - s * (points[b, 1] - points[a, 1]) * (points[i, 0] - points[a, 0]))
            if cross >= 0:
                h -= 1
            else:
                break
        hull[h] = i
        h += 1
    j = 0
    for i in range(n):
        while j < h - 2 and hull[j + 1] <= i:
            j += 1
        a, b = hull[j], hull[j + 1]
        dx = points[b, 0] - points[a, 0]
        dz = s * (points[b, 1] - points[a, 1])
        cross = dx * s * (points[i, 1] - points[a, 1]) - dz * (points[i, 0] - points[a, 0])
        depth[i] = -cross / max(math.hypot(dx, dz), 1e-12)
        keep[i] = depth[i] <= tol
    # a notch lies between stretches of the outline on the hull; points inside it next to an
    # end of the chain, or next to a lone outlier outward (which the hull takes as a vertex),
    # are kept (the line fits' robustness deals with them)
    i = 0
    while i < n:
        if keep[i]:
            i += 1
            continue
        j = i
        while j < n and not keep[j]:
            j += 1
        before = 0
        while i - before - 1 >= 0 and keep[i - before - 1]:
            before += 1
        after = 0
        while j + after < n and keep[j + after]:
            after += 1
        deepest = 0.0
        for m in range(i, j):
            deepest = max(deepest, depth[m])
        if before < HULL_SUPPORT or after < HULL_SUPPORT or deepest < HULL_NOTCH_PX:
            keep[i:j] = True
        else:  # and its rim, where the edge bends into it (blur, a highlight's halo)
            k = i - 1
            while k >= 0 and depth[k] > HULL_RIM_PX:
                keep[k] = False
                k -= 1
            for m in range(max(k - HULL_RIM_POINTS + 1, 0), k + 1):
                keep[m] = False
            k = j
            while k < n and depth[k] > HULL_RIM_PX:
                keep[k] = False
                k += 1
            for m in range(k, min(k + HULL_RIM_POINTS, n)):
                keep[m] = False
        i = j
    return keep
