"""``shepherd experiments``: the paper's experiments reproduced in simulation.

- Table 3: the camera's pose recovered from four rhombi at known positions, about 38 cm
  away, with the paper's camera matrix; spread between the four estimates.
- Fig. 9: the humanoid's distance from the camera over time in the control experiment
  (29 cm -> 60 cm), from a direct loop of the same modules the services use.
- Fig. 10: standard deviation of the estimated distance against the area ratio r, and the
  distance where r = 5%.
- Critical angle: standard deviation against the view angle at d = 25 cm.

Writes ``report.md`` and PNG plots; the paper's numbers beside ours.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from schemas import Command, MarkerVertices
from services.core.camera import CameraModel
from services.core.geometry import inv_T, make_T, rot_x, rot_y
from services.core.mounts import Geometry
from services.core.world import World
from services.data import SIM_CAMERA
from services.mission_controller.controller import ControlParams, HeuristicController
from services.monitor.plot import line_plot
from services.pose_estimator.estimate import estimate_marker_pose, up_in_camera
from services.pose_estimator.pose_filter import PoseFilter
from services.pose_estimator.service import PoseEstimator
from services.pose_estimator.service import Settings as PoseSettings
from services.sim.render import RenderStyle, render_view
from services.sim.scenes import marker_pose
from services.sim.state import SimWorld
from services.sim.webcam import WebcamParams
from services.tools import pose_sequences
from services.vertex_extractor.extractor import RhombusExtractor

PAPER_TABLE3_SPREAD = {"x": 0.265, "y": 0.580, "z": 1.419, "roll": 2.643, "pitch": 6.855,
                       "yaw": 0.857}


def _progress(text: str) -> None:
    print(f"  … {text}", file=sys.stderr, flush=True)


def _euler_deg(R: np.ndarray) -> tuple[float, float, float]:
    """(roll about z, pitch about x, yaw about y) in degrees of a camera-convention rotation
    (the paper's z along the optical axis, y vertical)."""
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, -R[1, 2]))))
    yaw = math.degrees(math.atan2(R[0, 2], R[2, 2]))
    roll = math.degrees(math.atan2(R[1, 0], R[1, 1]))
    return roll, pitch, yaw


def _noisy_style(rng: np.random.Generator, k: int) -> RenderStyle:
    """A web camera's look: noise about 3 grey levels, a little blur, lighting changes."""
    return RenderStyle(seed=int(rng.integers(0, 4)), noise_sigma=3.0,
                       brightness=float(rng.uniform(0.8, 1.15)),
                       motion_blur_px=float(rng.uniform(0.0, 1.5)))


