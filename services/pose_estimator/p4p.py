"""Analytic planar four-point pose (P4P) of the rhombus: IPPE, then Gauss-Newton.

The paper uses Kamata et al.'s (ICPR 1992) analytic P4P, whose text we could not obtain. This
is a known analytic coplanar solution in its place: **IPPE** (Infinitesimal Plane-based Pose
Estimation, Collins and Bartoli, IJCV 2014), written from the authors' reference steps
(``perspectiveIPPE.m`` / ``IPPE_dec.m``): a homography to normalised image coordinates, its
Jacobian at the model origin, and a closed-form decomposition into the **two** rotations that
explain it, each with its least-squares translation. Both candidates are returned; the caller
chooses with a prior (the humanoid stands upright). An optional Gauss-Newton refinement on the
reprojection error and a 6x6 covariance from its Jacobian complete the estimate.

The kernels are compiled with numba (scalar code on 3x3 matrices: numpy's per-call overhead
would be most of the time otherwise); the Python functions check their input and raise
``PoseError`` with the reason.

Limits: the points must be coplanar (z = 0 in the model frame) and not collinear; when the
projection is nearly affine (a small or distant marker) the two candidates explain the image
almost equally well, and only a prior can tell them apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from services.core.jit import njit


class PoseError(ValueError):
    """The input cannot give a pose; the message says why."""


@dataclass(frozen=True)
class PoseCandidate:
    """T_camera_marker as R (3x3) and t (3,) m; reprojection RMS in normalised units."""

    R: np.ndarray
    t: np.ndarray
    error: float


OK, NOT_FINITE, NOT_PLANAR, DEGENERATE_MODEL, DEGENERATE_IMAGE, PROJECTS_TO_LINE, \
    NONE_IN_FRONT, BEHIND = range(8)

MESSAGES = {
    NOT_FINITE: "non-finite coordinates (NaN or inf)",
    NOT_PLANAR: "model points must lie on the plane z = 0",
    DEGENERATE_MODEL: "degenerate model points: repeated or three collinear (no homography)",
    DEGENERATE_IMAGE: "degenerate points: repeated or three collinear (no homography)",
    PROJECTS_TO_LINE: "degenerate image: the marker projects to a line",
    NONE_IN_FRONT: "no pose puts the marker in front of the camera",
    BEHIND: "the pose puts the marker behind the camera",
}


def raise_for(status: int) -> None:
    """Raise PoseError for a kernel status other than OK."""
    if status != OK:
        raise PoseError(MESSAGES[status])


# -- homography ------------------------------------------------------------------------------

@njit()
def _square_to_quad(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Homography taking the unit square (0,0), (1,0), (1,1), (0,1) to a quad (Heckbert);
    all zeros when degenerate."""
    H = np.zeros((3, 3))
    sx = x[0] - x[1] + x[2] - x[3]
    sy = y[0] - y[1] + y[2] - y[3]
    dx1, dx2, dy1, dy2 = x[1] - x[2], x[3] - x[2], y[1] - y[2], y[3] - y[2]
    den = dx1 * dy2 - dx2 * dy1
    if abs(den) < 1e-15:
        return H
    g = (sx * dy2 - dx2 * sy) / den
    h = (dx1 * sy - sx * dy1) / den
    H[0, 0], H[0, 1], H[0, 2] = x[1] - x[0] + g * x[1], x[3] - x[0] + h * x[3], x[0]
    H[1, 0], H[1, 1], H[1, 2] = y[1] - y[0] + g * y[1], y[3] - y[0] + h * y[3], y[0]
    H[2, 0], H[2, 1], H[2, 2] = g, h, 1.0
    return H


@njit()
def _collinear(x: np.ndarray, y: np.ndarray) -> bool:
    """Are any three of the four points (nearly) collinear?"""
    scale = 0.0
    for i in range(4):
        scale = max(scale, abs(x[i]), abs(y[i]))
    scale = scale if scale > 0 else 1.0
    for i in range(4):
        j, k = (i + 1) % 4, (i + 2) % 4
        area = (x[j] - x[i]) * (y[k] - y[i]) - (x[k] - x[i]) * (y[j] - y[i])
        if abs(area) < 1e-9 * scale * scale:
            return True
    return False


