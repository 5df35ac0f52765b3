"""Zhang's planar calibration (Zhang, "A flexible new technique for camera calibration",
IEEE TPAMI 22(11), 2000; MSR-TR-98-71), written out from the paper's formulas
(the implementation notes beside the paper, section 3).

Steps: one homography per view (normalised DLT, refined by Levenberg-Marquardt); the linear
system V b = 0 for B = A^-T A^-1; the intrinsics (alpha, beta, gamma, u0, v0) in closed form;
each view's extrinsics; radial distortion k1, k2 by linear least squares; and a final
Levenberg-Marquardt refinement of every parameter on the reprojection error (scipy).

The camera model is Zhang's: x_d = x (1 + k1 r² + k2 r⁴), u = alpha x_d + gamma y_d + u0,
v = beta y_d + v0, which is OpenCV's with p1 = p2 = k3 = 0 plus a skew term gamma.

Note: the closed form needs at least three views in general position (two with gamma = 0
assumed); nearly parallel views make V b = 0 ill-conditioned, which the parameter standard
deviations reveal. Raises :class:`CalibrationError` for too few or degenerate views.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares


class CalibrationError(ValueError):
    """Calibration cannot proceed; the message says why."""


@dataclass(frozen=True)
class Calibration:
    """Result: K (3x3, px), dist (k1, k2, 0, 0, 0), per-view R|t (model -> camera)."""

    K: np.ndarray
    dist: np.ndarray
    rvecs: list[np.ndarray]
    tvecs: list[np.ndarray]
    rms_px: float                       # sqrt(mean over points of squared distance)
    per_view_rms_px: list[float]
    std: dict[str, float] = field(default_factory=dict)  # 1-sigma of alpha, beta, ... k2
    residuals_px: list[np.ndarray] = field(default_factory=list)  # per view (N, 2)


def _normalise(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = points.mean(0)
    s = math.sqrt(2) / np.mean(np.linalg.norm(points - c, axis=1))
    T = np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1]])
    return (points - c) * s, T


def homography(model_xy: np.ndarray, image_xy: np.ndarray, refine: bool = True) -> np.ndarray:
    """Homography model plane -> image by normalised DLT, then LM on the image distances."""
    if len(model_xy) < 4:
        raise CalibrationError("a homography needs at least 4 points")
    m, Tm = _normalise(model_xy)
    p, Tp = _normalise(image_xy)
    n = len(m)
    A = np.zeros((2 * n, 9))
    A[0::2, 0:2], A[0::2, 2] = m, 1
    A[0::2, 6:8], A[0::2, 8] = -p[:, :1] * m, -p[:, 0]
    A[1::2, 3:5], A[1::2, 5] = m, 1
    A[1::2, 6:8], A[1::2, 8] = -p[:, 1:2] * m, -p[:, 1]
    _, s, vt = np.linalg.svd(A)
    if s[-2] < 1e-9 * s[0]:
        raise CalibrationError("degenerate view: points collinear or repeated")
    H = np.linalg.inv(Tp) @ vt[-1].reshape(3, 3) @ Tm
    H /= H[2, 2]
    if refine:
        mh = np.column_stack([model_xy, np.ones(n)])

        def resid(h: np.ndarray) -> np.ndarray:
            q = mh @ np.append(h, 1.0).reshape(3, 3).T
            return (q[:, :2] / q[:, 2:3] - image_xy).ravel()
        H = np.append(least_squares(resid, H.ravel()[:8], method="lm").x, 1.0).reshape(3, 3)
    return H


def _v(H: np.ndarray, i: int, j: int) -> np.ndarray:
    hi, hj = H[:, i], H[:, j]
    return np.array([hi[0] * hj[0], hi[0] * hj[1] + hi[1] * hj[0], hi[1] * hj[1],
                     hi[2] * hj[0] + hi[0] * hj[2], hi[2] * hj[1] + hi[1] * hj[2],
                     hi[2] * hj[2]])


def intrinsics_from_homographies(Hs: list[np.ndarray]) -> np.ndarray:
    """Closed-form A from V b = 0 (Zhang, section 3.1 and appendix B)."""
    rows = []
    for H in Hs:
        rows += [_v(H, 0, 1), _v(H, 0, 0) - _v(H, 1, 1)]
    if len(Hs) == 2:
        rows.append(np.array([0, 1, 0, 0, 0, 0.0]))  # gamma = 0
    elif len(Hs) < 2:
        raise CalibrationError(f"need at least 2 views (3 for skew), got {len(Hs)}")
    _, _, vt = np.linalg.svd(np.array(rows))
    B11, B12, B22, B13, B23, B33 = vt[-1]
    if B11 < 0:  # b is defined up to sign; lambda / B11 must be positive
        B11, B12, B22, B13, B23, B33 = -vt[-1]
    den = B11 * B22 - B12 * B12
    if abs(den) < 1e-30 or B11 == 0:
        raise CalibrationError("degenerate views: V b = 0 has no camera solution")
    v0 = (B12 * B13 - B11 * B23) / den
    lam = B33 - (B13 * B13 + v0 * (B12 * B13 - B11 * B23)) / B11
    if lam / B11 <= 0 or lam * B11 / den <= 0:
        raise CalibrationError("degenerate views: no positive focal length (views too "
                               "similar or too few)")
    alpha = math.sqrt(lam / B11)
    beta = math.sqrt(lam * B11 / den)
    gamma = -B12 * alpha * alpha * beta / lam
    u0 = gamma * v0 / beta - B13 * alpha * alpha / lam
    return np.array([[alpha, gamma, u0], [0, beta, v0], [0, 0, 1]])


def extrinsics(A: np.ndarray, H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R (3x3, nearest rotation) and t of a view from its homography."""
    Ainv = np.linalg.inv(A)
    h1, h2, h3 = (Ainv @ H[:, i] for i in range(3))
    mu = 1.0 / np.linalg.norm(h1)
    r1, r2, t = mu * h1, mu * h2, mu * h3
    if t[2] < 0:
        r1, r2, t = -r1, -r2, -t
    U, _, Vt = np.linalg.svd(np.column_stack([r1, r2, np.cross(r1, r2)]))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1, 1, -1]) @ Vt
    return R, t