def table3(trials: int, seed: int = 0, estimator: CameraModel | None = None
           ) -> tuple[str, np.ndarray]:
    """Camera pose from each of four rhombi on a sheet, about 38 cm away (rendered with the
    paper's camera, estimated with ``estimator``'s intrinsics: the truth by default)."""
    cam, g = CameraModel.paper(), Geometry()
    est_cam = estimator or cam
    pts = g.marker_points()
    # the sheet frame S: x right, y down, z away from the camera (like the camera's own)
    T_camera_sheet = make_T(rot_x(math.radians(-8)) @ rot_y(math.radians(3)),
                            (0.03, 0.0, 0.38))
    offsets = [(-0.06, -0.05), (0.06, -0.05), (-0.06, 0.05), (0.06, 0.05)]
    T_sheet_markers = [make_T(np.diag([1.0, -1.0, -1.0]), (x, y, 0.0)) for x, y in offsets]
    rng = np.random.default_rng(seed)
    ex = RhombusExtractor()
    spreads = []
    per_marker_first: list[np.ndarray] = []
    for trial in range(trials):
        rows = []
        for T_sm in T_sheet_markers:
            T_cm = T_camera_sheet @ T_sm
            r = render_view(cam, T_cm, marker_points_m=pts, style=_noisy_style(rng, trial),
                            frame_index=trial)
            ex.reset()
            det = ex.extract(r.image)
            if not det.found or det.vertices_px is None:
                continue
            est = estimate_marker_pose(est_cam, det.vertices_px, pts, sigma_px=0.3)
            T_sheet_camera = T_sm @ inv_T(est.T_camera_marker)
            x, y, z = 100 * T_sheet_camera[:3, 3]
            rows.append([x, -y, -z, *_euler_deg(T_sheet_camera[:3, :3])])
        if len(rows) == 4:
            a = np.array(rows)
            spreads.append(np.mean(np.abs(a - a.mean(0)), axis=0))
            if not per_marker_first:
                per_marker_first = list(a)
    spread = np.mean(spreads, axis=0)
    names = ["x", "y", "z", "roll", "pitch", "yaw"]
    truth = inv_T(T_camera_sheet)
    tx, ty, tz = 100 * truth[:3, 3]
    lines = ["| | Rho. 1 | Rho. 2 | Rho. 3 | Rho. 4 | spread (ours) | spread (paper) |",
             "|---|---|---|---|---|---|---|"]
    for j, n in enumerate(names):
        vals = " | ".join(f"{m[j]:.3f}" for m in per_marker_first)
        unit = "cm" if j < 3 else "°"
        lines.append(f"| {n} ({unit}) | {vals} | {spread[j]:.3f} | "
                     f"{PAPER_TABLE3_SPREAD[n]:.3f} |")
    text = ("\n".join(lines) + f"\n\nTrue camera position in the sheet frame: ({tx:.2f}, "
            f"{-ty:.2f}, {-tz:.2f}) cm (x right, y up, z towards the camera, as the paper's "
            f"table). Spread = mean absolute deviation of the four estimates from their mean, "
            f"averaged over {len(spreads)} noisy trials (noise 3 grey levels, blur up to "
            "1.5 px, lighting 0.8-1.15); the first trial's estimates are shown.")
    return text, spread


@dataclass(frozen=True)
class ControlRun:
    truth: np.ndarray       # (t s, true x m, true y m)
    estimates: np.ndarray   # (t s, estimated x m, y m): raw
    filtered: np.ndarray    # (t s, x m, y m): the steady pose
    final: tuple[float, float]  # the humanoid's true final position (m)
    reversals: int
    reason: str             # how the controller ended


def _camera_style(seed: int, webcam: bool) -> RenderStyle:
    """The simulator's look: its webcam in a photographed room, or the ideal renders."""
    return (RenderStyle(seed=seed, camera=WebcamParams(), photos=True) if webcam
            else RenderStyle(seed=seed))


def control_run(seed: int = 1, max_s: float = 30.0, fps: float = 30.0,
                steer_by_filtered: bool = False, webcam: bool = True) -> ControlRun:
    """The paper's control experiment in a direct loop of the services' own modules: the
    stepping humanoid, the estimator on our calibration of the camera (not its truth), the
    camera fixed as in the paper, control at 10 Hz on the raw or the filtered pose; frames
    through the simulated webcam (or ideal renders)."""
    g = Geometry()
    sim = SimWorld(camera=CameraModel.paper(), geometry=g, world=World(),
                   humanoid_start=(0.29, 0.0, 0.0), camera_start=(0.0, 0.0, 0.0), seed=seed,
                   style=_camera_style(seed, webcam))
    ex = RhombusExtractor()
    calibrated = CameraModel.load(SIM_CAMERA)
    est = PoseEstimator(calibrated, g, PoseSettings(static_camera_pose=(0.0, 0.0, 0.0)))
    ctrl = HeuristicController(ControlParams())
    ctrl.set_waypoints([(0.60, 0.0)])
    truth, estimates, filtered = [], [], []
    steady = PoseFilter()
    last: Command | None = None
    dt = 1.0 / fps
    done_at = None
    reason = ""
    for k in range(int(max_s * fps)):
        t = k * dt
        sim.step(dt)
        det = ex.extract(sim.render().image)
        pose = None
        heading_sigma = None
        if det.found and det.vertices_px is not None:
            v = det.vertices_px
            msg = MarkerVertices(seq=k, stamp_ns=int(t * 1e9), found=True, vertices_px=(
                (v[0, 0], v[0, 1]), (v[1, 0], v[1, 1]), (v[2, 0], v[2, 1]), (v[3, 0], v[3, 1])))
            p = est.estimate(msg)
            assert p.x is not None and p.y is not None and p.yaw is not None
            pose = (p.x, p.y, p.yaw)
            if p.covariance is not None:
                heading_sigma = math.sqrt(max(p.covariance[2][2], 0.0))
            f, _ = steady.update(msg.stamp_ns, pose, None if p.covariance is None
                                 else np.array(p.covariance))
            estimates.append((t, p.x, p.y))
            filtered.append((t, f[0], f[1]))
            if steer_by_filtered:
                pose = (float(f[0]), float(f[1]), float(f[2]))
        truth.append((t, sim.humanoid.x, sim.humanoid.y))
        if k % 3 == 0:  # 10 Hz control
            d = ctrl.decide(pose, 0.0, False, now_s=t, heading_sigma_rad=heading_sigma)
            reason = d.reason
            if d.command is not last:
                sim.command(d.command)
                last = d.command
            if d.phase.value == "done" and done_at is None:
                done_at = t
        if done_at is not None and t - done_at > 1.5:
            break
    return ControlRun(np.array(truth), np.array(estimates), np.array(filtered),
                      (sim.humanoid.x, sim.humanoid.y), ctrl.reversals, reason)


