"""A marker the line fits refused for want of edge points, fitted as the deployment's rhombus
to the edge points it shows, where the camera's intrinsics are known (issue 21: "with a
whole edge hidden, recover it from the known shape or refuse").

A glossy print's highlight washing out a vertex and much of its edges, an arm over an edge, a
small or shaded marker: the line fits then refuse ("too few edge points on one side", "the
column and row scans disagree", "vertex uncertainty too large"). With the intrinsics the
rhombus's pose has six parameters and three of its edges' lines fix it, so its four vertices
follow from the edges that are seen:

1. both scans' finite edge points (without a notch's: ``measure._outside_notches``), each of
   the four chains split where it turns (``lines.best_split``) into its two edges' points;
2. candidate poses: IPPE on the quadrilateral of the four edges' lines, where all four have
   one; for each three consecutive edges with lines, the poses that put the rhombus's edges
   on them (``p3l``, closed form); IPPE on the blob's box turned where the chains turn;
3. each refined by Gauss-Newton on the points' distances (px) to the projected edges, each
   point on the nearer of its chain's two edges, Tukey weights (``refine``); the best kept;
4. accepted only where three edges carry points (``MIN_EDGE_POINTS`` along at least
   ``MIN_EDGE_SPAN`` of the edge), none more than ``MAX_BEYOND_PX`` beyond its edge's ends,
   every vertex has points within ``MAX_VERTEX_GAP`` of an edge's length of it (the model is
   not extrapolated further), no other candidate pose fits
   nearly as well (``MIN_RIVAL``: two poses the points cannot tell apart), the line fits'
   own shape tests pass (``view_refusal``, asked first of the four lines' quadrilateral: a
   pink card fully seen is no marker with points missing), and no marker-coloured pixel lies
   outside the quadrilateral (``MAX_MARKER_OUTSIDE``: it is not part of the marker).

The covariance reported is the fit's, each edge's points counted as at most ``EDGE_DOF``
independent ones (its errors do not average out along it; ``WEAK_EDGE_DOF`` on an edge that
does not carry the pose), plus ``EXTRAPOLATION`` of the
stretch between each vertex and its nearest point. The extractor then applies the shape
test's view bounds, the profile tests and the uncertainty limit as to any detection.

Pure (no bus); 0.5 ms where the four lines already refuse (a pink card), a few ms a fit,
compiled where it loops over points.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from services.core.camera import CameraModel, undistort_px
from services.core.jit import njit
from services.core.projection import project_px
from services.pose_estimator.p4p import OK, exp_so3, ippe4
from services.vertex_extractor import lines, measure, scan
from services.vertex_extractor.colour import HALO_MIN_CHROMA, chroma_amount, is_lit_marker

#: an edge carries the marker's pose where this many inlying points lie along at least this
#: share of it; three such edges are needed
MIN_EDGE_POINTS = 6
MIN_EDGE_SPAN = 0.4
#: every vertex must have an edge point within this share of an adjacent edge's length: the
#: model is not extrapolated further (on 1 500 views under a clipped highlight, a vertex 57 %
#: of its edge from the nearest point came out 2.4 px off)
MAX_VERTEX_GAP = 0.5
#: an edge's points may lie this far (px) beyond its ends (the window's reach at a vertex):
#: further, and the marker reaches further than the fitted rhombus
MAX_BEYOND_PX = 1.5
#: the best pose must fit the points better than any other candidate whose vertices lie more
#: than RIVAL_PX from its by this much (the truncated sum of squared residuals, in units of
#: the residuals' own variance): otherwise the points cannot tell the two apart
MIN_RIVAL = 3.0
RIVAL_PX = 2.0
#: an edge's points count as at most this many independent ones in the covariance; those of
#: an edge that does not carry the pose (too few, or too short a stretch) as one (the few
#: points of an edge next to a hidden one otherwise seemed to pin it)
EDGE_DOF = 4.0
WEAK_EDGE_DOF = 1.0
#: a vertex's sigma grows by this share of the stretch (px) between it and the nearest edge
#: point: the model's shape and the intrinsics carried that far
EXTRAPOLATION = 0.03
#: marker-coloured pixels allowed more than BAND_PX outside the quadrilateral (at least this
#: many, or this share of its area): more, and it is part of the marker, not all of it
BAND_PX = 2.0
MAX_MARKER_OUTSIDE = 3
MAX_MARKER_OUTSIDE_SHARE = 0.0005
SIGMA_FLOOR_PX = 0.3  # the residuals' scale is never taken smaller (Tukey's weights)
TUKEY = 4.685
ITERATIONS = 30
FIRST_STEPS = 6  # every start refined this far,
REFINED = 4  # then the best fitting this many to the end
#: the chains (column scan's upper and lower, row scan's left and right) and the two edges
#: (left-top, top-right, right-bottom, bottom-left: edge e joins vertex e and e + 1) each
#: runs along, in the order the chain meets them
CHAIN_EDGES = np.array([[0, 1], [3, 2], [0, 3], [1, 2]])


@dataclass(frozen=True)
class Recovery:
    """The rhombus fitted to the edge points: vertices (4, 2) px (left, top, right, bottom),
    their covariance (4, 2, 2) px², the inlying points' rms distance to the edges (px), and
    per edge the number of its inlying points and the share of its length they span."""

    vertices_px: np.ndarray
    cov_px2: np.ndarray
    rms_px: float
    edge_counts: tuple[int, int, int, int]
    edge_spans: tuple[float, float, float, float]


def edge_points(img: np.ndarray, x: int, y: int, radius: int, lut: np.ndarray,
                m: np.ndarray, prm: np.ndarray
                ) -> tuple[list[np.ndarray], np.ndarray, tuple[int, int]] | None:
    """Both scans' finite edge points of the marker at or near the seed (x, y), in image px:
    the column scan's upper and lower chains (by x) and the row scan's left and right ones
    (by y), without a notch's; with the walked blob's box (x0, x1, y0, y1) and the marker
    pixel the walk began at. None where there is no marker pixel or it reaches the
    border."""
    sx, sy = scan.find_seed(img, x, y, radius, lut, m)
    if sx < 0:
        return None
    status, _, _, _, u, d, box = measure.column_scan(img, sx, sy, lut, m, prm)
    if status == scan.BORDER:
        return None
    cu, cd, _, _ = lines.finite_points(u, d)
    if cu.shape[0] and cd.shape[0]:
        keep_u, keep_d = measure._outside_notches(img, cu, cd)
        cu, cd = cu[keep_u], cd[keep_d]
    status, _, _, _, ur, dr, rows, _ = measure._row_scan(img, sx, sy, lut, m, prm)
    ru, rd = np.empty((0, 2)), np.empty((0, 2))
    if status == scan.OK:
        ru, rd, _, _ = lines.finite_points(ur, dr)
        if ru.shape[0] and rd.shape[0]:
            keep_u, keep_d = measure._outside_notches(rows, ru, rd)
            ru, rd = ru[keep_u], rd[keep_d]
        ru, rd = ru[:, ::-1], rd[:, ::-1]  # (x, y) = (y', x')
    chains = [cu[np.argsort(cu[:, 0], kind="stable")], cd[np.argsort(cd[:, 0], kind="stable")],
              ru[np.argsort(ru[:, 1], kind="stable")], rd[np.argsort(rd[:, 1], kind="stable")]]
    return chains, box, (sx, sy)


def _split(chain: np.ndarray, k: int) -> int:
    """Where chain ``k`` (sorted along it) turns from its first edge to its second."""
    if chain.shape[0] < 4:
        return chain.shape[0] // 2
    along = chain if k < 2 else np.ascontiguousarray(chain[:, ::-1])
    return int(lines.best_split(np.ascontiguousarray(along), 2))


def _edge_lines(chains: list[np.ndarray], splits: list[int]
                ) -> list[tuple[np.ndarray, np.ndarray] | None]:
    """Each edge's line (a point on it, its unit direction; image px) through the points of
    the chains along it (each split at ``splits``, ``_split``), where it has at least
    MIN_EDGE_POINTS over 3 px or more."""
    groups: list[list[np.ndarray]] = [[], [], [], []]
    for k, (chain, j) in enumerate(zip(chains, splits, strict=True)):
        if chain.shape[0] == 0:
            continue
        groups[CHAIN_EDGES[k, 0]].append(chain[:j])
        groups[CHAIN_EDGES[k, 1]].append(chain[j:])
    out: list[tuple[np.ndarray, np.ndarray] | None] = []
    for g in groups:
        p = np.concatenate(g) if g else np.empty((0, 2))
        if p.shape[0] < MIN_EDGE_POINTS:
            out.append(None)
            continue
        c = p.mean(axis=0)
        direction = np.linalg.svd(p - c)[2][0]
        along = (p - c) @ direction
        out.append((c, direction) if along.max() - along.min() >= 3.0 else None)
    return out


def _meet(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]
          ) -> np.ndarray | None:
    """Where two lines (point, direction) cross; None when nearly parallel."""
    A = np.array([a[1], -b[1]]).T
    if abs(np.linalg.det(A)) < 1e-6:
        return None
    s = np.linalg.solve(A, b[0] - a[0])
    return a[0] + s[0] * a[1]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def p3l(normals: list[np.ndarray | None], model: np.ndarray, hidden: int
        ) -> list[tuple[np.ndarray, np.ndarray]]:
    """The poses (R, t: marker to camera) putting the rhombus ``model``'s (4, 3) m edges
    ``hidden`` + 1, + 2, + 3 on the image lines whose planes through the camera centre have
    the unit ``normals[e]`` (normalised image coordinates): the first and third (opposite,
    parallel) edges' direction is the cross product of their normals; the middle edge's is at
    the rhombus's corner angle to it and in its own plane (two solutions); each plane through
    its edge's vertex gives t (three linear equations). Up to four poses, all in front."""
    a, b, c = (hidden + 1) % 4, (hidden + 2) % 4, (hidden + 3) % 4
    na, nb, nc = normals[a], normals[b], normals[c]
    if na is None or nb is None or nc is None:
        return []
    direction = np.cross(na, nc)
    if np.linalg.norm(direction) < 1e-12:
        return []
    direction = _unit(direction)
    Da = _unit(model[(a + 1) % 4] - model[a])
    Db = _unit(model[(b + 1) % 4] - model[b])
    cos_b = float(Da @ Db)
    sin_b = math.sqrt(max(1.0 - cos_b * cos_b, 0.0))
    E2 = _unit(Db - cos_b * Da)
    E = np.stack([Da, E2, np.cross(Da, E2)], axis=1)
    planes = np.stack([na, nb, nc])
    if abs(np.linalg.det(planes)) < 1e-12:
        return []
    poses = []
    for u1 in (direction, -direction):
        p = _unit(np.cross(u1, [1.0, 0.0, 0.0] if abs(u1[0]) < 0.9 else [0.0, 1.0, 0.0]))
        q = np.cross(u1, p)
        A, B, C = sin_b * (nb @ p), sin_b * (nb @ q), -cos_b * (nb @ u1)
        r = math.hypot(A, B)
        if r < 1e-12 or abs(C) > r:
            continue
        base, turn = math.atan2(B, A), math.acos(max(-1.0, min(1.0, C / r)))
        for phi in (base + turn, base - turn):
            v2 = cos_b * u1 + sin_b * (math.cos(phi) * p + math.sin(phi) * q)
            F2 = _unit(v2 - (v2 @ u1) * u1)
            R = np.stack([u1, F2, np.cross(u1, F2)], axis=1) @ E.T
            t = np.linalg.solve(planes, -np.array([n @ (R @ model[e])
                                                   for n, e in ((na, a), (nb, b), (nc, c))]))
            if (model @ R.T + t)[:, 2].min() > 0.0:
                poses.append((R, t))
    return poses


