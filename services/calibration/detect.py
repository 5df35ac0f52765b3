"""Finding calibration target points in images.

- :func:`detect_grid`: the paper's pattern (section 3): straight lines by the classical Hough
  transform (OpenCV), split into two families of nine, refined to sub-pixel precision on the
  line's own pixels (darkness centroids across the line), and intersected. Lens distortion
  bends the lines, so each intersection comes from *local* line fits within about a pitch of
  it (piecewise straight), not from one line per family.
- :func:`detect_squares`: Zhang's board of separate squares: each square's four edges are
  located to sub-pixel precision and intersected; 256 corners in Zhang's order.
- :func:`detect_chessboard`: OpenCV's findChessboardCorners + cornerSubPix.

Each raises :class:`DetectionError` with the reason when the pattern is not found.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from services.calibration.pattern import PatternSpec


class DetectionError(ValueError):
    """The pattern was not found in an image; the message says why."""


def _grey(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def detect(image: np.ndarray, spec: PatternSpec) -> np.ndarray:
    """(N, 2) pixel points in the order of ``spec.model_points()``."""
    grey = _grey(image)
    if spec.kind == "grid":
        return detect_grid(grey, spec.rows, spec.cols)
    if spec.kind == "squares":
        return detect_squares(grey, spec.rows, spec.cols)
    return detect_chessboard(grey, spec.cols, spec.rows)


# -- chessboard ------------------------------------------------------------------------------

def detect_chessboard(grey: np.ndarray, cols: int, rows: int) -> np.ndarray:
    found, corners = cv2.findChessboardCorners(grey, (cols, rows))
    if not found:
        raise DetectionError(f"no {cols}x{rows} chessboard found")
    corners = cv2.cornerSubPix(grey, corners, (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.1))
    return corners.reshape(-1, 2).astype(np.float64)


# -- the paper's grid --------------------------------------------------------------------------

def _line_families(grey: np.ndarray, n_rows: int, n_cols: int
                   ) -> tuple[list[tuple[float, float]], list[tuple[float, float]], float]:
    """Coarse (rho, theta) of the row lines and the column lines, and the line width (px)."""
    # The lines are thin dark strips: a black-hat brings them out, whatever the lighting.
    H, W = grey.shape
    k = max(9, int(0.03 * min(H, W)) | 1)
    strips = cv2.morphologyEx(grey, cv2.MORPH_BLACKHAT,
                              cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    _, binary = cv2.threshold(strips, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    dist = cv2.distanceTransform(binary, cv2.DIST_L2, 3)
    width = max(2.0, 2.0 * float(np.percentile(dist[dist > 0], 95))) if np.any(dist) else 3.0
    # Thin the strips to their centre ridge (local maxima of the distance transform): a
    # line slightly off a strip's direction then collects few votes, the strip's own line
    # all of them.
    ridge = ((dist >= cv2.dilate(dist, np.ones((3, 3), np.uint8)) - 1e-3) & (dist >= 1.0)
             ).astype(np.uint8) * 255
    acc = cv2.HoughLinesWithAccumulator(ridge, 1, np.pi / 360,
                                        threshold=max(20, int(0.05 * min(H, W))))
    if acc is None or len(acc) < n_rows + n_cols:
        raise DetectionError(f"Hough found {0 if acc is None else len(acc)} lines, "
                             f"need at least {n_rows + n_cols}")
    acc = acc.reshape(-1, 3).astype(np.float64)
    # The strongest lines (real ones collect votes along their whole length) give the two
    # directions; diagonals through the crossings are far from both.
    strong = acc[acc[:, 2] >= 0.5 * acc[:, 2].max()]
    if len(strong) < 2:
        raise DetectionError("no dominant line directions")
    feats = np.column_stack([np.cos(2 * strong[:, 1]), np.sin(2 * strong[:, 1])]).astype(
        np.float32)
    _, _, centres = cv2.kmeans(feats, 2, None, (cv2.TERM_CRITERIA_EPS +
                                                cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4),
                               5, cv2.KMEANS_PP_CENTERS)
    dirs = 0.5 * np.arctan2(centres[:, 1], centres[:, 0])
    ys, xs = np.nonzero(binary)
    cx, cy = float(xs.mean()), float(ys.mean())
    sep = 3.0 * width + 4.0
    out = []
    for phi in dirs:
        n_expect = n_rows if abs(math.sin(phi)) > abs(math.cos(phi)) else n_cols
        rho, theta, votes = acc[:, 0].copy(), acc[:, 1].copy(), acc[:, 2]
        d = (theta - phi + np.pi / 2) % np.pi - np.pi / 2  # angle to the family, wrapped
        keep = np.abs(d) < np.radians(15)
        flip = keep & (np.abs(theta - phi) > np.pi / 2)
        rho[flip] = -rho[flip]
        theta = phi + d
        # signed distance from the pattern's centre: peaks of one thick line share it
        pos = rho - (cx * np.cos(theta) + cy * np.sin(theta))
        idx = np.flatnonzero(keep)
        idx = idx[np.argsort(-votes[idx])]
        accepted: list[int] = []
        top = votes[idx[0]] if len(idx) else 0.0
        for i in idx:  # greedy non-maximum suppression along the family
            if votes[i] < 0.2 * top or len(accepted) >= n_expect + 3:
                break
            if all(abs(pos[i] - pos[j]) > sep for j in accepted):
                accepted.append(int(i))
        accepted.sort(key=lambda i: pos[i])
        if len(accepted) < n_expect:
            raise DetectionError(f"found {len(accepted)} lines in one direction, need "
                                 f"{n_expect}")
        if len(accepted) > n_expect:  # extra lines (page edge, scale bar): most regular run
            best, best_cost = 0, math.inf
            for s in range(len(accepted) - n_expect + 1):
                r = np.diff([pos[i] for i in accepted[s:s + n_expect]])
                cost = float(np.std(np.diff(r)) / np.mean(r))
                if cost < best_cost:
                    best, best_cost = s, cost
            accepted = accepted[best:best + n_expect]
        out.append((phi, [(float(rho[i]), float(theta[i])) for i in accepted]))
    (phi_a, a), (_, b) = out
    rows, cols = (a, b) if abs(math.sin(phi_a)) > abs(math.cos(phi_a)) else (b, a)
    return rows, cols, width


def _intersect_rt(l1: tuple[float, float], l2: tuple[float, float]) -> np.ndarray:
    A = np.array([[math.cos(l1[1]), math.sin(l1[1])], [math.cos(l2[1]), math.sin(l2[1])]])
    if abs(np.linalg.det(A)) < 1e-9:
        raise DetectionError("a row line and a column line of the grid are parallel: the two "
                             "line families were not told apart (is the whole grid in view?)")
    return np.linalg.solve(A, [l1[0], l2[0]])


def _centre_samples(grey: np.ndarray, p0: np.ndarray, d: np.ndarray, n: np.ndarray,
                    ts: np.ndarray, half: float, width: float) -> np.ndarray:
    """Sub-pixel line centres: darkness-weighted centroid across the line at each t; a wide
    window finds the line, a narrow one (the line and a margin) measures it. Samples whose
    window does not end on white paper on both sides (the sheet's edge, clutter) are
    dropped."""
    pts = p0 + ts[:, None] * d
    keep = np.ones(len(ts), bool)
    for h in (half, 0.5 * width + 2.5):
        offs = np.arange(-h, h + 0.25, 0.25)
        grid = pts[:, None, :] + offs[None, :, None] * n
        prof = cv2.remap(grey, grid[..., 0].astype(np.float32), grid[..., 1].astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        white = np.maximum(prof[:, :3].mean(1), prof[:, -3:].mean(1))[:, None]
        keep &= np.minimum(prof[:, :3].mean(1), prof[:, -3:].mean(1)) > 0.85 * white[:, 0]
        dark = np.clip(white - prof, 0, None)
        mass = dark.sum(1)
        shift = (dark * offs).sum(1) / np.maximum(mass, 1e-9)
        pts = pts + shift[:, None] * n
    keep &= mass > 0.25 * np.median(mass)
    return pts[keep]


def detect_grid(grey: np.ndarray, n_rows: int = 9, n_cols: int = 9) -> np.ndarray:
    """(n_rows * n_cols, 2) sub-pixel intersections, row-major, rows top to bottom."""
    grey = _grey(grey)
    rows, cols, width = _line_families(grey, n_rows, n_cols)
    g = grey.astype(np.float32)
    H, W = grey.shape
    coarse = np.array([[_intersect_rt(r, c) for c in cols] for r in rows])  # (R, C, 2)
    if np.any(coarse < 2) or np.any(coarse[..., 0] > W - 3) or np.any(coarse[..., 1] > H - 3):
        raise DetectionError("grid not entirely inside the image")
    # order: rows top to bottom, columns left to right
    coarse = coarse[np.argsort(coarse[:, :, 1].mean(1))][:, np.argsort(coarse[:, :, 0].mean(0))]
    half = 1.5 * width + 3
    local_fits: dict[tuple[str, int], list[tuple[np.ndarray, np.ndarray]]] = {}
    for kind, count in (("row", n_rows), ("col", n_cols)):
        for i in range(count):
            xs = coarse[i] if kind == "row" else coarse[:, i]  # its intersections, in order
            d = xs[-1] - xs[0]
            d /= np.linalg.norm(d)
            n = np.array([-d[1], d[0]])
            p0 = xs[0]
            tj = (xs - p0) @ d
            gaps = np.diff(tj)  # local spacing varies with perspective
            ts = np.arange(tj[0] - 0.4 * gaps[0], tj[-1] + 0.4 * gaps[-1], 1.0)
            excl = width / 2 + 3
            ts = ts[np.min(np.abs(ts[:, None] - tj[None, :]), axis=1) > excl]
            if not len(ts):
                raise DetectionError(f"{kind} {i}: lines too close together to measure")
            pts = _centre_samples(g, p0, d, n, ts, half, width)
            tp = (pts - p0) @ d
            local = np.minimum(np.concatenate([[gaps[0]], gaps]),
                               np.concatenate([gaps, [gaps[-1]]]))
            fits = []
            for t, spacing in zip(tj, local, strict=True):
                sel = pts[np.abs(tp - t) < 0.75 * spacing]
                if len(sel) < 6:
                    raise DetectionError(f"{kind} {i}: too few line pixels near an "
                                         "intersection (occluded or out of focus?)")
                vx, vy, x0, y0 = cv2.fitLine(sel.astype(np.float32), cv2.DIST_L2, 0, 1e-3,
                                             1e-3).ravel()
                fits.append((np.array([x0, y0], float), np.array([vx, vy], float)))
            local_fits[(kind, i)] = fits
    out = np.empty((n_rows, n_cols, 2))
    for r in range(n_rows):
        for c in range(n_cols):
            (p, u), (q, v) = local_fits[("row", r)][c], local_fits[("col", c)][r]
            A = np.column_stack([u, -v])
            s = np.linalg.solve(A, q - p)
            out[r, c] = p + s[0] * u
    return out.reshape(-1, 2)


# -- Zhang's squares ---------------------------------------------------------------------------

def detect_squares(grey: np.ndarray, n_rows: int = 8, n_cols: int = 8) -> np.ndarray:
    """(n_rows * n_cols * 4, 2) square corners in Zhang's order (see PatternSpec)."""
    grey = _grey(grey)
    _, binary = cv2.threshold(cv2.GaussianBlur(grey, (3, 3), 0), 0, 255,
                              cv2.THRESH_BINARY_INV + cv2.THRESH_OTSU)
    contours, _ = cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
    quads = []
    for c in contours:
        area = cv2.contourArea(c)
        if area < 50:
            continue
        approx = cv2.approxPolyDP(c, 0.08 * cv2.arcLength(c, True), True)
        if len(approx) == 4 and cv2.isContourConvex(approx):
            quads.append(approx.reshape(4, 2).astype(np.float64))
    n = n_rows * n_cols
    if len(quads) < n:
        raise DetectionError(f"found {len(quads)} squares, need {n}")
    areas = np.array([cv2.contourArea(q.astype(np.float32)) for q in quads])
    med = np.median(np.sort(areas)[-n:])
    quads = [q for q, a in zip(quads, areas, strict=True) if 0.3 * med < a < 3 * med]
    if len(quads) != n:
        raise DetectionError(f"found {len(quads)} similar squares, need {n}")
    centres = np.array([q.mean(0) for q in quads])
    x, y = centres[:, 0], centres[:, 1]
    # bottom-left square is row 0, column 0 (Zhang's Model.txt: rows go up the image)
    corners_img = np.array([centres[np.argmax(y - x)], centres[np.argmax(x + y)],
                            centres[np.argmax(x - y)], centres[np.argmin(x + y)]])
    grid = np.array([[0, 0], [n_cols - 1, 0], [n_cols - 1, n_rows - 1], [0, n_rows - 1]],
                    np.float64)
    Hg = cv2.getPerspectiveTransform(corners_img.astype(np.float32), grid.astype(np.float32))
    gc = cv2.perspectiveTransform(centres.reshape(-1, 1, 2), Hg).reshape(-1, 2)
    idx = np.round(gc).astype(int)
    if np.abs(gc - idx).max() > 0.3 or len({tuple(i) for i in idx}) != n:
        raise DetectionError("squares do not form a regular grid")
    out = np.empty((n_rows, n_cols, 4, 2))
    g = grey.astype(np.float32)
    for q, (c, r) in zip(quads, idx, strict=True):
        # the square's corners in grid terms: u right, v up the image
        local = cv2.perspectiveTransform(q.reshape(-1, 1, 2), Hg).reshape(-1, 2) - (c, r)
        order = [int(np.argmin(-local[:, 1] + local[:, 0] * 0 + (local[:, 0] > 0) * 10)),
                 0, 0, 0]
        tl = int(np.argmax(local[:, 1] - local[:, 0]))   # up and left
        tr = int(np.argmax(local[:, 1] + local[:, 0]))
        br = int(np.argmax(-local[:, 1] + local[:, 0]))
        bl = int(np.argmax(-local[:, 1] - local[:, 0]))
        order = [tl, tr, br, bl]
        if len(set(order)) != 4:
            raise DetectionError("a square's corners are ambiguous")
        out[r, c] = _refine_square(g, q[order])
    return out.reshape(-1, 2)


def _refine_square(g: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Sub-pixel corners of a dark square: fit each edge on its own pixels, intersect."""
    lines = []
    centre = corners.mean(0)
    for i in range(4):
        a, b = corners[i], corners[(i + 1) % 4]
        d = (b - a) / np.linalg.norm(b - a)
        n = np.array([-d[1], d[0]])
        if (centre - a) @ n > 0:  # normal points out of the square
            n = -n
        length = float(np.linalg.norm(b - a))
        ts = np.arange(0.15 * length, 0.85 * length, 0.5)
        offs = np.arange(-4.0, 4.01, 0.25)
        grid = a + ts[:, None, None] * d + offs[None, :, None] * n
        prof = cv2.remap(g, grid[..., 0].astype(np.float32), grid[..., 1].astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        # edge = centroid of the intensity gradient across it (dark inside, bright outside)
        grad = np.clip(np.diff(prof, axis=1), 0, None)
        mid = 0.5 * (offs[1:] + offs[:-1])
        edge = (grad * mid).sum(1) / np.maximum(grad.sum(1), 1e-9)
        pts = a + ts[:, None] * d + edge[:, None] * n
        vx, vy, x0, y0 = cv2.fitLine(pts.astype(np.float32), cv2.DIST_HUBER, 0, 1e-3,
                                     1e-3).ravel()
        lines.append((np.array([x0, y0], float), np.array([vx, vy], float)))
    out = np.empty((4, 2))
    for i in range(4):
        (p, u), (q, v) = lines[i - 1], lines[i]
        s = np.linalg.solve(np.column_stack([u, -v]), q - p)
        out[i] = p + s[0] * u
    return out
