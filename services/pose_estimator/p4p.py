"""Analytic planar four-point pose (P4P) of the rhombus: IPPE, then Gauss-Newton.

The paper uses Kamata et al.'s (ICPR 1992) analytic P4P, whose text we could not obtain. This
is a known analytic coplanar solution in its place: **IPPE** (Infinitesimal Plane-based Pose
Estimation, Collins and Bartoli, IJCV 2014), written from the authors' reference steps
(``perspectiveIPPE.m`` / ``IPPE_dec.m``): a homography to normalised image coordinates, its
Jacobian at the model origin, and a closed-form decomposition into the **two** rotations that
explain it, each with its least-squares translation. Both candidates are returned; the caller
chooses with a prior (the humanoid stands upright). An optional Gauss-Newton refinement on the
reprojection error and a 6x6 covariance from its Jacobian complete the estimate.

Limits: the points must be coplanar (z = 0 in the model frame) and not collinear; when the
projection is nearly affine (a small or distant marker) the two candidates explain the image
almost equally well, and only a prior can tell them apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


class PoseError(ValueError):
    """The input cannot give a pose; the message says why."""


@dataclass(frozen=True)
class PoseCandidate:
    """T_camera_marker as R (3x3) and t (3,) m; reprojection RMS in normalised units."""

    R: np.ndarray
    t: np.ndarray
    error: float


def _square_to_quad(x: list[float], y: list[float]) -> np.ndarray:
    """Homography taking the unit square (0,0), (1,0), (1,1), (0,1) to a quad (Heckbert)."""
    sx = x[0] - x[1] + x[2] - x[3]
    sy = y[0] - y[1] + y[2] - y[3]
    dx1, dx2, dy1, dy2 = x[1] - x[2], x[3] - x[2], y[1] - y[2], y[3] - y[2]
    den = dx1 * dy2 - dx2 * dy1
    if abs(den) < 1e-15:
        raise PoseError("degenerate points: repeated or three collinear (no homography)")
    g = (sx * dy2 - dx2 * sy) / den
    h = (dx1 * sy - sx * dy1) / den
    return np.array([[x[1] - x[0] + g * x[1], x[3] - x[0] + h * x[3], x[0]],
                     [y[1] - y[0] + g * y[1], y[3] - y[0] + h * y[3], y[0]],
                     [g, h, 1.0]])


def _check_quad(x: list[float], y: list[float], scale: float) -> None:
    """Raise PoseError when any three of the four points are (nearly) collinear."""
    for i, j, k in ((0, 1, 2), (1, 2, 3), (2, 3, 0), (3, 0, 1)):
        area = (x[j] - x[i]) * (y[k] - y[i]) - (x[k] - x[i]) * (y[j] - y[i])
        if abs(area) < 1e-9 * scale * scale:
            raise PoseError("degenerate points: repeated or three collinear (no homography)")


def homography_4pt(model_xy: np.ndarray, image_xy: np.ndarray) -> np.ndarray:
    """Exact homography (3x3, H[2,2] = 1) mapping 4 model points to 4 image points, in
    closed form through the unit square. Raises PoseError for repeated or collinear points."""
    mx, my = model_xy[:, 0].tolist(), model_xy[:, 1].tolist()
    ix, iy = image_xy[:, 0].tolist(), image_xy[:, 1].tolist()
    _check_quad(mx, my, max(map(abs, mx + my)) or 1.0)
    _check_quad(ix, iy, max(map(abs, ix + iy)) or 1.0)
    H = _square_to_quad(ix, iy) @ np.linalg.inv(_square_to_quad(mx, my))
    return H / H[2, 2]


def _ippe_rotations(v: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two rotations of IPPE_dec from the image of the origin v and the Jacobian J."""
    t = math.hypot(v[0], v[1])
    if t < 1e-12:
        Rv = np.eye(3)
    else:
        s = math.sqrt(t * t + 1.0)
        costh, sinth = 1.0 / s, math.sqrt(1.0 - 1.0 / (s * s))
        Kc = np.array([[0.0, 0.0, v[0]], [0.0, 0.0, v[1]], [-v[0], -v[1], 0.0]]) / t
        Rv = np.eye(3) + sinth * Kc + (1.0 - costh) * (Kc @ Kc)
    B = np.array([[1.0, 0.0, -v[0]], [0.0, 1.0, -v[1]]]) @ Rv[:, :2]
    A = np.linalg.solve(B, J)
    a, b, c, d = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    gamma = math.sqrt(0.5 * (a * a + b * b + c * c + d * d + math.sqrt(
        (a * a - b * b + c * c - d * d) ** 2 + 4 * (a * b + c * d) ** 2)))
    R22 = A / gamma
    h = np.eye(2) - R22.T @ R22
    bvec = np.array([math.sqrt(max(h[0, 0], 0.0)), math.sqrt(max(h[1, 1], 0.0))])
    if h[0, 1] < 0:
        bvec[1] = -bvec[1]
    r00, r01, r10, r11 = R22[0, 0], R22[0, 1], R22[1, 0], R22[1, 1]
    b0, b1 = bvec
    c0, c1, a2 = r10 * b1 - b0 * r11, b0 * r01 - r00 * b1, r00 * r11 - r10 * r01
    M1 = np.array([[r00, r01, c0], [r10, r11, c1], [b0, b1, a2]])
    M2 = np.array([[r00, r01, -c0], [r10, r11, -c1], [-b0, -b1, a2]])
    return Rv @ M1, Rv @ M2


