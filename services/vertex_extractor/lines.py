"""The optimal two-line split (from prefix moments), robust line fits, intersections.

A line is ``(nx, ny, d)`` with unit normal (nx, ny): points (x, y) on it satisfy
nx x + ny y = d (pixels). The best split of an ordered point list is one cumulative sum of
moments; each side is then fitted by OpenCV's Huber-weighted total least squares.
"""

from __future__ import annotations

import cv2
import numpy as np

Line = tuple[float, float, float]


def moment_rows(points: np.ndarray) -> np.ndarray:
    """(N, 6) rows 1, x, y, x², y², xy of (N, 2) points (centre them first: numerical range)."""
    x, y = points[:, 0], points[:, 1]
    return np.column_stack([np.ones_like(x), x, y, x * x, y * y, x * y])


def best_split(rows: np.ndarray, min_points: int = 3) -> int:
    """Index k splitting ordered points (as moment rows) into two lines [:k] and [k:] with the
    least total TLS residual: the optimal version of the paper's greedy Table 2."""
    total = rows.sum(0)
    pre = np.cumsum(rows, axis=0)
    ks = np.arange(min_points, len(rows) - min_points + 1)
    left = pre[ks - 1]
    right = total - left
    return int(ks[np.argmin(_sse(left) + _sse(right))])


def _sse(s: np.ndarray) -> np.ndarray:
    n = s[:, 0]
    a = s[:, 3] - s[:, 1] ** 2 / n
    c = s[:, 4] - s[:, 2] ** 2 / n
    b = s[:, 5] - s[:, 1] * s[:, 2] / n
    return 0.5 * (a + c) - np.sqrt(np.maximum(0.25 * (a - c) ** 2 + b * b, 0.0))


def huber_fit(points: np.ndarray) -> tuple[Line, np.ndarray]:
    """Robust TLS line (OpenCV's fitLine with a Huber loss) and the squared distances of the
    inliers (within 3 robust sigmas, at least 0.25 px) for the residual figure."""
    vx, vy, x0, y0 = cv2.fitLine(points.astype(np.float32), cv2.DIST_HUBER, 0, 1e-3, 1e-3
                                 ).ravel().tolist()
    line = (-vy, vx, -vy * x0 + vx * y0)
    r2 = np.square(points[:, 0] * line[0] + points[:, 1] * line[1] - line[2])
    med = float(np.partition(r2, len(r2) // 2)[len(r2) // 2])
    return line, r2[r2 <= max(9 * 1.4826**2 * med, 0.0625)]


def intersect(a: Line, b: Line) -> tuple[float, float] | None:
    """Intersection of two lines, None if (nearly) parallel."""
    det = a[0] * b[1] - a[1] * b[0]
    if abs(det) < 1e-9:
        return None
    return (a[2] * b[1] - b[2] * a[1]) / det, (a[0] * b[2] - b[0] * a[2]) / det
