"""``shepherd bench --only calibration``: pattern detection and Zhang vs cv2.calibrateCamera."""

from __future__ import annotations

from functools import partial

import numpy as np

from services.tools.bench.common import DATASETS, Row, progress, section, times_us


def run(quick: bool) -> None:
    import cv2

    from services.calibration.detect import detect_chessboard, detect_grid, detect_squares
    from services.calibration.pattern import GridSheet, PatternSpec
    from services.calibration.run import read_image
    from services.calibration.synthetic import board_pose, render_plane
    from services.calibration.zhang import calibrate
    from services.core.camera import CameraModel
    datasets = DATASETS
    if not datasets.is_dir():
        progress(f"calibration: no real data sets at {datasets} (they live in a clone's "
                 "tests/data); simulated views only")
    reps = 3 if quick else 10
    rows: list[Row] = []
    # detection per image
    cam = CameraModel(np.array([[780.0, 0.0, 325.0], [0, 785.0, 238.0], [0, 0, 1]]),
                      np.array([-0.22, 0.09, 0.0, 0.0, 0.0]))
    sheet = GridSheet()
    tex = sheet.raster(10.0, page=False)
    origin = ((sheet.overhang_mm + 5) * 10.0,) * 2
    progress("calibration: rendering grid views")
    rng = np.random.default_rng(1)
    grids = []
    for i in range(4):
        distance = rng.uniform(0.4, 0.5)
        tilt_x, tilt_y, roll = np.radians(rng.uniform(-30, 30, 3))
        grids.append(render_plane(cam, board_pose(distance, tilt_x, tilt_y, roll, (0.08, 0.08),
                                                  (0, 0), cam), tex, 1e4, origin, seed=i))
    t = np.concatenate([times_us(detect_grid, reps, g) for g in grids])
    rows.append(("grid 9+9 lines, Hough + sub-pixel (ours), simulated 640x480",
                 f"{np.median(t) / 1e3:.1f}"))
    zhang = datasets / "zhang1998_calibration"
    opencv = datasets / "opencv_left_chessboard"
    if zhang.is_dir():
        imgs = [read_image(p) for p in sorted(zhang.glob("CalibIm*.gif"))]
        t = np.concatenate([times_us(detect_squares, reps, g) for g in imgs])
        rows.append(("Zhang's 8x8 squares (ours), his 5 images", f"{np.median(t) / 1e3:.1f}"))
    if opencv.is_dir():
        imgs = [read_image(p) for p in sorted(opencv.glob("left*.jpg"))]
        t = np.concatenate([times_us(detect_chessboard, reps, g, 9, 6)
                            for g in imgs])
        rows.append(("chessboard 9x6: cv2.findChessboardCorners + cornerSubPix, OpenCV's 13",
                     f"{np.median(t) / 1e3:.1f}"))
    section("Calibration: pattern detection per image", ("detector", "median ms"), rows)
    # the whole calibration on the same points
    sets = []
    if zhang.is_dir():
        model = np.loadtxt(zhang / "Model.txt").reshape(-1, 2)
        sets.append(("Zhang's published points, 5 x 256",
                     [model] * 5, [np.loadtxt(zhang / f"data{i}.txt").reshape(-1, 2)
                                   for i in range(1, 6)], (640, 480)))
    grid_model = PatternSpec.parse("grid:9x9:0.02").model_points()
    sets.append(("simulated grid views, 4 x 81", [grid_model] * 4,
                 [detect_grid(g) for g in grids], (640, 480)))
    rows = []
    for name, models, images, size in sets:
        ours_t = times_us(calibrate, reps, models, images)
        ours = calibrate(models, images)
        obj = [np.column_stack([m, np.zeros(len(m))]).astype(np.float32) for m in models]
        img = [i.astype(np.float32).reshape(-1, 1, 2) for i in images]
        flags = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
        cv_t = times_us(partial(cv2.calibrateCamera, flags=flags), reps, obj, img,
                        size, None, None)
        rms, K, dist, *_ = cv2.calibrateCamera(obj, img, size, None, None, flags=flags)
        rows.append((name, "ours (Zhang + LM)", f"{np.median(ours_t) / 1e3:.1f}",
                     f"{ours.K[0, 0]:.2f}", f"{ours.K[1, 1]:.2f}",
                     f"{ours.K[0, 2]:.2f}, {ours.K[1, 2]:.2f}", f"{ours.dist[0]:.4f}",
                     f"{ours.rms_px:.4f}"))
        rows.append(("", "cv2.calibrateCamera (k1, k2 only)", f"{np.median(cv_t) / 1e3:.1f}",
                     f"{K[0, 0]:.2f}", f"{K[1, 1]:.2f}", f"{K[0, 2]:.2f}, {K[1, 2]:.2f}",
                     f"{dist.ravel()[0]:.4f}", f"{rms:.4f}"))
    section("Calibration: the whole solve on the same points",
             ("points", "method", "median ms", "fx", "fy", "u0, v0", "k1", "RMS px"), rows,
             "Zhang's published values: fx 832.50, fy 832.53, (303.96, 206.59), k1 -0.2286, "
             "RMS 0.336. Simulated truth: fx 780, fy 785, (325, 238), k1 -0.22. OpenCV's model "
             "has no skew; ours estimates it.")
