"""Is a quadrilateral an image of the deployment's rhombus? The shape test with intrinsics.

Without intrinsics the extractor can only ask whether the quadrilateral is an affine view of
the rhombus (``lines.weak_view``: the diagonals' ratio and angles); any parallelogram is an
affine view of any rhombus, so the test rests on the views the camera can have. With the
camera's intrinsics (K and distortion) and the rhombus's true diagonals, four vertices give
eight numbers for a planar pose's six: the best pose (IPPE's two candidates, each refined by
Gauss-Newton on the reprojection error weighted by the vertices' covariance) leaves a
chi-square with 2 degrees of freedom that a quadrilateral of another shape (a card, a square,
a wide rhombus) cannot bring down, except where the view is nearly affine (small, distant);
there the pose itself still says how the camera would be seeing it: off the marker's normal,
and rolled or pitched against the world's up (the camera's mount), which the humanoid
standing upright bounds. A quadrilateral beyond either bound is refused with the figure.

The pose comes from the pose estimator's own planar solver (``pose_estimator/p4p.py``);
this module is pure (no Zenoh) and runs once per accepted detection.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from services.core.camera import CameraModel, undistort_px
from services.core.jit import njit
from services.core.mounts import Geometry
from services.core.projection import normalise_px, project_px
from services.pose_estimator.p4p import (
    MESSAGES,
    OK,
    _solve_spd,
    exp_so3,
    ippe4,
    refine,
    residuals_and_jacobian,
)


class ShapeParams(BaseModel):
    """The shape test with intrinsics (``shape.py``); the only place its defaults are defined."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    max_chi2: float = Field(
        default=16.0, gt=0, description="with intrinsics: largest reprojection chi-square "
        "(2 degrees of freedom) of the best planar pose of the rhombus, vertex errors weighted "
        "by their covariance plus the floors (16: p = 0.0003 for a true marker)")
    floor_px: float = Field(
        default=0.15, ge=0, description="with intrinsics: the model's own error added to each "
        "vertex's sigma (px; the calibration's rms_px if larger): intrinsics and the printed "
        "shape are not exact")
    floor_share: float = Field(
        default=0.001, ge=0, description="with intrinsics: and a model error proportional "
        "to the marker's size (share of its longer diagonal)")
    shear_sigma: float = Field(
        default=0.04, ge=0, description="with intrinsics: a rolling shutter's horizontal "
        "shear (px per row, 1 sigma) the test allows for: a camera panning or a humanoid "
        "walking across the view slants the marker, which no pose explains")
    sigma_px: float = Field(default=0.2, gt=0, description=(
        "with intrinsics: the vertex sigma (px) when a detection has no covariance"))
    max_off_normal_deg: float = Field(
        default=75.0, gt=0, le=90, description="with intrinsics: views further off the "
        "marker's normal (the line of sight to its centre) are refused")
    max_roll_deg: float = Field(
        default=35.0, gt=0, le=180, description="with intrinsics: largest turn of the marker "
        "about its normal away from the world's up (the deployment's camera mount)")
    max_pitch_deg: float = Field(
        default=45.0, gt=0, le=90, description="with intrinsics: largest angle of the marker's "
        "normal above or below the world's horizontal (the humanoid stands upright)")
    weak_slack_deg: float = Field(
        default=0.0, ge=0, le=30, description="with intrinsics: the weak-perspective shape "
        "test's bounds (the extractor's max_off_normal_deg, max_roll_deg, max_pitch_deg) "
        "raised by this much, since the pose's own view is bounded here (steep views)")


NOT_POSITIVE = 100  # the kernel's status for a covariance not positive definite


@dataclass(frozen=True)
class ShapeFit:
    """The best planar pose of the rhombus for four vertices, and how well it fits.

    ``chi2``: squared reprojection errors normalised by the vertex covariance (plus the
    floor), summed over the four vertices (a chi-square with 2 degrees of freedom for the
    true marker); ``reprojection_px``: the largest vertex's distance to its reprojection;
    ``off_normal_deg``: the angle between the marker's normal and the line of sight to its
    centre; ``roll_deg``: its turn about its normal from the world's up; ``pitch_deg``: its
    normal's angle above or below the horizontal; ``distance_m``: to its centre."""

    chi2: float
    reprojection_px: float
    off_normal_deg: float
    roll_deg: float
    pitch_deg: float
    distance_m: float
    T_camera_marker: np.ndarray


