"""One seed's measurement in one compiled call: the column scan, its line fits and tests, the
row scan of the marker (along the image's rows) and the two scans' cross-check.

``RhombusExtractor`` did this in Python with about ten kernel calls per frame and numpy glue
between them (a copy of the transposed region, reordering, the mean of the two scans); their
per-call costs were most of a tracked frame's time. Here the row scan reads a transposed
*view* of the image (no copy) and every test runs in the kernel; Python only turns a
refusal's status and figures into its message (``extractor._reasons``).

Statuses: ``FOUND``, or why not. ``FIT + s`` carries ``lines.fit_rhombus_robust``'s status
``s``, ``VERDICT + s`` ``lines.check_rhombus``'s. The figures a message needs are in the
``stats`` vector (layout below).
"""

from __future__ import annotations

import math

import numpy as np

from services.core.jit import njit
from services.vertex_extractor import lines, scan

FOUND, NO_SEED, BORDER, SMALL_AREA, FEW_COLUMNS, LOW_CONTRAST, FEW_POINTS = range(7)
FIT, VERDICT, SHAPE, UNCERTAIN, DISAGREE, ROWS_OFF, PERSPECTIVE = 10, 20, 30, 31, 32, 33, 34
#: statuses of a marker that may be too small for the parameters (a second try, or the
#: row scan for a tall narrow one)
FEW = (SMALL_AREA, FEW_COLUMNS, FEW_POINTS, FIT + lines.TOO_FEW_POINTS)
#: refusals for want of edge points (a highlight or an arm over an edge, a small or shaded
#: marker), where the known rhombus may still be fitted to those it shows
#: (``recover.py``, with intrinsics): too few, the lines failing to fit or to make a
#: plausible quadrilateral (``lines.check_rhombus``'s verdicts: the points they rest on are
#: partly another thing's), too uncertain, the scans disagreeing; not a seed, the border,
#: the contrast, the weak-perspective view (SHAPE), the diagonals' crossing (PERSPECTIVE)
WANT_OF_POINTS = (*FEW, UNCERTAIN, DISAGREE, ROWS_OFF,
                  *(FIT + s for s in (lines.TOO_FEW_POINTS, lines.PARALLEL, lines.HIDDEN_EDGE,
                                      lines.OUTSIDE_POINTS)),
                  *(VERDICT + s for s in (lines.NOT_FINITE, lines.OUTSIDE, lines.NOT_CONVEX,
                                          lines.BAD_ANGLES, lines.NOT_STRAIGHT,
                                          lines.AREA_MISMATCH)))
#: refusals that a shadow's boundary inside the sub-pixel window can cause (tried again with
#: a narrower one, ``ExtractorParams.narrow_window``; so is an edge off its step). Not
#: UNCERTAIN: a narrower window reports such a marker surer than it is (4 of 900 highlight
#: views then came out 2-5.5 px off at a reported sigma of 0.7-1 px)
BIASED = (DISAGREE,)
#: a marker this many times taller than wide whose column lines do not fit it is scanned along
#: its rows instead (a steep view: its near-vertical edges cross few columns)
TALL = 1.3
#: the joint fit (``_joint``): points this close to a vertex (px) go to neither edge; the
#: covariance scaled so (both scans' points along an edge read the same pixels); tried only
#: where this many pixels clip to white in the marker's box (a highlight took edge points
#: away: more points cure that; a shadow moves them, which they do not: on soft shadows the
#: joint fit found 11 more of 900 views, one 3.1 px off at a reported 0.3 px)
JOINT_DROP_PX = 2.0
JOINT_COV_SCALE = 2.0
JOINT_MIN_CLIPPED = 4
#: the rows instead of the columns (``points_off``): the column scan's edge points farther
#: than this (px) from the rows' lines are not the marker's edge (an arm across it)
OFF_OUTLIER_PX = 2.5
#: a marker under a highlight whose scans both failed (``_under_highlight``): each chain's
#: two lines need this many points to say where it turns
HIGHLIGHT_MIN_POINTS = 2

# the parameter vector (``params_vector``)
(MIN_LEN, DX, WINDOW, EDGE, OUTER, MIN_AREA, MIN_POINTS, MAX_OUTSIDE_SHARE, COV_SCALE,
 COV_FLOOR, MIN_ANGLE, MAX_RESIDUAL, DIAGONAL_RATIO, MAX_OFF_NORMAL, MAX_ROLL, MAX_PITCH,
 MAX_SIGMA, CROSS_CHECK, MAX_GAP, MEAN_COV_SCALE, GAP_COV_SCALE, FUSE, JOINT, MAX_OFF,
 JOINT_ROWS, UNDER_HIGHLIGHT, SHADED_SPREAD, MAX_DIAGONAL_SHIFT, SHADED_DEPTH,
 SHADED_GRADIENT, MAX_COLUMNS, N_PARAMS) = range(32)
