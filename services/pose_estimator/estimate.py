"""From pixel vertices to the marker pose in the camera and the humanoid's floor pose.

``T_world_humanoid = T_world_base · T_base_camera · T_camera_marker · T_marker_humanoid``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from services.camera import CameraModel
from services.geometry import floor_pose, inv_T, make_T
from services.pose_estimator.p4p import (
    PoseError,
    _exp_so3,
    covariance_6,
    ippe,
    refine,
)


@dataclass(frozen=True)
class MarkerPose:
    """T_camera_marker (4x4) with its quality figures and both IPPE candidates."""

    T_camera_marker: np.ndarray
    reprojection_px: float
    covariance: np.ndarray              # 6x6 over (rotation vector rad, translation m)
    candidates: tuple[np.ndarray, ...]  # 4x4 each, IPPE's two, best-reprojection first
    chosen: int                         # index into candidates before refinement


def undistort_px(camera: CameraModel, points_px: np.ndarray) -> np.ndarray:
    """Pixels -> ideal normalised image coordinates (N, 2), removing lens distortion."""
    pts = np.asarray(points_px, np.float64).reshape(-1, 1, 2)
    if not np.any(camera.dist):
        K = camera.K
        y = (pts[:, 0, 1] - K[1, 2]) / K[1, 1]
        x = (pts[:, 0, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        return np.column_stack([x, y])
    return cv2.undistortPointsIter(pts, camera.K, camera.dist, None, None,
                                   (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
                                   ).reshape(-1, 2)


def choose_upright(candidates: list, up_cam: np.ndarray | None, ambiguity: float,
                   min_gain_rad: float = math.radians(5.0)) -> int:
    """Index of the candidate to keep (candidates sorted by reprojection error).

    The humanoid stands upright, so the marker's normal is horizontal: its elevation
    ``asin(|n . up|)`` is near zero whatever the marker's roll. The best reprojection wins
    unless the other candidate explains the image about as well (error within 3x the best
    plus ``ambiguity``, normalised units) and its normal is more level by ``min_gain_rad``.
    ``up_cam`` is the world's up in the camera frame."""
    if up_cam is None or len(candidates) < 2:
        return 0
    best, other = candidates[0], candidates[1]
    if other.error > 3.0 * best.error + ambiguity:
        return 0
    tilt_best = math.asin(min(1.0, abs(float(best.R[:, 2] @ up_cam))))
    tilt_other = math.asin(min(1.0, abs(float(other.R[:, 2] @ up_cam))))
    return 1 if tilt_other < tilt_best - min_gain_rad else 0


def estimate_marker_pose(camera: CameraModel, vertices_px: np.ndarray, marker_points: np.ndarray,
                         *, up_cam: np.ndarray | None = None, refine_steps: int = 5,
                         sigma_px: float = 0.2) -> MarkerPose:
    """Pose of the marker in the camera from its four pixel vertices (left, top, right,
    bottom); raises PoseError with the reason when impossible."""
    v = np.asarray(vertices_px, np.float64)
    if v.shape != (4, 2):
        raise PoseError(f"need 4 vertices (4, 2), got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise PoseError("vertices contain NaN or inf")
    q = undistort_px(camera, v)
    cands = ippe(marker_points, q)
    f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    k = choose_upright(cands, up_cam, ambiguity=2.0 * sigma_px / f)
    R, t = cands[k].R, cands[k].t
    if refine_steps:
        R, t, J = refine(R, t, marker_points, q, refine_steps)
    else:
        from services.pose_estimator.p4p import residuals_and_jacobian
        _, J = residuals_and_jacobian(R, t, marker_points, q)
    if t[2] <= 0:
        raise PoseError("the pose puts the marker behind the camera")
    proj = camera.project(marker_points @ R.T + t)
    reproj = float(np.sqrt(np.mean(np.sum((proj - v) ** 2, axis=1))))
    cov = covariance_6(J, sigma_px / f)
    return MarkerPose(make_T(R, t), reproj, cov, tuple(make_T(c.R, c.t) for c in cands), k)


def humanoid_floor_pose(T_world_camera: np.ndarray, T_camera_marker: np.ndarray,
                        T_marker_humanoid: np.ndarray, cov6: np.ndarray | None = None
                        ) -> tuple[tuple[float, float, float], np.ndarray | None]:
    """(x m, y m, yaw rad) of the humanoid in the world and its 3x3 covariance (from the 6x6
    marker-pose covariance by a numerical Jacobian)."""
    def pose_of(Tcm: np.ndarray) -> np.ndarray:
        return np.array(floor_pose(T_world_camera @ Tcm @ T_marker_humanoid))

    base = pose_of(T_camera_marker)
    if cov6 is None:
        return (float(base[0]), float(base[1]), float(base[2])), None
    J = np.zeros((3, 6))
    eps = 1e-6
    R, t = T_camera_marker[:3, :3], T_camera_marker[:3, 3]
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        Tp = make_T(_exp_so3(d[:3]) @ R, t + d[3:])
        diff = pose_of(Tp) - base
        diff[2] = (diff[2] + math.pi) % (2 * math.pi) - math.pi
        J[:, i] = diff / eps
    return (float(base[0]), float(base[1]), float(base[2])), J @ cov6 @ J.T


def up_in_camera(T_base_camera: np.ndarray) -> np.ndarray:
    """The world's up (= base z, the base stands on the floor) in the camera frame."""
    return inv_T(T_base_camera)[:3, :3] @ np.array([0.0, 0.0, 1.0])