#: the walk of ``pose_tracking``: (command, seconds)
TRACKING_SCRIPT = ((Command.WALK_FORWARD, 3.0), (Command.TURN_LEFT, 1.5),
                   (Command.WALK_FORWARD, 2.0), (Command.TURN_RIGHT, 3.0),
                   (Command.WALK_BACKWARD, 2.0), (Command.TURN_LEFT, 1.5), (Command.STOP, 1.0))


def pose_tracking(seed: int = 4, fps: float = 30.0, webcam: bool = True
                  ) -> tuple[np.ndarray, np.ndarray, int, int]:
    """The humanoid walking and turning (``TRACKING_SCRIPT``) 35-60 cm in front of the static
    camera; every frame through the extractor and the pose estimator (our calibration).
    Returns (position errors m, heading errors deg, poses, frames)."""
    g = Geometry()
    sim = SimWorld(camera=CameraModel.paper(), geometry=g, world=World(),
                   humanoid_start=(0.40, 0.0, 0.0), camera_start=(0.0, 0.0, 0.0), seed=seed,
                   style=_camera_style(seed, webcam))
    ex = RhombusExtractor()
    est = PoseEstimator(CameraModel.load(SIM_CAMERA), g,
                        PoseSettings(static_camera_pose=(0.0, 0.0, 0.0)))
    dt = 1.0 / fps
    pos, yaw = [], []
    frames = 0
    k = 0
    for command, seconds in TRACKING_SCRIPT:
        sim.command(command)
        for _ in range(int(seconds * fps)):
            sim.step(dt)
            frames += 1
            det = ex.extract(sim.render().image)
            k += 1
            if not (det.found and det.vertices_px is not None):
                continue
            v = det.vertices_px
            p = est.estimate(MarkerVertices(seq=k, stamp_ns=int(k * dt * 1e9), found=True,
                                            vertices_px=tuple(  # type: ignore[arg-type]
                                                (float(a), float(b)) for a, b in v)))
            if p.x is None or p.y is None or p.yaw is None:
                continue
            h = sim.humanoid
            pos.append(math.hypot(p.x - h.x, p.y - h.y))
            yaw.append(abs(math.degrees(math.remainder(p.yaw - h.yaw, 2 * math.pi))))
    return np.array(pos), np.array(yaw), len(pos), frames


def control_statistics(seeds: int) -> tuple[np.ndarray, np.ndarray]:
    """Final true error (m) and command reversals of the control experiment over seeds."""
    runs = []
    for seed in range(seeds):
        _progress(f"control experiment, seed {seed + 1}/{seeds}")
        runs.append(control_run(seed=100 + seed))
    errors = np.array([math.hypot(r.final[0] - 0.60, r.final[1]) for r in runs])
    return errors, np.array([r.reversals for r in runs])


