"""Total-least-squares lines from point moments, the optimal two-line split, intersections.

A line is ``(n, d)`` with unit normal n: points p on it satisfy n . p = d (pixels).
"""

from __future__ import annotations

import numpy as np


def fit_line(points: np.ndarray) -> tuple[np.ndarray, float]:
    """TLS line through (N, 2) points, N >= 2."""
    c = points.mean(0)
    q = points - c
    cov = q.T @ q
    _, vecs = np.linalg.eigh(cov)
    n = vecs[:, 0]  # smallest eigenvalue: the normal
    return n, float(n @ c)


def distances(points: np.ndarray, line: tuple[np.ndarray, float]) -> np.ndarray:
    """Signed orthogonal distances (px) of points to a line."""
    n, d = line
    return points @ n - d


def _prefix_tls_sse(points: np.ndarray) -> np.ndarray:
    """sse[k] = TLS residual sum of squares of points[:k] for k = 0..N (from moments)."""
    x, y = points[:, 0], points[:, 1]
    n = np.arange(0, len(points) + 1, dtype=np.float64)
    cx = np.concatenate([[0], np.cumsum(x)])
    cy = np.concatenate([[0], np.cumsum(y)])
    cxx = np.concatenate([[0], np.cumsum(x * x)])
    cyy = np.concatenate([[0], np.cumsum(y * y)])
    cxy = np.concatenate([[0], np.cumsum(x * y)])
    with np.errstate(invalid="ignore", divide="ignore"):
        sxx = cxx - cx * cx / n
        syy = cyy - cy * cy / n
        sxy = cxy - cx * cy / n
        tr, det = sxx + syy, sxx * syy - sxy * sxy
        smallest = 0.5 * (tr - np.sqrt(np.maximum(tr * tr - 4 * det, 0.0)))
    smallest[:2] = 0.0
    return smallest


def best_split(points: np.ndarray, min_points: int = 3) -> int:
    """Index k splitting ordered points into two lines points[:k], points[k:] with the least
    total TLS residual (the optimal version of the paper's greedy Table 2 assignment)."""
    n = len(points)
    left = _prefix_tls_sse(points)
    right = _prefix_tls_sse(points[::-1])[::-1]
    ks = np.arange(min_points, n - min_points + 1)
    total = left[ks] + right[ks]
    return int(ks[np.argmin(total)])


def robust_fit(points: np.ndarray, iterations: int = 2, k_sigma: float = 3.0,
               floor_px: float = 0.2) -> tuple[tuple[np.ndarray, float], np.ndarray]:
    """TLS fit with iterative rejection of points beyond k robust sigmas; returns the line
    and the inlier mask."""
    keep = np.ones(len(points), bool)
    line = fit_line(points)
    for _ in range(iterations):
        r = np.abs(distances(points, line))
        sigma = 1.4826 * np.median(r[keep]) if keep.any() else 0.0
        new_keep = r <= max(k_sigma * sigma, floor_px)
        if new_keep.sum() < 2 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
        line = fit_line(points[keep])
    return line, keep


def intersect(a: tuple[np.ndarray, float], b: tuple[np.ndarray, float]) -> np.ndarray | None:
    """Intersection point of two lines, None if (nearly) parallel."""
    A = np.array([a[0], b[0]])
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    if abs(det) < 1e-9:
        return None
    return np.array([(a[1] * A[1, 1] - b[1] * A[0, 1]) / det,
                     (A[0, 0] * b[1] - A[1, 0] * a[1]) / det])
