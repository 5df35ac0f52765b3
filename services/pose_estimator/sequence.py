"""The marker's pose over a sequence of frames (no bus inside): continuity, the two IPPE
branches' tracks, the choice between them and an honest covariance.

One frame gives the marker's pose and its 6 x 6 covariance (``estimate.estimate_marker_pose``);
this module adds what the frames before it know:

- **continuity**: the previous pose, when recent, is a weak prior on the rotation; a marker that
  jumped (lost and found elsewhere) owes nothing to the last frame.
- **branches**: both IPPE candidates are tracked (``branches.BranchTracker``); the estimator
  follows the cheaper track, and re-solves on it when the frame alone chose the other.
- **the crossing**: seen face-on from the marker's height the two candidates are yaw mirrors
  about the line of sight, and they meet when the heading crosses it. When they are within
  the noise of each other (``merge_sigmas`` heading sigmas) the frame's pose is their midpoint
  (no branch to swap), its heading variance grows by the half gap squared, and the tracks
  lose their identities: which continues which branch after a meeting is unknown, so the
  evidence gathered before counts for neither. Where a frame cannot decide (the tracks still
  undecided, or crossing so that their candidates cannot be paired, or the followed branch
  being no minimum of its own) ``reason`` says "ambiguous" and the heading variance covers
  the other candidate: never a confident wrong branch.
- **covariance**: the sandwich covariance of the estimate under a vertex noise model
  (``noise_sigma_px`` per coordinate, plus what the extractor's per-vertex covariances report
  beyond a clean frame's level, plus a common scale error ``scale_sigma_px``), with the
  upright prior's information, plus the body's rock about its feet (the marker rolls about
  its normal with the gait, ``rock_sigma_rad``), which moves the floor position the marker
  implies. Over the webcam sequences its normalised estimation error squared of (x, y, yaw)
  averages 2.4-2.6.
- **the mount**: ``MountCheck`` estimates from the marker's mean lean how far the real
  camera mount is off the deployment file's; once that has settled (and only when it is
  significant) the sequence uses the estimated up instead of the file's
  (``mount_correction``), and ``R_mount_correction`` tells the world composition.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from services.core.camera import CameraModel, undistort_px
from services.pose_estimator.branches import BranchTracker, candidate_cost, rotation_angle
from services.pose_estimator.estimate import (
    TILT_HUBER_SIGMAS,
    TILT_SIGMA_DEG,
    UPRIGHT_PROBABILITY,
    VERTEX_SIGMA_PX,
    MarkerPose,
    elevation_up,
    estimate_marker_pose,
)
from services.pose_estimator.p4p import PoseError, huber_weight, residuals_and_jacobian

#: the marker's roll about its normal with the gait (1-sigma, deg): the simulator's 0.02 rad
#: rock, sine-shaped, has an RMS of 0.8 deg
ROCK_SIGMA_DEG = 0.8
CONTINUITY_WINDOW_S = 0.3
#: the extractor's vertex error through the simulated webcam, split: independent noise of each
#: coordinate (0.016-0.036 px RMS) and a common scale (the rhombus 0.04-0.16 px larger or
#: smaller at each vertex, with and without JPEG); the covariance's model when the extractor
#: sends no per-vertex covariance
NOISE_SIGMA_PX = 0.025
SCALE_SIGMA_PX = 0.1
#: the mount correction: on, and the smallest offset it corrects (deg)
MOUNT_CORRECTION = True
MOUNT_MIN_CORRECT_DEG = 1.5


@dataclass(frozen=True)
class SequenceParams:
    """Args:
        continuity_window_s: use the previous pose this recent as a prior.
        vertex_sigma_px: vertex noise (1-sigma px) when the extractor sends none.
        tilt_sigma_rad: the upright prior: marker normal level within this.
        refine: Gauss-Newton after IPPE.
        rock_sigma_rad: the marker's roll about its normal from the gait (1-sigma).
        noise_sigma_px, scale_sigma_px: the covariance's vertex noise model (see
            ``MarkerSequence._covariance``); the estimate itself weighs the vertices with
            ``vertex_sigma_px``.
        merge_sigmas: candidates closer in heading than this many heading sigmas are one.
        mount_correction: once the mount check has settled on a significant offset, the
            upright prior and the world composition use the estimated up instead of the
            deployment file's.
        height_m: the marker centre's height over the camera's optical centre (from the
            mounts): each frame's upright prior uses the up its elevation implies
            (``estimate.up_from_elevation``); None: the mount's up as it is.
        upright_probability: the per-frame test of the upright prior (see
            ``estimate.estimate_marker_pose``); 1: the prior always holds.
    """

    continuity_window_s: float = CONTINUITY_WINDOW_S
    vertex_sigma_px: float = VERTEX_SIGMA_PX
    tilt_sigma_rad: float = math.radians(TILT_SIGMA_DEG)
    refine: bool = True
    rock_sigma_rad: float = math.radians(ROCK_SIGMA_DEG)
    noise_sigma_px: float = NOISE_SIGMA_PX
    scale_sigma_px: float = SCALE_SIGMA_PX
    merge_sigmas: float = 2.0
    mount_correction: bool = MOUNT_CORRECTION
    height_m: float | None = None
    upright_probability: float = UPRIGHT_PROBABILITY


@dataclass(frozen=True)
class SequenceEstimate:
    """The marker pose of one frame in its sequence."""

    T_camera_marker: np.ndarray
    covariance: np.ndarray   # 6 x 6 over (left rotation increment rad, translation m)
    reprojection_px: float
    ambiguous: bool
    reason: str              # "" or why the heading is uncertain


def vertex_sigma(vertices_cov_px2: object | None, fallback_px: float) -> float:
    """One isotropic 1-sigma (px) from the extractor's four 2 x 2 covariances (the RMS of
    their axes), or ``fallback_px`` when there are none or they are unusable."""
    if vertices_cov_px2 is None:
        return fallback_px
    C = np.asarray(vertices_cov_px2, dtype=np.float64)
    if C.shape != (4, 2, 2) or not np.isfinite(C).all():
        return fallback_px
    var = float(np.mean(np.trace(C, axis1=1, axis2=2))) / 2.0
    return math.sqrt(var) if var > 1e-6 else fallback_px


#: The extractor's per-vertex sigma on clean frames (about its p99 on the webcam sequences,
#: px). Its errors there are mostly common to the four vertices (the rhombus seen a little
#: larger or smaller), which ``scale_sigma_px`` models; taken as independent they would
#: overstate the heading's variance. Only what it reports beyond this level (a blurred or
#: shadowed frame, the column and row scans disagreeing) is added to the noise model.
EXTRACTOR_CLEAN_SIGMA_PX = 0.1


def _excess_cov(vertices_cov_px2: object | None, clean_sigma_px: float) -> np.ndarray:
    """The extractor's four 2 x 2 covariances less ``clean_sigma_px``² on each axis (clipped
    at 0), px²; zeros when there are none or they are unusable."""
    out = np.zeros((4, 2, 2))
    if vertices_cov_px2 is None:
        return out
    C = np.asarray(vertices_cov_px2, dtype=np.float64)
    if C.shape != (4, 2, 2) or not np.isfinite(C).all():
        return out
    for i in range(4):
        w, V = np.linalg.eigh(0.5 * (C[i] + C[i].T))
        out[i] = (V * np.maximum(w - clean_sigma_px ** 2, 0.0)) @ V.T
    return out


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _exp_so3(w: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + math.sin(th) / th * K + (1 - math.cos(th)) / (th * th) * (K @ K)


def heading_about(up: np.ndarray, Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Signed angle (rad) about ``up`` from Ra's marker normal to Rb's (both projected on the
    plane normal to ``up``)."""
    def flat(n: np.ndarray) -> np.ndarray:
        return n - float(n @ up) * up
    a, b = flat(Ra[:, 2]), flat(Rb[:, 2])
    return math.atan2(float(np.cross(a, b) @ up), float(a @ b))