# the figures returned beside the status
(AREA, COLUMNS, CONTRAST, RESIDUAL, QUAD_AREA, ANGLE_MIN, ANGLE_MAX, TILT, ROLL, PITCH,
 SIGMA, GAP, AREA_RATIO, SEED_X, SEED_Y, SEED_RADIUS, CHECKED, COLUMNS_UNSURE, OFF,
 DIAGONAL_SHIFT, ROWS_INSTEAD, CAPPED, N_STATS) = range(23)
# CHECKED: 1 where the row scan agreed with the column scan; COLUMNS_UNSURE: 1 where the
# column scan alone was too uncertain and the rows were asked (``fuse``); OFF: how far the
# rows' lines are off the column scan's edge points where the rows were used instead;
# DIAGONAL_SHIFT: how far the diagonals cross off their midpoints (``lines.diagonal_shift``);
# ROWS_INSTEAD: 1 where the rows were measured instead of the columns (``_instead``);
# CAPPED: 1 where the walked blob is wider or taller than ``prm[MAX_COLUMNS]`` columns (a
# scan may have measured every k-th only)


@njit(inline="always")
def fit_failed(status: int) -> bool:
    """The column lines do not fit the marker: parallel, a vertex off the image, not convex,
    bad angles, not straight, the blob not the quadrilateral's, points beyond it or an edge
    hidden (a steep view's glancing columns, or an arm across them)."""
    return status == FIT + lines.PARALLEL or status == FIT + lines.HIDDEN_EDGE or \
        status == FIT + lines.OUTSIDE_POINTS or status == VERDICT + lines.OUTSIDE or \
        status == VERDICT + lines.NOT_CONVEX or status == VERDICT + lines.BAD_ANGLES or \
        status == VERDICT + lines.NOT_STRAIGHT or status == VERDICT + lines.AREA_MISMATCH


@njit()
def cross_check(v: np.ndarray, cov: np.ndarray, v_rows: np.ndarray, cov_rows: np.ndarray,
                mean_cov_scale: float, gap_cov_scale: float) -> float:
    """The column scan's vertices v (4, 2) and covariance cov (4, 2, 2) px² replaced, in
    place, by their mean with the row scan's, whose covariance is the scans' mean one scaled
    plus the squared disagreement scaled; returns the largest disagreement (px)."""
    worst = 0.0
    for i in range(4):
        gx, gy = v[i, 0] - v_rows[i, 0], v[i, 1] - v_rows[i, 1]
        gap = math.sqrt(gx * gx + gy * gy)
        worst = max(worst, gap)
        grow = gap_cov_scale * gap * gap
        v[i, 0] = 0.5 * (v[i, 0] + v_rows[i, 0])
        v[i, 1] = 0.5 * (v[i, 1] + v_rows[i, 1])
        for r in range(2):
            for c in range(2):
                cov[i, r, c] = mean_cov_scale * 0.5 * (cov[i, r, c] + cov_rows[i, r, c]) + (
                    grow if r == c else 0.0)
    return worst


@njit()
def fuse(v: np.ndarray, cov: np.ndarray, v_rows: np.ndarray, cov_rows: np.ndarray,
         mean_cov_scale: float, gap_cov_scale: float) -> tuple[float, float]:
    """Like ``cross_check``, but each vertex the two scans' mean weighted by the inverse of
    each one's variance (trace of its covariance: a scalar weight keeps the mean between
    the two, where two thin ellipses' matrix weights could carry it far off); returns the
    largest disagreement and the largest sigma of the result (px)."""
    worst = 0.0
    top = 0.0
    for i in range(4):
        gx, gy = v[i, 0] - v_rows[i, 0], v[i, 1] - v_rows[i, 1]
        gap = math.sqrt(gx * gx + gy * gy)
        worst = max(worst, gap)
        a = 1.0 / (cov[i, 0, 0] + cov[i, 1, 1])
        b = 1.0 / (cov_rows[i, 0, 0] + cov_rows[i, 1, 1])
        wa, wb = a / (a + b), b / (a + b)
        v[i, 0] = wa * v[i, 0] + wb * v_rows[i, 0]
        v[i, 1] = wa * v[i, 1] + wb * v_rows[i, 1]
        grow = gap_cov_scale * gap * gap
        for r in range(2):  # (equal weights: cross_check's mean_cov_scale * the mean one)
            for c in range(2):
                cov[i, r, c] = 2.0 * mean_cov_scale * (
                    wa * wa * cov[i, r, c] + wb * wb * cov_rows[i, r, c]) + (
                    grow if r == c else 0.0)
        top = max(top, math.sqrt(lines.largest_variance(cov[i, 0, 0], cov[i, 0, 1],
                                                        cov[i, 1, 1])))
    return worst, top


