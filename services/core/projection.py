"""The camera model's projection and its inverse without distortion, compiled with numba.

Pinhole with skew, radial k1 k2 k3 and tangential p1 p2 (OpenCV's five coefficients; OpenCV
itself has no skew). ``CameraModel.project`` calls ``project_px``; the pose estimator uses
both kernels directly on its hot path.
"""

from __future__ import annotations

import numpy as np

from services.core.jit import njit


@njit()
def project_px(K: np.ndarray, dist: np.ndarray, points_cam: np.ndarray) -> np.ndarray:
    """Points in the camera optical frame (N, 3) m -> pixels (N, 2)."""
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    n = points_cam.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        x = points_cam[i, 0] / points_cam[i, 2]
        y = points_cam[i, 1] / points_cam[i, 2]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        out[i, 0] = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
        out[i, 1] = K[1, 1] * yd + K[1, 2]
    return out


@njit()
def normalise_px(K: np.ndarray, points_px: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) -> normalised image coordinates (N, 2) for a camera without distortion."""
    n = points_px.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        y = (points_px[i, 1] - K[1, 2]) / K[1, 1]
        out[i, 0] = (points_px[i, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        out[i, 1] = y
    return out


@njit()
def rms_px(a: np.ndarray, b: np.ndarray) -> float:
    """RMS distance (px) between two (N, 2) point sets."""
    s = 0.0
    for i in range(a.shape[0]):
        s += (a[i, 0] - b[i, 0]) ** 2 + (a[i, 1] - b[i, 1]) ** 2
    return float(np.sqrt(s / a.shape[0]))
