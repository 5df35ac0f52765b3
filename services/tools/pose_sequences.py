"""Pose over sequences with truth: the humanoid walking straight away, turning in place and
standing at random nearby poses in front of a static camera at the marker's height, rendered
through the simulated webcam (tests, ``shepherd experiments``).

Each sequence is a list of true floor poses (x m, y m, yaw rad) with the marker's roll from the
gait; ``render`` turns it into the extractor's vertices, ``track`` runs the pose estimator over
them and scores every frame: heading and position error, the published heading sigma, its
``reason`` and the normalised estimation error squared (NEES) of (x, y, yaw) under the
published covariance (a chi-squared with 3 degrees of freedom, mean 3, when the covariance is
honest).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from schemas import MarkerVertices
from services.core.camera import CameraModel
from services.core.geometry import T_floor, inv_T, make_T, rot_z
from services.core.mounts import Geometry
from services.sim.render import RenderStyle, render_view
from services.sim.webcam import WebcamParams
from services.vertex_extractor.extractor import RhombusExtractor

#: (x m, y m, yaw rad, marker roll rad) per frame
Truth = tuple[float, float, float, float]


@dataclass(frozen=True)
class Sequence:
    name: str
    fps: float
    truth: list[Truth]


def walk_away(fps: float = 30.0, seed: int = 0, sway_deg: float = 4.0, start_m: float = 0.15,
              end_m: float = 0.60, speed_m_s: float = 0.067) -> Sequence:
    """Straight away from the camera, heading swaying ±``sway_deg`` with the steps (0.6 s
    each), the marker rolling ±1.1° with them, a few mm sideways."""
    rng = np.random.default_rng(seed)
    y0 = rng.uniform(-0.02, 0.02)
    phase = rng.uniform(0, 2 * math.pi)
    period = 2 * 0.6 * rng.uniform(0.9, 1.1)  # left and right step
    out: list[Truth] = []
    n = int((end_m - start_m) / speed_m_s * fps)
    for k in range(n):
        t = k / fps
        s = math.sin(2 * math.pi * t / period + phase)
        out.append((start_m + speed_m_s * t, y0 + 0.003 * s, math.radians(sway_deg) * s,
                    0.02 * math.sin(4 * math.pi * t / period + phase)))
    return Sequence(f"walk away {start_m * 100:.0f}-{end_m * 100:.0f} cm, sway ±{sway_deg:g}°, "
                    f"{fps:g} fps", fps, out)


def turn_in_place(fps: float = 30.0, seed: int = 0, distance_m: float = 0.35,
                  amplitude_deg: float = 30.0, seconds: float = 6.0) -> Sequence:
    """Standing ``distance_m`` away, turning to +``amplitude_deg``, to minus it and back."""
    rng = np.random.default_rng(seed)
    y0 = rng.uniform(-0.03, 0.03)
    out: list[Truth] = []
    for k in range(int(seconds * fps)):
        t = k / fps
        yaw = math.radians(amplitude_deg) * math.sin(2 * math.pi * t / seconds)
        out.append((distance_m, y0, yaw, 0.01 * math.sin(2 * math.pi * t / 0.4)))
    return Sequence(f"turn in place to ±{amplitude_deg:g}° at {distance_m * 100:.0f} cm, "
                    f"{fps:g} fps", fps, out)


def random_poses(fps: float = 30.0, seed: int = 0, n: int = 30, hold_frames: int = 6
                 ) -> Sequence:
    """``n`` random nearby poses (25-60 cm, within 12° of the axis, heading within ±40° of
    the line of sight), each held ``hold_frames`` frames."""
    rng = np.random.default_rng(seed)
    out: list[Truth] = []
    for _ in range(n):
        d, bearing = rng.uniform(0.25, 0.6), math.radians(rng.uniform(-12, 12))
        yaw = bearing + math.radians(rng.uniform(-40, 40))
        out += [(d * math.cos(bearing), d * math.sin(bearing), yaw, 0.0)] * hold_frames
    return Sequence(f"{n} random nearby poses, {fps:g} fps", fps, out)


@dataclass(frozen=True)
class Frame:
    stamp_ns: int
    truth: Truth
    vertices: MarkerVertices | None  # None: the extractor found nothing


def render(seq: Sequence, seed: int = 0, webcam: bool = True, jpeg: bool = True,
           camera: CameraModel | None = None, geometry: Geometry | None = None,
           T_base_camera: np.ndarray | None = None) -> list[Frame]:
    """Every frame rendered (the camera at the world origin, its mount ``T_base_camera``:
    the geometry's unless given) and through the vertex extractor."""
    cam = camera or CameraModel.paper()
    g = geometry or Geometry()
    pts = g.marker_points()
    T_wc = g.T_base_camera() if T_base_camera is None else T_base_camera
    T_hm = g.T_humanoid_marker()
    style = RenderStyle(seed=seed, camera=WebcamParams(jpeg_quality=90 if jpeg else 0),
                        photos=True) if webcam else RenderStyle(seed=seed)
    ex = RhombusExtractor()
    out = []
    for k, (x, y, yaw, roll) in enumerate(seq.truth):
        T_ch = inv_T(T_wc) @ T_floor(x, y, yaw)
        T_cm = T_ch @ T_hm @ make_T(rot_z(roll), (0.0, 0.0, 0.0))
        r = render_view(cam, T_cm, marker_points_m=pts, T_camera_humanoid=T_ch, style=style,
                        frame_index=k)
        stamp = int(1e12 + k * 1e9 / seq.fps)
        det = ex.extract(r.image)
        msg = None
        if det.found and det.vertices_px is not None:
            v = det.vertices_px
            cov = getattr(det, "vertices_cov_px2", None)
            msg = MarkerVertices(
                seq=k, stamp_ns=stamp, found=True, width=cam.width, height=cam.height,
                vertices_px=tuple((float(a), float(b)) for a, b in v),  # type: ignore[arg-type]
                vertices_cov_px2=None if cov is None else tuple(  # type: ignore[arg-type]
                    tuple(tuple(float(c) for c in row) for row in C) for C in cov))
        out.append(Frame(stamp, (x, y, yaw, roll), msg))
    return out


@dataclass(frozen=True)
class Scores:
    """Per estimated frame."""

    heading_err_deg: np.ndarray   # signed, estimate - truth
    position_err_m: np.ndarray
    heading_sigma_deg: np.ndarray
    ambiguous: np.ndarray         # bool: the reason says so
    nees: np.ndarray              # of (x, y, yaw); nan without a covariance
    t_s: np.ndarray
    truth_yaw_deg: np.ndarray
    frames: int

    def bad(self, limit_deg: float = 5.0, k: float = 1.0) -> int:
        """Frames more than ``limit_deg`` off, unless ambiguous with ``k`` sigma covering."""
        off = np.abs(self.heading_err_deg) > limit_deg
        covered = self.ambiguous & (np.abs(self.heading_err_deg) <= k * self.heading_sigma_deg)
        return int(np.sum(off & ~covered))


def track(frames: list[Frame], estimate) -> Scores:
    """``estimate``: MarkerVertices -> HumanoidPose (a PoseEstimator's ``estimate``)."""
    from services.pose_estimator.p4p import PoseError
    he, pe, sg, amb, nees, ts, ty = [], [], [], [], [], [], []
    t0 = frames[0].stamp_ns if frames else 0
    for f in frames:
        if f.vertices is None:
            continue
        try:
            p = estimate(f.vertices)
        except PoseError:
            continue
        if p.x is None or p.y is None or p.yaw is None:
            continue
        x, y, yaw, _ = f.truth
        e = np.array([p.x - x, p.y - y, math.remainder(p.yaw - yaw, 2 * math.pi)])
        he.append(math.degrees(e[2]))
        pe.append(math.hypot(e[0], e[1]))
        ts.append((f.stamp_ns - t0) / 1e9)
        ty.append(math.degrees(yaw))
        amb.append("ambiguous" in p.reason)
        if p.covariance is None:
            sg.append(float("nan"))
            nees.append(float("nan"))
        else:
            P = np.array(p.covariance)
            sg.append(math.degrees(math.sqrt(max(P[2, 2], 0.0))))
            nees.append(float(e @ np.linalg.solve(P, e)))
    return Scores(np.array(he), np.array(pe), np.array(sg), np.array(amb, bool),
                  np.array(nees), np.array(ts), np.array(ty), len(frames))


def standard_sequences(quick: bool = False) -> list[tuple[Sequence, bool]]:
    """The experiment's sequences, each with whether its frames go through JPEG: walking
    away with sway ±2, 4, 6° at 30 and 15 fps, the turn in place, random nearby poses."""
    sways = (4.0,) if quick else (2.0, 4.0, 6.0)
    out: list[tuple[Sequence, bool]] = []
    for i, sway in enumerate(sways):
        for fps in (30.0, 15.0):
            out.append((walk_away(fps, i, sway), len(out) % 2 == 0))
    out.append((turn_in_place(30.0, 0), True))
    out.append((random_poses(30.0, 0, n=10 if quick else 30), False))
    return out


def _row(name: str, sc: Scores) -> str:
    a = np.abs(sc.heading_err_deg)
    return (f"| {name} | {len(a)}/{sc.frames} | {np.median(a):.2f}° | "
            f"{np.percentile(a, 95):.2f}° | {a.max():.1f}° | {int(np.sum(sc.ambiguous))} | "
            f"{sc.bad()} | {1000 * np.percentile(sc.position_err_m, 95):.1f} mm | "
            f"{np.nanmean(sc.nees):.2f} |")


def experiment(camera: CameraModel, quick: bool = False
               ) -> tuple[list[str], Scores | None, float, str]:
    """Markdown rows (one a sequence), the scores of the first walk (for the plot), the
    mean NEES over all and what the mount check said of a camera whose real mount is
    pitched 8° off the deployment file's (four further rows, the turn in place and a walk
    away, each without and with the mount correction, out of the NEES); the estimator on
    ``camera`` (e.g. our calibration)."""
    from services.core.geometry import T_base_camera
    from services.pose_estimator.service import PoseEstimator, Settings
    rows, first, nees = [], None, []
    g = Geometry()
    engaged = 0
    for i, (seq, jpeg) in enumerate(standard_sequences(quick)):
        frames = render(seq, seed=i, jpeg=jpeg)
        est = PoseEstimator(camera, g, Settings(static_camera_pose=(0.0, 0.0, 0.0)))
        used: list[bool] = []

        def watched(msg: MarkerVertices, est: PoseEstimator = est,
                    used: list[bool] = used) -> object:
            pose = est.estimate(msg)
            used.append(est.sequence.mount_d is not None)
            return pose
        sc = track(frames, watched)
        engaged += int(any(used))
        if first is None:
            first = sc
        nees.append(sc.nees)
        rows.append(_row(f"{seq.name}{', JPEG' if jpeg else ''}", sc))
    told: list[str] = []
    pitched = T_base_camera(g.camera_forward_m, g.camera_height_m,
                            g.camera_pitch_rad + math.radians(8.0))
    for seq, seed in ((turn_in_place(30.0, 1), 99), (walk_away(30.0, 10, 4.0), 50)):
        frames = render(seq, seed=seed, T_base_camera=pitched)
        for correction in (False, True):
            est = PoseEstimator(camera, g, Settings(static_camera_pose=(0.0, 0.0, 0.0),
                                                    mount_correction=correction))
            correcting: list[bool] = []

            def estimate(msg: MarkerVertices, est: PoseEstimator = est,
                         correcting: list[bool] = correcting) -> object:
                pose = est.estimate(msg)
                if pose.x is not None:
                    correcting.append(est.sequence.mount_d is not None)
                return pose
            sc = track(frames, estimate)
            rows.append(_row(f"{seq.name}, the mount pitched 8° off the file's, "
                             f"{'corrected' if correction else 'not corrected'}", sc))
            short = seq.name.split(",")[0]
            if correction and any(correcting):
                on = np.array(correcting[:len(sc.position_err_m)])
                settled = int(np.argmax(on))
                told.append(f"{short}: {est.mount_warning() or 'no message'}; corrected from "
                            f"pose {settled} on; from then: position p95 "
                            f"{1000 * np.percentile(sc.position_err_m[on], 95):.1f} mm, heading "
                            f"p95 {np.percentile(np.abs(sc.heading_err_deg[on]), 95):.2f}°, "
                            f"NEES {np.nanmean(sc.nees[on]):.2f}")
            elif correction:
                told.append(f"{short}: never corrected")
            else:
                told.append(f"{short} without the correction, from pose 30 on: position p95 "
                            f"{1000 * np.percentile(sc.position_err_m[30:], 95):.1f} mm, "
                            f"heading p95 "
                            f"{np.percentile(np.abs(sc.heading_err_deg[30:]), 95):.2f}°")
    told.append(f"the correction engaged on {engaged} of the {len(nees)} correctly mounted "
                "sequences")
    mount = "; ".join(told) if told else "nothing (no disagreement found)"
    return (rows, first, float(np.nanmean(np.concatenate(nees))) if nees else float("nan"),
            mount)