def _translation(R: np.ndarray, model_xy: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Least-squares translation for rotation R (model points on z = 0, normalised q)."""
    P = model_xy @ R[:, :2].T  # (N, 3) rotated model points
    n = len(q)
    A = np.zeros((2 * n, 3))
    A[0::2, 0], A[0::2, 2] = 1.0, -q[:, 0]
    A[1::2, 1], A[1::2, 2] = 1.0, -q[:, 1]
    b = np.empty(2 * n)
    b[0::2] = q[:, 0] * P[:, 2] - P[:, 0]
    b[1::2] = q[:, 1] * P[:, 2] - P[:, 1]
    return np.linalg.solve(A.T @ A, A.T @ b)


def reprojection_rms(R: np.ndarray, t: np.ndarray, model: np.ndarray, q: np.ndarray) -> float:
    """RMS distance (normalised image units) between projected model points and q."""
    Xc = model @ R.T + t
    if np.any(Xc[:, 2] <= 0):
        return math.inf
    d = Xc[:, :2] / Xc[:, 2:3] - q
    return math.sqrt(float((d * d).sum()) / len(q))


def ippe(model: np.ndarray, q: np.ndarray) -> list[PoseCandidate]:
    """Both IPPE poses of a planar model (N, 3) with z = 0, from normalised image points q.

    Returns the candidates sorted by reprojection error (best first); a candidate with
    points behind the camera is dropped. Raises PoseError on degenerate input.
    """
    model = np.asarray(model, np.float64)
    q = np.asarray(q, np.float64)
    if model.shape != (len(q), 3) or len(q) < 4 or q.shape[1] != 2:
        raise PoseError(f"need N >= 4 model (N, 3) and image (N, 2) points, got {model.shape} "
                        f"and {q.shape}")
    if not (np.all(np.isfinite(model)) and np.all(np.isfinite(q))):
        raise PoseError("non-finite coordinates (NaN or inf)")
    if np.any(np.abs(model[:, 2]) > 1e-9):
        raise PoseError("model points must lie on the plane z = 0")
    centre = model[:, :2].mean(0)
    mxy = model[:, :2] - centre
    if len(q) == 4:
        H = homography_4pt(mxy, q)
    else:
        import cv2
        H, _ = cv2.findHomography(mxy, q, 0)
        if H is None:
            raise PoseError("degenerate points: no homography")
        H = H / H[2, 2]
    J = np.array([[H[0, 0] - H[2, 0] * H[0, 2], H[0, 1] - H[2, 1] * H[0, 2]],
                  [H[1, 0] - H[2, 0] * H[1, 2], H[1, 1] - H[2, 1] * H[1, 2]]])
    if abs(np.linalg.det(J)) < 1e-12:
        raise PoseError("degenerate image: the marker projects to a line")
    out = []
    for R in _ippe_rotations(H[:2, 2], J):
        t = _translation(R, mxy, q)
        t_model = t - R[:, :2] @ centre
        err = reprojection_rms(R, t_model, model, q)
        if math.isfinite(err):
            out.append(PoseCandidate(R, t_model, err))
    if not out:
        raise PoseError("no pose puts the marker in front of the camera")
    return sorted(out, key=lambda c: c.error)


def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _exp_so3(w: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(w))
    K = _skew(w)
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + math.sin(th) / th * K + (1 - math.cos(th)) / (th * th) * (K @ K)


def residuals_and_jacobian(R: np.ndarray, t: np.ndarray, model: np.ndarray,
                           q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (2N,) in normalised units and their Jacobian (2N, 6) with respect to a
    left rotation increment w (R <- exp(w) R) and t."""
    P = model @ R.T
    Xc = P + t
    X, Y, Z = Xc[:, 0], Xc[:, 1], Xc[:, 2]
    iz = 1.0 / Z
    r = (Xc[:, :2] * iz[:, None] - q).reshape(-1)
    n = len(q)
    J = np.zeros((2 * n, 6))
    ax, ay = -X * iz * iz, -Y * iz * iz  # d(X/Z)/dZ, d(Y/Z)/dZ
    px, py, pz = P[:, 0], P[:, 1], P[:, 2]
    # d Xc / d w = -[P]x  =>  rows (0, pz, -py), (-pz, 0, px), (py, -px, 0)
    J[0::2, 0] = ax * py
    J[0::2, 1] = iz * pz + ax * -px
    J[0::2, 2] = iz * -py
    J[1::2, 0] = iz * -pz + ay * py
    J[1::2, 1] = ay * -px
    J[1::2, 2] = iz * px
    J[0::2, 3], J[0::2, 5] = iz, ax
    J[1::2, 4], J[1::2, 5] = iz, ay
    return r, J


def refine(R: np.ndarray, t: np.ndarray, model: np.ndarray, q: np.ndarray,
           iterations: int = 5, prior: tuple[np.ndarray, float] | None = None
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Gauss-Newton on the reprojection error, optionally with an upright prior.

    ``prior = (up, weight)`` adds the residual ``weight * (n . up)``, n the marker normal
    (R's third column) and ``up`` the world's up in the camera frame: with ``weight =
    sigma_image / sigma_tilt`` the cost is the negative log posterior (times sigma_image²)
    of a marker whose normal is level within sigma_tilt. Returns R, t, the reprojection
    Jacobian (2N, 6) and the final cost (sum of squared residuals, normalised units).
    """
    def cost_of(R_: np.ndarray, t_: np.ndarray) -> float:
        Xc = model @ R_.T + t_
        if np.any(Xc[:, 2] <= 0):
            return math.inf
        d = Xc[:, :2] / Xc[:, 2:3] - q
        c = float((d * d).sum())
        if prior is not None:
            c += (prior[1] * float(R_[:, 2] @ prior[0])) ** 2
        return c

    cost = cost_of(R, t)
    for _ in range(iterations):
        r, J = residuals_and_jacobian(R, t, model, q)
        if prior is not None:
            up, w = prior
            n = R[:, 2]
            r = np.append(r, w * float(n @ up))
            # d(n . up)/dw = n x up for a left increment
            J = np.vstack([J, [w * (n[1] * up[2] - n[2] * up[1]),
                               w * (n[2] * up[0] - n[0] * up[2]),
                               w * (n[0] * up[1] - n[1] * up[0]), 0.0, 0.0, 0.0]])
        JTJ = J.T @ J
        try:
            delta = -np.linalg.solve(JTJ + 1e-12 * np.eye(6), J.T @ r)
        except np.linalg.LinAlgError:
            break
        R_new, t_new = _exp_so3(delta[:3]) @ R, t + delta[3:]
        new_cost = cost_of(R_new, t_new)
        if new_cost > cost:
            break
        converged = cost - new_cost <= 1e-9 * cost
        R, t, cost = R_new, t_new, new_cost
        if converged or float(np.linalg.norm(delta)) < 1e-12:
            break
    _, J = residuals_and_jacobian(R, t, model, q)
    return R, t, J, cost


def covariance_6(J: np.ndarray, sigma_normalised: float) -> np.ndarray:
    """6x6 covariance of (w rad, t m) from the Jacobian and the image noise (normalised)."""
    return sigma_normalised ** 2 * np.linalg.pinv(J.T @ J)