def std_vs_distance(trials: int, seed: int = 2, estimator: CameraModel | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(area ratio r, distance m, std of estimated z m) for a marker facing the camera."""
    cam, g = CameraModel.paper(), Geometry()
    est_cam = estimator or cam
    pts = g.marker_points()
    up = up_in_camera(g.T_base_camera())  # the system's upright prior, as the service uses
    rng = np.random.default_rng(seed)
    ex = RhombusExtractor()
    rs, ds, stds = [], [], []
    for d in np.linspace(0.15, 0.9, 16):
        zs, r_area = [], 0.0
        for k in range(trials):
            T = marker_pose(d, cam.K[0, 2], cam.K[1, 2], cam)
            rr = render_view(cam, T, marker_points_m=pts, style=_noisy_style(rng, k),
                             frame_index=k)
            ex.reset()
            det = ex.extract(rr.image)
            if det.found and det.vertices_px is not None:
                zs.append(estimate_marker_pose(est_cam, det.vertices_px, pts, up_cam=up,
                                               sigma_px=0.3).T_camera_marker[2, 3])
                r_area = det.area_ratio
        if len(zs) > 2:
            rs.append(r_area)
            ds.append(d)
            stds.append(float(np.std(zs)))
    return np.array(rs), np.array(ds), np.array(stds)


def std_vs_angle(trials: int, seed: int = 3, estimator: CameraModel | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(view angle deg, std of estimated z m, std of estimated yaw deg) at d = 25 cm."""
    cam, g = CameraModel.paper(), Geometry()
    est_cam = estimator or cam
    pts = g.marker_points()
    T_bc = g.T_base_camera()
    up = up_in_camera(T_bc)
    rng = np.random.default_rng(seed)
    ex = RhombusExtractor()
    angles, sz, syaw = [], [], []
    for a in range(0, 76, 5):
        zs, yaws = [], []
        for k in range(trials):
            T = marker_pose(0.25, cam.K[0, 2], cam.K[1, 2], cam, math.radians(a))
            rr = render_view(cam, T, marker_points_m=pts, style=_noisy_style(rng, k),
                             frame_index=k)
            ex.reset()
            det = ex.extract(rr.image)
            if det.found and det.vertices_px is not None:
                R = estimate_marker_pose(est_cam, det.vertices_px, pts, up_cam=up,
                                         sigma_px=0.3).T_camera_marker
                zs.append(R[2, 3])
                yaws.append(math.degrees(math.atan2(R[0, 2], -R[2, 2])))
        if len(zs) > 2:
            angles.append(a)
            sz.append(float(np.std(zs)))
            syaw.append(float(np.std(yaws)))
    return np.array(angles), np.array(sz), np.array(syaw)


def run(out: Path, quick: bool = False) -> int:
    out.mkdir(parents=True, exist_ok=True)
    trials = 4 if quick else 30
    t0 = time.monotonic()
    parts = ["# Shepherd: the paper's experiments in simulation", "",
             f"Generated by `shepherd experiments{' --quick' if quick else ''}` "
             f"({trials} noisy trials per point). Camera: the paper's A matrix, 640x480; the "
             "control runs see the simulated webcam (docs/how-it-works/simulator.md).", ""]
    calibrated = CameraModel.load(SIM_CAMERA)
    _progress("Table 3: camera pose from four rhombi")
    text, _ = table3(trials)
    _, spread_cal = table3(trials, estimator=calibrated)
    parts += ["## Table 3: camera pose from four rhombi (~38 cm)", "", text, "",
              "Beside it, the same trials estimated with our own calibration of the camera "
              "(`sim-camera.toml`) instead of its true intrinsics: spread "
              + ", ".join(f"{n} {v:.3f}" for n, v in zip(
                  ["x", "y", "z", "roll", "pitch", "yaw"], spread_cal, strict=True))
              + " (cm, °).", ""]

    _progress("Fig. 9: the control experiment")
    run_ = control_run(max_s=20.0 if quick else 30.0)
    truth, est, final = run_.truth, run_.estimates, run_.final
    err = math.hypot(final[0] - 0.60, final[1])
    cv2.imwrite(str(out / "fig9_distance.png"), line_plot(
        [("true (cm)", truth[:, 0], 100 * truth[:, 1]),
         ("estimated (cm)", est[:, 0], 100 * est[:, 1])],
        title="Fig. 9: humanoid distance from the camera (z) over time", xlabel="time (s)",
        ylabel="cm", hlines=[("goal 60 cm", 60.0)], residual=(
            "estimate - truth (mm)", est[:, 0],
            1000 * (est[:, 1] - np.interp(est[:, 0], truth[:, 0], truth[:, 1])))))
    parts += ["## Fig. 9: the control experiment", "", "![](fig9_distance.png)", "",
              "| | goal (x, y, z) cm | reached (x, y, z) cm | error |", "|---|---|---|---|",
              "| paper | (0, 4.7, 60) | (3.3, 4.8, 58.2) | 3.8 cm |",
              f"| ours (truth) | (0, 4.7, 60) | ({-100 * final[1]:.1f}, 4.7, "
              f"{100 * final[0]:.1f}) | {100 * err:.1f} cm |", "",
              "Ours: a direct loop of the simulator, extractor, pose estimator and heuristic "
              "controller at 30 fps (control at 10 Hz), the camera fixed as in the paper; y is "
              "the marker height above the camera axis and is not estimated on the floor.", ""]

    seeds = 5 if quick else 20
    errors, reversals = control_statistics(seeds)
    parts += [f"## The control experiment over {seeds} seeds", "",
              "The stepping humanoid (whole steps, sway, slip, heading drift, a stop that "
              "finishes the step), the pose estimator on our own calibration of the simulated "
              "camera, the heuristic controller with settling and step-back corrections.", "",
              "| | final true error median | p90 | max | command reversals (max) |",
              "|---|---|---|---|---|",
              "| paper (one run) | 3.8 cm | — | — | — |",
              f"| ours, {seeds} seeds | {100 * np.median(errors):.1f} cm | "
              f"{100 * np.percentile(errors, 90):.1f} cm | {100 * errors.max():.1f} cm | "
              f"{int(reversals.max())} |", "",
              "Goal: median <= 2 cm, p90 <= 3 cm, no run with more than 3 reversals.", ""]

    _progress("pose over frames of the walking humanoid")
    tracking = []
    for label, webcam in (("ideal renders", False), ("webcam", True)):
        pos, yaw, n, frames = pose_tracking(webcam=webcam)
        tracking.append(f"| {label} | {n}/{frames} | {1000 * np.median(pos):.1f} mm | "
                    f"{1000 * np.percentile(pos, 95):.1f} mm | {np.median(yaw):.2f}° | "
                    f"{np.percentile(yaw, 95):.2f}° |")
    parts += ["## Pose over frames of the walking humanoid", "",
              "The stepping humanoid walks, turns and walks back 35-60 cm in front of the "
              "static camera (" + ", ".join(f"{c.value} {t:g} s" for c, t in TRACKING_SCRIPT)
              + "); every frame through the extractor and the pose estimator on our "
              "calibration.", "",
              "| frames | poses | position median | p95 | heading median | p95 |",
              "|---|---|---|---|---|---|", *tracking, "",
              "Goal (webcam): heading median <= 0.5°, p95 <= 2°; position median <= 3 mm.", ""]

    _progress("heading over sequences at the marker's height")
    seq_rows, walk, nees, mount = pose_sequences.experiment(calibrated, quick)
    if walk is not None:
        cv2.imwrite(str(out / "heading_walk_away.png"), line_plot(
            [("true heading (°)", walk.t_s, walk.truth_yaw_deg),
             ("estimated heading (°)", walk.t_s, walk.truth_yaw_deg + walk.heading_err_deg),
             ("published 1-sigma (°)", walk.t_s, walk.heading_sigma_deg)],
            title="Heading while walking straight away (camera at the marker's height)",
            xlabel="time (s)", ylabel="degrees",
            residual=("estimate - truth (°)", walk.t_s, walk.heading_err_deg)))
    parts += ["## Heading over sequences at the marker's height", "",
              "![](heading_walk_away.png)", "",
              "The static camera at the marker's height (where the two IPPE poses are yaw "
              "mirrors that cross whenever the heading crosses the line of sight); frames "
              "through the simulated webcam in the photographed room, the extractor and the "
              "pose estimator on our calibration. Walking away: the heading sways with the "
              "steps, the marker rolls ±1.1° with them.", "",
              "| sequence | poses | heading median | p95 | max | ambiguous | > 5° off, "
              "not covered | position p95 | NEES (x, y, yaw) |",
              "|---|---|---|---|---|---|---|---|---|", *seq_rows, "",
              f"Mean NEES over all sequences: **{nees:.2f}** (an honest covariance: 3, a "
              "chi-squared with 3 degrees of freedom). 'Not covered': more than 5° off and "
              "not marked ambiguous with its heading sigma covering the error. Goal: walking away "
              "heading median <= 0.5°, p95 <= 2°, position p95 <= 6 mm; none not covered; "
              "NEES 2-4.5.", "",
              "The last four rows: the camera's real mount pitched 8° down while the "
              "deployment file says level (the marker-to-feet lever then goes through the "
              "wrong vertical; each frame's upright prior takes its vertical from the "
              "marker's elevation), turning in place and walking away, without and with the "
              "mount correction (`mount_correction`: once the marker's mean lean has "
              "settled, the estimated up replaces the file's; the first 30 or more poses are "
              f"before it settles). The mount check said: _{mount}_.", ""]

    _progress("Fig. 10: spread against area ratio")
    rs, ds, stds = std_vs_distance(trials)
    rs_c, _, stds_c = std_vs_distance(trials, estimator=calibrated)
    cv2.imwrite(str(out / "fig10_std_vs_r.png"), line_plot(
        [("std of z, true intrinsics (mm)", 100 * rs, 1000 * stds),
         ("std of z, our calibration (mm)", 100 * rs_c, 1000 * stds_c)],
        title="Fig. 10: std of estimated z against the area ratio r", xlabel="r (%)",
        ylabel="mm"))
    d5 = float(np.interp(0.05, rs[::-1], ds[::-1])) if len(rs) else float("nan")
    rows = "\n".join(f"| {100 * r:.2f} | {100 * d:.1f} | {1000 * s:.2f} |"
                     for r, d, s in zip(rs, ds, stds, strict=True))
    parts += ["## Fig. 10: standard deviation of z against r", "", "![](fig10_std_vs_r.png)",
              "", "| r (%) | distance (cm) | std of z (mm) |", "|---|---|---|", rows, "",
              f"r = 5% at d = {100 * d5:.1f} cm (paper: 25 cm). The paper saw the deviation "
              "rise quickly below r = 5%; here it grows with distance as expected "
              "(std ~ z² / (f · size)).", ""]

    _progress("critical angle")
    angles, sz, syaw = std_vs_angle(trials)
    angles_c, sz_c, syaw_c = std_vs_angle(trials, estimator=calibrated)
    cv2.imwrite(str(out / "critical_angle.png"), line_plot(
        [("std of z (mm)", angles, 1000 * sz), ("std of yaw (deg)", angles, syaw),
         ("std of z, our calibration (mm)", angles_c, 1000 * sz_c),
         ("std of yaw, our calibration (deg)", angles_c, syaw_c)],
        title="Spread against the view angle off the marker normal (d = 25 cm)",
        xlabel="degrees off the normal", ylabel="mm / deg"))
    rows = "\n".join(f"| {a:.0f} | {1000 * s:.2f} | {y:.2f} |"
                     for a, s, y in zip(angles, sz, syaw, strict=True))
    parts += ["## Critical angle", "", "![](critical_angle.png)", "",
              "| view angle off normal (°) | std of z (mm) | std of yaw (°) |", "|---|---|---|",
              rows, "", "The paper found theta = 50° (the view at most 40° off the marker's "
              "normal) keeps its spread under 5%; Shepherd's planner uses the same default.",
              ""]
    parts.append(f"_Run time {time.monotonic() - t0:.0f} s._")
    (out / "report.md").write_text("\n".join(parts) + "\n")
    print(f"wrote {out / 'report.md'} and {len(list(out.glob('*.png')))} plots")
    return 0
