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
from services.vertex_extractor.colour import (
    HALO_CLIPPED,
    HALO_MIN_CHROMA,
    HALO_MIN_WHITE,
    chroma_amount,
    chroma_direction,
    is_lit_marker,
    is_marker,
    score,
)

OK, BORDER, LOW_CONTRAST = 0, 1, 2
#: least marker-to-surround score difference (linear light x 255): this many times the inside's
#: pixel noise (a dim marker is measured as long as its edges stand out of the noise), and at
#: least MIN_CONTRAST
MIN_CONTRAST = 3.0
CONTRAST_SNR = 8.0
#: a marker whose columns' centres spread by more than this share of the brightest is shaded
#: (a cast shadow over part of it): each edge point takes its local inside level, where the
#: chain's mean is off by the shadow's gradient or step (webcam renders: soft shadows'
#: median vertex error 0.23 -> 0.20 px, wrong frames fewer; unshaded markers as before)
SHADED = 0.2
#: a shaded marker's inside level is read this many rows inside each run's end (plus a steep
#: edge's extra rows) instead of just beyond the window: a shadow's gradient or boundary
#: then lies between the level and the edge less often (6 000 views each: hard shadow 65 ->
#: 50 wrong, soft 44 -> 40; docs/measured.md). Only where the edges are sharp enough
#: (``_sharpness``): blur's ramp reaches that deep (without that test, shaded markers under
#: motion blur 8 -> 17 wrong of 3 000, and a shadow with defocus 3 px 0.28 -> 0.59 px off)
SHADED_DEPTH = 4
SHARP = 0.96  # least ``_sharpness`` of a shaded marker whose inside level is read nearer
#: ... and where the light changes across its edges (a soft shadow's penumbra), each edge
#: point's inside level follows it: the levels of two deeper bands of rows, GRADIENT_GAP
#: and 2 GRADIENT_GAP rows further in, give the change per row, carried over the window's
#: rows (``_edge``). Only where the light changes steadily: the two bands' steps alike in
#: sign and within GRADIENT_LINEAR of each other (a hard shadow's boundary between them is
#: one step, not a gradient), and by GRADIENT_MIN to GRADIENT_MAX of the edge's contrast
#: over the bands (less is the JPEG's noise), and where nearly every neighbouring column
#: reaches both bands (BAND_SHARE of the level's rows; not next to a vertex). Webcam
#: renders: the soft shadow's median 0.19 -> 0.17 px, NEES 2.7 -> 2.4; found and wrong
#: within 0.3 % under both shadows (docs/measured.md)
GRADIENT_GAP = 3
GRADIENT_LINEAR = 0.5
GRADIENT_MIN = 0.04
GRADIENT_MAX = 0.5
BAND_SHARE = 0.9  # a deeper band's rows read, at least this share of the level's


@njit(inline="always")
def _run_up(img, x, y, lut, m, chroma):  # type: ignore[no-untyped-def]
    """Topmost row of the run of marker pixels containing (x, y), bridging 1-px gaps."""
    while y > 0:
        if is_lit_marker(img, y - 1, x, lut, m, chroma, False):
            y -= 1
        elif y > 1 and is_lit_marker(img, y - 2, x, lut, m, chroma, False):
            y -= 2
        else:
            break
    return y


@njit(inline="always")
def _run_down(img, x, y, lut, m, chroma):  # type: ignore[no-untyped-def]
    """Bottom row of the run of marker pixels containing (x, y), bridging 1-px gaps."""
    last = img.shape[0] - 1
    while y < last:
        if is_lit_marker(img, y + 1, x, lut, m, chroma, False):
            y += 1
        elif y < last - 1 and is_lit_marker(img, y + 2, x, lut, m, chroma, False):
            y += 2
        else:
            break
    return y


@njit(inline="always")
def _column(img, x, prev_top, prev_bottom, lut, m, chroma):  # type: ignore[no-untyped-def]
    """(top, bottom) rows of column x's run overlapping the previous column's run
    [prev_top, prev_bottom]; (-1, -1) when the column has none."""
    y = prev_top
    if is_lit_marker(img, y, x, lut, m, chroma, False):
        top = _run_up(img, x, y, lut, m, chroma)
    else:
        y += 1
        while y <= prev_bottom and not is_lit_marker(img, y, x, lut, m, chroma, False):
            y += 1
        if y > prev_bottom:
            return -1, -1
        top = y
    y = prev_bottom
    if is_lit_marker(img, y, x, lut, m, chroma, False):
        bottom = _run_down(img, x, y, lut, m, chroma)
    else:
        y -= 1
        while y > top and not is_lit_marker(img, y, x, lut, m, chroma, False):
            y -= 1
        bottom = y
    return top, bottom


