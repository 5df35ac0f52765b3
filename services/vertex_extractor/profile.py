"""Is each fitted edge a clean step? The marker's profile across its edges (issue 21).

Light that changes *along* an edge cannot move it (each edge point has its own levels), but a
shadow's boundary running along an edge, a pixel or two inside the marker, turns the marker's
rim into a strip of darker ink that the coverage sum reads as part coverage: the whole edge
moves inward by a steady 1-3 px, the line stays straight and every other test passes. The
profile across such an edge is two steps (lit ink, shaded ink, background), not one: where the
median profile across the edge crosses half way between its levels lies away from the fitted
line. Any symmetric blur (optics, defocus, motion, demosaicing) leaves a single step whose
half-way crossing is the edge itself; a wide blur's edges come out a little off it, but all
four alike, so an edge is odd only when it is off its step and off the others' offsets.

At most ``MAX_POINTS`` points per edge, sampled (bilinear in ``colour.score``) at the two
levels and at the ``OFFSETS`` between the line and the crossing only; pure, compiled, no bus.
"""

from __future__ import annotations

import math

import numpy as np

from services.core.jit import njit
from services.core.order import median_in_place
from services.vertex_extractor.colour import chroma_direction, is_marker, score

#: the quadrilateral's vertices and its edges, each from vertex k to the next
VERTEX_NAMES = ("left", "top", "right", "bottom")
EDGE_NAMES = ("upper left", "upper right", "lower right", "lower left")

#: profile samples across an edge, px from the fitted line (outward positive); the first and
#: last give the inside and outside levels
OFFSETS = np.array([-4.0, -1.5, -1.25, -1.0, -0.75, -0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0,
                    1.25, 1.5, 4.0])
MAX_POINTS = 24   # per edge, spread over its middle 70 %
MIN_SPAN = 0.3    # a point whose level step is below this share of the edge's median is left out


@njit(inline="always")
def _bilinear(img, x, y, lut, w):  # type: ignore[no-untyped-def]
    """The score at sub-pixel (x, y) (pixel centres at integers), clamped to the image."""
    H, W = img.shape[0], img.shape[1]
    x = min(max(x, 0.0), W - 1.001)
    y = min(max(y, 0.0), H - 1.001)
    x0, y0 = int(x), int(y)
    fx, fy = x - x0, y - y0
    acc = 0.0
    for dy in range(2):
        for dx in range(2):
            wt = (fx if dx else 1.0 - fx) * (fy if dy else 1.0 - fy)
            acc += wt * score(img, y0 + dy, x0 + dx, lut, w)
    return acc


#: a vertex sharper than this (deg; a steep view's) has its other edge within the inside
#: level's reach (``OFFSETS[0]``) along the first few px of each edge: those are not read
SHARP_DEG = 45.0
CLEAR_PX = 1.5  # how far (px) from the other edge the inside level is then read, at least


@njit(inline="always")
def _clearance(v, k):  # type: ignore[no-untyped-def]
    """How far (px) along either edge from vertex k its points are not read: none unless the
    vertex is sharper than ``SHARP_DEG`` (the first px next to a vertex are where a shadow's
    boundary shows), then as far as the inside level comes within ``CLEAR_PX`` of the other
    edge."""
    ax, ay = v[(k + 1) % 4, 0] - v[k, 0], v[(k + 1) % 4, 1] - v[k, 1]
    bx, by = v[(k + 3) % 4, 0] - v[k, 0], v[(k + 3) % 4, 1] - v[k, 1]
    norms = max(math.hypot(ax, ay) * math.hypot(bx, by), 1e-9)
    cosine = (ax * bx + ay * by) / norms
    if cosine < math.cos(math.radians(SHARP_DEG)):
        return 0.0
    sine = max(abs(ax * by - ay * bx) / norms, 1e-3)
    return (CLEAR_PX - OFFSETS[0] * cosine) / sine


@njit(inline="always")
def _median_at(img, bx, by, nx, ny, off, lo, inv, keep, lut, w, buf):  # type: ignore[no-untyped-def]
    """The median over the kept points of the profile at ``off`` px, levels normalised."""
    for i in range(keep):
        buf[i] = (_bilinear(img, bx[i] + off * nx, by[i] + off * ny, lut, w) - lo[i]) * inv[i]
    return median_in_place(buf, keep)