@njit()
def _project(R: np.ndarray, t: np.ndarray, model: np.ndarray) -> np.ndarray:
    """The model's (4, 3) vertices in normalised image coordinates (4, 2)."""
    P = np.empty((4, 2))
    for k in range(4):
        X = R[0, 0] * model[k, 0] + R[0, 1] * model[k, 1] + R[0, 2] * model[k, 2] + t[0]
        Y = R[1, 0] * model[k, 0] + R[1, 1] * model[k, 1] + R[1, 2] * model[k, 2] + t[1]
        Z = R[2, 0] * model[k, 0] + R[2, 1] * model[k, 1] + R[2, 2] * model[k, 2] + t[2]
        Z = max(Z, 1e-9)  # (a vertex at or behind the camera: far off, refused later)
        P[k, 0], P[k, 1] = X / Z, Y / Z
    return P


@njit()
def _assign(P: np.ndarray, q: np.ndarray, chain: np.ndarray, who: np.ndarray) -> None:
    """Each point q (n, 2) on the nearer (to the segment) of its chain's two edges of the
    projected quadrilateral P (4, 2), into ``who``."""
    for i in range(q.shape[0]):
        best = np.inf
        for j in range(2):
            e = CHAIN_EDGES[chain[i], j]
            ax, ay = P[e, 0], P[e, 1]
            dx, dy = P[(e + 1) % 4, 0] - ax, P[(e + 1) % 4, 1] - ay
            s = ((q[i, 0] - ax) * dx + (q[i, 1] - ay) * dy) / max(dx * dx + dy * dy, 1e-18)
            s = min(max(s, 0.0), 1.0)
            dist = math.hypot(q[i, 0] - ax - s * dx, q[i, 1] - ay - s * dy)
            if dist < best:
                best, who[i] = dist, e