@njit()
def _inv3(M: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 matrix by its adjugate."""
    a, b, c = M[0, 0], M[0, 1], M[0, 2]
    d, e, f = M[1, 0], M[1, 1], M[1, 2]
    g, h, i = M[2, 0], M[2, 1], M[2, 2]
    A, B, C = e * i - f * h, -(d * i - f * g), d * h - e * g
    det = a * A + b * B + c * C
    out = np.empty((3, 3))
    out[0, 0], out[1, 0], out[2, 0] = A / det, B / det, C / det
    out[0, 1], out[1, 1], out[2, 1] = -(b * i - c * h) / det, (a * i - c * g) / det, \
        -(a * h - b * g) / det
    out[0, 2], out[1, 2], out[2, 2] = (b * f - c * e) / det, -(a * f - c * d) / det, \
        (a * e - b * d) / det
    return out


@njit()
def homography_4pt(model_xy: np.ndarray, image_xy: np.ndarray) -> tuple[int, np.ndarray]:
    """(status, H): exact homography (H[2,2] = 1) mapping 4 model points to 4 image points,
    in closed form through the unit square."""
    mx, my = model_xy[:, 0].copy(), model_xy[:, 1].copy()
    ix, iy = image_xy[:, 0].copy(), image_xy[:, 1].copy()
    if _collinear(mx, my):
        return DEGENERATE_MODEL, np.zeros((3, 3))
    if _collinear(ix, iy):
        return DEGENERATE_IMAGE, np.zeros((3, 3))
    H = _square_to_quad(ix, iy) @ _inv3(_square_to_quad(mx, my))
    return OK, H / H[2, 2]


# -- IPPE ------------------------------------------------------------------------------------

@njit()
def _ippe_rotations(v0: float, v1: float, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two rotations of IPPE_dec from the image of the origin v and the Jacobian J."""
    t = math.hypot(v0, v1)
    Rv = np.eye(3)
    if t >= 1e-12:
        s = math.sqrt(t * t + 1.0)
        costh, sinth = 1.0 / s, math.sqrt(1.0 - 1.0 / (s * s))
        Kc = np.array([[0.0, 0.0, v0], [0.0, 0.0, v1], [-v0, -v1, 0.0]]) / t
        Rv = Rv + sinth * Kc + (1.0 - costh) * (Kc @ Kc)
    # B = [[1, 0, -v0], [0, 1, -v1]] Rv[:, :2];  A = B^-1 J
    b00, b01 = Rv[0, 0] - v0 * Rv[2, 0], Rv[0, 1] - v0 * Rv[2, 1]
    b10, b11 = Rv[1, 0] - v1 * Rv[2, 0], Rv[1, 1] - v1 * Rv[2, 1]
    det = b00 * b11 - b01 * b10
    a = (b11 * J[0, 0] - b01 * J[1, 0]) / det
    b = (b11 * J[0, 1] - b01 * J[1, 1]) / det
    c = (-b10 * J[0, 0] + b00 * J[1, 0]) / det
    d = (-b10 * J[0, 1] + b00 * J[1, 1]) / det
    gamma = math.sqrt(0.5 * (a * a + b * b + c * c + d * d + math.sqrt(
        (a * a - b * b + c * c - d * d) ** 2 + 4 * (a * b + c * d) ** 2)))
    r00, r01, r10, r11 = a / gamma, b / gamma, c / gamma, d / gamma
    h00 = 1.0 - r00 * r00 - r10 * r10
    h01 = -(r00 * r01 + r10 * r11)
    h11 = 1.0 - r01 * r01 - r11 * r11
    b0, b1 = math.sqrt(max(h00, 0.0)), math.sqrt(max(h11, 0.0))
    if h01 < 0:
        b1 = -b1
    c0, c1, a2 = r10 * b1 - b0 * r11, b0 * r01 - r00 * b1, r00 * r11 - r10 * r01
    M1 = np.array([[r00, r01, c0], [r10, r11, c1], [b0, b1, a2]])
    M2 = np.array([[r00, r01, -c0], [r10, r11, -c1], [-b0, -b1, a2]])
    return Rv @ M1, Rv @ M2


@njit()
def _translation(R: np.ndarray, mxy: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Least-squares translation for rotation R (model points (x, y, 0), normalised q)."""
    n = q.shape[0]
    A = np.zeros((3, 3))  # normal equations of rows [1, 0, -qx] and [0, 1, -qy]
    rhs = np.zeros(3)
    for i in range(n):
        px = R[0, 0] * mxy[i, 0] + R[0, 1] * mxy[i, 1]
        py = R[1, 0] * mxy[i, 0] + R[1, 1] * mxy[i, 1]
        pz = R[2, 0] * mxy[i, 0] + R[2, 1] * mxy[i, 1]
        qx, qy = q[i, 0], q[i, 1]
        bx, by = qx * pz - px, qy * pz - py
        A[0, 2] -= qx
        A[1, 2] -= qy
        A[2, 2] += qx * qx + qy * qy
        rhs[0] += bx
        rhs[1] += by
        rhs[2] -= qx * bx + qy * by
    A[0, 0] = A[1, 1] = n
    A[2, 0], A[2, 1] = A[0, 2], A[1, 2]
    return _inv3(A) @ rhs


@njit()
def reprojection_rms(R: np.ndarray, t: np.ndarray, model: np.ndarray, q: np.ndarray) -> float:
    """RMS distance (normalised image units) between projected model points and q; inf if a
    point is behind the camera."""
    s = 0.0
    n = q.shape[0]
    for i in range(n):
        X = R[0, 0] * model[i, 0] + R[0, 1] * model[i, 1] + R[0, 2] * model[i, 2] + t[0]
        Y = R[1, 0] * model[i, 0] + R[1, 1] * model[i, 1] + R[1, 2] * model[i, 2] + t[1]
        Z = R[2, 0] * model[i, 0] + R[2, 1] * model[i, 1] + R[2, 2] * model[i, 2] + t[2]
        if Z <= 0:
            return np.inf
        s += (X / Z - q[i, 0]) ** 2 + (Y / Z - q[i, 1]) ** 2
    return math.sqrt(s / n)


@njit()
def check_inputs(model: np.ndarray, q: np.ndarray) -> int:
    """NOT_FINITE, NOT_PLANAR or OK."""
    for i in range(q.shape[0]):
        if not (math.isfinite(q[i, 0]) and math.isfinite(q[i, 1])):
            return NOT_FINITE
        for k in range(3):
            if not math.isfinite(model[i, k]):
                return NOT_FINITE
        if abs(model[i, 2]) > 1e-9:
            return NOT_PLANAR
    return OK


@njit()
def ippe_from_homography(H: np.ndarray, model: np.ndarray, q: np.ndarray
                         ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, int]:
    """Both IPPE candidates from the homography H of the centred model (x, y) to q.

    Returns (status, Rs (2, 3, 3), ts (2, 3), errors (2,), count), best reprojection first;
    a candidate with points behind the camera is dropped (count 1), none left: NONE_IN_FRONT.
    """
    n = q.shape[0]
    cx, cy = model[:, 0].mean(), model[:, 1].mean()
    mxy = np.empty((n, 2))
    for i in range(n):
        mxy[i, 0], mxy[i, 1] = model[i, 0] - cx, model[i, 1] - cy
    J = np.empty((2, 2))
    J[0, 0] = H[0, 0] - H[2, 0] * H[0, 2]
    J[0, 1] = H[0, 1] - H[2, 1] * H[0, 2]
    J[1, 0] = H[1, 0] - H[2, 0] * H[1, 2]
    J[1, 1] = H[1, 1] - H[2, 1] * H[1, 2]
    Rs = np.zeros((2, 3, 3))
    ts = np.zeros((2, 3))
    errs = np.full(2, np.inf)
    if abs(J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]) < 1e-12:
        return PROJECTS_TO_LINE, Rs, ts, errs, 0
    R1, R2 = _ippe_rotations(H[0, 2], H[1, 2], J)
    count = 0
    for R in (R1, R2):
        t = _translation(R, mxy, q)
        t[0] -= R[0, 0] * cx + R[0, 1] * cy
        t[1] -= R[1, 0] * cx + R[1, 1] * cy
        t[2] -= R[2, 0] * cx + R[2, 1] * cy
        err = reprojection_rms(R, t, model, q)
        if math.isfinite(err):
            Rs[count], ts[count], errs[count] = R, t, err
            count += 1
    if count == 0:
        return NONE_IN_FRONT, Rs, ts, errs, 0
    if count == 2 and errs[1] < errs[0]:
        R0, t0, e0 = Rs[0].copy(), ts[0].copy(), errs[0]
        Rs[0], ts[0], errs[0] = Rs[1], ts[1], errs[1]
        Rs[1], ts[1], errs[1] = R0, t0, e0
    return OK, Rs, ts, errs, count


@njit()
def ippe4(model: np.ndarray, q: np.ndarray
          ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, int]:
    """IPPE for four points: checks, the closed-form homography, both candidates."""
    status = check_inputs(model, q)
    if status != OK:
        return status, np.zeros((2, 3, 3)), np.zeros((2, 3)), np.full(2, np.inf), 0
    cx, cy = model[:, 0].mean(), model[:, 1].mean()
    mxy = np.empty((4, 2))
    for i in range(4):
        mxy[i, 0], mxy[i, 1] = model[i, 0] - cx, model[i, 1] - cy
    status, H = homography_4pt(mxy, q)
    if status != OK:
        return status, np.zeros((2, 3, 3)), np.zeros((2, 3)), np.full(2, np.inf), 0
    return ippe_from_homography(H, model, q)


def ippe(model: np.ndarray, q: np.ndarray) -> list[PoseCandidate]:
    """Both IPPE poses of a planar model (N, 3) with z = 0, from normalised image points q.

    Returns the candidates sorted by reprojection error (best first); a candidate with
    points behind the camera is dropped. Raises PoseError on degenerate input.
    """
    model = np.ascontiguousarray(model, np.float64)
    q = np.ascontiguousarray(q, np.float64)
    if model.ndim != 2 or q.ndim != 2 or model.shape != (len(q), 3) or len(q) < 4 or \
            q.shape[1] != 2:
        raise PoseError(f"need N >= 4 model (N, 3) and image (N, 2) points, got {model.shape} "
                        f"and {q.shape}")
    if len(q) == 4:
        status, Rs, ts, errs, count = ippe4(model, q)
    else:
        import cv2
        raise_for(check_inputs(model, q))
        H, _ = cv2.findHomography(model[:, :2] - model[:, :2].mean(0), q, 0)
        if H is None:
            raise PoseError("degenerate points: no homography")
        status, Rs, ts, errs, count = ippe_from_homography(H / H[2, 2], model, q)
    raise_for(status)
    return [PoseCandidate(Rs[i], ts[i], float(errs[i])) for i in range(count)]


# -- refinement ------------------------------------------------------------------------------

@njit()
def exp_so3(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector w (rad)."""
    th = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + math.sin(th) / th * K + (1 - math.cos(th)) / (th * th) * (K @ K)


@njit(inline="always")
def _point_rows(R: np.ndarray, t: np.ndarray, m: np.ndarray, q: np.ndarray,
                jx: np.ndarray, jy: np.ndarray) -> tuple[float, float]:
    """Residual (rx, ry) of one model point m (3,) against q (2,), normalised units, and its
    two Jacobian rows jx, jy (6,) for a left rotation increment w (R <- exp(w) R) and t."""
    px = R[0, 0] * m[0] + R[0, 1] * m[1] + R[0, 2] * m[2]
    py = R[1, 0] * m[0] + R[1, 1] * m[1] + R[1, 2] * m[2]
    pz = R[2, 0] * m[0] + R[2, 1] * m[1] + R[2, 2] * m[2]
    X, Y, Z = px + t[0], py + t[1], pz + t[2]
    iz = 1.0 / Z
    ax, ay = -X * iz * iz, -Y * iz * iz  # d(X/Z)/dZ, d(Y/Z)/dZ
    # d Xc / d w = -[P]x  =>  rows (0, pz, -py), (-pz, 0, px), (py, -px, 0)
    jx[0], jx[1], jx[2] = ax * py, iz * pz - ax * px, -iz * py
    jx[3], jx[4], jx[5] = iz, 0.0, ax
    jy[0], jy[1], jy[2] = -iz * pz + ay * py, -ay * px, iz * px
    jy[3], jy[4], jy[5] = 0.0, iz, ay
    return X * iz - q[0], Y * iz - q[1]


@njit()
def residuals_and_jacobian(R: np.ndarray, t: np.ndarray, model: np.ndarray,
                           q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residuals (2N,) in normalised units and their Jacobian (2N, 6) with respect to a
    left rotation increment w (R <- exp(w) R) and t."""
    n = q.shape[0]
    r = np.empty(2 * n)
    J = np.empty((2 * n, 6))
    for i in range(n):
        r[2 * i], r[2 * i + 1] = _point_rows(R, t, model[i], q[i], J[2 * i], J[2 * i + 1])
    return r, J


@njit()
def _normal_equations(R: np.ndarray, t: np.ndarray, model: np.ndarray, q: np.ndarray,
                      JTJ: np.ndarray, g: np.ndarray) -> None:
    """JTJ = J^T J and g = J^T r of the reprojection residuals, without forming J."""
    JTJ[:] = 0.0
    g[:] = 0.0
    jx = np.empty(6)
    jy = np.empty(6)
    for i in range(q.shape[0]):
        rx, ry = _point_rows(R, t, model[i], q[i], jx, jy)
        for a in range(6):
            g[a] += jx[a] * rx + jy[a] * ry
            for b in range(a, 6):
                JTJ[a, b] += jx[a] * jx[b] + jy[a] * jy[b]
    for a in range(6):
        for b in range(a):
            JTJ[a, b] = JTJ[b, a]


@njit()
def _solve_spd(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """-A^-1 b for a symmetric positive (semi)definite 6x6 A by Cholesky, with a 1e-12
    ridge; NaN when A is singular."""
    n = 6
    L = np.zeros((n, n))
    for i in range(n):
        for k in range(i + 1):
            s = A[i, k] + (1e-12 if i == k else 0.0)
            for m in range(k):
                s -= L[i, m] * L[k, m]
            if i == k:
                if s <= 0.0:
                    return np.full(n, np.nan)
                L[i, i] = math.sqrt(s)
            else:
                L[i, k] = s / L[k, k]
    y = np.empty(n)
    for i in range(n):
        s = -b[i]
        for m in range(i):
            s -= L[i, m] * y[m]
        y[i] = s / L[i, i]
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        s = y[i]
        for m in range(i + 1, n):
            s -= L[m, i] * x[m]
        x[i] = s / L[i, i]
    return x


@njit(inline="always")
def huber_weight(tilt: float, huber: float) -> float:
    """IRLS weight of the prior residual: 1 within ``huber`` (sine of the tilt), falling as
    (huber / |tilt|)² beyond it (a heavy-tailed, Cauchy-like prior); ``huber <= 0``: 1."""
    a = abs(tilt)
    return 1.0 if huber <= 0.0 or a <= huber else (huber / a) ** 2


@njit(inline="always")
def prior_cost(tilt: float, prior_w: float, huber: float) -> float:
    """``(prior_w * tilt)²`` within ``huber``, growing only logarithmically beyond it."""
    a = abs(tilt)
    if huber <= 0.0 or a <= huber:
        return (prior_w * tilt) ** 2
    return prior_w * prior_w * huber * huber * (1.0 + 2.0 * math.log(a / huber))


@njit()
def posterior_cost(R: np.ndarray, t: np.ndarray, model: np.ndarray, q: np.ndarray,
                   up: np.ndarray, prior_w: float, huber: float) -> float:
    """Sum of squared reprojection residuals plus the upright prior's cost (normalised
    units): ``(prior_w * tilt)²``, heavy-tailed beyond ``huber`` (0: quadratic throughout)."""
    rms = reprojection_rms(R, t, model, q)
    if not math.isfinite(rms):
        return np.inf
    tilt = R[0, 2] * up[0] + R[1, 2] * up[1] + R[2, 2] * up[2]
    return rms * rms * q.shape[0] + prior_cost(tilt, prior_w, huber)


@njit()
def refine(R: np.ndarray, t: np.ndarray, model: np.ndarray, q: np.ndarray, iterations: int,
           up: np.ndarray, prior_w: float, huber: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Gauss-Newton on the reprojection error, with an upright prior when ``prior_w > 0``.

    The prior adds the residual ``prior_w * (n . up)``, n the marker normal (R's third
    column) and ``up`` the world's up in the camera frame: with ``prior_w = sigma_image /
    sigma_tilt`` the cost is the negative log posterior (times sigma_image²) of a marker
    whose normal is level within sigma_tilt; beyond ``huber`` (sine of the tilt, 0: never)
    the prior's tails are heavy (by reweighting, see ``prior_cost``), so a marker that leans, or
    a mount a little off, costs little. Returns R, t, the reprojection Jacobian (2N, 6) and
    the final cost (sum of squared residuals, normalised units).
    """
    cost = posterior_cost(R, t, model, q, up, prior_w, huber)
    JTJ = np.empty((6, 6))
    g = np.empty(6)
    row = np.empty(6)
    for _ in range(iterations):
        _normal_equations(R, t, model, q, JTJ, g)
        if prior_w > 0:
            tilt = R[0, 2] * up[0] + R[1, 2] * up[1] + R[2, 2] * up[2]
            w = prior_w * math.sqrt(huber_weight(tilt, huber))
            # d(n . up)/dw = n x up for a left increment
            row[0] = w * (R[1, 2] * up[2] - R[2, 2] * up[1])
            row[1] = w * (R[2, 2] * up[0] - R[0, 2] * up[2])
            row[2] = w * (R[0, 2] * up[1] - R[1, 2] * up[0])
            for a in range(3):
                g[a] += row[a] * w * tilt
                for b in range(3):
                    JTJ[a, b] += row[a] * row[b]
        delta = _solve_spd(JTJ, g)
        if not np.all(np.isfinite(delta)):
            break
        R_new = exp_so3(delta[:3]) @ R
        t_new = t + delta[3:]
        new_cost = posterior_cost(R_new, t_new, model, q, up, prior_w, huber)
        if new_cost > cost:
            break
        converged = cost - new_cost <= 1e-9 * cost
        R, t, cost = R_new, t_new, new_cost
        if converged or math.sqrt((delta * delta).sum()) < 1e-12:
            break
    _, J = residuals_and_jacobian(R, t, model, q)
    return R, t, J, cost


@njit()
def covariance_6(J: np.ndarray, sigma_normalised: float) -> np.ndarray:
    """6x6 covariance of (w rad, t m) from the Jacobian and the image noise (normalised)."""
    return sigma_normalised ** 2 * np.linalg.pinv(J.T @ J)


@njit()
def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle (rad) of the rotation between Ra and Rb."""
    tr = 0.0
    for i in range(3):
        for k in range(3):
            tr += Ra[k, i] * Rb[k, i]
    return math.acos(max(-1.0, min(1.0, 0.5 * (tr - 1.0))))


@njit()
def map_pose(model: np.ndarray, q: np.ndarray, steps: int, up: np.ndarray, prior_w: float,
             previous_R: np.ndarray, continuity_w: float, ambiguity_n: float, huber: float
             ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, int, np.ndarray, np.ndarray,
                        int]:
    """IPPE, then the maximum a posteriori candidate, refined.

    ``prior_w > 0`` enables the upright prior (see ``refine``); ``continuity_w > 0`` adds
    ``(continuity_w * angle to previous_R)²`` to each candidate's cost. Both candidates are
    refined only when a prior is on and the second's reprojection error is within
    ``ambiguity_n`` (normalised units) of the first's. Returns (status, R, t, J, chosen,
    candidate Rs, candidate ts, candidate count).
    """
    status, Rs, ts, errs, count = ippe4(model, q)
    if status != OK:
        return status, np.eye(3), np.zeros(3), np.zeros((8, 6)), 0, Rs, ts, 0
    if steps == 0:
        _, J = residuals_and_jacobian(Rs[0], ts[0], model, q)
        return OK, Rs[0].copy(), ts[0].copy(), J, 0, Rs, ts, count
    ambiguous = count > 1 and (prior_w > 0 or continuity_w > 0) and \
        errs[1] <= errs[0] + ambiguity_n
    best = np.inf
    chosen = 0
    R_best, t_best, J_best = Rs[0].copy(), ts[0].copy(), np.zeros((2 * q.shape[0], 6))
    for i in range(2 if ambiguous else 1):
        R, t, J, cost = refine(Rs[i].copy(), ts[i].copy(), model, q, steps, up, prior_w, huber)
        if continuity_w > 0:
            cost += (continuity_w * rotation_angle(R, previous_R)) ** 2
        if i == 0 or cost < best:
            best, chosen, R_best, t_best, J_best = cost, i, R, t, J
    if t_best[2] <= 0:
        return BEHIND, R_best, t_best, J_best, chosen, Rs, ts, count
    return OK, R_best, t_best, J_best, chosen, Rs, ts, count
