"""Accuracy of our P4P beside OpenCV's solvePnP on the same noisy vertices (tests, bench).

Views follow the system's geometry, so the upright prior holds: the humanoid stands at a
random floor pose 15-80 cm in front of a camera whose height and pitch vary, with its marker
rolled a little by the gait; vertices get Gaussian noise of 0.1-1 px.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from services.camera import CameraModel
from services.config import Geometry
from services.geometry import T_base_camera, T_floor, inv_T, make_T, rot_z
from services.pose_estimator.estimate import estimate_marker_pose, up_in_camera


@dataclass(frozen=True)
class PoseCase:
    T_camera_marker: np.ndarray
    vertices_px: np.ndarray      # noisy
    up_cam: np.ndarray
    noise_px: float


def pose_cases(n: int, seed: int = 0, camera: CameraModel | None = None,
               noise_px: tuple[float, float] = (0.1, 1.0)) -> list[PoseCase]:
    camera = camera or CameraModel.paper()
    g = Geometry()
    pts = g.marker_points()
    rng = np.random.default_rng(seed)
    out: list[PoseCase] = []
    while len(out) < n:
        T_bc = T_base_camera(0.0, rng.uniform(0.12, 0.3), math.radians(rng.uniform(-5, 20)))
        dist = rng.uniform(0.15, 0.8)
        bearing = rng.uniform(-0.3, 0.3)
        mx, my = dist * math.cos(bearing), dist * math.sin(bearing)
        yaw = math.atan2(my, mx) + math.radians(rng.uniform(-40, 40))
        hx, hy = mx + g.marker_back_offset_m * math.cos(yaw), my + g.marker_back_offset_m * \
            math.sin(yaw)
        sway = make_T(rot_z(math.radians(rng.uniform(-3, 3))), (0, 0, 0))
        T = inv_T(T_bc) @ T_floor(hx, hy, yaw) @ g.T_humanoid_marker() @ sway
        v = camera.project((T[:3, :3] @ pts.T).T + T[:3, 3])
        if T[2, 3] < 0.1 or np.any(v < 5) or np.any(v > [camera.width - 6, camera.height - 6]):
            continue
        sigma = rng.uniform(*noise_px)
        out.append(PoseCase(T, v + rng.normal(0, sigma, v.shape), up_in_camera(T_bc), sigma))
    return out


def _errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(position error m, rotation error rad)."""
    dR = T_est[:3, :3].T @ T_true[:3, :3]
    angle = math.acos(max(-1.0, min(1.0, (np.trace(dR) - 1) / 2)))
    return float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])), angle


def opencv_solver(flag: int, camera: CameraModel) -> Callable[[PoseCase], np.ndarray]:
    pts = Geometry().marker_points()

    def solve(case: PoseCase) -> np.ndarray:
        v, K = camera.deskew_px(case.vertices_px)  # OpenCV's model has no skew
        _, rvec, tvec = cv2.solvePnP(pts, v, K, camera.dist, flags=flag)
        R, _ = cv2.Rodrigues(rvec)
        return make_T(R, tvec.ravel())
    return solve


def ours_solver(camera: CameraModel, refine: bool = True) -> Callable[[PoseCase], np.ndarray]:
    pts = Geometry().marker_points()

    def solve(case: PoseCase) -> np.ndarray:
        return estimate_marker_pose(camera, case.vertices_px, pts, up_cam=case.up_cam,
                                    refine_steps=5 if refine else 0,
                                    sigma_px=case.noise_px).T_camera_marker
    return solve


def compare(cases: list[PoseCase], camera: CameraModel | None = None
            ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per method: arrays of position errors (m) and rotation errors (rad)."""
    camera = camera or CameraModel.paper()
    methods = {"ours (IPPE + upright prior + GN)": ours_solver(camera),
               "ours, analytic only": ours_solver(camera, refine=False),
               "cv2 IPPE": opencv_solver(cv2.SOLVEPNP_IPPE, camera),
               "cv2 ITERATIVE": opencv_solver(cv2.SOLVEPNP_ITERATIVE, camera),
               "cv2 SQPNP": opencv_solver(cv2.SOLVEPNP_SQPNP, camera)}
    out = {}
    for name, solve in methods.items():
        errs = np.array([_errors(solve(c), c.T_camera_marker) for c in cases])
        out[name] = (errs[:, 0], errs[:, 1])
    return out


def wrong_branches(cases: list[PoseCase], camera: CameraModel | None = None,
                   tilt_sigma_rad: float = math.radians(3.0)) -> tuple[int, int, int]:
    """(wrong, decidable, wrong among decidable) over views whose two IPPE candidates differ
    by > 5 deg: wrong when the final pose is nearer (in rotation) the candidate farther from
    the truth than it is to the truth; decidable when that candidate's normal is tilted more
    than 2 sigma beyond the truth's, so the upright prior can tell them apart."""
    camera = camera or CameraModel.paper()
    pts = Geometry().marker_points()
    wrong = decidable = wrong_decidable = 0
    for c in cases:
        mp = estimate_marker_pose(camera, c.vertices_px, pts, up_cam=c.up_cam,
                                  sigma_px=c.noise_px, tilt_sigma_rad=tilt_sigma_rad)
        if len(mp.candidates) < 2:
            continue
        d = [_errors(T, c.T_camera_marker)[1] for T in mp.candidates]
        if abs(d[0] - d[1]) <= math.radians(5):
            continue
        other = mp.candidates[int(np.argmax(d))]
        is_wrong = _errors(mp.T_camera_marker, c.T_camera_marker)[1] > \
            _errors(mp.T_camera_marker, other)[1]
        tilt_other = math.asin(min(1.0, abs(float(other[:3, 2] @ c.up_cam))))
        tilt_true = math.asin(min(1.0, abs(float(c.T_camera_marker[:3, 2] @ c.up_cam))))
        can = tilt_other > 2 * tilt_sigma_rad + tilt_true
        decidable += int(can)
        wrong += int(is_wrong)
        wrong_decidable += int(can and is_wrong)
    return wrong, decidable, wrong_decidable