@njit()
def _residuals(P: np.ndarray, q: np.ndarray, who: np.ndarray, f: float, r: np.ndarray
               ) -> None:
    """Each point's signed distance (px, at focal length f) to its edge's line, into r."""
    for i in range(q.shape[0]):
        e = who[i]
        ax, ay = P[e, 0], P[e, 1]
        dx, dy = P[(e + 1) % 4, 0] - ax, P[(e + 1) % 4, 1] - ay
        norm = max(math.hypot(dx, dy), 1e-18)
        r[i] = f * ((q[i, 0] - ax) * -dy + (q[i, 1] - ay) * dx) / norm


@njit()
def _jacobian(R: np.ndarray, t: np.ndarray, model: np.ndarray, q: np.ndarray,
              who: np.ndarray, f: float, r: np.ndarray) -> np.ndarray:
    """The residuals' derivatives (n, 6) by the pose's rotation vector (applied on the left)
    and translation, by forward differences."""
    J = np.empty((q.shape[0], 6))
    r2 = np.empty(q.shape[0])
    h = 1e-6
    for k in range(6):
        w = np.zeros(3)
        t2 = t.copy()
        if k < 3:
            w[k] = h
        else:
            t2[k - 3] += h
        _residuals(_project(exp_so3(w) @ R, t2, model), q, who, f, r2)
        J[:, k] = (r2 - r) / h
    return J


