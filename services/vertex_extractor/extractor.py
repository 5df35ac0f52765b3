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

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from services.vertex_extractor.colour import ColourModel
from services.vertex_extractor.lines import Line, best_split, huber_fit, intersect, moment_rows


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
        small = self.params.colour.mask(np.ascontiguousarray(image[s // 2::s, s // 2::s]))
        count = int(np.count_nonzero(small))
        if count == 0:
            return "no marker-coloured pixels"
        if count > 0.5 * small.size:
            return "most of the frame is marker-coloured"
        _, _, stats, _ = cv2.connectedComponentsWithStats(small, connectivity=8)
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

    def _extract_in(self, image: np.ndarray, box: tuple[int, int, int, int], tracked: bool,
                    separate_blobs: bool = False) -> Detection:
        """Scan the box. Fast path: the colour mask's columns directly; if that gives no
        plausible rhombus (another marker-coloured thing in the box), again on the largest
        connected blob only."""
        p = self.params
        H, W = image.shape[:2]
        x0, y0, x1, y1 = box
        roi = np.ascontiguousarray(image[y0:y1, x0:x1])  # OpenCV is slow on strided views
        mask = p.colour.mask(roi)
        if separate_blobs:
            n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
            if n < 2:
                return _miss("no marker-coloured pixels", tracked)
            best = int(np.argmax(stats[1:, cv2.CC_STAT_AREA])) + 1
            mask = (labels == best).view(np.uint8)
        has = mask.any(0)
        area = int(np.count_nonzero(mask))
        if area == 0:
            return _miss("no marker-coloured pixels", tracked)
        if area < p.min_area_px:
            return _miss(f"marker too small ({area} px < {p.min_area_px:.0f} px)", tracked)
        top = np.argmax(mask, 0)
        bottom = mask.shape[0] - 1 - np.argmax(mask[::-1], 0)
        xs = np.flatnonzero(has)
        bx0, bx1 = int(xs[0]), int(xs[-1])
        by0, by1 = int(top[has].min()), int(bottom[has].max())
        if bx0 + x0 <= 0 or by0 + y0 <= 0 or bx1 + x0 >= W - 1 or by1 + y0 >= H - 1:
            return _miss("marker touches the image border", tracked)
        w = p.window
        rh, rw = mask.shape
        if bx0 < 1 or by0 < w + 2 or bx1 > rw - 2 or by1 > rh - w - 3:
            # the blob reaches the box edge: the box was too tight, look at the whole frame
            if box != (0, 0, W, H):
                return self._extract_in(image, (0, 0, W, H), tracked, separate_blobs)
            return _miss("marker touches the image border", tracked)
        chord = np.where(has, bottom - top + 1, 0)
        seed = int(np.argmax(chord))
        # Table 1: walk right and left from the seed column until a chord < MIN_LEN.
        short = chord < p.min_len_px
        right_stop = np.flatnonzero(short[seed:])
        left_stop = np.flatnonzero(short[:seed + 1][::-1])
        hi = seed + (int(right_stop[0]) if right_stop.size else rw - seed)
        lo = seed - (int(left_stop[0]) if left_stop.size else seed + 1) + 1
        cols = np.arange(lo, hi, p.dx)
        if cols.size < 2 * p.min_points_per_edge + 4:
            return _miss(f"marker too small ({cols.size} usable columns)", tracked)
        det = self._edges_and_fit(roi, cols, top[cols], bottom[cols], area, (x0, y0), (W, H),
                                  tracked)
        if not det.found and not separate_blobs and det.reason.startswith(_RETRYABLE):
            return self._extract_in(image, box, tracked, separate_blobs=True)
        return det

    def _edges_and_fit(self, roi: np.ndarray, cols: np.ndarray, top: np.ndarray,
                       bottom: np.ndarray, blob_area: int, offset: tuple[int, int],
                       size: tuple[int, int], tracked: bool) -> Detection:
        p = self.params
        w = p.window
        # levels: chord middles inside, just beyond each window outside
        s_in = float(_score(roi[(top + bottom) // 2, cols]).mean())
        outside = _score(np.concatenate([roi[top - w - 2, cols], roi[bottom + w + 2, cols]]))
        s_out = float(np.partition(outside, len(outside) // 2)[len(outside) // 2])  # median
        if s_in - s_out < 20.0:
            return _miss(f"marker contrast too low ({s_in - s_out:.0f} grey levels)", tracked)
        inv = 1.0 / (s_in - s_out)
        offs = np.arange(-w, w)[:, None]
        cu = np.clip((_score(roi[top + offs, cols]) - s_out) * inv, -0.5, 1.5)
        cd = np.clip((_score(roi[bottom + 1 + offs, cols]) - s_out) * inv, -0.5, 1.5)
        # sum of coverages over a window across the edge = distance from its inner end
        x = cols.astype(np.float64) + offset[0]
        u_pts = np.column_stack([x, (top + w - 0.5) - cu.sum(0) + offset[1]])
        d_pts = np.column_stack([x, (bottom - w + 0.5) + cd.sum(0) + offset[1]])
        return self._fit(u_pts, d_pts, blob_area, size, tracked)

    def _fit(self, u_pts: np.ndarray, d_pts: np.ndarray, blob_area: int,
             size: tuple[int, int], tracked: bool) -> Detection:
        p = self.params
        lines: list[Line] = []
        sq_sum, n_in = 0.0, 0
        for pts in (u_pts, d_pts):
            centre = pts.mean(0)
            local = pts - centre  # moments about the centre keep the sums well conditioned
            k = best_split(moment_rows(local), p.min_points_per_edge)
            drop = 2  # the columns at the split: their window straddles the vertex
            for part in (local[:max(k - drop, 0)], local[k + drop:]):
                if len(part) < p.min_points_per_edge:
                    return _miss("too few edge points on one side (partly hidden?)", tracked)
                line, r2 = huber_fit(part)
                sq_sum += r2.sum()
                n_in += len(r2)
                lines.append((line[0], line[1], line[2] + line[0] * centre[0]
                              + line[1] * centre[1]))
        lu, ru, ld, rd = lines
        corners = [intersect(lu, ld), intersect(lu, ru), intersect(ru, rd), intersect(ld, rd)]
        if any(c is None for c in corners):
            return _miss("parallel edges: not a rhombus", tracked)
        v = np.array(corners)
        residual = math.sqrt(sq_sum / n_in)
        reason, area = _implausible(v, residual, blob_area, size, p)
        if reason:
            return _miss(reason, tracked)
        return Detection(True, v, min(area / (size[0] * size[1]), 1.0), residual, "",
                         tracked, (u_pts, d_pts))


#: failures that another marker-coloured blob inside the box can cause
_RETRYABLE = ("edges are not straight", "quadrilateral area", "the four lines",
              "implausible corner", "edge points do not", "too few edge points",
              "a vertex falls outside")


def _score(pixels: np.ndarray) -> np.ndarray:
    """(R + B) / 2 - G of BGR pixels (..., 3), float32: linear in the marker's coverage."""
    f = pixels.astype(np.float32)
    return 0.5 * (f[..., 0] + f[..., 2]) - f[..., 1]


def _implausible(v: np.ndarray, residual: float, blob_area: int, size: tuple[int, int],
                 p: ExtractorParams) -> tuple[str, float]:
    """Why the quadrilateral v (left, top, right, bottom) is not the marker ('' if it is),
    and its area (px²)."""
    W, H = size
    if not np.all(np.isfinite(v)):
        return "vertices not finite", 0.0
    if v[:, 0].min() < -0.5 or v[:, 1].min() < -0.5 or v[:, 0].max() > W - 0.5 or \
            v[:, 1].max() > H - 0.5:
        return "a vertex falls outside the image (marker cut by the border)", 0.0
    e = v[[1, 2, 3, 0]] - v  # edge i: vertex i -> i + 1
    nxt = e[[1, 2, 3, 0]]
    cross = e[:, 0] * nxt[:, 1] - e[:, 1] * nxt[:, 0]
    if not (np.all(cross > 0) or np.all(cross < 0)):
        return "the four lines do not make a convex quadrilateral", 0.0
    prev = e[[3, 0, 1, 2]]  # edge arriving at vertex i
    cosang = -(prev * e).sum(1) / (np.hypot(*prev.T) * np.hypot(*e.T))
    angles = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
    if angles.min() < p.min_angle_deg or angles.max() > 180 - p.min_angle_deg:
        return f"implausible corner angles {np.round(angles).astype(int).tolist()} deg", 0.0
    if residual > p.max_residual_px:
        return f"edges are not straight (residual {residual:.2f} px): partly hidden?", 0.0
    area = 0.5 * abs(float(v[:, 0] @ v[[1, 2, 3, 0], 1] - v[:, 1] @ v[[1, 2, 3, 0], 0]))
    if abs(area - blob_area) > 0.15 * area + 2 * math.sqrt(area):
        return (f"quadrilateral area {area:.0f} px does not match the blob's {blob_area} px "
                "(partly hidden?)"), area
    return "", area
