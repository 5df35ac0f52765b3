"""Accuracy of our P4P beside OpenCV's solvePnP on the same noisy vertices (tests, bench).

Views follow the system's geometry, so the upright prior holds: the humanoid stands at a
random floor pose 15-80 cm in front of a camera whose height and pitch vary, leaning up to
2 deg forward or back, its marker rolled a little by the gait; vertices get Gaussian noise
of 0.1-1 px.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from services.core.camera import CameraModel, undistort_px
from services.core.geometry import T_base_camera, T_floor, inv_T, make_T, rot_x, rot_y, rot_z
from services.core.mounts import Geometry
from services.pose_estimator.estimate import (
    TILT_HUBER_SIGMAS,
    TILT_SIGMA_DEG,
    VERTEX_SIGMA_PX,
    estimate_marker_pose,
    up_in_camera,
)
from services.pose_estimator.p4p import ippe, posterior_cost, refine


@dataclass(frozen=True)
class PoseCase:
    T_camera_marker: np.ndarray
    vertices_px: np.ndarray      # noisy
    up_cam: np.ndarray
    noise_px: float


def pose_cases(n: int, seed: int = 0, camera: CameraModel | None = None,
               noise_px: tuple[float, float] = (0.1, 1.0), lean_deg: float = 2.0,
               roll_deg: float = 0.0, mount_error_deg: float = 0.0) -> list[PoseCase]:
    """Views of the system's geometry. ``lean_deg``: the marker pitched up to this forward or
    back; ``roll_deg``: rolled up to this sideways (both break the upright prior);
    ``mount_error_deg``: the up vector given to the estimator comes from a mount pitched
    and rolled this much off the true one (a deployment file that is off)."""
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
        lean = make_T(rot_y(math.radians(rng.uniform(-lean_deg, lean_deg))) @ rot_x(
            math.radians(rng.uniform(-roll_deg, roll_deg))), (0, 0, 0))
        T = inv_T(T_bc) @ T_floor(hx, hy, yaw) @ lean @ g.T_humanoid_marker() @ sway
        v = camera.project((T[:3, :3] @ pts.T).T + T[:3, 3])
        if T[2, 3] < 0.1 or np.any(v < 5) or np.any(v > [camera.width - 6, camera.height - 6]):
            continue
        sigma = rng.uniform(*noise_px)
        up = up_in_camera(T_bc)
        if mount_error_deg > 0:
            a = math.radians(mount_error_deg)
            up = rot_x(a * rng.choice([-1, 1])) @ rot_z(rng.uniform(-a, a)) @ up
        out.append(PoseCase(T, v + rng.normal(0, sigma, v.shape), up, sigma))
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


def ours_solver(camera: CameraModel, refine: bool = True, sigma_px: float | None = None
                ) -> Callable[[PoseCase], np.ndarray]:
    """Our estimator with the up vector of the view's mounts (which a deployment configures)
    and ``sigma_px`` as the vertex noise (the service's setting), or each view's true noise
    when None (knowledge the service does not have)."""
    pts = Geometry().marker_points()

    def solve(case: PoseCase) -> np.ndarray:
        return estimate_marker_pose(camera, case.vertices_px, pts, up_cam=case.up_cam,
                                    refine_steps=5 if refine else 0,
                                    sigma_px=case.noise_px if sigma_px is None else sigma_px
                                    ).T_camera_marker
    return solve



def unrelated_views(n: int, seed: int = 0, *, lean_deg: float = 3.0, roll_deg: float = 0.0,
                    mount_off_deg: float = 0.0, noise_px: float = 0.3,
                    camera: CameraModel | None = None) -> list[PoseCase]:
    """Unrelated views of the humanoid in front of a camera at the marker's height (the
    deployment's geometry): 15-80 cm, bearing within ±17°, heading within ±40° of the line
    of sight; the marker leaning forward or back up to ``lean_deg`` and sideways up to
    ``roll_deg``; the real mount pitched ±``mount_off_deg`` from the file's, whose up
    vector the estimator is given; ``noise_px`` on every vertex coordinate."""
    camera = camera or CameraModel.paper()
    g = Geometry()
    pts = g.marker_points()
    T_file = g.T_base_camera()
    rng = np.random.default_rng(seed)
    out: list[PoseCase] = []
    while len(out) < n:
        dist, bearing = rng.uniform(0.15, 0.8), rng.uniform(-0.3, 0.3)
        yaw = bearing + math.radians(rng.uniform(-40, 40))
        tilt = make_T(rot_y(math.radians(rng.uniform(-lean_deg, lean_deg))) @ rot_x(
            math.radians(rng.uniform(-roll_deg, roll_deg))), (0, 0, 0))
        T_real = T_file if mount_off_deg == 0 else T_base_camera(
            g.camera_forward_m, g.camera_height_m,
            g.camera_pitch_rad + math.radians(mount_off_deg * rng.choice([-1, 1])))
        T = inv_T(T_real) @ T_floor(dist * math.cos(bearing) + g.marker_back_offset_m *
                                    math.cos(yaw), dist * math.sin(bearing) +
                                    g.marker_back_offset_m * math.sin(yaw), yaw) @ tilt @ \
            g.T_humanoid_marker()
        v = camera.project(pts @ T[:3, :3].T + T[:3, 3])
        if T[2, 3] > 0.1 and np.all(v > 5) and np.all(v < [camera.width - 6,
                                                          camera.height - 6]):
            out.append(PoseCase(T, v + rng.normal(0, noise_px, v.shape), up_in_camera(T_file),
                                noise_px))
    return out


def ippe_errors(cases: list[PoseCase], camera: CameraModel | None = None,
                noise_known: bool = True, **estimator: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Position errors (m) of our estimator and of OpenCV's IPPE on the same vertices.

    Ours as the service runs it on a single frame: the views' up vector (the mount's), the
    marker centre's height over the camera (the mounts': the elevation's up), the vertex
    sigma the extractor's covariance would carry (each view's noise) when ``noise_known``,
    else the fixed setting (``VERTEX_SIGMA_PX``); ``estimator`` keyword arguments on top.
    OpenCV gets the same pixels and intrinsics, no priors."""
    camera = camera or CameraModel.paper()
    g = Geometry()
    pts = g.marker_points()
    kw: dict[str, object] = {"height_m": g.marker_centre_height_m - g.camera_height_m}
    kw.update(estimator)
    cv = opencv_solver(cv2.SOLVEPNP_IPPE, camera)
    ours = np.array([_errors(estimate_marker_pose(
        camera, c.vertices_px, pts, up_cam=c.up_cam,
        sigma_px=c.noise_px if noise_known else VERTEX_SIGMA_PX,
        **kw).T_camera_marker, c.T_camera_marker)[0] for c in cases])  # type: ignore[arg-type]
    ref = np.array([_errors(cv(c), c.T_camera_marker)[0] for c in cases])
    return ours, ref


def ippe_ratios(ours: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """(median ratio, p90 ratio) of our position errors over OpenCV IPPE's."""
    return (float(np.median(ours) / np.median(ref)),
            float(np.percentile(ours, 90) / np.percentile(ref, 90)))


def against_ippe(cases: list[PoseCase], camera: CameraModel | None = None,
                 noise_known: bool = True, **estimator: float) -> tuple[float, float]:
    """Position error of our estimator over OpenCV's IPPE on the same vertices (see
    ``ippe_errors``): (median ratio, p90 ratio)."""
    return ippe_ratios(*ippe_errors(cases, camera, noise_known, **estimator))


def compare(cases: list[PoseCase], camera: CameraModel | None = None
            ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per method: arrays of position errors (m) and rotation errors (rad)."""
    camera = camera or CameraModel.paper()
    methods = {"ours (IPPE + upright prior + GN)": ours_solver(camera, sigma_px=VERTEX_SIGMA_PX),
               "ours, given each view's true noise": ours_solver(camera),
               "ours, analytic only": ours_solver(camera, refine=False),
               "cv2 IPPE": opencv_solver(cv2.SOLVEPNP_IPPE, camera),
               "cv2 ITERATIVE": opencv_solver(cv2.SOLVEPNP_ITERATIVE, camera),
               "cv2 SQPNP": opencv_solver(cv2.SOLVEPNP_SQPNP, camera)}
    out = {}
    for name, solve in methods.items():
        errs = np.array([_errors(solve(c), c.T_camera_marker) for c in cases])
        out[name] = (errs[:, 0], errs[:, 1])
    return out


@dataclass(frozen=True)
class BranchReport:
    """How often the final pose is on the wrong IPPE branch (see ``wrong_branches``)."""

    views: int            # views whose mirror pose is more than 10 deg from the truth
    wrong: int            # of those: the final pose nearer the mirror than the truth
    decidable: int        # views whose mirror is tilted > ``margin`` sigma beyond the truth
    wrong_decidable: int  # of those: wrong
    search_misses: int    # wrong although the truth's side has the higher posterior peak


def _mirror(camera: CameraModel, T_true: np.ndarray, pts: np.ndarray) -> np.ndarray | None:
    """The second IPPE pose of the noise-free view: the branch a wrong choice lands on."""
    v = camera.project((T_true[:3, :3] @ pts.T).T + T_true[:3, 3])
    for c in ippe(pts, undistort_px(camera, v)):
        T = make_T(c.R, c.t)
        if _errors(T, T_true)[1] > math.radians(10):
            return T
    return None


def _tilt(T: np.ndarray, up_cam: np.ndarray) -> float:
    """Angle (rad) between the marker plane and the vertical: 0 when upright."""
    return math.asin(min(1.0, abs(float(T[:3, 2] @ up_cam))))


def wrong_branches(cases: list[PoseCase], camera: CameraModel | None = None,
                   tilt_sigma_rad: float = math.radians(TILT_SIGMA_DEG), margin: float = 4.0,
                   prior: bool = True, upright_probability: float = 1.0) -> BranchReport:
    """Branch choices of the estimator (upright prior on unless ``prior`` is False, tested per
    view when ``upright_probability`` is below 1; no continuity prior).

    The mirror is the other IPPE pose of the noise-free view; a view counts when it is more
    than 10 deg from the truth. The final pose is wrong when nearer the mirror than the
    truth. The prior can decide a view when the mirror is tilted more than ``margin``
    sigmas beyond the truth. A wrong choice is a search miss when Gauss-Newton started at
    the truth, on the truth's side, ends with a lower posterior cost than the chosen pose:
    the estimator missed a better mode rather than followed the data.
    """
    camera = camera or CameraModel.paper()
    pts = Geometry().marker_points()
    f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    views = wrong = decidable = wrong_decidable = misses = 0
    for c in cases:
        T_true = c.T_camera_marker
        mirror = _mirror(camera, T_true, pts)
        if mirror is None:
            continue
        mp = estimate_marker_pose(camera, c.vertices_px, pts,
                                  up_cam=c.up_cam if prior else None, sigma_px=c.noise_px,
                                  tilt_sigma_rad=tilt_sigma_rad,
                                  upright_probability=upright_probability)
        T = mp.T_camera_marker
        is_wrong = _errors(T, T_true)[1] > _errors(T, mirror)[1]
        can = _tilt(mirror, c.up_cam) - _tilt(T_true, c.up_cam) > margin * tilt_sigma_rad
        views += 1
        wrong += int(is_wrong)
        decidable += int(can)
        wrong_decidable += int(can and is_wrong)
        if is_wrong:
            q = undistort_px(camera, c.vertices_px)
            w = c.noise_px / f / tilt_sigma_rad if prior else 0.0
            h = math.sin(TILT_HUBER_SIGMAS * tilt_sigma_rad)
            chosen = posterior_cost(T[:3, :3].copy(), T[:3, 3].copy(), pts, q, c.up_cam, w, h)
            R, t, _, truth_side = refine(T_true[:3, :3].copy(), T_true[:3, 3].copy(), pts, q,
                                         30, c.up_cam, w, h)
            T_side = make_T(R, t)
            misses += int(truth_side < 0.999 * chosen and
                          _errors(T_side, T_true)[1] < _errors(T_side, mirror)[1])
    return BranchReport(views, wrong, decidable, wrong_decidable, misses)