@njit()
def refine(q: np.ndarray, chain: np.ndarray, model: np.ndarray, R: np.ndarray,
           t: np.ndarray, f: float, iterations: int
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """The pose (R, t) refined by damped Gauss-Newton on the points' (normalised q (n, 2),
    chain index each) distances to the model's projected edges, Tukey weights on the
    residuals' robust scale (at least ``SIGMA_FLOOR_PX``). Returns R, t, the residuals (px),
    each point's edge, the weights and the scale (px)."""
    n = q.shape[0]
    who = np.zeros(n, np.int64)
    r = np.empty(n)
    w = np.empty(n)
    s = SIGMA_FLOOR_PX
    for step_no in range(iterations + 1):
        P = _project(R, t, model)
        _assign(P, q, chain, who)
        _residuals(P, q, who, f, r)
        s = max(1.4826 * np.median(np.abs(r)), SIGMA_FLOOR_PX)
        c = TUKEY * s
        for i in range(n):
            w[i] = (1.0 - (r[i] / c) ** 2) ** 2 if abs(r[i]) < c else 0.0
        if step_no == iterations:
            break
        J = _jacobian(R, t, model, q, who, f, r)
        A = J.T @ (J * w.reshape(-1, 1))
        g = J.T @ (w * r)
        for k in range(6):
            A[k, k] += 1e-3 * A[k, k] + 1e-12
        step = -np.linalg.solve(A, g)
        if not np.all(np.isfinite(step)):
            break
        R = exp_so3(step[:3]) @ R
        t = t + step[3:]
        if t[2] <= 0.0 or np.abs(step).max() < 1e-10:
            break
    return R, t, r, who, w, s


@njit()
def _outside_marker(img: np.ndarray, outer: np.ndarray, x0: int, y0: int, lut: np.ndarray,
                    m: np.ndarray, halo_chroma: float) -> int:
    """Marker-coloured pixels (lit or not, unclipped) of the region at (x0, y0) outside the
    ``outer`` mask."""
    count = 0
    for yy in range(outer.shape[0]):
        for xx in range(outer.shape[1]):
            if not outer[yy, xx] and is_lit_marker(img, yy + y0, xx + x0, lut, m,
                                                   halo_chroma, True):
                count += 1
    return count


def _marker_outside(img: np.ndarray, v: np.ndarray, seed: tuple[int, int], lut: np.ndarray,
                    m: np.ndarray) -> tuple[int, float]:
    """Marker-coloured pixels more than ``BAND_PX`` outside the quadrilateral v (4, 2) px (in
    its box and 8 px around), and the quadrilateral's area (px²)."""
    H, W = img.shape[:2]
    x0, x1 = max(int(v[:, 0].min()) - 8, 0), min(int(v[:, 0].max()) + 9, W)
    y0, y1 = max(int(v[:, 1].min()) - 8, 0), min(int(v[:, 1].max()) + 9, H)
    area = quad_area(v)
    if x1 <= x0 or y1 <= y0:
        return 0, area
    # each edge moved BAND_PX outward: the lines' offsets, the new corners where they meet
    c = v.mean(axis=0)
    shifted = []
    for e in range(4):
        a, b = v[e], v[(e + 1) % 4]
        normal = _unit(np.array([b[1] - a[1], a[0] - b[0]]))
        if normal @ (a - c) < 0:
            normal = -normal
        shifted.append((a + BAND_PX * normal, _unit(b - a)))
    grown = [_meet(shifted[(k - 1) % 4], shifted[k]) for k in range(4)]
    if any(p is None for p in grown):
        return 0, area
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    pts = np.round((np.array(grown) - [x0, y0]) * 256).astype(np.int32)
    cv2.fillConvexPoly(mask, pts, 1, lineType=cv2.LINE_8, shift=8)
    halo = HALO_MIN_CHROMA * chroma_amount(img, seed[1], seed[0], lut)
    return int(_outside_marker(img, mask.astype(np.bool_), x0, y0, lut, m, halo)), area


def edge_normals(fitted: list[tuple[np.ndarray, np.ndarray] | None], camera: CameraModel
                 ) -> list[np.ndarray | None]:
    """Each image line's (point, direction px) plane through the camera centre: its unit
    normal in normalised image coordinates (undistorted at two points 10 px apart)."""
    normals: list[np.ndarray | None] = []
    for line in fitted:
        if line is None:
            normals.append(None)
            continue
        a, b = undistort_px(camera, np.array([line[0] - 5.0 * line[1], line[0] + 5.0 * line[1]]))
        normals.append(_unit(np.cross([a[0], a[1], 1.0], [b[0], b[1], 1.0])))
    return normals


def _box_quad(chains: list[np.ndarray], splits: list[int], box: np.ndarray) -> np.ndarray:
    """The blob's box (x0, x1, y0, y1) turned into a quadrilateral at the sides' points where
    the chains turn (the middle of a side where a chain has too few points)."""
    middle = (0.5 * (box[0] + box[1]), 0.5 * (box[0] + box[1]),
              0.5 * (box[2] + box[3]), 0.5 * (box[2] + box[3]))
    turns = list(middle)  # top, bottom (x), left, right (y)
    for k, (chain, j) in enumerate(zip(chains, splits, strict=True)):
        if chain.shape[0] >= 4:
            axis = 0 if k < 2 else 1
            turns[k] = 0.5 * (chain[j - 1, axis] + chain[j, axis])
    top, bottom, left, right = turns
    return np.array([[box[0], left], [top, box[2]], [box[1], right], [bottom, box[3]]], float)


def _candidates(fitted: list[tuple[np.ndarray, np.ndarray] | None], chains: list[np.ndarray],
                splits: list[int], box: np.ndarray, camera: CameraModel, model: np.ndarray
                ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Initial poses: IPPE on the four edges' lines' quadrilateral, ``p3l`` on each three
    consecutive edges' lines, IPPE on the blob's box turned where the chains turn."""
    quads = [_box_quad(chains, splits, box)]
    if all(line is not None for line in fitted):
        quads.append(_quad(fitted))  # type: ignore[arg-type]
    poses = []
    for quad in quads:
        if not np.all(np.isfinite(quad)):
            continue
        status, Rs, ts, _, count = ippe4(model, np.ascontiguousarray(undistort_px(camera, quad)))
        if status == OK:
            poses += [(Rs[i].copy(), ts[i].copy()) for i in range(count)]
    normals = edge_normals(fitted, camera)
    for hidden in range(4):
        poses += p3l(normals, model, hidden)
    return poses


def _quad(fitted: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The quadrilateral (4, 2) px of four edges' lines (NaN where two are parallel)."""
    corners = [_meet(fitted[(k - 1) % 4], fitted[k]) for k in range(4)]
    return np.array([c if c is not None else (np.nan, np.nan) for c in corners])


def recover(img: np.ndarray, seed: tuple[int, int, int], lut: np.ndarray, m: np.ndarray,
            prm: np.ndarray, camera: CameraModel, model: np.ndarray,
            view_refusal: Callable[[np.ndarray], str]) -> Recovery | str:
    """The rhombus ``model`` (4, 3) m (left, top, right, bottom) fitted to the edge points of
    the marker at or near ``seed`` (x, y, search radius px) seen by ``camera``, or why not
    (module docstring). ``view_refusal``: why a quadrilateral (4, 2) px is no view of the
    marker ("" when it may be: the extractor's shape tests); asked of the four edges' lines'
    quadrilateral first, where they all have one (a thing fully seen whose lines make no view
    of the marker is not the marker with points missing), and of the fitted one."""
    found = edge_points(img, seed[0], seed[1], seed[2], lut, m, prm)
    if found is None:
        return "no marker pixels at the seed, or the marker reaches the border"
    chains, box, start = found
    points = np.concatenate(chains)
    if points.shape[0] < 3 * MIN_EDGE_POINTS:
        return f"too few edge points to fit the rhombus to ({points.shape[0]})"
    splits = [_split(chain, k) for k, chain in enumerate(chains)]
    fitted = _edge_lines(chains, splits)
    lined = sum(line is not None for line in fitted)
    if lined < 3:
        return f"{lined} edges show a line, not 3"
    if lined == 4:
        quad = _quad(fitted)  # type: ignore[arg-type]
        why = view_refusal(quad) if np.all(np.isfinite(quad)) else "parallel edges"
        if why:
            return f"its edges' lines: {why}"
    chain = np.concatenate([np.full(c.shape[0], k, np.int64) for k, c in enumerate(chains)])
    q = np.ascontiguousarray(undistort_px(camera, points))
    f = float(camera.K[1, 1])
    model = np.ascontiguousarray(model, np.float64)
    # every start a few steps (its first cost says little: a wrong start can look better),
    # the best REFINED of them to the end
    starts = []
    for i, (R, t) in enumerate(_candidates(fitted, chains, splits, box, camera, model)):
        R, t, r, _, _, s = refine(q, chain, model, R, t, f, FIRST_STEPS)
        if np.all(np.isfinite(r)) and (model @ R.T + t)[:, 2].min() > 0.0:
            starts.append((float(np.minimum(r * r, (3.0 * s) ** 2).sum()), i, R, t))
    fits = []
    for _, _, R, t in sorted(starts, key=lambda c: c[:2])[:REFINED]:
        R, t, r, who, w, s = refine(q, chain, model, R, t, f, ITERATIONS)
        if not (np.all(np.isfinite(r)) and (model @ R.T + t)[:, 2].min() > 0.0):
            continue
        cost = float(np.minimum(r * r, (3.0 * s) ** 2).sum())
        fits.append((cost, R, t, r, who, w, s, project_px(camera.K, camera.dist,
                                                          model @ R.T + t)))
    if not fits:
        return "no pose of the rhombus fits its edge points"
    cost, R, t, r, who, w, s, v = min(fits, key=lambda fit: fit[0])
    rival = min((c for c, *_, vv in fits if np.abs(vv - v).max() > RIVAL_PX), default=np.inf)
    if rival - cost < MIN_RIVAL * s * s:
        return "two poses of the rhombus fit its edge points alike (ambiguous)"
    inlying = np.abs(r) < 3.0 * s
    counts, spans, gaps, beyond = [], [], np.ones(4), 0.0
    for e in range(4):
        a, b = v[e], v[(e + 1) % 4]
        on = inlying & (who == e)
        counts.append(int(on.sum()))
        if counts[-1] < 2:
            spans.append(0.0)
            continue
        length = float(np.linalg.norm(b - a))
        along = (points[on] - a) @ (b - a) / (length * length)
        beyond = max(beyond, -along.min() * length, (along.max() - 1.0) * length)
        along = np.clip(along, 0.0, 1.0)
        spans.append(float(along.max() - along.min()))
        gaps[e] = min(gaps[e], along.min())  # vertex e starts edge e
        gaps[(e + 1) % 4] = min(gaps[(e + 1) % 4], 1.0 - along.max())  # vertex e+1 ends it
    carrying = sum(n >= MIN_EDGE_POINTS and span >= MIN_EDGE_SPAN
                   for n, span in zip(counts, spans, strict=True))
    if carrying < 3:
        return f"the rhombus fitted to its edge points rests on {carrying} edges, not 3"
    if beyond > MAX_BEYOND_PX:
        return (f"the rhombus fitted to its edge points has an edge's points {beyond:.1f} px "
                "beyond its vertex (the marker is larger)")
    if gaps.max() > MAX_VERTEX_GAP:
        return (f"the rhombus fitted to its edge points puts a vertex {gaps.max():.0%} of an "
                "edge from any point (hidden)")
    why = view_refusal(v)
    if why:
        return f"the rhombus fitted to its edge points: {why}"
    outside, area = _marker_outside(img, v, start, lut, m)
    if outside > max(MAX_MARKER_OUTSIDE, MAX_MARKER_OUTSIDE_SHARE * area):
        return (f"the rhombus fitted to its edge points leaves {outside} marker pixels out "
                "(part of the marker)")
    # the covariance: each edge's points count as at most EDGE_DOF
    J = _jacobian(R, t, model, q, who, f, r)
    per_edge = np.bincount(who[inlying], minlength=4).astype(float)
    carries = np.array([n >= MIN_EDGE_POINTS and span >= MIN_EDGE_SPAN
                        for n, span in zip(counts, spans, strict=True)])
    dof = np.where(carries, EDGE_DOF, WEAK_EDGE_DOF)
    wc = w * np.minimum(1.0, dof[who] / np.maximum(per_edge[who], 1.0))
    try:
        C = np.linalg.inv(J.T @ (J * wc[:, None])) * s * s
    except np.linalg.LinAlgError:
        return "the rhombus's pose is not fixed by its edge points"
    Jv = np.empty((8, 6))
    h = 1e-6
    for k in range(6):
        step = np.zeros(6)
        step[k] = h
        moved = project_px(camera.K, camera.dist,
                           model @ (exp_so3(step[:3]) @ R).T + t + step[3:])
        Jv[:, k] = ((moved - v) / h).ravel()
    Cv = Jv @ C @ Jv.T
    cov = np.array([Cv[2 * k:2 * k + 2, 2 * k:2 * k + 2] for k in range(4)])
    for k in range(4):  # a vertex further from the points is the model's extrapolation
        reach = 0.5 * float(np.linalg.norm(v[k] - v[k - 1]) + np.linalg.norm(v[(k + 1) % 4] - v[k]))
        cov[k] += (EXTRAPOLATION * gaps[k] * reach) ** 2 * np.eye(2)
    if not np.all(np.isfinite(cov)):
        return "the rhombus's pose is not fixed by its edge points"
    rms = float(np.sqrt(np.mean(r[inlying] ** 2))) if inlying.any() else 0.0
    return Recovery(v, cov, rms, tuple(counts), tuple(spans))  # type: ignore[arg-type]


def quad_area(v: np.ndarray) -> float:
    """The area (px²) of the quadrilateral v (4, 2): half its diagonals' cross product."""
    (ax, ay), (bx, by) = v[2] - v[0], v[3] - v[1]
    return 0.5 * abs(float(ax * by - ay * bx))


def largest_sigma_px(cov: np.ndarray) -> float:
    """The largest 1-sigma axis (px) of the four vertices' covariance (4, 2, 2)."""
    return float(math.sqrt(max(np.linalg.eigvalsh(c).max() for c in cov)))


def warm_up() -> None:
    """Compile (or load from numba's on-disk cache) the fit's kernels."""
    model = np.array([[-0.03, 0.0, 0.0], [0.0, -0.05, 0.0], [0.03, 0.0, 0.0], [0.0, 0.05, 0.0]])
    P = _project(np.eye(3), np.array([0.0, 0.0, 0.4]), model)
    q = np.ascontiguousarray(0.5 * (P + np.roll(P, -1, axis=0)))  # each edge's middle
    chain = np.array([0, 0, 1, 1])
    refine(q, chain, model, np.eye(3), np.array([0.0, 0.0, 0.4]), 750.0, 2)
    image = np.zeros((8, 8, 3), np.uint8)  # (all inside the mask: no pixel is tested)
    image.flags.writeable = False  # (as the extractor passes frames)
    _outside_marker(image, np.ones((8, 8), np.bool_), 0, 0, np.zeros(256), np.zeros(8), 0.0)