@njit()
def points_off(u: np.ndarray, d: np.ndarray, v: np.ndarray, drop_px: float,
               min_points: int) -> float:
    """How far (px) the other scan's edge points u, d (image px; NaN rows: unmeasured) are off
    the quadrilateral v (4, 2) px, left, top, right, bottom: each point goes to its nearest
    edge (none within ``drop_px`` of a vertex, none farther than ``OFF_OUTLIER_PX``: an
    occluder's boundary), and on each edge with at least ``min_points`` a straight line
    through their signed distances along it gives the largest, at either end of their
    stretch. A scan whose own lines failed still says where its measured stretches of the
    edges are: 0 where no edge has enough of them."""
    n = u.shape[0] + d.shape[0]
    edge = np.full(n, -1, np.int64)
    t = np.zeros(n)
    r = np.zeros(n)
    for i in range(n):
        p = u[i] if i < u.shape[0] else d[i - u.shape[0]]
        if not np.isfinite(p[1]):
            continue
        best = np.inf
        for k in range(4):
            ax, ay = v[k, 0], v[k, 1]
            bx, by = v[(k + 1) % 4, 0], v[(k + 1) % 4, 1]
            ex, ey = bx - ax, by - ay
            length = math.sqrt(ex * ex + ey * ey)
            if length < 1e-9:
                return np.inf
            s = ((p[0] - ax) * ex + (p[1] - ay) * ey) / length
            if s < drop_px or s > length - drop_px:
                continue
            dist = ((p[0] - ax) * ey - (p[1] - ay) * ex) / length
            if abs(dist) < best and abs(dist) <= OFF_OUTLIER_PX:
                best = abs(dist)
                edge[i], t[i], r[i] = k, s, dist
    worst = 0.0
    for k in range(4):
        m = 0
        st = sr = stt = str_ = 0.0
        lo, hi = np.inf, -np.inf
        for i in range(n):
            if edge[i] == k:
                m += 1
                st += t[i]
                sr += r[i]
                lo, hi = min(lo, t[i]), max(hi, t[i])
        if m < min_points:
            continue
        tm, rm = st / m, sr / m
        for i in range(n):
            if edge[i] == k:
                stt += (t[i] - tm) ** 2
                str_ += (t[i] - tm) * (r[i] - rm)
        slope = str_ / stt if stt > 1e-9 else 0.0
        worst = max(worst, abs(rm + slope * (lo - tm)), abs(rm + slope * (hi - tm)))
    return worst


@njit()
def _outside_notches(img, u, d):  # type: ignore[no-untyped-def]
    """Which of the finite U and D points (image px) lie outside a notch in the outline (an
    occluder across an edge; a clipped highlight's notch is kept: ``scan.notch_kept``)."""
    return (scan.notch_kept(img, u, lines.on_hull(u, True, lines.HULL_TOLERANCE_PX), -1),
            scan.notch_kept(img, d, lines.on_hull(d, False, lines.HULL_TOLERANCE_PX), 1))


@njit()
def _judge(img, status, area, n, contrast, u, d, width, height, prm, transposed,  # type: ignore[no-untyped-def]
           stats, v_out, cov_out):
    """The scan's result tested as the marker: its status, and the finite edge points (in
    the image's frame). ``img``: what the scan ran on; ``transposed``: the transposed image
    (the row scan)."""
    stats[AREA], stats[COLUMNS], stats[CONTRAST] = area, n, contrast
    if status == scan.BORDER:
        return BORDER, u, d
    if area < prm[MIN_AREA]:
        return SMALL_AREA, u, d
    min_points = int(prm[MIN_POINTS])
    if n < 2 * min_points + 4:
        return FEW_COLUMNS, u, d
    if status == scan.LOW_CONTRAST:
        return LOW_CONTRAST, u, d
    u, d, cx, cy = lines.finite_points(u, d)  # without points where no edge was measured
    found, u_out, d_out = _tests(u, d, cx, cy, area, width, height, prm, transposed, stats,
                                 v_out, cov_out)
    if found == FOUND:
        return found, u_out, d_out
    # where the points as they are fail, again without the points of a notch in the outline
    # (the marker is convex: an arm across an edge), unless the notch is a clipped highlight
    keep_u, keep_d = _outside_notches(img, u, d)
    if keep_u.all() and keep_d.all():
        return found, u_out, d_out
    u2, d2, cx2, cy2 = lines.finite_points(u[keep_u], d[keep_d])
    stats_again = stats.copy()
    v_again, cov_again = v_out.copy(), cov_out.copy()
    again, u_again, d_again = _tests(u2, d2, cx2, cy2, area, width, height, prm, transposed,
                                     stats_again, v_again, cov_again)
    if again != FOUND:
        return found, u_out, d_out
    stats[:] = stats_again
    v_out[:] = v_again
    cov_out[:] = cov_again
    return again, u_again, d_again