@njit()
def find_seed(img: np.ndarray, sx: int, sy: int, radius: int, lut: np.ndarray, m: np.ndarray
              ) -> tuple[int, int]:
    """A marker pixel at or near (sx, sy): along the seed's column, then its row, out to
    ``radius`` px; (-1, -1) when there is none."""
    H, W = img.shape[0], img.shape[1]
    if sx < 0 or sy < 0 or sx >= W or sy >= H:
        return -1, -1
    for k in range(radius + 1):
        for y in (sy - k, sy + k):
            if 0 <= y < H and is_marker(img, y, sx, lut, m):
                return sx, y
        for x in (sx - k, sx + k):
            if 0 <= x < W and is_marker(img, sy, x, lut, m):
                return x, sy
    return -1, -1


@njit()
def scan(img: np.ndarray, sx: int, sy: int, min_len: int, dx: int, window: int,
         lut: np.ndarray, m: np.ndarray, edge_mode: int = 1, outer: int = -1,
         shaded_spread: float = SHADED, shaded_depth: int = SHADED_DEPTH,
         shaded_gradient: bool = True, max_columns: int = 0
         ) -> tuple[int, int, int, float, np.ndarray, np.ndarray, np.ndarray]:
    """Walk the marker's columns from the marker pixel (sx, sy) and measure its edges.

    Returns (status, blob area px, usable columns, contrast grey levels, U points (n, 2),
    D points (n, 2), the walked blob's box x0, x1, y0, y1 inclusive), points in pixels
    (x, y) on columns Δx = ``dx`` apart, over the widest
    column and its neighbours whose run is at least ``min_len`` px long (Table 1's stop).
    Status: OK, BORDER (the marker reaches the image border, or the edge windows on one side
    would in every column; a column's window that would is left out: NaN),
    LOW_CONTRAST (less than MIN_CONTRAST or CONTRAST_SNR x the inside's noise between inside
    and outside, linear x 255). ``shaded_spread``: a marker whose columns' centres spread by
    more than this share of the brightest (``_levels``) is shaded, and each edge point then
    takes its local inside level (``SHADED``), read ``shaded_depth`` rows inside the run's
    end where its edges are sharp and that is nearer than just beyond the window
    (``SHADED_DEPTH``; 0: just beyond the window, as elsewhere), and there, where
    ``shaded_gradient``, follows the light's steady change across the edge
    (``GRADIENT_GAP``). ``max_columns`` (0: no limit): a marker with more usable columns is
    measured on every k-th, Δx = k ``dx`` with k the least that leaves at most that many,
    each edge point's inside level over about as many px as on every column
    (``ExtractorParams.max_columns``).
    """
    H, W = img.shape[0], img.shape[1]
    empty = np.empty((0, 2))
    box = np.zeros(4, np.int64)
    top = np.full(W, -1, np.int64)
    bottom = np.full(W, -1, np.int64)
    # a highlight's halo keeps most of the marker's chroma (the seed is a marker pixel)
    halo_chroma = HALO_MIN_CHROMA * chroma_amount(img, sy, sx, lut)
    top[sx] = _run_up(img, sx, sy, lut, m, halo_chroma)
    bottom[sx] = _run_down(img, sx, sy, lut, m, halo_chroma)
    lo, hi = sx, sx + 1  # walked columns [lo, hi)
    for step in (1, -1):
        t, b = top[sx], bottom[sx]
        x = sx + step
        while 0 <= x < W:
            t, b = _column(img, x, t, b, lut, m, halo_chroma)
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
    box[0], box[1], box[2], box[3] = lo, hi - 1, H, 0
    for x in range(lo, hi):
        area += bottom[x] - top[x] + 1
        box[2] = min(box[2], top[x])
        box[3] = max(box[3], bottom[x])
        touches = touches or top[x] == 0 or bottom[x] == H - 1
        if bottom[x] - top[x] > bottom[widest] - top[widest]:
            widest = x
    if touches:
        return BORDER, area, 0, 0.0, empty, empty, box
    a = widest  # Table 1: from the widest column right and left until a run < MIN_LEN
    while a > lo and bottom[a - 1] - top[a - 1] + 1 >= min_len:
        a -= 1
    z = widest + 1
    while z < hi and bottom[z] - top[z] + 1 >= min_len:
        z += 1
    if bottom[widest] - top[widest] + 1 < min_len:
        return OK, area, 0, 0.0, empty, empty, box
    k = 1  # every k-th of the columns Δx apart (``max_columns``)
    if max_columns > 0 and z - a > max_columns * dx:
        k = (z - a + max_columns * dx - 1) // (max_columns * dx)
    dx *= k
    n = (z - a + dx - 1) // dx
    span = max((INSIDE_SPAN + k // 2) // k, 2)  # (INSIDE_SPAN columns' px, 2 at least)
    if outer < 0:
        outer = window
    gap = max(window, outer) + 1 + LOCAL_ROWS
    inside = np.zeros(3)
    inside_rows = np.empty(n, np.int64)  # each column's plain marker row (-1: none)
    counted = 0
    # an edge point whose window or outside level would reach past the image's top or
    # bottom (next to a vertex a few px from the border) is not measured: its line and the
    # vertex come from the rest of the edge. (Inward, a window widened by a steep edge
    # reaches as far; on a run shorter than that, past its other end.)
    clear = np.empty((2, n), np.bool_)
    reach = (1 + MAX_WIDEN) * window
    for i in range(n):
        x = a + i * dx
        clear[0, i] = top[x] >= gap and top[x] + reach <= H - 1
        clear[1, i] = bottom[x] + gap <= H - 1 and bottom[x] - reach >= 0
        y = _inside_row(img, x, top[x], bottom[x], lut, m)
        inside_rows[i] = y
        if y >= 0:  # not an occluder or a highlight across the run
            counted += 1
            for c in range(3):
                inside[c] += lut[img[y, x, c]]
    if not (clear[0].any() and clear[1].any()):
        return BORDER, area, n, 0.0, empty, empty, box
    if counted == 0:
        return LOW_CONTRAST, area, n, 0.0, empty, empty, box
    w = chroma_direction(inside[0], inside[1], inside[2])  # the marker's own chroma
    s_in, s_out, noise, spread = _levels(img, a, n, dx, top, bottom, gap, lut, w, inside_rows,
                                         clear)
    contrast = s_in - s_out
    if contrast < max(MIN_CONTRAST, CONTRAST_SNR * noise):
        return LOW_CONTRAST, area, n, contrast, empty, empty, box
    u = np.empty((n, 2))
    d = np.empty((n, 2))
    wl = np.empty(3)  # the score direction at one edge point
    # one edge point's window scores: window + outer + 2 ext rows, ext <= MAX_WIDEN window
    rows = np.empty(window + outer + 2 * MAX_WIDEN * window + 2)
    exts = np.zeros((2, n), np.int64)
    # a shaded marker with sharp edges: its inside level nearer the edge (``SHADED_DEPTH``;
    # a narrow window's own rows may be as near: then as elsewhere)
    nearer = 0 < shaded_depth <= window and spread > shaded_spread and \
        _sharpness(img, a, n, dx, top, bottom, window, shaded_depth, lut, w) >= SHARP
    colour = np.zeros((2, n + 1, 4))  # prefix sums of the local inside colour B, G, R, count
    # ... and of two deeper bands' (band, side, column, B G R count): the light's gradient
    gradient = nearer and shaded_gradient
    deeper = np.zeros((2, 2, n + 1 if gradient else 1, 4))
    for i in range(n):
        x = a + i * dx
        u[i, 0] = x
        d[i, 0] = x
        # a steep edge crosses a column over more rows: widen the window by its slope, as far
        # as the border and half the chord allow
        xl, xr = max(x - 1, lo), min(x + 1, hi - 1)
        room = (bottom[x] - top[x] + 1) // 2 - window
        mid = (top[x] + bottom[x]) // 2
        for side in range(2):
            run = top if side == 0 else bottom
            slope = abs(run[xr] - run[xl]) / max(xr - xl, 1)
            end = top[x] if side == 0 else bottom[x]
            border = end - gap if side == 0 else H - 1 - gap - end
            ext = max(min(int(STEEP * slope + 0.5), MAX_WIDEN * window, room, border), 0)
            exts[side, i] = ext
            out = -1 if side == 0 else 1
            depth = (shaded_depth if nearer else window + 1) + ext
            _band(img, x, end, out, depth, mid, True, lut, m, halo_chroma, colour[side, i],
                  colour[side, i + 1])
            if gradient:
                for band in range(2):
                    _band(img, x, end, out, depth + (band + 1) * GRADIENT_GAP, mid, False, lut,
                          m, halo_chroma, deeper[band, side, i], deeper[band, side, i + 1])
    local = np.empty(3)
    deep = np.zeros((2, 3))  # the deeper bands' local colour (B, G, R)
    # a shaded marker (its columns' centres spread by more than ``shaded_spread``, by default
    # SHADED; 1 or more: never): each edge point takes its local inside level, the chain's
    # mean being off wherever a shadow's gradient or boundary lies; in even light the chain's
    # mean where the local one is within 8 % of it (the JPEG's blocks and the demosaicing
    # move the local one about, not the light)
    shaded = spread > shaded_spread
    mean_colour = np.zeros((2, 3))  # each edge's mean inside colour (B, G, R) and level
    far_level = np.zeros(2)
    for side in range(2):
        total = colour[side, n, 3]
        if total > 0.0:
            for c in range(3):
                mean_colour[side, c] = colour[side, n, c] / total
                far_level[side] += w[c] * mean_colour[side, c]
    span_c = np.empty(3)
    for i in range(n):
        x = a + i * dx
        i0, i1 = max(i - span, 0), min(i + span + 1, n)
        for side in range(2):
            count = colour[side, i1, 3] - colour[side, i0, 3]
            if count < LOCAL_ROWS or not clear[side, i]:
                if side == 0:
                    u[i, 1] = np.nan
                else:
                    d[i, 1] = np.nan
                continue
            # the inside level along this edge, where it differs from the whole edge's by
            # more than noise (a shadow, a highlight) or the marker is shaded; the whole
            # edge's (less noisy) elsewhere (products of reciprocals: divisions were a third
            # of this loop's time)
            per = 1.0 / count
            far = far_level[side]
            nb = colour[side, i + 1, 3] - colour[side, i0, 3]
            na = colour[side, i1, 3] - colour[side, i, 3]
            near = 0.0
            before = 0.0
            after = 0.0
            for c in range(3):
                span_c[c] = colour[side, i1, c] - colour[side, i0, c]
                near += w[c] * span_c[c]
                before += w[c] * (colour[side, i + 1, c] - colour[side, i0, c])
                after += w[c] * (colour[side, i1, c] - colour[side, i, c])
            near *= per
            before /= max(nb, 1.0)
            after /= max(na, 1.0)
            if nb >= LOCAL_ROWS and na >= LOCAL_ROWS and \
                    abs(before - after) > LEVEL_STEP * max(before, after):
                # a shadow's boundary or a highlight crosses the edge here: the inside level
                # changes within the window's reach
                if side == 0:
                    u[i, 1] = np.nan
                else:
                    d[i, 1] = np.nan
                continue
            t = 1.0 if shaded else \
                min(max((abs(near - far) / max(far, 1e-9) - 0.08) / 0.08, 0.0), 1.0)
            for c in range(3):
                local[c] = t * span_c[c] * per + (1.0 - t) * mean_colour[side, c]
            ext = exts[side, i]
            end = top[x] if side == 0 else bottom[x]
            level_row = 0.0  # (0: the inside level is one for the whole window)
            if gradient:
                # the local level's middle row; the bands only where (nearly) every column
                # reaches them on this edge's half (short runs, near a vertex: no gradient)
                level_row = shaded_depth + ext + (LOCAL_ROWS - 1) / 2
                for band in range(2):
                    in_band = deeper[band, side, i1, 3] - deeper[band, side, i0, 3]
                    if in_band < max(LOCAL_ROWS, BAND_SHARE * count):
                        level_row = 0.0
                        break
                    for c in range(3):
                        deep[band, c] = (deeper[band, side, i1, c]
                                         - deeper[band, side, i0, c]) / in_band
            if _at_highlight(img, x, end, -1 if side == 0 else 1, lut) or _clipped_halo(
                    img, x, end, -1 if side == 0 else 1, window + ext, lut):
                if side == 0:
                    u[i, 1] = np.nan
                else:
                    d[i, 1] = np.nan
                continue
            if side == 0:
                u[i, 1] = _edge(img, x, top[x], -1, window + ext, outer + ext, s_in, s_out,
                                edge_mode, lut, w, wl, local, rows, deep, level_row)
            else:
                d[i, 1] = _edge(img, x, bottom[x], 1, window + ext, outer + ext, s_in, s_out,
                                edge_mode, lut, w, wl, local, rows, deep, level_row)
    return OK, area, n, contrast, u, d, box


@njit(inline="always")
def _band(img, x, end, out, depth, mid, clamp, lut, m, halo_chroma, prev, cur):  # type: ignore[no-untyped-def]
    """A prefix sum's next entry: ``cur`` (B, G, R, count) = ``prev`` plus column x's
    marker pixels (not hidden or clipped) in the ``LOCAL_ROWS`` rows from ``depth`` rows
    inside the run's end ``end`` (``out``: -1 upper edge, +1 lower). Rows past the middle
    row ``mid`` stay on this edge's half: read at ``mid`` where ``clamp``, else left out."""
    for c in range(4):
        cur[c] = prev[c]
    for k in range(LOCAL_ROWS):
        r = end - out * (depth + k)
        if (r - mid) * out < 0:
            if not clamp:
                continue
            r = mid
        if is_lit_marker(img, r, x, lut, m, halo_chroma, True):
            for c in range(3):
                cur[c] += lut[img[r, x, c]]
            cur[3] += 1.0


@njit()
def _sharpness(img, a, n, dx, top, bottom, window, depth, lut, w):  # type: ignore[no-untyped-def]
    """How sharp the marker's edges are for its inside level read ``depth`` rows inside its
    runs' ends: the median, over the columns' run ends, of the score there over the score in
    the middle of
    the rows just beyond the window (``window`` + 2 rows in). Near 1 where the edges are
    sharp (a shadow's gradient or boundary in between goes either way: the median holds);
    less where blur's ramp reaches that deep (motion blur, defocus)."""
    ratio = np.empty(2 * n)
    k = 0
    for i in range(n):
        x = a + i * dx
        if bottom[x] - top[x] + 1 < 2 * (window + 2):  # (on this edge's half, or a row past)
            continue
        for end, out in ((top[x], -1), (bottom[x], 1)):
            deep = score(img, end - out * (window + 2), x, lut, w)
            if deep > 0.0:
                ratio[k] = score(img, end - out * depth, x, lut, w) / deep
                k += 1
    return np.median(ratio[:k]) if k > 0 else 0.0


@njit(inline="always")
def _inside_row(img, x, top, bottom, lut, m):  # type: ignore[no-untyped-def]
    """A row of column x's run [top, bottom] whose pixel is plain marker: its middle, else its
    quarter or three-quarter row (a glossy print's clipped core over the middle); -1: none."""
    mid = (top + bottom) // 2
    if is_marker(img, mid, x, lut, m):
        return mid
    quarter = (bottom - top) // 4
    if quarter >= 2:
        if is_marker(img, top + quarter, x, lut, m):
            return top + quarter
        if is_marker(img, bottom - quarter, x, lut, m):
            return bottom - quarter
    return -1


@njit(inline="always")
def _levels(img, a, n, dx, top, bottom, gap, lut, w, inside_rows, clear):  # type: ignore[no-untyped-def]
    """(inside, outside) score levels of the whole marker: the median at the columns' centres
    (marker pixels only: ``inside_rows``, each column's ``_inside_row``) and the median just
    beyond the edge windows; the inside's pixel
    noise (robust sigma, from the differences between neighbouring centres); and how the
    centres spread (their 10th to 90th percentile, a share of the 90th: the light across the
    marker, a cast shadow's, not the blur at its edges)."""
    inside = np.empty(n)
    k = 0
    outside = np.empty(2 * n)
    j = 0
    for i in range(n):
        x = a + i * dx
        y = inside_rows[i]
        if y >= 0:
            inside[k] = score(img, y, x, lut, w)
            k += 1
        if clear[0, i]:
            outside[j] = score(img, top[x] - gap, x, lut, w)
            j += 1
        if clear[1, i]:
            outside[j] = score(img, bottom[x] + gap, x, lut, w)
            j += 1
    level = np.sort(inside[:k])  # (k >= 1: the scan counted the same centres)
    noise = 0.0
    spread = 0.0
    if k > 2:  # neighbouring columns' differences: a shadow's or highlight's step is one of them
        noise = 1.4826 / np.sqrt(2.0) * np.median(np.abs(np.diff(inside[:k])))
        top_level = level[k - 1 - k // 10]
        if top_level > 0:
            spread = (top_level - level[k // 10]) / top_level
    median = 0.5 * (level[(k - 1) // 2] + level[k // 2])  # (sorted once, for both)
    return median, np.median(outside[:j]), noise, spread


LOCAL_ROWS = 3  # rows beyond the window that give the local background level
LEVEL_STEP = 0.2  # a change of the inside level along an edge that drops its points there
FLAT_TOLERANCE = 0.12  # how much brighter than the inside level the window's inner rows may be
INSIDE_SPAN = 6  # columns (px) each side whose inside colour gives an edge point's inside level
STEEP = 1.5     # extra window rows per unit of edge slope (rows per column)
MAX_WIDEN = 2   # ... and at most this many windows more
GLOBAL, LOCAL, CROSSING, ORTHOGONAL = 0, 1, 2, 3  # edge methods (ExtractorParams.edge)


@njit(inline="always")
def _edge(img, x, end, out, window, outer, s_in, s_out, mode, lut, w, wl,  # type: ignore[no-untyped-def]
          local, rows, deep, level_row):
    """Sub-pixel row of the edge beyond ``end`` (the run's last marker row in column x);
    ``out`` = -1 for the upper edge (background above), +1 for the lower; NaN when the edge
    cannot be measured here (no contrast between the local levels).

    Both levels are local: the outside level just beyond the window (``LOCAL_ROWS`` rows),
    the inside level from ``local``, the marker's linear colour (B, G, R) just inside the
    window: averaged over the neighbouring columns (``INSIDE_SPAN`` each side) where that
    differs from the whole edge's mean by more than noise or the marker is shaded
    (``SHADED``), so that a shadow's boundary or gradient or a highlight elsewhere on the
    marker moves no edge.

    GLOBAL: the coverage sum over ``window`` rows each side, with the whole marker's inside and
    outside levels (exact on area-sampled images on a uniform background, in uniform light).
    LOCAL: the same sum between the local levels.
    CROSSING: where the profile crosses halfway between the local levels (linear
    interpolation), which only reads the pixels at the edge.
    ORTHOGONAL: the LOCAL sum along a direction orthogonal to grey and to the local
    background's own chroma (measured beyond the window), so that the surround's brightness
    and saturation changes score nothing; LOCAL where the background is grey or its chroma
    leaves too little contrast. ``wl``: scratch for the local direction; ``rows``: for the
    window's scores (at least ``window + outer`` long). ``level_row`` > 0: ``local`` is the
    inside colour that many rows inside ``end``, ``deep`` (2, 3) the colours
    ``GRADIENT_GAP`` and twice that further in: where they change steadily, each row's
    coverage is taken against the inside level carried to that row (``_gradient``).
    """
    wl[0], wl[1], wl[2] = w[0], w[1], w[2]
    ib, ig, ir = local[0], local[1], local[2]
    base = end + out * (outer + 1)
    hi_w = w[0] * ib + w[1] * ig + w[2] * ir
    if mode == GLOBAL:
        lo, hi = s_out, s_in
    else:
        v0 = score(img, base, x, lut, w)
        v1 = score(img, base + out, x, lut, w)
        v2 = score(img, base + 2 * out, x, lut, w)
        lo = max(min(v0, v1), min(max(v0, v1), v2))  # median of three
        hi = hi_w
    if mode == ORTHOGONAL:
        pb = pg = pr = 0.0
        for k in range(LOCAL_ROWS):
            pb += lut[img[base + k * out, x, 0]]
            pg += lut[img[base + k * out, x, 1]]
            pr += lut[img[base + k * out, x, 2]]
        mean = (pb + pg + pr) / 3.0
        pb, pg, pr = pb - mean, pg - mean, pr - mean  # the surround's chroma (x LOCAL_ROWS)
        cb, cg, cr = pg - pr, pr - pb, pb - pg        # (1, 1, 1) x chroma: orthogonal to both
        norm = np.sqrt(cb * cb + cg * cg + cr * cr)
        local = hi_w - lo
        if local > 0 and norm > 0.05 * LOCAL_ROWS * local:  # a coloured surround
            cb, cg, cr = cb / norm, cg / norm, cr / norm
            hi_o = cb * ib + cg * ig + cr * ir
            if hi_o < 0:
                cb, cg, cr, hi_o = -cb, -cg, -cr, -hi_o
            if hi_o > 0.4 * local:
                wl[0], wl[1], wl[2] = cb, cg, cr
                w = wl
                hi = hi_o
                lo = 0.0
                v0 = score(img, base, x, lut, w)
                v1 = score(img, base + out, x, lut, w)
                v2 = score(img, base + 2 * out, x, lut, w)
                lo = max(min(v0, v1), min(max(v0, v1), v2))
    span = hi - lo
    if span < 0.15 * (s_in - s_out) or span <= 1e-9:
        return np.nan  # no edge to measure here (a highlight, an occluder, no light)
    inv = 1.0 / span
    # the window's inner rows must not be brighter than the inside level: a shadow's boundary
    # running along the edge, inside the window, would move the edge outward (blur only makes
    # them darker)
    if out < 0:
        first, last = end - outer, end + window - 1
    else:
        first, last = end + 1 - window, end + outer
    for k in range(last - first + 1):  # each score once: the tests below all read them
        rows[k] = score(img, first + k, x, lut, w)
    k0 = max(2, window // 2 + 1)
    if window - k0 >= 1:
        acc_in = 0.0
        for k in range(k0, window):
            acc_in += rows[end - out * k - first]
        if (acc_in / (window - k0) - lo) * inv > 1.0 + FLAT_TOLERANCE:
            return np.nan
    if mode == CROSSING:
        # walk outward from the run's end to the first row below half coverage
        y = end
        prev = (score(img, y, x, lut, w) - lo) * inv
        for _ in range(outer + 1):
            cur = (score(img, y + out, x, lut, w) - lo) * inv
            if cur < 0.5:
                t = (prev - 0.5) / (prev - cur) if prev > cur else 0.5
                return y + out * t
            prev = cur
            y += out
        return end + out * 0.5
    acc = 0.0
    g = _gradient(w, deep, hi, span) if level_row > 0.0 and mode != GLOBAL else 0.0
    if g != 0.0:  # each row against the inside level carried there (but at least half)
        for k in range(last - first + 1):
            level = max(span + g * ((first + k - end) * -out - level_row), 0.5 * span)
            acc += min(max((rows[k] - lo) / level, -0.5), 1.5)
    else:
        for k in range(last - first + 1):
            acc += min(max((rows[k] - lo) * inv, -0.5), 1.5)
    if out < 0:
        edge = end + window - 0.5 - acc
    else:
        edge = end - window + 0.5 + acc
    # (against the plain half-way crossing: a gradient's correction that moves the edge
    # further from it than a shaded strip would drops the point too)
    if _crossing_gap(rows, first, last, lo, inv, edge) > MAX_CROSSING_GAP_PX:
        return np.nan  # two steps: a shadow's boundary in the window, beside the edge
    return edge


MAX_CROSSING_GAP_PX = 0.8  # the coverage sum's edge and the half-way crossing may differ by


@njit(inline="always")
def _gradient(w, deep, near, span):  # type: ignore[no-untyped-def]
    """The inside level's change per row inward (score units) from the level ``near`` and
    the deeper bands' colours ``deep`` along ``w``, where it changes steadily
    (``GRADIENT_LINEAR``, by ``GRADIENT_MIN`` to ``GRADIENT_MAX`` of ``span``); else 0."""
    mid = w[0] * deep[0, 0] + w[1] * deep[0, 1] + w[2] * deep[0, 2]
    far = w[0] * deep[1, 0] + w[1] * deep[1, 1] + w[2] * deep[1, 2]
    d1, d2 = mid - near, far - mid
    change = abs(far - near)
    if d1 * d2 <= 0.0 or min(abs(d1), abs(d2)) < GRADIENT_LINEAR * max(abs(d1), abs(d2)) or \
            change < GRADIENT_MIN * span or change > GRADIENT_MAX * span:
        return 0.0
    return (far - near) / (2 * GRADIENT_GAP)


@njit(inline="always")
def _crossing_gap(rows, first, last, lo, inv, edge):  # type: ignore[no-untyped-def]
    """Distance (px) from ``edge`` (the coverage sum's) to the nearest row position in
    rows ``first``..``last`` of a column (their scores in ``rows``) where the coverage
    crosses half way. One step, blurred
    symmetrically (optics, motion, defocus), puts both at the same place; a shadow's boundary
    within the window beside the edge makes a plateau of partial coverage, which moves the
    sum's edge but not the crossing: they differ by the plateau's darkening times its width."""
    best = np.inf
    prev = (rows[0] - lo) * inv
    for y in range(first + 1, last + 1):
        cur = (rows[y - first] - lo) * inv
        if (prev - 0.5) * (cur - 0.5) <= 0.0 and prev != cur:
            best = min(best, abs(y - 1 + (0.5 - prev) / (cur - prev) - edge))
        prev = cur
    return best


CLIPPED = 235  # a pixel whose every channel reaches this (sRGB) is a clipped highlight
HIGHLIGHT_DEPTH = 3  # rows inside a run's end where a highlight's halo shows


@njit(inline="always")
def _clipped_halo(img, x, end, out, window, lut):  # type: ignore[no-untyped-def]
    """Is the marker side of column x's edge window (rows 1 to ``window`` inside the run's
    end) in a highlight's halo where a channel clips? White light moves no chroma score
    until the ink's own channels clip; then the edge's inside level is wrong there. (Plain
    ink as bright has no white in it: its green stays dark.)"""
    H = img.shape[0]
    for k in range(1, window + 1):
        r = end - out * k
        if r < 0 or r >= H:
            return False
        b, g, rr = lut[img[r, x, 0]], lut[img[r, x, 1]], lut[img[r, x, 2]]
        hi = max(max(b, g), rr)
        if hi >= HALO_CLIPPED and min(min(b, g), rr) >= HALO_MIN_WHITE * hi:
            return True
    return False


@njit(inline="always")
def _at_highlight(img, x, end, out, lut):  # type: ignore[no-untyped-def]
    """Does column x's run end at ``end`` (``out`` = -1: its top, +1: its bottom) on a
    highlight's clipped core rather than on the marker's edge? Clipped white just beyond the
    end and the halo's white light a few rows inside it (``colour.HALO_MIN_WHITE``): a marker
    on a clipped white surround has plain ink there, past the blur."""
    H = img.shape[0]
    r = end + out
    if r < 0 or r >= H or img[r, x, 0] < CLIPPED or img[r, x, 1] < CLIPPED or \
            img[r, x, 2] < CLIPPED:
        return False
    r = end - out * HIGHLIGHT_DEPTH
    if r < 0 or r >= H:
        return False
    b, g, rr = lut[img[r, x, 0]], lut[img[r, x, 1]], lut[img[r, x, 2]]
    return min(min(b, g), rr) >= HALO_MIN_WHITE * max(max(b, g), rr)


@njit()
def notch_kept(img: np.ndarray, points: np.ndarray, keep: np.ndarray, out: int) -> np.ndarray:
    """``keep`` (``lines.on_hull``'s notch test of the edge points (N, 2) px, ``out`` = -1
    for the upper chain, +1 for the lower), or all points where a notch is a clipped
    highlight (white just outward of its points): an occluder's notch is left out of the
    fit, but a highlight's halo bends the edge beside it too, so the marker is then measured
    (or refused) as if there were no notch."""
    H, W = img.shape[0], img.shape[1]
    for i in range(points.shape[0]):
        if keep[i]:
            continue
        x = int(points[i, 0] + 0.5)
        for k in range(1, 4):
            r = int(points[i, 1] + 0.5) + out * k
            if 0 <= r < H and 0 <= x < W and img[r, x, 0] >= CLIPPED and \
                    img[r, x, 1] >= CLIPPED and img[r, x, 2] >= CLIPPED:
                return np.ones(points.shape[0], np.bool_)
    return keep