def _size_sigma(d: np.ndarray, cov: np.ndarray) -> tuple[float, float]:
    """The size of the offset ``d`` (rad) and its 1-sigma: along ``d`` (a direction the
    views hardly see, such as the roll of a face-on marker, is held near zero by the ridge
    and neither delays nor makes a correction); the whole trace when ``d`` is zero."""
    size = float(np.linalg.norm(d))
    if size < 1e-9:
        return size, math.sqrt(max(float(np.trace(cov)), 0.0))
    u = d / size
    return size, math.sqrt(max(float(u @ cov @ u), 0.0))


class MountCheck:
    """Is the world's up where the deployment file's mount puts it? Over a sequence.

    The humanoid stands upright, so the marker's normal ``n``, from the image alone (the IPPE
    candidate, no prior), is level on average. With the real mount turned by a small
    rotation ``d`` (camera frame) from the file's, the true up is ``exp(d) up_file`` and each
    frame's ``n . exp(d) up_file`` is zero up to the noise: a Gauss-Newton least squares over
    the frames (relinearised, so 8° is not shortened) gives ``d``, reported as the camera's
    pitch (about its x) and roll (about its z) off the file. A ridge keeps a direction the
    views hardly see (the roll, from a marker always seen face-on) near zero, and ``d``
    about the up itself (a turn the lean cannot see) at zero.

    The estimate's uncertainty is the residual spread over the information, inflated for
    frames that are not independent (``correlated_frames`` in a row say little more than
    one). Once settled (``min_frames``, the sigma along the offset under ``settle_sigma_deg``,
    the offset beyond
    ``significant_sigmas`` sigmas and ``min_correct_deg``) ``correction()`` returns ``d``;
    a correct mount stays below that and is never corrected. When the last
    ``jump_frames`` frames disagree with the settled estimate by more than ``jump_deg``
    (and their own noise), the evidence changed (the camera knocked, a new mount): the check
    restarts from those frames.
    """

    def __init__(self, up_cam: np.ndarray, min_frames: int = 30, alert_deg: float = 3.0,
                 max_tilt_deg: float = 30.0, window_frames: int = 900,
                 settle_sigma_deg: float = 1.0, significant_sigmas: float = 4.0,
                 min_correct_deg: float = MOUNT_MIN_CORRECT_DEG,
                 correlated_frames: float = 12.0, jump_frames: int = 30,
                 jump_deg: float = 3.0) -> None:
        self.up = np.asarray(up_cam, np.float64)
        self.min_frames, self.alert_deg = min_frames, alert_deg
        self.max_tilt = math.sin(math.radians(max_tilt_deg))
        self.settle_sigma = math.radians(settle_sigma_deg)
        self.significant_sigmas = significant_sigmas
        self.min_correct = math.radians(min_correct_deg)
        self.correlated_frames = correlated_frames
        self.jump_frames, self.jump = jump_frames, math.radians(jump_deg)
        self.normals: deque[np.ndarray] = deque(maxlen=window_frames)
        self.resets = 0
        self._solved: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def frames(self) -> int:
        return len(self.normals)

    def add(self, R_image: np.ndarray, distance_m: float = 0.3) -> None:
        """One frame's marker rotation from the image alone, seen ``distance_m`` away (the
        lean's noise grows with the distance: the frame weighs (0.3 m / distance)^2)."""
        n = np.asarray(R_image, np.float64)[:, 2]
        if abs(float(n @ self.up)) > self.max_tilt:  # not a standing humanoid's marker
            return
        w = min((0.3 / max(distance_m, 1e-3)) ** 2, 4.0)
        self.normals.append(np.append(n, w))
        self._solved = None
        if self.frames >= self.min_frames + self.jump_frames and \
                self.frames % self.jump_frames == 0:
            # the last frames' mean lean off the up the earlier ones settled on
            d, _ = self._solve(np.array(self.normals)[:-self.jump_frames])
            last = np.array(self.normals)[-self.jump_frames:]
            r = last[:, :3] @ (_exp_so3(d) @ self.up)
            noise = float(np.std(r)) * math.sqrt(self.correlated_frames / len(r))
            if abs(float(np.mean(r))) > max(math.sin(self.jump), 3.0 * noise):
                recent = list(self.normals)[-self.jump_frames:]
                self.normals.clear()
                self.normals.extend(recent)
                self.resets += 1

    def _solve(self, Nw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(d rad, its 3 x 3 covariance) from the normals and weights ``Nw`` (k x 4)."""
        N, w = Nw[:, :3], Nw[:, 3]
        k = len(N)
        ridge = (np.outer(self.up, self.up) + 0.02 * np.eye(3)) * float(w.sum())
        d = np.zeros(3)
        for _ in range(3):
            u = _exp_so3(d) @ self.up
            r = N @ u                       # each frame's lean off the level
            J = np.cross(u, N)              # d r / d d (left increment)
            A = (J * w[:, None]).T @ J + ridge
            d = d - np.linalg.solve(A, (J * w[:, None]).T @ r + ridge @ d)
        u = _exp_so3(d) @ self.up
        r = N @ u
        s2 = float(w @ (r * r)) / max(k - 2, 1)
        cov = s2 * min(self.correlated_frames, float(k)) * np.linalg.inv(A)
        return d, cov

    def solved(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(d rad, covariance) or None before ``min_frames``."""
        if self.frames < self.min_frames:
            return None
        if self._solved is None:
            self._solved = self._solve(np.array(self.normals))
        return self._solved

    def offset_deg(self) -> tuple[float, float] | None:
        """(pitch, roll) of the real mount off the file's, deg (camera x and z), or None
        before ``min_frames``."""
        s = self.solved()
        if s is None:
            return None
        return math.degrees(float(s[0][0])), math.degrees(float(s[0][2]))

    def sigma_deg(self) -> float | None:
        """1-sigma of the offset's size (deg), or None before ``min_frames``."""
        s = self.solved()
        return None if s is None else math.degrees(_size_sigma(*s)[1])

    def correction(self) -> np.ndarray | None:
        """``d`` (rad, camera frame; the true up is ``exp(d) up_file``) once settled and
        significant, else None."""
        s = self.solved()
        if s is None:
            return None
        d, cov = s
        size, sigma = _size_sigma(d, cov)
        if sigma > self.settle_sigma or size < max(self.significant_sigmas * sigma,
                                                   self.min_correct):
            return None
        return d

    def message(self, correcting: bool = False) -> str:
        """A warning when the mount looks more than ``alert_deg`` off, else ""."""
        off, sigma = self.offset_deg(), self.sigma_deg()
        if off is None or sigma is None or math.hypot(*off) < self.alert_deg:
            return ""
        return (f"the marker leans {math.hypot(*off):.1f}° ± {sigma:.1f}° on average over "
                f"{self.frames} frames: the camera mount looks pitched {off[0]:+.1f}° and "
                f"rolled {off[1]:+.1f}° off the deployment file's (check camera_pitch_rad); "
                + ("the pose uses the estimated up" if correcting else
                   "not corrected (mount_correction off or not settled)"))


class MarkerSequence:
    """Feed it each frame's vertices in order; it returns the marker pose of the frame."""

    def __init__(self, camera: CameraModel, points: np.ndarray, up_cam: np.ndarray | None,
                 params: SequenceParams | None = None) -> None:
        self.camera = camera
        self.points = points
        self.up_file = up_cam   # the deployment file's up (camera frame)
        self.up_cam = up_cam    # the up the estimate uses: the file's, or corrected
        self.params = params or SequenceParams()
        self.branches = BranchTracker()
        self.previous: tuple[int, np.ndarray] | None = None  # (stamp_ns, R) of the last pose
        self.mount = MountCheck(up_cam) if up_cam is not None else None
        self.mount_d: np.ndarray | None = None  # the correction in use (rad), or None
        self.mount_cov: np.ndarray | None = None  # its 3 x 3 covariance (rad^2)

    @property
    def R_mount_correction(self) -> np.ndarray:
        """The rotation (camera frame) from the file's up to the one in use: the real
        ``T_base_camera`` is the file's times ``make_T(R_mount_correction.T, 0)``."""
        return np.eye(3) if self.mount_d is None else _exp_so3(self.mount_d)

    def _correct_mount(self) -> None:
        d = self.mount.correction() if self.mount is not None and \
            self.params.mount_correction else None
        self.mount_d = d
        solved = self.mount.solved() if d is not None and self.mount is not None else None
        self.mount_cov = None if solved is None else solved[1]
        if self.up_file is not None:
            self.up_cam = self.up_file if d is None else _exp_so3(d) @ self.up_file

    def reset(self) -> None:
        self.branches.reset()
        self.previous = None

    def update(self, stamp_ns: int, vertices_px: np.ndarray,
               vertices_cov_px2: object | None = None) -> SequenceEstimate:
        """Raises PoseError when the vertices give no pose."""
        p = self.params
        self._correct_mount()
        recent = self.previous is not None and \
            abs(stamp_ns - self.previous[0]) < p.continuity_window_s * 1e9
        if not recent:
            self.branches.reset()
        v = np.asarray(vertices_px, dtype=np.float64)
        # the vertices' weight: the extractor's noise when larger than the setting, never
        # smaller (its covariance leaves out errors common to the vertices, such as the
        # scale, and a smaller weight would weaken the priors against them)
        sigma_px = max(vertex_sigma(vertices_cov_px2, p.vertex_sigma_px), p.vertex_sigma_px)
        up = self.up_cam
        if up is not None and p.height_m is not None and p.refine:
            up = elevation_up(np.ascontiguousarray(self.points, np.float64),
                              undistort_px(self.camera, v), up, p.height_m)

        def solve(previous_R: np.ndarray | None, sigma_deg: float = 10.0) -> MarkerPose:
            return estimate_marker_pose(
                self.camera, v, self.points, up_cam=up,
                refine_steps=5 if p.refine else 0, sigma_px=sigma_px,
                tilt_sigma_rad=p.tilt_sigma_rad, previous_R=previous_R,
                continuity_sigma_rad=math.radians(sigma_deg),
                upright_probability=p.upright_probability)
        mp = solve(self.previous[1] if recent and self.previous else None)
        last = self.branches.position
        if recent and last is not None and float(np.linalg.norm(
                mp.T_camera_marker[:3, 3] - last)) > self.branches.max_move_m:
            mp = solve(None)  # the marker jumped: an unrelated view owes nothing to the last
        follow, ambiguous = self.branches.update([
            (c[:3, :3], candidate_cost(self.camera, c, self.points, v, sigma_px, up,
                                       p.tilt_sigma_rad))
            for c in mp.candidates], mp.T_camera_marker[:3, 3])
        if follow is not None and rotation_angle(follow, mp.T_camera_marker[:3, :3]) > \
                math.radians(10.0):
            mp = solve(follow, 3.0)  # the frame alone chose the other branch: follow the track
        T = mp.T_camera_marker.copy()
        if self.mount is not None:
            self.mount.add(min(mp.candidates, key=lambda c: rotation_angle(
                c[:3, :3], T[:3, :3]))[:3, :3], float(np.linalg.norm(T[:3, 3])))
        cov = self._covariance(T, v, sigma_px, vertices_cov_px2, up, mp.upright_weight)
        if self.mount_cov is not None:
            # the corrected mount's own uncertainty: a mount turned by e (camera frame) turns
            # the marker's pose about the camera, (w, t) by (e, e x t)
            G = np.vstack([np.eye(3), -_skew(T[:3, 3])])
            cov += G @ self.mount_cov @ G.T
        reason = ""
        pair = self._pair(T[:3, :3], mp.candidates)
        if pair is not None and self.up_cam is not None:
            up = self.up_cam
            near, far = pair
            off = heading_about(up, near, T[:3, :3])  # from the nearer candidate to ours
            gap = heading_about(up, near, far)        # from it to the mirror, rad
            sigma_h = math.sqrt(max(float(up @ cov[:3, :3] @ up), 0.0))
            stuck = abs(off) > max(3.0 * sigma_h, math.radians(2.0))
            if abs(gap) < p.merge_sigmas * sigma_h or stuck:
                # within the noise (or the track's branch is no minimum of its own): the
                # candidates' midpoint, the half gap added to the variance
                T[:3, :3] = _exp_so3((0.5 * gap - off) * up) @ T[:3, :3]
                cov[:3, :3] += (0.5 * gap) ** 2 * np.outer(up, up)
                if abs(gap) < p.merge_sigmas * sigma_h:
                    self.branches.crossed()
                if stuck and abs(gap) >= p.merge_sigmas * sigma_h:
                    reason = ("ambiguous: the frame and the track disagree on the branch; "
                              f"midpoint of the two ({math.degrees(abs(gap)):.1f}° apart)")
            elif ambiguous or (self.branches.skipped and abs(gap) > math.radians(4.0)):
                cov[:3, :3] += gap ** 2 * np.outer(up, up)
                why = ("the mirror pose fits nearly as well" if ambiguous else
                       "the branches cross: which is which is unknown this frame")
                reason = (f"ambiguous: {why} ({math.degrees(abs(gap)):.1f}° away); "
                          "heading sigma widened")
        self.previous = (stamp_ns, T[:3, :3])
        return SequenceEstimate(T, cov, mp.reprojection_px, bool(reason), reason)

    def _covariance(self, T: np.ndarray, v: np.ndarray, weight_px: float,
                    vertices_cov_px2: object | None, up: np.ndarray | None = None,
                    upright_weight: float = 1.0) -> np.ndarray:
        """6 x 6 covariance of the estimate (a weighted least squares with weight
        ``weight_px`` plus the upright prior) under the vertex noise model: ``noise_sigma_px``
        on each coordinate plus what the extractor's per-vertex covariances report beyond a
        clean frame's level (``EXTRACTOR_CLEAN_SIGMA_PX``), plus a common scale error of
        ``scale_sigma_px`` (the rhombus seen a little larger or smaller, as
        blur, gamma and JPEG make it), plus the gait's rock about the marker normal. The
        sandwich A^-1 B A^-1 of the Gauss-Newton normal equations; the upright prior about
        ``up`` (the sequence's when None), its information scaled by the frame's prior-test
        weight ``upright_weight``."""
        p = self.params
        f = 0.5 * (self.camera.K[0, 0] + self.camera.K[1, 1])
        q = undistort_px(self.camera, v)
        R, t = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
        try:
            _, J = residuals_and_jacobian(R, t, np.ascontiguousarray(self.points, np.float64),
                                          q)
        except ZeroDivisionError:
            raise PoseError("numerically degenerate view (a vertex at the camera's depth "
                            "0)") from None
        J = J * f  # px per unit of (w, t)
        S = np.zeros((8, 8))
        fixed = np.eye(2) * p.noise_sigma_px ** 2
        excess = _excess_cov(vertices_cov_px2, EXTRACTOR_CLEAN_SIGMA_PX)
        for i in range(4):
            S[2 * i:2 * i + 2, 2 * i:2 * i + 2] = fixed + excess[i]
        d = (v - v.mean(axis=0)).ravel()
        d /= max(float(np.linalg.norm(d)), 1e-12) / 2.0  # about 1 px per vertex
        S += p.scale_sigma_px ** 2 * np.outer(d, d)
        A = J.T @ J / weight_px ** 2
        B = J.T @ S @ J / weight_px ** 4
        up = self.up_cam if up is None else up
        if up is not None:
            g = np.zeros(6)
            g[:3] = np.cross(R[:, 2], up) / p.tilt_sigma_rad  # d(n . up)/dw
            g *= math.sqrt(upright_weight * huber_weight(
                float(R[:, 2] @ up), math.sin(TILT_HUBER_SIGMAS * p.tilt_sigma_rad)))
            A += np.outer(g, g)
            B += np.outer(g, g)
        try:
            A_inv = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            A_inv = np.linalg.pinv(A)
        cov = A_inv @ B @ A_inv
        n = R[:, 2]
        cov[:3, :3] += p.rock_sigma_rad ** 2 * np.outer(n, n)
        return 0.5 * (cov + cov.T)

    @staticmethod
    def _pair(R: np.ndarray, candidates: tuple[np.ndarray, ...]
              ) -> tuple[np.ndarray, np.ndarray] | None:
        """(the candidate nearer R, the other), or None with a single candidate."""
        if len(candidates) < 2:
            return None
        a, b = candidates[0][:3, :3], candidates[1][:3, :3]
        return (a, b) if rotation_angle(a, R) <= rotation_angle(b, R) else (b, a)