@njit(inline="always")
def _capped(box, prm):  # type: ignore[no-untyped-def]
    """1.0 where a walk's box (x0, x1, y0, y1 px) is wider or taller than the cap
    (``prm[MAX_COLUMNS]`` columns Δx apart; 0: none): its scan may have measured every k-th
    column only (``scan.scan``); else 0.0."""
    cap = prm[MAX_COLUMNS] * prm[DX]
    return 1.0 if cap > 0 and max(box[1] - box[0], box[3] - box[2]) + 1 > cap else 0.0


@njit(inline="always")
def _column_step(u, d, axis):  # type: ignore[no-untyped-def]
    """The least step (px) between consecutive edge points of u, d (n, 2) along ``axis``
    (their scan's columns); inf with no two."""
    step = np.inf
    for pts in (u, d):
        for i in range(1, pts.shape[0]):
            step = min(step, pts[i, axis] - pts[i - 1, axis])
    return step


@njit(inline="always")
def _scale_for(step, prm):  # type: ignore[no-untyped-def]
    """``prm[COV_SCALE]`` for points ``step`` px apart: over k = step / Δx where k > 1."""
    k = step / max(prm[DX], 1.0) if np.isfinite(step) else 1.0
    return max(prm[COV_SCALE] / k, 1.0) if k > 1.0 else prm[COV_SCALE]


@njit(inline="always")
def _cov_scale(u, d, prm):  # type: ignore[no-untyped-def]
    """The line fits' covariance scale for the edge points u, d (n, 2), columns in their
    first coordinate: ``prm[COV_SCALE]`` counts neighbouring columns' points as partly one
    (they share pixels through the blur, the demosaicing and JPEG); points on every k-th
    column only (``MAX_COLUMNS``) share fewer, and the scale is ``prm[COV_SCALE]`` / k, at
    least 1 (webcam renders: the squared vertex errors normalised by it as on every column;
    docs/measured.md)."""
    return _scale_for(_column_step(u, d, 0), prm)


@njit()
def _tests(u, d, cx, cy, area, width, height, prm, transposed,  # type: ignore[no-untyped-def]
           stats, v_out, cov_out):
    """The finite edge points u, d (centre cx, cy) fitted and tested as the marker; the
    vertices and covariance go to v_out, cov_out only when found."""
    min_points = int(prm[MIN_POINTS])
    if u.shape[0] < 2 * min_points + 4 or d.shape[0] < 2 * min_points + 4:
        return FEW_POINTS, u, d
    fit, v, residual, cov, sigma = lines.fit_rhombus_robust(
        u, d, min_points, 2, cx, cy, prm[MAX_OUTSIDE_SHARE], _cov_scale(u, d, prm),
        prm[COV_FLOOR])
    stats[RESIDUAL], stats[SIGMA] = residual, sigma
    if fit != lines.FIT_OK:
        return FIT + fit, u, d
    if transposed:  # back to the image: (x', y') = (y, x), L T R B = T' L' B' R'
        t = v.copy()
        tc = cov.copy()
        for i in range(4):
            j = (1, 0, 3, 2)[i]
            v[i, 0], v[i, 1] = t[j, 1], t[j, 0]
            cov[i, 0, 0], cov[i, 0, 1] = tc[j, 1, 1], tc[j, 1, 0]
            cov[i, 1, 0], cov[i, 1, 1] = tc[j, 0, 1], tc[j, 0, 0]
        ut = np.empty_like(u)
        dt = np.empty_like(d)
        for i in range(u.shape[0]):
            ut[i, 0], ut[i, 1] = u[i, 1], u[i, 0]
        for i in range(d.shape[0]):
            dt[i, 0], dt[i, 1] = d[i, 1], d[i, 0]
        u, d = ut, dt
    return _accept(v, residual, cov, sigma, area, width, height, prm, stats, v_out,
                   cov_out), u, d


@njit()
def _accept(v, residual, cov, sigma, area, width, height, prm,  # type: ignore[no-untyped-def]
            stats, v_out, cov_out):
    """The fitted quadrilateral v (image px) tested as the marker: plausible, the marker's
    shape in a view it can have (its diagonals crossing near their midpoints, as from no
    nearer than the working distance: ``lines.diagonal_shift``), certain enough; the
    vertices and covariance go to v_out, cov_out once it passes all but the last."""
    verdict, quad_area, amin, amax = lines.check_rhombus(
        v, residual, float(area), width, height, prm[MIN_ANGLE], prm[MAX_RESIDUAL])
    stats[QUAD_AREA], stats[ANGLE_MIN], stats[ANGLE_MAX] = quad_area, amin, amax
    if verdict != lines.PLAUSIBLE:
        return VERDICT + verdict
    tilt, roll, pitch, _ = lines.weak_view(v, prm[DIAGONAL_RATIO])
    stats[TILT], stats[ROLL], stats[PITCH] = tilt, roll, pitch
    if tilt > prm[MAX_OFF_NORMAL] or roll > prm[MAX_ROLL] or pitch > prm[MAX_PITCH]:
        return SHAPE
    stats[DIAGONAL_SHIFT] = lines.diagonal_shift(v)
    if stats[DIAGONAL_SHIFT] > prm[MAX_DIAGONAL_SHIFT]:
        return PERSPECTIVE
    stats[AREA_RATIO] = min(quad_area / (width * height), 1.0)
    v_out[:] = v
    cov_out[:] = cov
    if sigma > prm[MAX_SIGMA]:
        return UNCERTAIN
    return FOUND