@njit(inline="always")
def _direction(img, v, lut):  # type: ignore[no-untyped-def]
    """The marker's chroma direction (B, G, R weights): its median linear colour at points
    halfway to each vertex."""
    cx = 0.25 * (v[0, 0] + v[1, 0] + v[2, 0] + v[3, 0])
    cy = 0.25 * (v[0, 1] + v[1, 1] + v[2, 1] + v[3, 1])
    col = np.empty((3, 9))
    for i in range(9):
        s = 0.0 if i == 8 else (0.25 if i < 4 else 0.5)
        x = cx + s * (v[i % 4, 0] - cx)
        y = cy + s * (v[i % 4, 1] - cy)
        px = img[int(y + 0.5), int(x + 0.5)]
        col[0, i], col[1, i], col[2, i] = lut[px[0]], lut[px[1]], lut[px[2]]
    return chroma_direction(median_in_place(col[0], 9), median_in_place(col[1], 9),
                            median_in_place(col[2], 9))


@njit()
def _offsets(img, v, lut, w, a0, a1, max_points):  # type: ignore[no-untyped-def]
    """For each edge of the quadrilateral v (4, 2) px (L, T, R, B), how far (px, outward
    positive) from the fitted line its median profile along ``w`` (``_direction``) crosses
    half way between the inside and outside levels (walking from the line towards the
    crossing, so the profile is read only where needed); NaN where it cannot be told (too
    few points with contrast, or no crossing within 1.5 px). ``a0``, ``a1``: the stretch of
    each edge read (shares of its length), at most ``max_points`` points on it."""
    out = np.full(4, np.nan)
    cx = 0.25 * (v[0, 0] + v[1, 0] + v[2, 0] + v[3, 0])
    cy = 0.25 * (v[0, 1] + v[1, 1] + v[2, 1] + v[3, 1])
    n_off = OFFSETS.shape[0]
    j0 = n_off // 2  # offset 0
    bx, by = np.empty(MAX_POINTS), np.empty(MAX_POINTS)
    lo, inv, span = np.empty(MAX_POINTS), np.empty(MAX_POINTS), np.empty(MAX_POINTS)
    buf = np.empty(MAX_POINTS)
    for k in range(4):
        px_, py_ = v[k, 0], v[k, 1]
        qx, qy = v[(k + 1) % 4, 0], v[(k + 1) % 4, 1]
        length = math.hypot(qx - px_, qy - py_)
        if length < 4.0:
            continue
        tx, ty = (qx - px_) / length, (qy - py_) / length
        nx, ny = ty, -tx
        if nx * (0.5 * (px_ + qx) - cx) + ny * (0.5 * (py_ + qy) - cy) < 0:
            nx, ny = -nx, -ny
        # clear of the vertices by as much as the inside level's offset needs: next to a
        # sharp vertex (a steep view) the other edge is within 4 px and that level is not ink
        start = max(a0 * length, _clearance(v, k))
        end = min(a1 * length, length - _clearance(v, (k + 1) % 4))
        if end - start < 2.0:
            continue
        count = min(max_points, max(int(end - start), 1))
        for i in range(count):
            a = start + (end - start) * (i + 0.5) / count
            bx[i], by[i] = px_ + a * tx, py_ + a * ty
            lo[i] = _bilinear(img, bx[i] + OFFSETS[-1] * nx, by[i] + OFFSETS[-1] * ny, lut, w)
            span[i] = _bilinear(img, bx[i] + OFFSETS[0] * nx, by[i] + OFFSETS[0] * ny, lut,
                                w) - lo[i]
        buf[:count] = span[:count]
        typical = median_in_place(buf, count)
        if typical <= 0.0:
            continue
        keep = 0
        for i in range(count):
            if span[i] > MIN_SPAN * typical:
                bx[keep], by[keep], lo[keep], inv[keep] = bx[i], by[i], lo[i], 1.0 / span[i]
                keep += 1
        if keep < 3:
            continue
        j = j0
        m = _median_at(img, bx, by, nx, ny, OFFSETS[j], lo, inv, keep, lut, w, buf)
        step = 1 if m >= 0.5 else -1  # towards the crossing
        while 1 <= j + step <= n_off - 2:
            m2 = _median_at(img, bx, by, nx, ny, OFFSETS[j + step], lo, inv, keep, lut, w, buf)
            if (m2 < 0.5) == (step == 1):  # crossed between j and j + step
                hi_j, hi_m, lo_m = (j, m, m2) if step == 1 else (j - 1, m2, m)
                out[k] = OFFSETS[hi_j] + (OFFSETS[hi_j + 1] - OFFSETS[hi_j]) * (
                    hi_m - 0.5) / (hi_m - lo_m)
                break
            j, m = j + step, m2
    return out