def project(params_A: np.ndarray, k: tuple[float, float], R: np.ndarray, t: np.ndarray,
            model: np.ndarray) -> np.ndarray:
    """Zhang's model: model points (N, 3) -> distorted pixels (N, 2)."""
    X = model @ R.T + t
    x, y = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2]
    r2 = x * x + y * y
    f = 1 + k[0] * r2 + k[1] * r2 * r2
    xd, yd = x * f, y * f
    a, g, u0 = params_A[0]
    _, b, v0 = params_A[1]
    return np.column_stack([a * xd + g * yd + u0, b * yd + v0])


def radial_distortion(A: np.ndarray, Rs: list[np.ndarray], ts: list[np.ndarray],
                      models: list[np.ndarray], images: list[np.ndarray]) -> np.ndarray:
    """Linear least-squares k1, k2 (Zhang, section 3.3)."""
    u0, v0 = A[0, 2], A[1, 2]
    D, d = [], []
    for R, t, M, m in zip(Rs, ts, models, images, strict=True):
        ideal = project(A, (0.0, 0.0), R, t, M)
        X = M @ R.T + t
        r2 = (X[:, 0] / X[:, 2]) ** 2 + (X[:, 1] / X[:, 2]) ** 2
        du, dv = ideal[:, 0] - u0, ideal[:, 1] - v0
        D += [np.column_stack([du * r2, du * r2 * r2]), np.column_stack([dv * r2, dv * r2 * r2])]
        d += [m[:, 0] - ideal[:, 0], m[:, 1] - ideal[:, 1]]
    k, *_ = np.linalg.lstsq(np.vstack(D), np.concatenate(d), rcond=None)
    return k


def calibrate(models: list[np.ndarray], images: list[np.ndarray], *, skew: bool = True,
              refine: bool = True) -> Calibration:
    """Calibrate from per-view model points (N, 2 or 3; z = 0) and image points (N, 2) px.

    Raises CalibrationError with fewer than three views (two with ``skew=False``)."""
    need = 3 if skew else 2
    if len(models) < need:
        raise CalibrationError(f"need at least {need} usable views, got {len(models)}")
    models3 = [np.column_stack([np.asarray(m, float)[:, :2], np.zeros(len(m))]) for m in models]
    images = [np.asarray(i, float) for i in images]
    Hs = [homography(m[:, :2], i) for m, i in zip(models3, images, strict=True)]
    A = intrinsics_from_homographies(Hs)
    if not skew:
        A[0, 1] = 0.0
    RT = [extrinsics(A, H) for H in Hs]
    k0 = radial_distortion(A, [r for r, _ in RT], [t for _, t in RT], models3, images)
    rvecs = [cv2.Rodrigues(R)[0].ravel() for R, _ in RT]
    tvecs = [t for _, t in RT]
    n_views = len(models3)

    def unpack(p: np.ndarray) -> tuple[np.ndarray, tuple[float, float], list, list]:
        a, b, g, u0, v0, k1, k2 = p[:7]
        Ap = np.array([[a, g if skew else 0.0, u0], [0, b, v0], [0, 0, 1]])
        ext = p[7:].reshape(n_views, 6)
        return Ap, (k1, k2), [e[:3] for e in ext], [e[3:] for e in ext]

    def residuals(p: np.ndarray) -> np.ndarray:
        Ap, kp, rv, tv = unpack(p)
        return np.concatenate([(project(Ap, kp, cv2.Rodrigues(r)[0], t, M) - m).ravel()
                               for r, t, M, m in zip(rv, tv, models3, images, strict=True)])

    p0 = np.concatenate([[A[0, 0], A[1, 1], A[0, 1], A[0, 2], A[1, 2], k0[0], k0[1]],
                         *[np.concatenate([r, t]) for r, t in zip(rvecs, tvecs, strict=True)]])
    if refine:
        sol = least_squares(residuals, p0, method="lm", x_scale="jac")
        p = sol.x
        J = sol.jac
    else:
        p = p0
        J = None  # no refinement: no Jacobian
    A, k, rvecs, tvecs = unpack(p)
    res = residuals(p).reshape(-1, 2)
    per_view, out_res, i = [], [], 0
    for m in images:
        r = res[i:i + len(m)]
        out_res.append(r)
        per_view.append(float(np.sqrt(np.mean(np.sum(r * r, axis=1)))))
        i += len(m)
    rms = float(np.sqrt(np.mean(np.sum(res * res, axis=1))))
    std: dict[str, float] = {}
    if J is not None:
        dof = max(res.size - len(p), 1)
        sigma2 = float((res * res).sum()) / dof
        cov = np.linalg.pinv(J.T @ J) * sigma2
        names = ["alpha", "beta", "gamma", "u0", "v0", "k1", "k2"]
        std = {n: float(math.sqrt(max(cov[j, j], 0.0))) for j, n in enumerate(names)
               if skew or n != "gamma"}
    dist = np.array([k[0], k[1], 0.0, 0.0, 0.0])
    return Calibration(A, dist, list(rvecs), list(tvecs), rms, per_view, std, out_res)
