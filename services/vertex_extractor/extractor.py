"""Rhombus vertices from one frame: the paper's scan-line method (section 4.1), sub-pixel.

The paper (Table 1) walks from a seed pixel column by column, Δx apart, collecting for each
column the upper and lower edge points U_k and D_k until a column is shorter than MIN_LEN; then
(Table 2) assigns the U points to two lines (left and right of the top vertex) and likewise the
D points, fits each by least squares, and intersects the four lines into the vertices.

Where we depart from the paper, keeping its spirit:
- The seed is the previous frame's marker when tracking; otherwise a coarse 1-in-8 pixel grid
  search finds it without converting the whole frame.
- Columns are those of the seed's connected colour blob, found in one vectorised pass over a
  region of interest (equivalent to Table 1's walk for a convex blob, far faster in numpy).
- Edge points are sub-pixel: the colour score is linear in the marker's coverage of a pixel,
  so the sum of coverages over a window across the edge gives the edge position exactly on
  area-sampled images.
- Table 2's greedy, order-dependent assignment is replaced by the optimal split (least total
  residual over all split points, from prefix moments) and total-least-squares fits with
  robust outlier rejection; columns at the split are dropped (their window straddles a vertex).
- A plausibility check (convex, sensible angles, enough points per edge, small residual, area
  consistent with the blob) turns anything else into ``found = False`` with a reason.

Limits: one marker per frame (two similar blobs on a cold search are refused as ambiguous);
the marker's horizontal diagonal must be the wider one within about 35 degrees of roll.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from services.vertex_extractor.colour import ColourModel
from services.vertex_extractor.lines import best_split, distances, intersect, robust_fit


@dataclass(frozen=True)
class ExtractorParams:
    colour: ColourModel = field(default_factory=ColourModel)
    dx: int = 1                  # Δx, column step (px)
    min_len_px: int = 12         # MIN_LEN: shortest column chord used (px)
    window: int = 5              # sub-pixel window: rows each side of the edge
    coarse_step: int = 8         # grid step of the cold search (px)
    min_area_px: float = 200.0   # smaller markers are refused as too small
    max_residual_px: float = 0.8
    min_points_per_edge: int = 4
    roi_margin_px: int = 16
    min_angle_deg: float = 25.0


@dataclass(frozen=True)
class Detection:
    """Result for one frame. Vertices (4, 2) px, left, top, right, bottom, if found."""

    found: bool
    vertices_px: np.ndarray | None = None
    area_ratio: float = 0.0
    residual_px: float = 0.0
    reason: str = ""
    tracked: bool = False
    edge_points: tuple[np.ndarray, np.ndarray] | None = None  # U and D points (for plots)


def _miss(reason: str, tracked: bool = False) -> Detection:
    return Detection(False, reason=reason, tracked=tracked)


class RhombusExtractor:
    """Stateful extractor: remembers the last marker to seed the next frame (tracking)."""

    def __init__(self, params: ExtractorParams | None = None) -> None:
        self.params = params or ExtractorParams()
        self._last_box: tuple[int, int, int, int] | None = None

    def reset(self) -> None:
        self._last_box = None

    def extract(self, image: np.ndarray) -> Detection:
        """Find the rhombus in an H x W x 3 uint8 BGR image."""
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            return _miss(f"expected an H x W x 3 uint8 BGR image, got shape {image.shape} "
                         f"{image.dtype}")
        if self._last_box is not None:
            det = self._extract_in(image, self._last_box, tracked=True)
            if det.found:
                self._remember(det, image.shape)
                return det
        box_or_reason = self._coarse_search(image)
        if isinstance(box_or_reason, str):
            self._last_box = None
            return _miss(box_or_reason)
        det = self._extract_in(image, box_or_reason, tracked=False)
        if det.found:
            self._remember(det, image.shape)
        else:
            self._last_box = None
        return det

    def _remember(self, det: Detection, shape: tuple[int, ...]) -> None:
        v = det.vertices_px
        assert v is not None
        m = self.params.roi_margin_px + 0.15 * float(np.ptp(v[:, 0]))
        lo, hi = v.min(0) - m, v.max(0) + m
        self._last_box = (max(int(lo[0]), 0), max(int(lo[1]), 0),
                          min(int(hi[0]) + 1, shape[1]), min(int(hi[1]) + 1, shape[0]))

    def _coarse_search(self, image: np.ndarray) -> tuple[int, int, int, int] | str:
        s = self.params.coarse_step
        small = self.params.colour.mask(image[s // 2::s, s // 2::s])
        count = int(small.sum())
        if count == 0:
            return "no marker-coloured pixels"
        if count > 0.5 * small.size:
            return "most of the frame is marker-coloured"
        _, _, stats, _ = cv2.connectedComponentsWithStats(small.view(np.uint8), connectivity=8)
        areas = stats[1:, cv2.CC_STAT_AREA]
        order = np.argsort(areas)[::-1]
        best = order[0] + 1
        if len(order) > 1 and areas[order[1]] >= max(3, 0.4 * areas[order[0]]):
            return "two or more marker-coloured blobs of similar size (ambiguous)"
        x, y, w, h = stats[best, :4]
        m = s + self.params.roi_margin_px
        H, W = image.shape[:2]
        x0, y0 = max(s // 2 + x * s - m, 0), max(s // 2 + y * s - m, 0)
        x1, y1 = min(s // 2 + (x + w) * s + m, W), min(s // 2 + (y + h) * s + m, H)
        return int(x0), int(y0), int(x1), int(y1)

    def _extract_in(self, image: np.ndarray, box: tuple[int, int, int, int],
                    tracked: bool) -> Detection:
        p = self.params
        H, W = image.shape[:2]
        x0, y0, x1, y1 = box
        roi = image[y0:y1, x0:x1]
        mask = p.colour.mask(roi)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.view(np.uint8),
                                                               connectivity=8)
        if n < 2:
            return _miss("no marker-coloured pixels", tracked)
        best = int(np.argmax(stats[1:, cv2.CC_STAT_AREA])) + 1
        bx, by, bw, bh, area = (int(v) for v in stats[best])
        if area < p.min_area_px:
            return _miss(f"marker too small ({area} px < {p.min_area_px:.0f} px)", tracked)
        if bx + x0 <= 0 or by + y0 <= 0 or bx + bw + x0 >= W or by + bh + y0 >= H:
            return _miss("marker touches the image border", tracked)
        w = p.window
        if bx < w + 1 or by < w + 1 or bx + bw > mask.shape[1] - w - 1 or \
                by + bh > mask.shape[0] - w - 1:
            # blob reaches the ROI edge: the box was too tight; retry on the whole frame once
            if (x0, y0, x1, y1) != (0, 0, W, H) and tracked:
                return self._extract_in(image, (0, 0, W, H), tracked)
            return _miss("marker touches the image border", tracked)
        blob = labels[by:by + bh, bx:bx + bw] == best
        has = blob.any(0)
        top = np.argmax(blob, 0)
        bottom = bh - 1 - np.argmax(blob[::-1], 0)
        chord = np.where(has, bottom - top + 1, 0)
        seed = int(np.argmax(chord))
        # Table 1: walk right and left from the seed column until a chord < MIN_LEN.
        short = chord < p.min_len_px
        right_stop = np.flatnonzero(short[seed:])
        left_stop = np.flatnonzero(short[:seed + 1][::-1])
        hi = seed + (int(right_stop[0]) if right_stop.size else bw - seed)
        lo = seed - (int(left_stop[0]) if left_stop.size else seed + 1) + 1
        cols = np.arange(lo, hi, p.dx)
        if cols.size < 2 * p.min_points_per_edge:
            return _miss(f"marker too small ({cols.size} usable columns)", tracked)
        score = ColourModel.score(roi)
        s_in, s_out = _levels(score, mask, labels == best)
        if s_in - s_out < 20.0:
            return _miss(f"marker contrast too low ({s_in - s_out:.0f} grey levels)", tracked)
        u_pts, d_pts = _subpixel_edges(score, cols, top[cols] + by, bottom[cols] + by, bx, w,
                                       s_in, s_out)
        u_pts += [x0, y0]
        d_pts += [x0, y0]
        return self._fit(u_pts, d_pts, area, (W, H), tracked)

    def _fit(self, u_pts: np.ndarray, d_pts: np.ndarray, blob_area: int,
             size: tuple[int, int], tracked: bool) -> Detection:
        p = self.params
        lines = []
        inliers = []
        for pts in (u_pts, d_pts):
            k = best_split(pts, p.min_points_per_edge)
            # drop the columns at the split: their window straddles the vertex
            drop = 2
            left, right = pts[:max(k - drop, 0)], pts[k + drop:]
            if len(left) < p.min_points_per_edge or len(right) < p.min_points_per_edge:
                return _miss("too few edge points on one side (partly hidden?)", tracked)
            for part in (left, right):
                line, keep = robust_fit(part)
                if keep.sum() < p.min_points_per_edge:
                    return _miss("edge points do not lie on a line (partly hidden?)", tracked)
                lines.append(line)
                inliers.append(distances(part[keep], line))
        lu, ru, ld, rd = lines
        corners = [intersect(lu, ld), intersect(lu, ru), intersect(ru, rd), intersect(ld, rd)]
        if any(c is None for c in corners):
            return _miss("parallel edges: not a rhombus", tracked)
        v = np.array(corners)
        residual = float(np.sqrt(np.mean(np.concatenate(inliers) ** 2)))
        reason = _implausible(v, residual, blob_area, size, p)
        if reason:
            return _miss(reason, tracked)
        x, y = v[:, 0], v[:, 1]
        area = 0.5 * abs(float(x @ np.roll(y, -1) - y @ np.roll(x, -1)))
        return Detection(True, v, min(area / (size[0] * size[1]), 1.0), residual, "",
                         tracked, (u_pts, d_pts))


def _levels(score: np.ndarray, mask: np.ndarray, blob: np.ndarray) -> tuple[float, float]:
    """Inside and outside score levels: the blob's eroded interior and a ring around it."""
    k = np.ones((3, 3), np.uint8)
    b8 = blob.view(np.uint8)
    inner = cv2.erode(b8, k, iterations=2).view(bool)
    ring = cv2.dilate(b8, k, iterations=6).view(bool) & ~cv2.dilate(b8, k, iterations=3).view(
        bool)
    s_in = float(np.median(score[inner])) if inner.any() else float(score[blob].max())
    s_out = float(np.median(score[ring & ~mask])) if (ring & ~mask).any() else 0.0
    return s_in, s_out