#: the stretch of each edge next to a vertex whose profile ``vertex_steps`` reads (shares of
#: the edge's length from that vertex)
NEAR_VERTEX = (0.03, 0.3)
NEAR_VERTEX_POINTS = 8  # points read on each such stretch
#: a vertex is visible when the marker's colour is found at these shares of the way from it
#: to the centre (a shaded vertex is still the marker's chroma; an arm over it is not)
VISIBLE_AT = (0.12, 0.18)


@njit()
def vertex_steps(img: np.ndarray, v: np.ndarray, lut: np.ndarray, m: np.ndarray
                 ) -> np.ndarray:
    """``_offsets`` of the stretch of each edge next to each vertex (8: edge k next to
    vertex k, then edge k next to vertex k + 1), NaN where that vertex is hidden (an arm or
    a bar over it: no marker colour just inside it; its place then comes from the lines)."""
    return _vertex_steps(img, v, lut, m, _direction(img, v, lut))


@njit()
def _vertex_steps(img, v, lut, m, w):  # type: ignore[no-untyped-def]
    """``vertex_steps`` with the score direction ``w`` given."""
    a0, a1 = NEAR_VERTEX
    out = np.empty(8)
    out[:4] = _offsets(img, v, lut, w, a0, a1, NEAR_VERTEX_POINTS)
    out[4:] = _offsets(img, v, lut, w, 1.0 - a1, 1.0 - a0, NEAR_VERTEX_POINTS)
    H, W = img.shape[0], img.shape[1]
    cx = 0.25 * (v[0, 0] + v[1, 0] + v[2, 0] + v[3, 0])
    cy = 0.25 * (v[0, 1] + v[1, 1] + v[2, 1] + v[3, 1])
    for k in range(4):
        seen = True
        for f in VISIBLE_AT:
            x = int(v[k, 0] + f * (cx - v[k, 0]) + 0.5)
            y = int(v[k, 1] + f * (cy - v[k, 1]) + 0.5)
            if not (0 <= x < W and 0 <= y < H and is_marker(img, y, x, lut, m)):
                seen = False
        if not seen:
            out[k] = np.nan
            out[4 + (k + 3) % 4] = np.nan
    return out


@njit()
def odd_vertex(offsets: np.ndarray, max_deviation_px: float) -> tuple[int, float]:
    """The vertex (0-3) one of whose edges, next to it, steps further than
    ``max_deviation_px`` from the median of the eight stretches' offsets (``vertex_steps``),
    and that deviation; (-1, 0) for none. A shadow's boundary near a vertex bends the edge
    points there, and the vertex the lines give is then px off while the edges' middles are
    fine (``odd_edge`` does not see it)."""
    s = np.sort(np.where(np.isnan(offsets), 0.0, offsets))
    median = 0.5 * (s[3] + s[4])
    odd, worst = -1, max_deviation_px
    for i in range(offsets.shape[0]):
        x = offsets[i]
        if not math.isnan(x) and abs(x - median) > worst:
            odd, worst = (i if i < 4 else (i - 3) % 4), abs(x - median)
    return odd, (worst if odd >= 0 else 0.0)


#: an outward offset (the step beyond the line) is allowed this many times the inward limit:
#: a shaded rim puts the step inside the line; a coloured surround skews a profile read along
#: the marker's chroma outward (the extractor's own edges are measured across that surround)
OUTWARD = 1.6


@njit()
def odd_edge(offsets: np.ndarray, max_offset_px: float, max_spread_px: float) -> int:
    """The edge (0-3) whose step lies more than ``max_offset_px`` inside its fitted line
    (``OUTWARD`` times that beyond it) *and* more than ``max_spread_px`` from the four edges'
    median offset, the furthest such; -1 for none. A blurred marker's edges all lie a little
    off their steps alike (the window's truncation of a wide ramp); a shadow's boundary along
    one edge moves that edge alone."""
    o = np.where(np.isnan(offsets), 0.0, offsets)
    s = np.sort(o)
    median = 0.5 * (s[1] + s[2])
    odd, worst = -1, 0.0
    for k in range(4):
        x = o[k]
        if ((x < -max_offset_px or x > OUTWARD * max_offset_px)
                and abs(x - median) > max_spread_px and abs(x) > worst):
            odd, worst = k, abs(x)
    return odd