@njit()
def _rows(img, sx, sy, lut, m, prm, stats, v, cov):  # type: ignore[no-untyped-def]
    """The marker at the marker pixel (sx, sy) scanned along its rows (``_row_scan``) and
    judged; ``stats[CAPPED]`` set too where the row walk is over the cap (``_capped``)."""
    status, area, n, contrast, u, d, rows, row_box = _row_scan(img, sx, sy, lut, m, prm)
    stats[CAPPED] = max(stats[CAPPED], _capped(row_box, prm))
    return _judge(rows, status, area, n, contrast, u, d, img.shape[1], img.shape[0], prm,
                  True, stats, v, cov)


@njit()
def _row_scan(img, sx, sy, lut, m, prm):  # type: ignore[no-untyped-def]
    """``scan.scan`` along the rows from the marker pixel (sx, sy): the column scan on the
    transposed image (a view, no copy). Not on a region around the column scan's box: under
    a highlight the row walk can go round the clipped core further than the columns went,
    and the region's side stopped it as the image's border would
    (``tests/test_hard_conditions.py``). Returns its result, that view and the row walk's
    box in the image (x0, x1, y0, y1)."""
    rows = img[0:img.shape[0], 0:img.shape[1]].transpose(1, 0, 2)
    status, area, n, contrast, u, d, walked = scan.scan(
        rows, sy, sx, int(prm[MIN_LEN]), int(prm[DX]), int(prm[WINDOW]), lut, m,
        int(prm[EDGE]), int(prm[OUTER]), prm[SHADED_SPREAD], int(prm[SHADED_DEPTH]),
        prm[SHADED_GRADIENT] > 0, int(prm[MAX_COLUMNS]))
    box = np.array([walked[2], walked[3], walked[0], walked[1]])
    return status, area, n, contrast, u, d, rows, box


@njit()
def _split_at(points):  # type: ignore[no-untyped-def]
    """Where a chain (n, 2) px sorted by x turns from one line to the next (x px; the best
    two-line split, ``lines.best_split``), or NaN with too few points."""
    if points.shape[0] < 2 * HIGHLIGHT_MIN_POINTS:
        return np.nan
    k = lines.best_split(points, HIGHLIGHT_MIN_POINTS)
    return 0.5 * (points[k - 1, 0] + points[k, 0])


@njit()
def _under_highlight(img, u, d, sx, sy, box, area, lut, m, prm,  # type: ignore[no-untyped-def]
                     stats):
    """A marker under a clipped highlight whose column and row lines both failed (a vertex
    or much of an edge washed out: too few points on an edge of either scan alone), each
    edge fitted to both scans' measured points (``_joint``) from where each chain turns
    (``_split_at``); the clipped pixels in the box count as the blob's (the highlight hides
    marker there). The box and the blob's area are both walks' (``box``, ``area``: the
    column walk's): where the highlight splits the blob, the row walk can go round the core
    where the column walk stopped. Returns (status, vertices (4, 2) px, covariance
    (4, 2, 2) px²)."""
    v = np.zeros((4, 2))
    cov = np.zeros((4, 2, 2))
    status, row_area, _, _, u_rows, d_rows, rows, row_box = _row_scan(img, sx, sy, lut, m,
                                                                      prm)
    stats[CAPPED] = max(stats[CAPPED], _capped(row_box, prm))
    if status != scan.OK:
        return FIT + lines.TOO_FEW_POINTS, v, cov
    box = np.array([min(box[0], row_box[0]), max(box[1], row_box[1]),
                    min(box[2], row_box[2]), max(box[3], row_box[3])])
    area = max(area, row_area)
    cu, cd, _, _ = lines.finite_points(u, d)
    keep_u, keep_d = _outside_notches(img, cu, cd)
    cu, cd = cu[keep_u], cd[keep_d]
    ru, rd, _, _ = lines.finite_points(u_rows, d_rows)
    keep_u, keep_d = _outside_notches(rows, ru, rd)
    ru, rd = ru[keep_u], rd[keep_d]
    top, bottom, left, right = _split_at(cu), _split_at(cd), _split_at(ru), _split_at(rd)
    if not (np.isfinite(top) and np.isfinite(bottom) and np.isfinite(left) and
            np.isfinite(right)):
        return FIT + lines.TOO_FEW_POINTS, v, cov
    v0 = np.empty((4, 2))  # left, top, right, bottom: the box's sides where a chain turns
    v0[0, 0], v0[0, 1] = box[0], left
    v0[1, 0], v0[1, 1] = top, box[2]
    v0[2, 0], v0[2, 1] = box[1], right
    v0[3, 0], v0[3, 1] = bottom, box[3]
    # the rows' chains in the image: (x, y) = (y', x')
    left_chain = np.empty((ru.shape[0], 2))
    right_chain = np.empty((rd.shape[0], 2))
    for i in range(ru.shape[0]):
        left_chain[i, 0], left_chain[i, 1] = ru[i, 1], ru[i, 0]
    for i in range(rd.shape[0]):
        right_chain[i, 0], right_chain[i, 1] = rd[i, 1], rd[i, 0]
    clipped = 0
    for y in range(box[2], box[3] + 1):
        for x in range(box[0], box[1] + 1):
            clipped += min(min(img[y, x, 0], img[y, x, 1]), img[y, x, 2]) >= scan.CLIPPED
    return _joint(cu, cd, left_chain, right_chain, v0, area + clipped, img.shape[1],
                  img.shape[0], prm, stats)


