"""From pixel vertices to the marker pose in the camera and the humanoid's floor pose.

``T_world_humanoid = T_world_base · T_base_camera · T_camera_marker · T_marker_humanoid``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from services.core.camera import CameraModel, undistort_px
from services.core.geometry import inv_T
from services.core.jit import njit
from services.core.projection import project_px, rms_px
from services.pose_estimator.p4p import (
    OK,
    PoseError,
    covariance_6,
    exp_so3,
    huber_weight,
    ippe4,
    map_pose,
    prior_cost,
    raise_for,
    rotation_angle,
)

#: The vertex noise (1-sigma, px) assumed unless told otherwise: the extractor's measured error.
VERTEX_SIGMA_PX = 0.2
#: The upright prior: the marker's normal level within this (1-sigma, deg) ...
TILT_SIGMA_DEG = 2.0
#: ... out to this many sigmas; beyond, its tails are heavy (Cauchy-like: a marker that
#: really leans, or a mount a few degrees off the deployment file's, pays little for it).
TILT_HUBER_SIGMAS = 1.75
#: The per-view prior test: the marker stands as upright as ``TILT_SIGMA_DEG`` says with this
#: probability, else it leans anyhow (within ``WIDE_TILT_SIGMA_DEG``, 1-sigma). Each view's
#: pose is the two models' estimates weighed by their posterior probabilities (the evidence of
#: the tilt the image sees, under either prior): a view whose data disagree with the upright
#: prior turns it off. With the elevation's up (below), on 4 x 1000 unrelated views at 0.3 px
#: (the noise known), position error against OpenCV's IPPE, median and p90: upright (within
#: 3°) 0.94x, 0.94x; pitched to 15° and rolled to 10° 0.98x, 0.99x; the mount off by 8°
#: 0.95x, 0.97x (neither, at 0.2 px: 0.96x 0.95x, 0.99x 0.99x, 1.00x 1.02x).
UPRIGHT_PROBABILITY = 0.8
WIDE_TILT_SIGMA_DEG = 10.0
#: The marker's elevation: the marker centre's height over the camera's optical centre
#: (from the mounts) is known within this (1-sigma, m: the floor, the gait, the file) ...
HEIGHT_SIGMA_M = 0.005
#: ... and the deployment file's camera pitch within this (1-sigma, deg): where the marker is
#: seen in the image then says where the true up is in the line of sight's vertical plane
#: (``up_from_elevation``), so a mount pitched a few degrees off the file's still gives
#: the upright prior the right vertical.
MOUNT_SIGMA_DEG = 5.0
#: the service takes each frame's vertical from the marker's elevation (``elevation_up``)
ELEVATION_UP = True


@dataclass(frozen=True)
class MarkerPose:
    """T_camera_marker (4x4) with its quality figures and both IPPE candidates."""

    T_camera_marker: np.ndarray
    reprojection_px: float
    covariance: np.ndarray              # 6x6 over (rotation vector rad, translation m)
    candidates: tuple[np.ndarray, ...]  # 4x4 each, IPPE's two, best-reprojection first
    chosen: int                         # index into candidates before refinement
    upright_weight: float = 1.0         # the prior test's probability of the upright model


def estimate_marker_pose(camera: CameraModel, vertices_px: np.ndarray, marker_points: np.ndarray,
                         *, up_cam: np.ndarray | None = None, refine_steps: int = 5,
                         sigma_px: float = VERTEX_SIGMA_PX,
                         tilt_sigma_rad: float = math.radians(TILT_SIGMA_DEG),
                         ambiguity: float = 4.0, previous_R: np.ndarray | None = None,
                         continuity_sigma_rad: float = math.radians(10.0),
                         tilt_huber_sigmas: float = TILT_HUBER_SIGMAS,
                         height_m: float | None = None,
                         upright_probability: float = UPRIGHT_PROBABILITY) -> MarkerPose:
    """Pose of the marker in the camera from its four pixel vertices (left, top, right,
    bottom); raises PoseError with the reason when impossible.

    IPPE gives two candidates. With ``up_cam`` (the world's up in the camera frame) the
    humanoid-stands-upright prior decides between them: both are refined to the maximum a
    posteriori pose (reprojection error with image noise ``sigma_px``, plus the marker
    normal level within ``tilt_sigma_rad``) and the lower posterior cost wins. The prior is
    only consulted when the second candidate's reprojection error is within ``ambiguity``
    image-noise sigmas; otherwise the image alone decides. Without ``up_cam`` or refinement,
    the best reprojection wins. ``previous_R`` (the marker's rotation in the previous frame)
    adds a continuity prior: rotation change within ``continuity_sigma_rad``. The upright
    prior is Gaussian out to ``tilt_huber_sigmas`` sigmas and Huber beyond (0: Gaussian
    throughout): a marker that leans, or a mount a little off the deployment file's, pays
    little for the prior.

    ``height_m`` (the marker centre's height over the camera's optical centre, from the
    mounts) corrects ``up_cam`` in the line of sight's vertical plane from where the marker
    is seen (``up_from_elevation``). ``upright_probability`` below 1 tests the prior on each
    view: the pose is the upright and the leaning model's estimates weighed by their
    posterior probabilities (``prior_test_weight``), and its covariance their mixture's.
    """
    v = np.ascontiguousarray(vertices_px, np.float64)
    if v.shape != (4, 2):
        raise PoseError(f"need 4 vertices (4, 2), got shape {v.shape}")
    if not np.isfinite(v).all():
        raise PoseError("vertices contain NaN or inf")
    model = np.ascontiguousarray(marker_points, np.float64)
    if model.shape != (4, 3):
        raise PoseError(f"need 4 marker points (4, 3), got shape {model.shape}")
    q = undistort_px(camera, v)
    sigma_n = sigma_px / (0.5 * (camera.K[0, 0] + camera.K[1, 1]))
    continuity_w = 0.0 if previous_R is None else sigma_n / continuity_sigma_rad
    up = _NO_UP if up_cam is None else np.ascontiguousarray(up_cam, np.float64)
    if up_cam is not None and height_m is not None and refine_steps > 0:
        up = elevation_up(model, q, up, height_m)

    def solve(tilt_rad: float, huber_sigmas: float) -> tuple[
            np.ndarray, float, np.ndarray, int, np.ndarray]:
        try:
            status, T, reproj, cov, chosen, cands = _marker_pose(
                model, v, q, camera.K, camera.dist, refine_steps, up,
                0.0 if up_cam is None else sigma_n / tilt_rad,
                _NO_R if previous_R is None else np.asarray(previous_R, np.float64),
                continuity_w, ambiguity * sigma_n, sigma_n,
                math.sin(min(huber_sigmas * tilt_rad, 1.5)) if huber_sigmas > 0 else 0.0)
        except ZeroDivisionError:  # a refinement step put a vertex in the camera's plane
            raise PoseError("numerically degenerate view (a vertex at the camera's depth "
                            "0)") from None
        raise_for(status)
        return T, reproj, cov, chosen, cands

    T, reproj, cov, chosen, cands = solve(tilt_sigma_rad, tilt_huber_sigmas)
    if up_cam is None or refine_steps == 0 or upright_probability >= 1.0:
        return MarkerPose(T, reproj, cov, tuple(cands), chosen)
    wide = math.radians(WIDE_TILT_SIGMA_DEG)
    T_w, reproj_w, cov_w, _, _ = solve(wide, 0.0)
    if rotation_angle(T[:3, :3], T_w[:3, :3]) > math.radians(10.0):
        # the two models chose different branches: the one with the higher density under
        # the mixture prior (the reprojection error over the vertex noise, and the tilt)
        def neg_log(T_k: np.ndarray, reproj_px: float) -> float:
            tilt = float(T_k[:3, 2] @ up)
            density = sum(p / s * math.exp(-0.5 * (tilt / s) ** 2) for p, s in (
                (upright_probability, tilt_sigma_rad), (1.0 - upright_probability, wide)))
            return 2.0 * (reproj_px / sigma_px) ** 2 - math.log(max(density, 1e-300))
        if neg_log(T_w, reproj_w) < neg_log(T, reproj):
            return MarkerPose(T_w, reproj_w, cov_w, tuple(cands), chosen, 0.0)
        return MarkerPose(T, reproj, cov, tuple(cands), chosen)
    weight = prior_test_weight(T_w, cov_w, up, tilt_sigma_rad, wide, upright_probability)
    T_mix, cov_mix = mix_poses(T, cov, T_w, cov_w, weight)
    return MarkerPose(T_mix, weight * reproj + (1 - weight) * reproj_w, cov_mix,
                      tuple(cands), chosen, weight)


@njit()
def prior_test_weight(T_wide: np.ndarray, cov_wide: np.ndarray, up: np.ndarray,
                      tilt_sigma_rad: float, wide_sigma_rad: float, upright_probability: float
                      ) -> float:
    """The posterior probability that the marker stands upright (tilt within
    ``tilt_sigma_rad``) rather than leaning (within ``wide_sigma_rad``), from the tilt the
    image sees (the nearly unconstrained estimate ``T_wide``) and its variance from the
    image alone (``cov_wide``, the reprojection's): under either model the seen tilt is
    Gaussian with the prior's variance plus the image's."""
    n = np.empty(3)
    for i in range(3):
        n[i] = T_wide[i, 2]
    tilt = n[0] * up[0] + n[1] * up[1] + n[2] * up[2]
    g = np.cross(n, up)  # d(n . up)/dw
    var = 0.0
    for a in range(3):
        for b in range(3):
            var += g[a] * cov_wide[a, b] * g[b]
    var = max(var, 0.0)
    log_odds = math.log(upright_probability / (1.0 - upright_probability))
    s2 = tilt_sigma_rad ** 2 + var
    log_odds += -0.5 * tilt * tilt / s2 - 0.5 * math.log(s2)
    s2 = wide_sigma_rad ** 2 + var
    log_odds -= -0.5 * tilt * tilt / s2 - 0.5 * math.log(s2)
    return 1.0 / (1.0 + math.exp(-max(min(log_odds, 50.0), -50.0)))


@njit()
def mix_poses(T_a: np.ndarray, cov_a: np.ndarray, T_b: np.ndarray, cov_b: np.ndarray,
              weight_a: float) -> tuple[np.ndarray, np.ndarray]:
    """The mean (rotation on the manifold, about T_a) and covariance of a two-pose mixture,
    ``weight_a`` on the first; covariances over (left rotation increment, translation)."""
    Ra = np.ascontiguousarray(T_a[:3, :3])
    d = np.zeros(6)
    d[:3] = _log_so3(np.ascontiguousarray(T_b[:3, :3]) @ Ra.T)
    for i in range(3):
        d[3 + i] = T_b[i, 3] - T_a[i, 3]
    wb = 1.0 - weight_a
    T = np.eye(4)
    T[:3, :3] = exp_so3(wb * d[:3]) @ Ra
    for i in range(3):
        T[i, 3] = T_a[i, 3] + wb * d[3 + i]
    cov = weight_a * cov_a + wb * cov_b + weight_a * wb * np.outer(d, d)
    return T, cov


@njit()
def _log_so3(R: np.ndarray) -> np.ndarray:
    th = rotation_angle(R, np.eye(3))
    w = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return w if th < 1e-9 else w * th / math.sin(th)


@njit()
def up_from_elevation(up_cam: np.ndarray, t_m: np.ndarray, height_m: float,
                      height_sigma_m: float = HEIGHT_SIGMA_M,
                      mount_sigma_rad: float = math.radians(MOUNT_SIGMA_DEG)
                      ) -> tuple[np.ndarray, float]:
    """The world's up in the camera frame given that the marker centre, seen at ``t_m``
    (camera frame, m), is ``height_m`` over the optical centre: ``up . t = height_m``.

    The file's ``up_cam`` is turned in the vertical plane of the line of sight (about
    ``up x t``, the one direction the elevation sees) by the least-squares blend of the
    file (within ``mount_sigma_rad``) and the elevation (within ``height_sigma_m`` over the
    distance). Returns (up, the turn's 1-sigma rad); the file's up unchanged when the line
    of sight is near the vertical."""
    up = np.empty(3)
    t = np.empty(3)
    for i in range(3):
        up[i], t[i] = up_cam[i], t_m[i]
    d = math.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
    axis = np.cross(up, t)
    s = math.sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2])
    if d <= 0 or s < 0.2 * d:
        return up, mount_sigma_rad
    axis /= s
    side = np.cross(axis, up)
    slope = (side[0] * t[0] + side[1] * t[1] + side[2] * t[2]) / d  # d(u . up)/d angle
    angle_ml = (height_m - (up[0] * t[0] + up[1] * t[1] + up[2] * t[2])) / d / slope
    var_ml = (height_sigma_m / d / slope) ** 2
    k = mount_sigma_rad ** 2 / (mount_sigma_rad ** 2 + var_ml)
    return exp_so3(k * angle_ml * axis) @ up, math.sqrt(k * var_ml)


@njit()
def elevation_up(model: np.ndarray, q: np.ndarray, up: np.ndarray, height_m: float
                 ) -> np.ndarray:
    """``up_from_elevation`` at the marker centre IPPE sees (both candidates agree on it)."""
    status, _, ts, _, count = ippe4(model, q)
    if status != OK or count == 0:
        return up.copy()
    return up_from_elevation(up, ts[0], height_m)[0]


@njit()
def _marker_pose(model: np.ndarray, v: np.ndarray, q: np.ndarray, K: np.ndarray,
                 dist: np.ndarray, steps: int, up: np.ndarray, prior_w: float,
                 previous_R: np.ndarray, continuity_w: float, ambiguity_n: float,
                 sigma_n: float, huber: float
                 ) -> tuple[int, np.ndarray, float, np.ndarray, int, np.ndarray]:
    """map_pose, then T (4x4), reprojection RMS (px), covariance and the candidates (k, 4, 4)."""
    status, R, t, J, chosen, Rs, ts, count = map_pose(model, q, steps, up, prior_w,
                                                      previous_R, continuity_w, ambiguity_n,
                                                      huber)
    T = np.eye(4)
    cands = np.zeros((count, 4, 4))
    if status != OK:
        return status, T, 0.0, np.zeros((6, 6)), chosen, cands
    T[:3, :3], T[:3, 3] = R, t
    for i in range(count):
        cands[i, :3, :3], cands[i, :3, 3], cands[i, 3, 3] = Rs[i], ts[i], 1.0
    Xc = np.empty((4, 3))
    for i in range(4):
        for k in range(3):
            Xc[i, k] = R[k, 0] * model[i, 0] + R[k, 1] * model[i, 1] + R[k, 2] * model[i, 2] \
                + t[k]
    reproj = rms_px(project_px(K, dist, Xc), v)
    return OK, T, reproj, covariance_6(J, sigma_n), chosen, cands


_NO_UP = np.zeros(3)
_NO_R = np.eye(3)


def humanoid_floor_pose(T_world_camera: np.ndarray, T_camera_marker: np.ndarray,
                        T_marker_humanoid: np.ndarray, cov6: np.ndarray | None = None
                        ) -> tuple[tuple[float, float, float], np.ndarray | None]:
    """(x m, y m, yaw rad) of the humanoid in the world and its 3x3 covariance, propagated
    from the 6x6 marker-pose covariance (left rotation increment w, then t) by the
    analytic Jacobian."""
    x, y, yaw, J = _floor_pose_jacobian(np.ascontiguousarray(T_world_camera, np.float64),
                                        np.ascontiguousarray(T_camera_marker, np.float64),
                                        np.ascontiguousarray(T_marker_humanoid, np.float64))
    return (x, y, yaw), (None if cov6 is None else J @ cov6 @ J.T)


@njit()
def _floor_pose_jacobian(T_wc: np.ndarray, T_cm: np.ndarray, T_mh: np.ndarray
                         ) -> tuple[float, float, float, np.ndarray]:
    """Floor pose of T_wc T_cm T_mh and its Jacobian (3, 6) for T_cm <- (exp(w) R, t + dt).

    Position p = R_wc (R_cm t_mh + t_cm) + t_wc: dp/dw = -R_wc [a]x with a = R_cm t_mh,
    dp/dt = R_wc. Heading h = R_wc R_cm R_mh e_x: dh/dw = -R_wc [b]x with b = R_cm R_mh e_x,
    and yaw = atan2(h_y, h_x).
    """
    a, b, p, h = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
    for i in range(3):
        for k in range(3):
            a[i] += T_cm[i, k] * T_mh[k, 3]
            b[i] += T_cm[i, k] * T_mh[k, 0]
    for i in range(3):
        p[i] = T_wc[i, 3]
        for k in range(3):
            p[i] += T_wc[i, k] * (a[k] + T_cm[k, 3])
            h[i] += T_wc[i, k] * b[k]
    J = np.zeros((3, 6))
    inv_h2 = 1.0 / (h[0] * h[0] + h[1] * h[1])
    for col in range(3):  # column col of -R_wc [v]x is R_wc (e_col x v)
        e = np.zeros(3)
        e[col] = 1.0
        da, db = np.cross(e, a), np.cross(e, b)
        dp, dh = np.zeros(3), np.zeros(3)
        for i in range(3):
            for k in range(3):
                dp[i] += T_wc[i, k] * da[k]
                dh[i] += T_wc[i, k] * db[k]
        J[0, col], J[1, col] = dp[0], dp[1]
        J[0, 3 + col], J[1, 3 + col] = T_wc[0, col], T_wc[1, col]
        J[2, col] = (h[0] * dh[1] - h[1] * dh[0]) * inv_h2
    return p[0], p[1], math.atan2(h[1], h[0]), J


def up_in_camera(T_base_camera: np.ndarray) -> np.ndarray:
    """The world's up (= base z, the base stands on the floor) in the camera frame."""
    return inv_T(T_base_camera)[:3, :3] @ np.array([0.0, 0.0, 1.0])


def warm_up() -> None:
    """Compile (or load from numba's on-disk cache) the pose kernels: a view with and
    without distortion, with both priors, and the world pose."""
    from services.core.geometry import T_floor
    model = np.array([[-0.03, 0.0, 0.0], [0.0, 0.04, 0.0], [0.03, 0.0, 0.0], [0.0, -0.04, 0.0]])
    T = np.eye(4)
    T[:3, :3] = [[0.9, 0.0, 0.43589], [0.0, 1.0, 0.0], [-0.43589, 0.0, 0.9]]
    T[:3, 3] = (0.02, -0.01, 0.4)
    for dist in (np.zeros(5), np.array([-0.1, 0.01, 0.0, 0.0, 0.0])):
        camera = CameraModel(np.array([[750.0, 2.0, 320.0], [0.0, 750.0, 240.0],
                                       [0.0, 0.0, 1.0]]), dist)
        v = camera.project(model @ T[:3, :3].T + T[:3, 3])
        for up, previous in ((None, None), (np.array([0.0, -1.0, 0.0]), T[:3, :3])):
            estimate_marker_pose(camera, v, model, up_cam=up, previous_R=previous,
                                 height_m=None if up is None else 0.05)
        estimate_marker_pose(camera, v, model, refine_steps=0)
    humanoid_floor_pose(T_floor(0.0, 0.0, 0.0), T, np.eye(4), np.eye(6))
    # the prior's two scalar kernels are also called from Python (branches, sequence)
    prior_cost(0.1, 1.0, 1.0)
    huber_weight(0.1, 1.0)
