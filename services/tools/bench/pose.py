"""``shepherd bench --only pose``: per-pose time and accuracy vs cv2.solvePnP."""

from __future__ import annotations

import math

import cv2
import numpy as np

from services.core.camera import CameraModel, undistort_px
from services.core.mounts import Geometry
from services.pose_estimator.estimate import estimate_marker_pose
from services.pose_estimator.evaluate import (
    PoseCase,
    compare,
    ippe_errors,
    ippe_ratios,
    pose_cases,
    unrelated_views,
    wrong_branches,
)
from services.pose_estimator.p4p import ippe
from services.tools.bench.common import Row, progress, section, times_us


def run(quick: bool) -> None:
    cam = CameraModel.paper()
    pts = Geometry().marker_points()
    n = 300 if quick else 1000
    progress(f"pose: {n} views")
    cases = pose_cases(n, seed=3)
    reps = 3
    timings: dict[str, np.ndarray] = {}
    timings["ours: IPPE analytic (undistort + both candidates)"] = np.concatenate([
        times_us(_ippe_undistorted, reps, cam, pts, c)
        for c in cases])
    timings["ours: + upright MAP choice + Gauss-Newton"] = np.concatenate([
        times_us(_ours_map, reps, cam, pts, c) for c in cases])
    flags = {"cv2 IPPE": cv2.SOLVEPNP_IPPE, "cv2 ITERATIVE": cv2.SOLVEPNP_ITERATIVE,
             "cv2 SQPNP": cv2.SOLVEPNP_SQPNP, "cv2 AP3P": cv2.SOLVEPNP_AP3P}
    for name, flag in flags.items():
        timings[name] = np.concatenate([
            times_us(_cv_pnp, reps, cam, pts, c, flag) for c in cases])
    ref = float(np.median(timings["cv2 IPPE"]))
    rows: list[Row] = [(k, f"{np.median(t):.1f}", f"{np.percentile(t, 99):.1f}",
                        f"{np.median(t) / ref:.2f}") for k, t in timings.items()]
    section(f"Pose: time per pose, {n} views", ("method", "median µs", "p99 µs",
                                                  "median / cv2 IPPE"), rows,
             "Goal: our analytic solve no slower than cv2 IPPE.")
    progress("pose: accuracy")
    res = compare(cases, cam)
    rows = [(k, f"{1000 * np.median(p):.2f}", f"{1000 * np.percentile(p, 90):.2f}",
             f"{math.degrees(np.median(a)):.2f}", f"{math.degrees(np.percentile(a, 90)):.2f}")
            for k, (p, a) in res.items()]
    section(f"Pose: accuracy on the same {n} views (15-80 cm, vertex noise 0.1-1 px)",
             ("method", "position median mm", "p90 mm", "rotation median °", "p90 °"), rows,
             "Ours is given what the service has: its fixed vertex noise (0.2 px) and the up "
             "vector of the view's camera mounts (a deployment configures them); the second "
             "row is given each view's true noise as well, for reference. OpenCV gets the "
             "same pixels and intrinsics, no priors. Goal: never worse than the best OpenCV "
             "method by more than 2%.")
    progress("pose: the upright prior when it is right and when it is wrong")
    rows = []
    seeds, m = ((21, 22), 500) if quick else ((21, 22, 23, 24), 1000)
    variants: dict[str, dict[str, object]] = {
        "known": {}, "fixed": {"noise_known": False},
        "before": {"noise_known": False, "height_m": None, "upright_probability": 1.0}}
    for label, kw in (("upright (within 3°)", {}),
                      ("pitched to 15°, rolled to 10°", {"lean_deg": 15.0, "roll_deg": 10.0}),
                      ("mount 8° off the file's", {"lean_deg": 2.0, "mount_off_deg": 8.0})):
        # several seeds pooled: one seed's ratio of medians moves by about ±2-4 %
        errs: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {k: [] for k in variants}
        for seed in seeds:
            views = unrelated_views(m, seed=seed, **kw)  # type: ignore[arg-type]
            for k, v in variants.items():
                errs[k].append(ippe_errors(views, **v))  # type: ignore[arg-type]
        per_seed = [ippe_ratios(*e)[0] for e in errs["known"]]
        pooled = {k: ippe_ratios(*(np.concatenate(x) for x in zip(*e, strict=True)))
                  for k, e in errs.items()}
        rows.append((label, f"{pooled['known'][0]:.3f}",
                     f"{min(per_seed):.3f}-{max(per_seed):.3f}", f"{pooled['known'][1]:.3f}",
                     f"{pooled['fixed'][0]:.3f}", f"{pooled['fixed'][1]:.3f}",
                     f"{pooled['before'][0]:.3f}", f"{pooled['before'][1]:.3f}"))
    section(f"Pose: position error / cv2 IPPE, unrelated views at the marker's height, "
            f"0.3 px ({len(seeds)} seeds x {m} views pooled)",
            ("markers", "ours: median", "median, per seed", "p90",
             "fixed 0.2 px: median", "p90", "before: median", "p90"), rows,
            "Ours: the mount's up, corrected per view by the marker's elevation "
            "(estimate.up_from_elevation), the upright prior (2°, heavy-tailed beyond "
            "1.75 sigma) tested per view (estimate.UPRIGHT_PROBABILITY), the vertex sigma "
            "the extractor's covariance carries (0.3 px: the noise the bench adds). "
            "'fixed 0.2 px': no knowledge of the noise, the service's setting. 'before': "
            "no elevation, no test, 0.2 px. OpenCV gets the same pixels and intrinsics, no "
            "priors. The ratios are of the pooled errors; 'per seed' is the spread of one "
            "seed's median ratio. Goal: upright median <= 0.95x, p90 <= 1.0x; pitched or a "
            "mount off: median <= 1.05x, p90 <= 1.0x.")
    progress("pose: IPPE branches")
    rows = []
    for lo, hi in ((0.05, 0.3), (0.1, 1.0)):
        noisy = cases if (lo, hi) == (0.1, 1.0) else pose_cases(n, seed=3, noise_px=(lo, hi))
        for prior in (True, False):
            r = wrong_branches(noisy, cam, prior=prior)
            rows.append((f"{lo}-{hi} px", "upright prior" if prior else "image only",
                         str(r.views), str(r.wrong), str(r.decidable), str(r.wrong_decidable),
                         str(r.search_misses)))
    section(f"Pose: IPPE branch choice, {n} views (truth leans up to 2°, prior sigma 2°)",
             ("vertex noise", "choice by", "two branches", "wrong", "prior decides",
              "wrong there", "search misses"), rows,
             "'prior decides': the mirror branch is tilted > 4 sigma beyond the truth. "
             "Goal: never wrong there. 0.05-0.3 px is the vertex extractor's measured error; "
             "at 1 px an upright mirror can fit the image better than the truth (search misses "
             "= 0: every wrong pick is the posterior's own). Yaw mirrors, level on both "
             "branches, are left to the service's frame-to-frame continuity prior.")


def _ippe_undistorted(cam: CameraModel, pts: np.ndarray, case: PoseCase) -> object:
    return ippe(pts, undistort_px(cam, case.vertices_px))


def _ours_map(cam: CameraModel, pts: np.ndarray, case: PoseCase) -> object:
    return estimate_marker_pose(cam, case.vertices_px, pts, up_cam=case.up_cam,
                                sigma_px=case.noise_px)


def _cv_pnp(cam: CameraModel, pts: np.ndarray, case: PoseCase, flag: int) -> object:
    return cv2.solvePnP(pts, *_cv_inputs(cam, case), flags=flag)


def _cv_inputs(cam: CameraModel, case: PoseCase) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    v, K = cam.deskew_px(case.vertices_px)
    return v, K, cam.dist