@njit()
def _clipped(img, box):  # type: ignore[no-untyped-def]
    """Does a highlight clip to white in the marker's box (x0, x1, y0, y1; at least
    ``JOINT_MIN_CLIPPED`` pixels of every second row and column)?"""
    n = 0
    for y in range(box[2], box[3] + 1, 2):
        for x in range(box[0], box[1] + 1, 2):
            if min(min(img[y, x, 0], img[y, x, 1]), img[y, x, 2]) >= scan.CLIPPED:
                n += 1
                if n >= JOINT_MIN_CLIPPED:
                    return True
    return False


@njit()
def white_near(img: np.ndarray, v: np.ndarray, radius: int, level: int) -> bool:
    """Is there white (every channel at ``level`` or more: a highlight's clipped core, as
    ``highlight.py`` calls it) within ``radius`` px (a square, every second row and column)
    of a vertex of v (4, 2) px? A few microseconds: whether a found marker is checked under a
    highlight (``highlight.CHECK_NEAR_PX``). (``_clipped`` counts such pixels in a box.)"""
    H, W = img.shape[0], img.shape[1]
    for k in range(v.shape[0]):
        if not (math.isfinite(v[k, 0]) and math.isfinite(v[k, 1])):
            continue
        cx, cy = int(v[k, 0] + 0.5), int(v[k, 1] + 0.5)
        for y in range(max(cy - radius, 0), min(cy + radius, H - 1) + 1, 2):
            for x in range(max(cx - radius, 0), min(cx + radius, W - 1) + 1, 2):
                if img[y, x, 0] >= level and img[y, x, 1] >= level and img[y, x, 2] >= level:
                    return True
    return False


@njit()
def _joint(u, d, u_rows, d_rows, v0, area, width, height, prm,  # type: ignore[no-untyped-def]
           stats):
    """Both scans' edge points (image px; the rows' upper and lower chains are the image's
    left and right ones) fitted together, split at ``v0``, and tested as the marker; their
    points along one edge read the same pixels, so the covariance counts them as half as
    many (x ``JOINT_COV_SCALE``)."""
    v = np.zeros((4, 2))
    cov = np.zeros((4, 2, 2))
    cx = 0.25 * (v0[0, 0] + v0[1, 0] + v0[2, 0] + v0[3, 0])
    cy = 0.25 * (v0[0, 1] + v0[1, 1] + v0[2, 1] + v0[3, 1])
    fit, vj, residual, cj, sigma = lines.fit_joint(
        np.ascontiguousarray(u), np.ascontiguousarray(d), np.ascontiguousarray(u_rows),
        np.ascontiguousarray(d_rows), v0, JOINT_DROP_PX, int(prm[MIN_POINTS]), cx, cy,
        prm[MAX_OUTSIDE_SHARE], JOINT_COV_SCALE * _scale_for(
            min(_column_step(u, d, 0), _column_step(u_rows, d_rows, 1)), prm), prm[COV_FLOOR])
    if fit != lines.FIT_OK:
        return FIT + fit, v, cov
    status = _accept(vj, residual, cj, sigma, area, width, height, prm, stats, v, cov)
    if status == FOUND:  # (its area ratio, angles and view in stats too)
        stats[SIGMA], stats[RESIDUAL] = sigma, residual
    return status, v, cov


