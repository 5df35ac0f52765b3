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
from services.core.mounts import Geometry
from services.pose_estimator.estimate import up_in_camera
from services.pose_estimator.p4p import (
    MESSAGES,
    OK,
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
        default=10.0, ge=0, le=30, description="with intrinsics: the weak-perspective shape "
        "test's bounds (the extractor's max_off_normal_deg, max_roll_deg, max_pitch_deg) "
        "raised by this much, since the pose's own view is bounded here (steep views)")


_NO_UP = np.zeros(3)  # refine's upright prior, off


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


def _whitener(vertices_px: np.ndarray, cov_px2: np.ndarray, shear_sigma: float,
              camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """Normalised image points (4, 2) and the (8, 8) inverse Cholesky factor of their
    covariance in normalised units (through the undistortion's local Jacobian): the vertices'
    own (4, 2, 2) px², and a rolling shutter's unknown horizontal shear (x moves by
    ``shear_sigma`` px per row from the centre, 1 sigma), common to the four."""
    if camera.dist.any():
        h = 0.5
        step = np.array([[h, 0.0], [0.0, h]])
        pts = np.concatenate([vertices_px, vertices_px + step[0], vertices_px + step[1]])
        qs = undistort_px(camera, pts)
        q = qs[:4]
        J = np.stack([(qs[4:8] - q) / h, (qs[8:] - q) / h], axis=2)  # (4, 2, 2) dq / dpx
    else:  # linear: the inverse of K's upper 2 x 2
        q = undistort_px(camera, vertices_px)
        K = camera.K
        J = np.broadcast_to(np.array([[1.0 / K[0, 0], -K[0, 1] / (K[0, 0] * K[1, 1])],
                                      [0.0, 1.0 / K[1, 1]]]), (4, 2, 2))
    C = (J @ cov_px2 @ J.transpose(0, 2, 1)).tolist()  # per vertex, normalised units
    Linv = np.zeros((8, 8))  # the inverse Cholesky factor of the block-diagonal part
    for k, ((a, b), (_, c)) in enumerate(C):
        if not (a > 0 and c * a - b * b > 0):
            raise np.linalg.LinAlgError("not positive definite")
        l11 = math.sqrt(a)
        l21 = b / l11
        l22 = math.sqrt(c - l21 * l21)
        Linv[2 * k, 2 * k] = 1.0 / l11
        Linv[2 * k + 1, 2 * k] = -l21 / (l11 * l22)
        Linv[2 * k + 1, 2 * k + 1] = 1.0 / l22
    # the shear adds u u^T (u: its effect, normalised): C = L (I + w w^T) L^T, w = L^-1 u,
    # whose inverse square root (I - c w w^T) L^-1 whitens (Sherman-Morrison)
    u = (J[:, :, 0] * (shear_sigma * (vertices_px[:, 1] - vertices_px[:, 1].mean()))[:, None]
         ).ravel()
    w = Linv @ u
    ww = float(w @ w)
    if ww > 0:
        c = (1.0 - 1.0 / math.sqrt(1.0 + ww)) / ww
        Linv -= c * np.outer(w, w @ Linv)
    return np.ascontiguousarray(q), Linv


def _weighted_fit(R: np.ndarray, t: np.ndarray, model: np.ndarray, q: np.ndarray,
                  W: np.ndarray, iterations: int = 6
                  ) -> tuple[np.ndarray, np.ndarray, float]:
    """Gauss-Newton on the whitened reprojection residuals from (R, t): (R, t, chi2) of the
    best iterate (the first step may overshoot when the shear's freedom moves the pose)."""
    best = (R, t, np.inf)
    for _ in range(iterations):
        r, J = residuals_and_jacobian(R, t, model, q)
        rw, Jw = W @ r, W @ J
        chi2 = float(rw @ rw)
        if not math.isfinite(chi2):
            break
        if chi2 < best[2]:
            best = (R, t, chi2)
        try:
            delta = -np.linalg.solve(Jw.T @ Jw + 1e-12 * np.eye(6), Jw.T @ rw)
        except np.linalg.LinAlgError:
            break
        R, t = exp_so3(delta[:3]) @ R, t + delta[3:]
        if t[2] <= 0 or float(delta @ delta) < 1e-12:
            break
    return best


def fit(vertices_px: np.ndarray, cov_px2: np.ndarray | None, camera: CameraModel,
        marker_points: np.ndarray, up_cam: np.ndarray, params: ShapeParams) -> ShapeFit | str:
    """The best planar pose of the rhombus ``marker_points`` (4, 3) m, left, top, right,
    bottom, for ``vertices_px`` (4, 2) with their covariance (4, 2, 2) px² (None: ``sigma_px``
    each way), and its figures; a string says why there is none."""
    v = np.ascontiguousarray(vertices_px, np.float64)
    cov = (np.tile(params.sigma_px ** 2 * np.eye(2), (4, 1, 1)) if cov_px2 is None
           else np.asarray(cov_px2, np.float64).reshape(4, 2, 2))
    if not (np.isfinite(v).all() and np.isfinite(cov).all()):
        return "vertices or their covariance not finite"
    size = max(math.hypot(*(v[2] - v[0])), math.hypot(*(v[3] - v[1])))
    floor2 = max(params.floor_px, camera.rms_px) ** 2 + (params.floor_share * size) ** 2
    cov = cov + floor2 * np.eye(2)
    try:
        q, W = _whitener(v, cov, params.shear_sigma, camera)
    except np.linalg.LinAlgError:
        return "vertex covariance not positive definite"
    model = np.ascontiguousarray(marker_points, np.float64)
    status, Rs, ts, _, count = ippe4(model, q)
    if status != OK:
        return MESSAGES[status]
    start: tuple[np.ndarray, np.ndarray, float] | None = None
    for i in range(count):  # each candidate to its least squares (compiled) ...
        R, t, _, _ = refine(Rs[i].copy(), ts[i].copy(), model, q, 5, _NO_UP, 0.0, 0.0)
        rw = W @ residuals_and_jacobian(R, t, model, q)[0]
        if start is None or float(rw @ rw) < start[2]:
            start = (R, t, float(rw @ rw))
    assert start is not None  # ... the better one weighted (both end there when they differ)
    R, t, chi2 = _weighted_fit(start[0], start[1], model, q, W)
    miss = camera.project(model @ R.T + t) - v  # px, less the rolling shutter's best shear:
    g = np.zeros((4, 2))
    g[:, 0] = v[:, 1] - v[:, 1].mean()
    Ci = np.linalg.inv(cov)
    gCg = float(np.einsum("ki,kij,kj->", g, Ci, g))
    if params.shear_sigma > 0:
        miss -= g * float(np.einsum("ki,kij,kj->", g, Ci, miss)) / (
            gCg + 1.0 / params.shear_sigma ** 2)
    n = R[:, 2]
    distance = float(np.linalg.norm(t))
    sight = -t / distance
    off_normal = math.degrees(math.acos(min(abs(float(n @ sight)), 1.0)))
    up = up_cam / np.linalg.norm(up_cam)
    elevation = float(n @ up)
    pitch = math.degrees(math.asin(min(abs(elevation), 1.0)))
    up_in_plane = up - elevation * n  # the world's up in the marker's plane
    norm = float(np.linalg.norm(up_in_plane))
    roll = 180.0 if norm < 1e-9 else math.degrees(math.acos(
        max(-1.0, min(1.0, float(R[:, 1] @ up_in_plane) / norm))))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return ShapeFit(chi2, float(np.sqrt((miss ** 2).sum(1)).max()), off_normal, roll,
                    pitch, distance, T)


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
        self.up_cam = up_in_camera(geometry.T_base_camera())

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
