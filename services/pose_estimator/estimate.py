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
    residuals_and_jacobian,
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
    deskewed, K = camera.deskew_px(pts)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
    src = deskewed.reshape(-1, 1, 2)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
        out = cv2.undistortPointsIter(src, K, camera.dist, None, None, criteria)
    else:  # OpenCV 5 folds the criteria into undistortPoints
        out = cv2.undistortPoints(src, K, camera.dist, None, None, None, criteria)
    return out.reshape(-1, 2)


def estimate_marker_pose(camera: CameraModel, vertices_px: np.ndarray, marker_points: np.ndarray,
                         *, up_cam: np.ndarray | None = None, refine_steps: int = 5,
                         sigma_px: float = 0.2, tilt_sigma_rad: float = math.radians(3.0),
                         ambiguity: float = 4.0, previous_R: np.ndarray | None = None,
                         continuity_sigma_rad: float = math.radians(10.0)) -> MarkerPose:
    """Pose of the marker in the camera from its four pixel vertices (left, top, right,
    bottom); raises PoseError with the reason when impossible.

    IPPE gives two candidates. With ``up_cam`` (the world's up in the camera frame) the
    humanoid-stands-upright prior decides between them: both are refined to the maximum a
    posteriori pose (reprojection error with image noise ``sigma_px``, plus the marker
    normal level within ``tilt_sigma_rad``) and the lower posterior cost wins. The prior is
    only consulted when the second candidate's reprojection error is within ``ambiguity``
    image-noise sigmas; otherwise the image alone decides. Without ``up_cam`` or refinement,
    the best reprojection wins. ``previous_R`` (the marker's rotation in the previous frame)
    adds a continuity prior: rotation change within ``continuity_sigma_rad``.
    """
    v = np.asarray(vertices_px, np.float64)
    if v.shape != (4, 2):
        raise PoseError(f"need 4 vertices (4, 2), got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise PoseError("vertices contain NaN or inf")
    q = undistort_px(camera, v)
    cands = ippe(marker_points, q)
    f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    sigma_n = sigma_px / f
    chosen = 0
    if refine_steps:
        prior = None if up_cam is None else (up_cam, sigma_n / tilt_sigma_rad)
        ambiguous = len(cands) > 1 and (prior is not None or previous_R is not None) and \
            cands[1].error <= cands[0].error + ambiguity * sigma_n
        options = [refine(c.R, c.t, marker_points, q, refine_steps, prior)
                   for c in (cands if ambiguous else cands[:1])]
        costs = [o[3] for o in options]
        if previous_R is not None:
            for i, o in enumerate(options):
                turn = math.acos(max(-1.0, min(1.0, (np.trace(o[0].T @ previous_R) - 1) / 2)))
                costs[i] += (sigma_n * turn / continuity_sigma_rad) ** 2
        chosen = int(np.argmin(costs))
        R, t, J, _ = options[chosen]
    else:
        R, t = cands[0].R, cands[0].t
        _, J = residuals_and_jacobian(R, t, marker_points, q)
    if t[2] <= 0:
        raise PoseError("the pose puts the marker behind the camera")
    proj = camera.project(marker_points @ R.T + t)
    reproj = float(np.sqrt(np.mean(np.sum((proj - v) ** 2, axis=1))))
    cov = covariance_6(J, sigma_n)
    return MarkerPose(make_T(R, t), reproj, cov, tuple(make_T(c.R, c.t) for c in cands),
                      chosen)


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