@njit()
def examine(img: np.ndarray, v: np.ndarray, lut: np.ndarray, m: np.ndarray,
            max_offset_px: float, max_spread_px: float, max_vertex_step_px: float
            ) -> tuple[np.ndarray, np.ndarray, int, int, float]:
    """Both profile tests of the quadrilateral v (4, 2) px in one call (the extractor's, per
    detection): ``_offsets`` of each edge's middle 70 % (4), ``vertex_steps`` (8),
    ``odd_edge`` of the first and ``odd_vertex`` of the second (the vertex and its
    deviation px)."""
    w = _direction(img, v, lut)
    offsets = _offsets(img, v, lut, w, 0.15, 0.85, MAX_POINTS)
    steps = _vertex_steps(img, v, lut, m, w)
    vertex, deviation = odd_vertex(steps, max_vertex_step_px)
    return offsets, steps, odd_edge(offsets, max_offset_px, max_spread_px), vertex, deviation


#: where ``marker_beyond`` reads each edge's outside: px beyond the fitted line, and the
#: stretch of the edge (shares of its length)
BEYOND_OFFSETS_PX = (2.5, 3.5)
BEYOND_STRETCH = (0.15, 0.85)
BEYOND_MAX_POINTS = 64  # an edge and offset (24 let a 2.2 px error at 1.06 px through)


@njit()
def marker_beyond(img: np.ndarray, v: np.ndarray, lut: np.ndarray, m: np.ndarray) -> float:
    """The largest share, over the four edges of the quadrilateral v (4, 2) px, of pixels
    that pass the marker's colour test (``colour.is_marker``) ``BEYOND_OFFSETS_PX`` outside
    the edge along its middle (``BEYOND_STRETCH``), one pixel apart (at most
    ``BEYOND_MAX_POINTS`` an offset, spread over it). A marker edge has its surround there;
    a shadow's boundary running along an edge inside the marker, taken for the edge, has the
    strip of shaded ink beyond it."""
    H, W = img.shape[0], img.shape[1]
    cx = 0.25 * (v[0, 0] + v[1, 0] + v[2, 0] + v[3, 0])
    cy = 0.25 * (v[0, 1] + v[1, 1] + v[2, 1] + v[3, 1])
    worst = 0.0
    for k in range(4):
        px_, py_ = v[k, 0], v[k, 1]
        dx, dy = v[(k + 1) % 4, 0] - px_, v[(k + 1) % 4, 1] - py_
        length = math.hypot(dx, dy)
        if length < 1e-9:
            continue
        nx, ny = dy / length, -dx / length
        if nx * (px_ + 0.5 * dx - cx) + ny * (py_ + 0.5 * dy - cy) < 0.0:
            nx, ny = -nx, -ny  # (outward)
        a0, a1 = BEYOND_STRETCH
        n = min(max(int((a1 - a0) * length), 4), BEYOND_MAX_POINTS)
        hits = total = 0
        for off in BEYOND_OFFSETS_PX:
            for i in range(n):
                t = a0 + (a1 - a0) * i / (n - 1)
                x = int(px_ + t * dx + off * nx + 0.5)
                y = int(py_ + t * dy + off * ny + 0.5)
                if 0 <= x < W and 0 <= y < H:
                    total += 1
                    hits += is_marker(img, y, x, lut, m)
        if total > 0:
            worst = max(worst, hits / total)
    return worst


def warm_up() -> None:
    """Compile (or load) the kernel for read-only frames, the service's."""
    img = np.zeros((40, 40, 3), np.uint8)
    img.flags.writeable = False
    v = np.array([[10.0, 20.0], [20.0, 10.0], [30.0, 20.0], [20.0, 30.0]])
    lut = np.linspace(0.0, 255.0, 256)
    m = np.array([0.615, 0.02, 1.0, 0.0, 1.0, 12.75])
    examine(img, v, lut, m, 0.5, 0.3, 1.0)
    marker_beyond(img, v, lut, m)