@njit()
def _whitener(cov: np.ndarray, J: np.ndarray, shear_px: np.ndarray) -> np.ndarray:
    """The (8, 8) inverse square root of the vertices' covariance in normalised units
    (through the undistortion's local Jacobian J (4, 2, 2)): their own (4, 2, 2) px², and a
    rolling shutter's unknown horizontal shear moving vertex k by ``shear_px[k]`` px (1
    sigma), common to the four. Zeros when a covariance is not positive definite."""
    W = np.zeros((8, 8))
    u = np.zeros(8)
    for k in range(4):
        Jk = J[k]
        C = Jk @ cov[k] @ Jk.T
        a, b, c = C[0, 0], C[0, 1], C[1, 1]
        if not (a > 0.0 and a * c - b * b > 0.0):
            return np.zeros((8, 8))
        l11 = math.sqrt(a)
        l21 = b / l11
        l22 = math.sqrt(c - l21 * l21)
        W[2 * k, 2 * k] = 1.0 / l11
        W[2 * k + 1, 2 * k] = -l21 / (l11 * l22)
        W[2 * k + 1, 2 * k + 1] = 1.0 / l22
        u[2 * k], u[2 * k + 1] = Jk[0, 0] * shear_px[k], Jk[1, 0] * shear_px[k]
    # C = L (I + w w^T) L^T with w = L^-1 u: its inverse square root is (I - c w w^T) L^-1
    w = W @ u
    ww = w @ w
    if ww > 0.0:
        W = W - (1.0 - 1.0 / math.sqrt(1.0 + ww)) / ww * np.outer(w, w @ W)
    return W


@njit()
def _fit(v: np.ndarray, cov: np.ndarray, J: np.ndarray, q: np.ndarray, model: np.ndarray,
         shear_sigma: float, K: np.ndarray, dist: np.ndarray
         ) -> tuple[int, float, float, np.ndarray, np.ndarray]:
    """(status, chi2, largest miss px less the best shear, R, t) of the best planar pose:
    IPPE's candidates each refined to least squares, the better one weighted by the
    whitened covariance then refined by Gauss-Newton (its best iterate: the first step may
    overshoot when the shear's freedom moves the pose)."""
    shear_px = shear_sigma * (v[:, 1] - v[:, 1].mean())
    W = _whitener(cov, J, shear_px)
    if W[0, 0] == 0.0:
        return NOT_POSITIVE, np.inf, np.inf, np.eye(3), np.zeros(3)
    status, Rs, ts, _, count = ippe4(model, q)
    if status != OK:
        return status, np.inf, np.inf, np.eye(3), np.zeros(3)
    R, t, best = Rs[0].copy(), ts[0].copy(), np.inf
    for i in range(count):
        Ri, ti, _, _ = refine(Rs[i].copy(), ts[i].copy(), model, q, 5, np.zeros(3), 0.0, 0.0)
        r, _ = residuals_and_jacobian(Ri, ti, model, q)
        rw = W @ r
        if rw @ rw < best:
            R, t, best = Ri, ti, rw @ rw
    R_best, t_best, best = R.copy(), t.copy(), np.inf
    for _ in range(6):
        r, Jr = residuals_and_jacobian(R, t, model, q)
        rw = W @ r
        Jw = W @ Jr
        chi2 = rw @ rw
        if not math.isfinite(chi2):
            break
        if chi2 < best:
            R_best, t_best, best = R.copy(), t.copy(), chi2
        delta = _solve_spd(Jw.T @ Jw, Jw.T @ rw)
        if not np.all(np.isfinite(delta)):
            break
        R = exp_so3(delta[:3]) @ R
        t = t + delta[3:]
        if t[2] <= 0.0 or delta @ delta < 1e-12:
            break
    # the largest miss in px, less the shear that best explains the misses (its prior too)
    miss = project_px(K, dist, model @ R_best.T + t_best) - v
    gCg = 0.0
    gCm = 0.0
    for k in range(4):
        a, b, c = cov[k, 0, 0], cov[k, 0, 1], cov[k, 1, 1]
        det = a * c - b * b
        g = v[k, 1] - v[:, 1].mean()
        gCg += g * g * c / det
        gCm += g * (c * miss[k, 0] - b * miss[k, 1]) / det
    if shear_sigma > 0.0:
        s = gCm / (gCg + 1.0 / (shear_sigma * shear_sigma))
        for k in range(4):
            miss[k, 0] -= s * (v[k, 1] - v[:, 1].mean())
    worst = 0.0
    for k in range(4):
        worst = max(worst, math.hypot(miss[k, 0], miss[k, 1]))
    return OK, best, worst, R_best, t_best


