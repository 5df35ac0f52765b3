"""``shepherd bench --only vertices``: rhombus extraction vs OpenCV's contour route, ArUco
and AprilTag on the same frames."""

from __future__ import annotations

import numpy as np

from services.tools.bench.common import Row, progress, section, times_us


def run(quick: bool) -> None:
    import cv2

    from services.sim.scenes import random_views
    from services.vertex_extractor.extractor import RhombusExtractor
    n = 60 if quick else 200
    progress(f"vertices: rendering {n} frames")
    views = list(random_views(n, seed=42, distance_m=(0.2, 0.6)))
    frames = [v.rendered.image for v in views]
    aruco_frames = [_aruco_frame(v) for v in views]
    ex = RhombusExtractor()

    def cold(img: np.ndarray) -> object:
        ex.reset()
        return ex.extract(img)

    tracked_t: list[np.ndarray] = []
    for img in frames:
        ex.reset()
        ex.extract(img)
        tracked_t.append(times_us(ex.extract, 5, img))
    cold_t = np.concatenate([times_us(cold, 3, img) for img in frames])
    contour_t = np.concatenate([times_us(_contour_route, 3, img)
                                for img in frames])
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    aruco_t = np.concatenate([times_us(detector.detectMarkers, 3, img)
                              for img in aruco_frames])
    rows: list[Row] = []
    ref = float(np.median(contour_t))
    entries = [("ours, tracked (the last marker's centre seeds the scan)",
                np.concatenate(tracked_t)),
               ("ours, cold (coarse grid search)", cold_t),
               ("OpenCV contour route: cvtColor, inRange, findContours, approxPolyDP", contour_t),
               ("OpenCV ArUco 4x4, same size", aruco_t)]
    try:
        import pupil_apriltags
        det = pupil_apriltags.Detector(families="tag36h11", nthreads=1)
        grey = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in aruco_frames]
        entries.append(("AprilTag (pupil-apriltags, tag36h11, 1 thread)",
                        np.concatenate([times_us(det.detect, 3, g) for g in grey])))
    except ImportError:
        rows.append(("AprilTag", "not installed: pip install '.[bench]'", "", ""))
    for name, t in entries:
        rows.append((name, f"{np.median(t) / 1e3:.3f}", f"{np.percentile(t, 99) / 1e3:.3f}",
                     f"{np.median(t) / ref:.2f}"))
    errs: list[np.ndarray] = []
    for v in views:
        ex.reset()
        d = ex.extract(v.rendered.image)
        if d.found and d.vertices_px is not None:
            errs.append(np.linalg.norm(d.vertices_px - v.rendered.vertices_px, axis=1))
    e = np.concatenate(errs)
    section(f"Vertex extraction, {n} simulated 640x480 frames (20-60 cm)",
             ("method", "median ms", "p99 ms", "median / contour route"), rows,
             f"Our vertex error on these frames: median {np.median(e):.3f} px, p95 "
             f"{np.percentile(e, 95):.3f} px, found {len(errs)}/{n}. Goal: tracked <= 0.15 ms "
             "and faster than every reference; cold no slower than the contour route.")


def _contour_route(img: np.ndarray) -> object:
    import cv2
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    mask = cv2.inRange(hsv, (140, 150, 60), (160, 255, 255))
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return None
    c = max(contours, key=cv2.contourArea)
    return cv2.approxPolyDP(c, 0.02 * cv2.arcLength(c, True), True)


def _aruco_frame(view) -> np.ndarray:
    """The same frame with an ArUco marker warped onto the rhombus's bounding square."""
    import cv2
    tag = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(
        cv2.aruco.DICT_4X4_50), 3, 120)
    tag = cv2.copyMakeBorder(tag, 20, 20, 20, 20, cv2.BORDER_CONSTANT, value=255)
    v = view.rendered.vertices_px.astype(np.float32)  # left, top, right, bottom
    corners = np.array([[v[0, 0], v[1, 1]], [v[2, 0], v[1, 1]], [v[2, 0], v[3, 1]],
                        [v[0, 0], v[3, 1]]], np.float32)
    H = cv2.getPerspectiveTransform(np.array([[0, 0], [159, 0], [159, 159], [0, 159]],
                                             np.float32),
                                    corners)
    img = view.rendered.image.copy()
    warped = cv2.warpPerspective(cv2.cvtColor(tag, cv2.COLOR_GRAY2BGR), H, img.shape[1::-1])
    inside = cv2.warpPerspective(np.full((160, 160), 255, np.uint8), H, img.shape[1::-1]) > 0
    img[inside] = warped[inside]
    return img