@njit()
def measure(img: np.ndarray, x: int, y: int, radius: int, lut: np.ndarray, m: np.ndarray,
            prm: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                      np.ndarray]:
    """The marker at or near the seed (x, y) (a marker pixel within ``radius`` px) measured
    along the columns and judged; then along the rows: instead, for a marker whose columns
    are too few (a small one) or a tall one whose column lines do not fit it (``fit_failed``:
    a steep view's near-vertical edges crossed at a glancing angle, an arm across them),
    refused where its lines miss the columns' measured edge points, else fitted with them
    (``_instead``);
    otherwise as a cross-check (``cross_check``; refused when
    the scans disagree by more than ``prm[MAX_GAP]`` px). A column scan too uncertain alone
    is combined with an agreeing row scan (``fuse``, where ``prm[FUSE]``), and where that
    is still too uncertain under a clipped highlight, both scans' points are fitted at once
    (``_joint``, where ``prm[JOINT]``). Where ``prm[UNDER_HIGHLIGHT]``, a marker under a
    clipped highlight whose column and row lines both failed is fitted to both scans'
    points at once (``_under_highlight``).

    Returns (status, stats, vertices (4, 2) px, covariance (4, 2, 2) px², U and D edge
    points (n, 2) px); when found, the next frame's seed is in ``stats``.
    """
    H, W = img.shape[0], img.shape[1]
    stats = np.zeros(N_STATS)
    v = np.zeros((4, 2))
    cov = np.zeros((4, 2, 2))
    sx, sy = scan.find_seed(img, x, y, radius, lut, m)
    if sx < 0:
        return NO_SEED, stats, v, cov, np.empty((0, 2)), np.empty((0, 2))
    status, area, n, contrast, u, d, box = column_scan(img, sx, sy, lut, m, prm)
    stats[CAPPED] = _capped(box, prm)
    found, u, d = _judge(img, status, area, n, contrast, u, d, W, H, prm, False, stats, v,
                         cov)
    if found == UNCERTAIN and prm[FUSE] > 0:  # the rows may know the vertex better
        stats[COLUMNS_UNSURE] = 1.0
        v_rows = np.zeros((4, 2))
        cov_rows = np.zeros((4, 2, 2))
        scratch = np.zeros(N_STATS)
        rows, u_rows, d_rows = _rows(img, sx, sy, lut, m, prm, scratch, v_rows, cov_rows)
        stats[CAPPED] = max(stats[CAPPED], scratch[CAPPED])
        if rows == FOUND or rows == UNCERTAIN:
            vf, cf = v.copy(), cov.copy()
            stats[GAP], sigma = fuse(vf, cf, v_rows, cov_rows, prm[MEAN_COV_SCALE],
                                     prm[GAP_COV_SCALE])
            if stats[GAP] > prm[MAX_GAP]:
                return DISAGREE, stats, v, cov, u, d
            if sigma <= prm[MAX_SIGMA]:
                stats[SIGMA], stats[CHECKED] = sigma, 1.0
                _seed(vf, stats)
                return FOUND, stats, vf, cf, u, d
            if prm[JOINT] > 0 and _clipped(img, box):  # each edge from both scans' points
                joint, vj, cj = _joint(u, d, u_rows, d_rows, vf, area, W, H, prm, stats)
                if joint == FOUND:
                    stats[CHECKED] = 1.0
                    _seed(vj, stats)
                    return FOUND, stats, vj, cj, u, d
        return found, stats, v, cov, u, d
    if found != FOUND:
        few = found == SMALL_AREA or found == FEW_COLUMNS or found == FEW_POINTS or \
            found == FIT + lines.TOO_FEW_POINTS
        # the column lines not the marker's (not an uncertain one: a shadow's bias that the
        # rows, without a cross-check, would not see)
        tall = box[3] - box[2] > TALL * (box[1] - box[0])
        if status != scan.BORDER and (few or (tall and fit_failed(found))):
            stats_rows = np.zeros(N_STATS)
            stats_rows[CAPPED] = stats[CAPPED]
            rows, u_rows, d_rows = _rows(img, sx, sy, lut, m, prm, stats_rows, v, cov)
            if rows == FOUND:  # checked against and fitted with the columns' edge points
                rows = _instead(img, u, d, u_rows, d_rows, v, cov, prm, stats_rows)
            if rows == FOUND:
                _seed(v, stats_rows)
                stats_rows[ROWS_INSTEAD] = 1.0
                return FOUND, stats_rows, v, cov, u_rows, d_rows
            if rows == ROWS_OFF:
                return ROWS_OFF, stats_rows, v, cov, u_rows, d_rows
        if status != scan.BORDER and (few or fit_failed(found)) and prm[UNDER_HIGHLIGHT] > 0 \
                and _clipped(img, box):  # neither scan's lines alone: both scans' points
            stats_joint = stats.copy()
            joint, vj, cj = _under_highlight(img, u, d, sx, sy, box, area, lut, m, prm,
                                             stats_joint)
            if joint == FOUND:  # (not CHECKED: no scan was tested against the other)
                _seed(vj, stats_joint)
                return FOUND, stats_joint, vj, cj, u, d
        return found, stats, v, cov, u, d
    if prm[CROSS_CHECK] > 0:
        v_rows = np.zeros((4, 2))
        cov_rows = np.zeros((4, 2, 2))
        scratch = np.zeros(N_STATS)
        rows, _, _ = _rows(img, sx, sy, lut, m, prm, scratch, v_rows, cov_rows)
        stats[CAPPED] = max(stats[CAPPED], scratch[CAPPED])
        if rows == FOUND:
            vc, cc = v.copy(), cov.copy()
            stats[GAP] = cross_check(vc, cc, v_rows, cov_rows, prm[MEAN_COV_SCALE],
                                     prm[GAP_COV_SCALE])
            if stats[GAP] > prm[MAX_GAP]:
                return DISAGREE, stats, v, cov, u, d
            v, cov = vc, cc
            stats[CHECKED] = 1.0
    _seed(v, stats)
    return FOUND, stats, v, cov, u, d