def _subpixel_edges(score: np.ndarray, cols: np.ndarray, top: np.ndarray, bottom: np.ndarray,
                    bx: int, w: int, s_in: float, s_out: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel upper and lower edge points of the given blob columns (ROI pixels).

    Over a window of 2w rows across an edge, the marker's coverage sums to the distance from
    the window's inner end to the edge: y_top = (t + w - 0.5) - sum c_i, where
    c_i = (s_i - s_out) / (s_in - s_out) is each pixel's coverage.
    """
    x = cols + bx
    offs = np.arange(-w, w)
    inv = 1.0 / (s_in - s_out)
    cu = np.clip((score[top[None, :] + offs[:, None], x[None, :]] - s_out) * inv, -0.5, 1.5)
    y_top = (top + w - 0.5) - cu.sum(0)
    offs_d = np.arange(-w + 1, w + 1)
    cd = np.clip((score[bottom[None, :] + offs_d[:, None], x[None, :]] - s_out) * inv, -0.5,
                 1.5)
    y_bot = (bottom - w + 0.5) + cd.sum(0)
    xf = x.astype(np.float64)
    return np.column_stack([xf, y_top]), np.column_stack([xf, y_bot])


def _implausible(v: np.ndarray, residual: float, blob_area: int, size: tuple[int, int],
                 p: ExtractorParams) -> str:
    if not np.all(np.isfinite(v)):
        return "vertices not finite"
    W, H = size
    if np.any(v < -0.5) or np.any(v > [W - 0.5, H - 0.5]):
        return "a vertex falls outside the image (marker cut by the border)"
    e = np.roll(v, -1, axis=0) - v
    cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    if not (np.all(cross > 0) or np.all(cross < 0)):
        return "the four lines do not make a convex quadrilateral"
    a, b = -e, np.roll(e, 1, axis=0)  # edges meeting at each vertex
    cosang = (a * b).sum(1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    angles = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
    if np.any(angles < p.min_angle_deg) or np.any(angles > 180 - p.min_angle_deg):
        return f"implausible corner angles {np.round(angles).astype(int).tolist()} deg"
    if residual > p.max_residual_px:
        return f"edges are not straight (residual {residual:.2f} px): partly hidden?"
    x, y = v[:, 0], v[:, 1]
    area = 0.5 * abs(float(x @ np.roll(y, -1) - y @ np.roll(x, -1)))
    if abs(area - blob_area) > 0.15 * area + 2 * np.sqrt(area):
        return (f"quadrilateral area {area:.0f} px does not match the blob's {blob_area} px "
                "(partly hidden?)")
    return ""