def fit(vertices_px: np.ndarray, cov_px2: np.ndarray | None, camera: CameraModel,
        marker_points: np.ndarray, up_cam: np.ndarray, params: ShapeParams) -> ShapeFit | str:
    """The best planar pose of the rhombus ``marker_points`` (4, 3) m, left, top, right,
    bottom, for ``vertices_px`` (4, 2) with their covariance (4, 2, 2) px² (None: ``sigma_px``
    each way), and its figures; a string says why there is none."""
    v = np.ascontiguousarray(vertices_px, np.float64)
    cov = (np.tile(params.sigma_px ** 2 * np.eye(2), (4, 1, 1)) if cov_px2 is None
           else np.asarray(cov_px2, np.float64).reshape(4, 2, 2))
    if v.shape != (4, 2) or not (np.isfinite(v).all() and np.isfinite(cov).all()):
        return "vertices or their covariance not finite"
    (x0, y0), (x1, y1), (x2, y2), (x3, y3) = v.tolist()
    size = max(math.hypot(x2 - x0, y2 - y0), math.hypot(x3 - x1, y3 - y1))
    floor2 = max(params.floor_px, camera.rms_px) ** 2 + (params.floor_share * size) ** 2
    cov = cov + floor2 * np.eye(2)
    K = camera.K
    if camera.dist.any():  # the undistortion's local Jacobian, numerically
        h = 0.5
        step = np.array([[h, 0.0], [0.0, h]])
        qs = undistort_px(camera, np.concatenate([v, v + step[0], v + step[1]]))
        q = np.ascontiguousarray(qs[:4])
        J = np.ascontiguousarray(np.stack([(qs[4:8] - q) / h, (qs[8:] - q) / h], axis=2))
    else:  # linear: the inverse of K's upper 2 x 2
        q = normalise_px(K, v)
        J = np.empty((4, 2, 2))
        J[:] = ((1.0 / K[0, 0], -K[0, 1] / (K[0, 0] * K[1, 1])), (0.0, 1.0 / K[1, 1]))
    status, chi2, miss, R, t = _fit(v, cov, J, q, np.ascontiguousarray(marker_points,
                                                                       np.float64),
                                    params.shear_sigma, K, camera.dist)
    if status == NOT_POSITIVE:
        return "vertex covariance not positive definite"
    if status != OK:
        return MESSAGES[status]
    n0, n1, n2 = R[:, 2].tolist()
    t0, t1, t2 = t.tolist()
    distance = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    off_normal = math.degrees(math.acos(min(abs(n0 * t0 + n1 * t1 + n2 * t2) / distance, 1.0)))
    u0, u1, u2 = (up_cam / np.linalg.norm(up_cam)).tolist()
    elevation = n0 * u0 + n1 * u1 + n2 * u2
    pitch = math.degrees(math.asin(min(abs(elevation), 1.0)))
    p0, p1, p2 = u0 - elevation * n0, u1 - elevation * n1, u2 - elevation * n2  # up, in plane
    norm = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    y0_, y1_, y2_ = R[:, 1].tolist()
    roll = 180.0 if norm < 1e-9 else math.degrees(math.acos(
        max(-1.0, min(1.0, (y0_ * p0 + y1_ * p1 + y2_ * p2) / norm))))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return ShapeFit(float(chi2), float(miss), off_normal, roll, pitch, distance, T)


def refusal(f: ShapeFit | str, params: ShapeParams) -> str:
    """Why the fitted quadrilateral is not the marker ("" when it may be)."""
    if isinstance(f, str):
        return f"not the marker's shape: no planar pose of the rhombus ({f})"
    if f.chi2 > params.max_chi2:
        return (f"not the marker's shape: its best pose reprojects "
                f"{f.reprojection_px:.1f} px off (chi-square {f.chi2:.0f} > "
                f"{params.max_chi2:.0f})")
    if f.off_normal_deg > params.max_off_normal_deg or f.roll_deg > params.max_roll_deg or \
            f.pitch_deg > params.max_pitch_deg:
        return (f"not the marker's shape in any expected view (its best pose is "
                f"{f.off_normal_deg:.0f} deg off its normal, rolled {f.roll_deg:.0f} deg, "
                f"its normal {f.pitch_deg:.0f} deg off the horizontal)")
    return ""


class ShapeTest:
    """The shape test for one camera and one deployment's geometry."""

    def __init__(self, camera: CameraModel, geometry: Geometry | None = None,
                 params: ShapeParams | None = None) -> None:
        geometry = geometry or Geometry()
        self.camera = camera
        self.size = (camera.width, camera.height)
        self.params = params or ShapeParams()
        self.marker_points = geometry.marker_points()
        self.up_cam = geometry.T_base_camera()[2, :3].copy()  # the world's up, camera frame

    def fit(self, vertices_px: np.ndarray, cov_px2: np.ndarray | None) -> ShapeFit | str:
        return fit(vertices_px, cov_px2, self.camera, self.marker_points, self.up_cam,
                   self.params)

    def refusal(self, vertices_px: np.ndarray, cov_px2: np.ndarray | None) -> str:
        """Why these vertices are not the marker ("" when they may be)."""
        try:
            f = self.fit(vertices_px, cov_px2)
        except (ValueError, ArithmeticError, np.linalg.LinAlgError) as err:  # odd intrinsics
            f = f"{type(err).__name__}: {err}"
        return refusal(f, self.params)


def warm_up() -> None:
    """Compile (or load from numba's on-disk cache) the fit's kernels."""
    camera = CameraModel.paper()
    v = np.array([[290.0, 240.0], [320.0, 200.0], [350.0, 240.0], [320.0, 280.0]])
    ShapeTest(camera).refusal(v, None)
    ShapeTest(CameraModel(camera.K, np.array([-0.1, 0.0, 0.0, 0.0, 0.0]))).refusal(v, None)