@njit()
def column_scan(img: np.ndarray, sx: int, sy: int, lut: np.ndarray, m: np.ndarray,
                prm: np.ndarray) -> tuple[int, int, int, float, np.ndarray, np.ndarray,
                                          np.ndarray]:
    """``scan.scan`` along the columns from the marker pixel (sx, sy), with the parameters
    ``prm``. The image is read through a view typed like the rows' transposed one (any
    layout): one compiled scan for both (about half the first compile, no slower), and for
    every caller (``recover.edge_points`` too: another variant would cost half a minute's
    compile at its first call)."""
    H, W = img.shape[0], img.shape[1]
    return scan.scan(img[0:H, 0:W], sx, sy, int(prm[MIN_LEN]), int(prm[DX]),
                     int(prm[WINDOW]), lut, m, int(prm[EDGE]), int(prm[OUTER]),
                     prm[SHADED_SPREAD], int(prm[SHADED_DEPTH]), prm[SHADED_GRADIENT] > 0,
                     int(prm[MAX_COLUMNS]))


@njit()
def _instead(img, u, d, u_rows, d_rows, v, cov, prm, stats):  # type: ignore[no-untyped-def]
    """The rows' vertices v and covariance cov (image px), found instead of the columns'
    (whose lines failed), against and with the column scan's measured edge points u, d
    (without a notch's): ``ROWS_OFF`` where the rows' lines miss them by more than
    ``prm[MAX_OFF]`` px (``points_off``, in ``stats[OFF]``); else, where ``prm[JOINT_ROWS]``,
    each edge fitted to both scans' points at once (``_joint``) replaces v, cov in place
    when that passes every test. A shadow over part of an edge takes the columns' points
    there away and can tilt the rows' line through it: 25 of 1 235 rows-instead detections
    on 21 000 hard-condition views were 2-5 px off (2 %, against 0.06 % of cross-checked
    ones); the columns' points on the rest of the edge pull it back. Neither where one of
    the column scan's chains has no measured point."""
    cu, cd, _, _ = lines.finite_points(u, d)
    if cu.shape[0] == 0 or cd.shape[0] == 0:
        return FOUND
    keep_u, keep_d = _outside_notches(img, cu, cd)
    cu, cd = cu[keep_u], cd[keep_d]
    if prm[MAX_OFF] > 0:
        stats[OFF] = points_off(cu, cd, v, JOINT_DROP_PX, int(prm[MIN_POINTS]))
        if stats[OFF] > prm[MAX_OFF]:
            return ROWS_OFF
    if prm[JOINT_ROWS] > 0:
        ur, dr, _, _ = lines.finite_points(u_rows, d_rows)
        joint_stats = stats.copy()
        joint, vj, cj = _joint(cu, cd, ur, dr, v, stats[AREA], img.shape[1], img.shape[0],
                               prm, joint_stats)
        if joint == FOUND:
            v[:] = vj
            cov[:] = cj
            stats[:] = joint_stats
    return FOUND


@njit()
def _seed(v, stats):  # type: ignore[no-untyped-def]
    """The next frame's seed: the vertices' centre, a quarter of the box's smaller side."""
    x0, x1, x2, x3 = v[0, 0], v[1, 0], v[2, 0], v[3, 0]
    y0, y1, y2, y3 = v[0, 1], v[1, 1], v[2, 1], v[3, 1]
    w = max(max(max(x0, x1), x2), x3) - min(min(min(x0, x1), x2), x3)
    h = max(max(max(y0, y1), y2), y3) - min(min(min(y0, y1), y2), y3)
    stats[SEED_X] = int((((x0 + x1) + x2) + x3) / 4)
    stats[SEED_Y] = int((((y0 + y1) + y2) + y3) / 4)
    stats[SEED_RADIUS] = max(4, int(0.25 * min(w, h)))
