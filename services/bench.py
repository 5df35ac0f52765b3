"""``shepherd bench``: each measurement printed beside the reference it competes with.

Sections: ``bus`` (one Zenoh hop, ours vs raw zenoh-python), ``vertices`` (rhombus extraction
vs OpenCV's contour route, ArUco and AprilTag on the same frames), ``pose`` (per-pose time
and accuracy vs cv2.solvePnP), ``calibration`` (pattern detection and Zhang vs
cv2.calibrateCamera), ``e2e`` (frame to ``humanoid/pose`` through the services).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import socket
import sys
import time
from collections.abc import Callable, Sequence

import numpy as np

Row = tuple[str, ...]


def _table(header: Row, rows: Sequence[Row]) -> str:
    widths = [max(len(str(r[i])) for r in (header, *rows)) for i in range(len(header))]
    line = "| " + " | ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)) + " |"
    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    body = ["| " + " | ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True)) + " |"
            for r in rows]
    return "\n".join([line, sep, *body])


def _section(title: str, header: Row, rows: Sequence[Row], note: str = "") -> None:
    print(f"\n## {title}\n\n{_table(header, rows)}")
    if note:
        print(f"\n{note}")
    sys.stdout.flush()


def _times_us(fn: Callable[[], object], n: int) -> np.ndarray:
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter_ns()
        fn()
        out[i] = (time.perf_counter_ns() - t0) / 1e3
    return out


def _endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _progress(what: str) -> None:
    print(f"  … {what}", file=sys.stderr, flush=True)


# -- bus ------------------------------------------------------------------------------------

def bench_bus(quick: bool) -> None:
    """One hop between two sessions over loopback TCP: ping latency and flat-out rate."""
    from schemas import CameraPose
    from services.bus import ZenohSettings, encode_frame, open_session

    n = 200 if quick else 1000
    ep = _endpoint()
    image = np.random.default_rng(0).integers(0, 255, (480, 640, 3), dtype=np.uint8)
    header, frame_bytes = encode_frame(image, 0, 0)
    msg = CameraPose(x=1.0, y=2.0, yaw=0.3)
    rows: list[Row] = []
    with open_session(ZenohSettings(listen=[ep], multicast_scouting=False)) as a, \
            open_session(ZenohSettings(connect=[ep], multicast_scouting=False)) as b:
        time.sleep(0.5)
        for kind, payload in (("JSON message", msg.model_dump_json().encode()),
                              ("640x480 bgr8 frame", frame_bytes)):
            _progress(f"bus: {kind}")
            raw = _raw_hop(a, b, payload, n)
            bridged = asyncio.run(_raw_asyncio_hop(a, b, payload, n))
            ours = asyncio.run(_our_hop(a, b, kind, msg, header, frame_bytes, n))
            for name, (lat, rate) in (("raw zenoh-python (callback thread)", raw),
                                      ("raw zenoh -> asyncio (call_soon_threadsafe)", bridged),
                                      ("shepherd bus (typed, validated, asyncio)", ours)):
                rows.append((kind, name, f"{np.median(lat):.0f}", f"{np.percentile(lat, 99):.0f}",
                             f"{rate:,.0f}", f"{np.median(lat) / np.median(raw[0]):.2f}",
                             f"{np.median(lat) / np.median(bridged[0]):.2f}"))
    _section("Bus: one hop over loopback TCP (two sessions, one process)",
             ("payload", "layer", "p50 µs", "p99 µs", "msgs/s flat out", "p50 / raw",
              "p50 / raw->asyncio"), rows,
             "Ours = typed publish + validation on receipt + delivery into asyncio. "
             "Goal: p50 within 1.20 of raw. Most of the gap is the hand-over from Zenoh's "
             "thread to the event loop, which any asyncio consumer pays (second row).")


def _raw_hop(a, b, payload: bytes, n: int) -> tuple[np.ndarray, float]:
    import threading
    got = threading.Event()
    count = [0]

    last = [0.0]

    def on_sample(_s: object) -> None:
        count[0] += 1
        last[0] = time.perf_counter()
        got.set()

    sub = b.declare_subscriber("bench/raw", on_sample)
    pub = a.declare_publisher("bench/raw")
    time.sleep(0.3)
    lat = np.empty(n)
    for i in range(n):
        got.clear()
        t0 = time.perf_counter_ns()
        pub.put(payload)
        got.wait(2.0)
        lat[i] = (time.perf_counter_ns() - t0) / 1e3
    count[0] = 0
    t0 = time.perf_counter()
    for _ in range(n):
        pub.put(payload)
    deadline = time.perf_counter() + 2.0
    while count[0] < n and time.perf_counter() < deadline:
        time.sleep(0.001)
    rate = count[0] / max(last[0] - t0, 1e-9)
    pub.undeclare()
    sub.undeclare()
    return lat, rate


async def _raw_asyncio_hop(a, b, payload: bytes, n: int):
    loop = asyncio.get_running_loop()
    queue: asyncio.Queue[bytes] = asyncio.Queue()
    sub = b.declare_subscriber(
        "bench/rawa", lambda s: loop.call_soon_threadsafe(queue.put_nowait, s.payload.to_bytes()))
    pub = a.declare_publisher("bench/rawa")
    await asyncio.sleep(0.3)
    lat = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter_ns()
        pub.put(payload)
        await asyncio.wait_for(queue.get(), 2.0)
        lat[i] = (time.perf_counter_ns() - t0) / 1e3
    t0 = time.perf_counter()
    for _ in range(n):
        pub.put(payload)
    got = 0
    last = t0
    try:
        while got < n:
            await asyncio.wait_for(queue.get(), 0.5)
            got += 1
            last = time.perf_counter()
    except TimeoutError:
        pass
    pub.undeclare()
    sub.undeclare()
    return lat, got / max(last - t0, 1e-9)


async def _our_hop(a, b, kind, msg, header, frame_bytes, n):
    from schemas import CameraPose, Keys
    from schemas.keys import ODOM
    from services.bus import Bus
    pub, sub_bus = Bus(a, Keys("bench"), "pub"), Bus(b, Keys("bench"), "sub")
    is_frame = kind.startswith("640")
    sub = sub_bus.subscribe_frames(latest=False, queue=n) if is_frame else \
        sub_bus.subscribe(ODOM, CameraPose, latest=False, queue=n)
    await asyncio.sleep(0.3)

    def send() -> None:
        if is_frame:
            pub.put_frame(header, frame_bytes)
        else:
            pub.put(ODOM, msg)

    lat = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter_ns()
        send()
        await sub.recv(2.0)
        lat[i] = (time.perf_counter_ns() - t0) / 1e3
    t0 = time.perf_counter()
    for _ in range(n):
        send()
    got = 0
    last = t0
    try:
        while got < n:
            await sub.recv(0.5)
            got += 1
            last = time.perf_counter()
    except TimeoutError:
        pass
    rate = got / max(last - t0, 1e-9)
    pub.close()
    sub_bus.close()
    return lat, rate


# -- vertices -------------------------------------------------------------------------------

def bench_vertices(quick: bool) -> None:
    import cv2

    from services.sim.scenes import random_views
    from services.vertex_extractor.extractor import RhombusExtractor
    n = 60 if quick else 200
    _progress(f"vertices: rendering {n} frames")
    views = list(random_views(n, seed=42, distance_m=(0.2, 0.6)))
    frames = [v.rendered.image for v in views]
    aruco_frames = [_aruco_frame(v) for v in views]
    ex = RhombusExtractor()

    def cold(img: np.ndarray) -> object:
        ex.reset()
        return ex.extract(img)

    tracked_t = []
    for img in frames:
        ex.reset()
        ex.extract(img)
        tracked_t.append(_times_us(lambda img=img: ex.extract(img), 5))
    cold_t = np.concatenate([_times_us(lambda img=img: cold(img), 3) for img in frames])
    contour_t = np.concatenate([_times_us(lambda img=img: _contour_route(img), 3)
                                for img in frames])
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
    aruco_t = np.concatenate([_times_us(lambda img=img: detector.detectMarkers(img), 3)
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
                        np.concatenate([_times_us(lambda g=g: det.detect(g), 3) for g in grey])))
    except ImportError:
        rows.append(("AprilTag", "not installed: pip install '.[bench]'", "", ""))
    for name, t in entries:
        rows.append((name, f"{np.median(t) / 1e3:.3f}", f"{np.percentile(t, 99) / 1e3:.3f}",
                     f"{np.median(t) / ref:.2f}"))
    errs = []
    for v in views:
        ex.reset()
        d = ex.extract(v.rendered.image)
        if d.found:
            errs.append(np.linalg.norm(d.vertices_px - v.rendered.vertices_px, axis=1))
    e = np.concatenate(errs)
    _section(f"Vertex extraction, {n} simulated 640x480 frames (20-60 cm)",
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
    H = cv2.getPerspectiveTransform(np.float32([[0, 0], [159, 0], [159, 159], [0, 159]]),
                                    corners)
    img = view.rendered.image.copy()
    warped = cv2.warpPerspective(cv2.cvtColor(tag, cv2.COLOR_GRAY2BGR), H, img.shape[1::-1])
    inside = cv2.warpPerspective(np.full((160, 160), 255, np.uint8), H, img.shape[1::-1]) > 0
    img[inside] = warped[inside]
    return img


# -- pose -----------------------------------------------------------------------------------

def bench_pose(quick: bool) -> None:
    import cv2

    from services.camera import CameraModel
    from services.config import Geometry
    from services.pose_estimator.estimate import estimate_marker_pose, undistort_px
    from services.pose_estimator.evaluate import compare, pose_cases, wrong_branches
    from services.pose_estimator.p4p import ippe
    cam = CameraModel.paper()
    pts = Geometry().marker_points()
    n = 300 if quick else 1000
    _progress(f"pose: {n} views")
    cases = pose_cases(n, seed=3)
    reps = 3
    timings: dict[str, np.ndarray] = {}
    timings["ours: IPPE analytic (undistort + both candidates)"] = np.concatenate([
        _times_us(lambda c=c: ippe(pts, undistort_px(cam, c.vertices_px)), reps)
        for c in cases])
    timings["ours: + upright MAP choice + Gauss-Newton"] = np.concatenate([
        _times_us(lambda c=c: estimate_marker_pose(cam, c.vertices_px, pts, up_cam=c.up_cam,
                                                   sigma_px=c.noise_px), reps) for c in cases])
    flags = {"cv2 IPPE": cv2.SOLVEPNP_IPPE, "cv2 ITERATIVE": cv2.SOLVEPNP_ITERATIVE,
             "cv2 SQPNP": cv2.SOLVEPNP_SQPNP, "cv2 AP3P": cv2.SOLVEPNP_AP3P}
    for name, flag in flags.items():
        timings[name] = np.concatenate([
            _times_us(lambda c=c, flag=flag: cv2.solvePnP(pts, *_cv_inputs(cam, c), flags=flag),
                      reps) for c in cases])
    ref = float(np.median(timings["cv2 IPPE"]))
    rows = [(k, f"{np.median(t):.1f}", f"{np.percentile(t, 99):.1f}", f"{np.median(t) / ref:.2f}")
            for k, t in timings.items()]
    _section(f"Pose: time per pose, {n} views", ("method", "median µs", "p99 µs",
                                                  "median / cv2 IPPE"), rows,
             "Goal: our analytic solve no slower than cv2 IPPE.")
    _progress("pose: accuracy")
    res = compare(cases, cam)
    rows = [(k, f"{1000 * np.median(p):.2f}", f"{1000 * np.percentile(p, 90):.2f}",
             f"{math.degrees(np.median(a)):.2f}", f"{math.degrees(np.percentile(a, 90)):.2f}")
            for k, (p, a) in res.items()]
    _section(f"Pose: accuracy on the same {n} views (15-80 cm, vertex noise 0.1-1 px)",
             ("method", "position median mm", "p90 mm", "rotation median °", "p90 °"), rows,
             "Goal: never worse than the best OpenCV method by more than 2%.")
    _progress("pose: IPPE branches")
    rows = []
    for lo, hi in ((0.05, 0.3), (0.1, 1.0)):
        noisy = cases if (lo, hi) == (0.1, 1.0) else pose_cases(n, seed=3, noise_px=(lo, hi))
        for prior in (True, False):
            r = wrong_branches(noisy, cam, prior=prior)
            rows.append((f"{lo}-{hi} px", "upright prior" if prior else "image only",
                         str(r.views), str(r.wrong), str(r.decidable), str(r.wrong_decidable),
                         str(r.search_misses)))
    _section(f"Pose: IPPE branch choice, {n} views (truth leans up to 2°, prior sigma 3°)",
             ("vertex noise", "choice by", "two branches", "wrong", "prior decides",
              "wrong there", "search misses"), rows,
             "'prior decides': the mirror branch is tilted > 4 sigma beyond the truth. "
             "Goal: never wrong there. 0.05-0.3 px is the vertex extractor's measured error; "
             "at 1 px an upright mirror can fit the image better than the truth (search misses "
             "= 0: every wrong pick is the posterior's own). Yaw mirrors, level on both "
             "branches, are left to the service's frame-to-frame continuity prior.")


def _cv_inputs(cam, case):
    v, K = cam.deskew_px(case.vertices_px)
    return v, K, cam.dist


# -- calibration ----------------------------------------------------------------------------

def bench_calibration(quick: bool) -> None:
    import cv2

    from services.calibration.detect import detect_chessboard, detect_grid, detect_squares
    from services.calibration.pattern import GridSheet, PatternSpec
    from services.calibration.run import read_image
    from services.calibration.synthetic import board_pose, render_plane
    from services.calibration.zhang import calibrate
    from services.camera import CameraModel
    from services.cli import DEFAULT_DEPLOYMENT
    datasets = DEFAULT_DEPLOYMENT.parent.parent.parent / "shared" / "datasets"
    reps = 3 if quick else 10
    rows: list[Row] = []
    # detection per image
    cam = CameraModel(np.array([[780.0, 0.0, 325.0], [0, 785.0, 238.0], [0, 0, 1]]),
                      np.array([-0.22, 0.09, 0.0, 0.0, 0.0]))
    sheet = GridSheet()
    tex = sheet.raster(10.0, page=False)
    origin = ((sheet.overhang_mm + 5) * 10.0,) * 2
    _progress("calibration: rendering grid views")
    rng = np.random.default_rng(1)
    grids = [render_plane(cam, board_pose(rng.uniform(0.4, 0.5), *np.radians(
        rng.uniform(-30, 30, 3)), (0.08, 0.08), (0, 0), cam), tex, 1e4, origin, seed=i)
        for i in range(4)]
    t = np.concatenate([_times_us(lambda g=g: detect_grid(g), reps) for g in grids])
    rows.append(("grid 9+9 lines, Hough + sub-pixel (ours), simulated 640x480",
                 f"{np.median(t) / 1e3:.1f}"))
    zhang = datasets / "zhang1998_calibration"
    opencv = datasets / "opencv_left_chessboard"
    if zhang.is_dir():
        imgs = [read_image(p) for p in sorted(zhang.glob("CalibIm*.gif"))]
        t = np.concatenate([_times_us(lambda g=g: detect_squares(g), reps) for g in imgs])
        rows.append(("Zhang's 8x8 squares (ours), his 5 images", f"{np.median(t) / 1e3:.1f}"))
    if opencv.is_dir():
        imgs = [read_image(p) for p in sorted(opencv.glob("left*.jpg"))]
        t = np.concatenate([_times_us(lambda g=g: detect_chessboard(g, 9, 6), reps)
                            for g in imgs])
        rows.append(("chessboard 9x6: cv2.findChessboardCorners + cornerSubPix, OpenCV's 13",
                     f"{np.median(t) / 1e3:.1f}"))
    _section("Calibration: pattern detection per image", ("detector", "median ms"), rows)
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
        ours_t = _times_us(lambda m=models, i=images: calibrate(m, i), reps)
        ours = calibrate(models, images)
        obj = [np.column_stack([m, np.zeros(len(m))]).astype(np.float32) for m in models]
        img = [i.astype(np.float32).reshape(-1, 1, 2) for i in images]
        flags = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
        cv_t = _times_us(lambda o=obj, i=img, s=size, f=flags: cv2.calibrateCamera(
            o, i, s, None, None, flags=f), reps)
        rms, K, dist, *_ = cv2.calibrateCamera(obj, img, size, None, None, flags=flags)
        rows.append((name, "ours (Zhang + LM)", f"{np.median(ours_t) / 1e3:.1f}",
                     f"{ours.K[0, 0]:.2f}", f"{ours.K[1, 1]:.2f}",
                     f"{ours.K[0, 2]:.2f}, {ours.K[1, 2]:.2f}", f"{ours.dist[0]:.4f}",
                     f"{ours.rms_px:.4f}"))
        rows.append(("", "cv2.calibrateCamera (k1, k2 only)", f"{np.median(cv_t) / 1e3:.1f}",
                     f"{K[0, 0]:.2f}", f"{K[1, 1]:.2f}", f"{K[0, 2]:.2f}, {K[1, 2]:.2f}",
                     f"{dist.ravel()[0]:.4f}", f"{rms:.4f}"))
    _section("Calibration: the whole solve on the same points",
             ("points", "method", "median ms", "fx", "fy", "u0, v0", "k1", "RMS px"), rows,
             "Zhang's published values: fx 832.50, fy 832.53, (303.96, 206.59), k1 -0.2286, "
             "RMS 0.336. Simulated truth: fx 780, fy 785, (325, 238), k1 -0.22. OpenCV's model "
             "has no skew; ours estimates it.")


# -- end to end ------------------------------------------------------------------------------

E2E_DEPLOYMENT = """
[zenoh]
connect = ["{ep}"]
multicast_scouting = false
[services.vertex_extractor]
[services.pose_estimator]
intrinsics = "{intrinsics}"
static_camera_pose = [0.0, 0.0, 0.0]
"""


def bench_e2e(quick: bool) -> None:
    """Frame published -> humanoid/pose received, through the vertex extractor and pose
    estimator services, in one process and with one process per service."""
    import subprocess
    import tempfile
    from pathlib import Path

    from services.cli import DEFAULT_DEPLOYMENT
    from services.config import load_deployment
    from services.launcher import run_deployment
    dur = 3.0 if quick else 8.0
    frames = _e2e_frames(60)
    ep = _endpoint()
    rows: list[Row] = []
    intrinsics = DEFAULT_DEPLOYMENT.parent / "paper-camera.toml"
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "e2e.toml"
        path.write_text(E2E_DEPLOYMENT.format(ep=ep, intrinsics=intrinsics))
        dep = load_deployment(path)
        for mode in E2E_MODES:
            for rate in (30.0, None):
                _progress(f"e2e: {mode}, {'30 fps' if rate else 'flat out'}")
                if mode == E2E_MODES[0]:
                    res = asyncio.run(_e2e_run(ep, frames, rate, dur, lambda s: run_deployment(
                        dep, duration=dur + 4, session=s)))
                elif mode == E2E_MODES[1]:
                    res = asyncio.run(_e2e_run(ep, frames, rate, dur, lambda s: run_deployment(
                        dep, duration=dur + 4)))
                else:
                    proc = subprocess.Popen([sys.executable, "-m", "services.cli",
                                             "--log-level", "WARNING", "run", str(path),
                                             "--processes"])
                    try:
                        res = asyncio.run(_e2e_run(ep, frames, rate, dur, None))
                    finally:
                        proc.terminate()
                        proc.wait(10)
                lat, sent, got, first, last = res
                rows.append((mode, "30 fps" if rate else "flat out", f"{sent / dur:.0f}",
                             f"{got / dur:.0f}", f"{np.median(lat):.2f}",
                             f"{np.percentile(lat, 99):.2f}", f"{first:.2f} -> {last:.2f}"))
    _section("End to end: frame published -> humanoid/pose received (640x480 bgr8)",
             ("deployment", "rate", "frames/s sent", "poses/s", "p50 ms", "p99 ms",
              "p50 first s -> last s"), rows,
             "Latest-value frames: when the services fall behind, old frames are dropped, so "
             "the latency stays flat (last column) instead of growing. One session: the "
             "publisher shares the services' Zenoh session, as the simulator does in `shepherd "
             "run`; own session: the publisher is a second session in the process, reaching the "
             "services over TCP loopback, as a frame source on another machine would. Event "
             f"loop: {type(asyncio.get_event_loop_policy()).__module__.split('.')[0]}. Goal: "
             "p50 <= 1.5 ms and p99 <= 5 ms in one process at 30 fps; >= 200 frames/s "
             "sustained flat out.")


E2E_MODES = ("one process, one session", "one process, publisher's own session (TCP)",
             "one process per service")


def _e2e_frames(n: int) -> list[np.ndarray]:
    from schemas import Command
    from services.camera import CameraModel
    from services.config import Geometry
    from services.sim.state import SimWorld
    from services.sim.world import World
    sim = SimWorld(camera=CameraModel.paper(), geometry=Geometry(), world=World(),
                   humanoid_start=(0.29, 0.0, 0.0), camera_start=(0.0, 0.0, 0.0))
    sim.command(Command.WALK_FORWARD)
    out = []
    for _ in range(n):
        sim.step(1 / 30)
        out.append(sim.render().image)
    return out


async def _e2e_run(ep: str, frames: list[np.ndarray], rate: float | None, duration: float,
                   services) -> tuple[np.ndarray, int, int, float, float]:
    from schemas import HumanoidPose, Keys
    from schemas.keys import HUMANOID_POSE
    from services.bus import Bus, ZenohSettings, encode_frame, open_session
    with open_session(ZenohSettings(listen=[ep], multicast_scouting=False)) as session:
        bus = Bus(session, Keys("shepherd"), "bench")
        poses = bus.subscribe_stamped(HUMANOID_POSE, HumanoidPose, queue=100000)
        task = asyncio.create_task(services(session)) if services else None
        await asyncio.sleep(2.5)  # services up, intrinsics loaded, discovery done
        sent_at: dict[int, int] = {}
        t0 = time.monotonic()
        seq = 0

        def publish() -> None:
            nonlocal seq
            stamp = time.time_ns()
            header, payload = encode_frame(frames[seq % len(frames)], seq, stamp)
            bus.put_frame(header, payload)
            sent_at[seq] = stamp
            seq += 1

        if rate:  # from the event loop, as the simulator service publishes
            while time.monotonic() - t0 < duration:
                publish()
                await asyncio.sleep(max(0.0, t0 + seq / rate - time.monotonic()))
        else:  # from a thread of its own, as a camera driver would: never starves the loop
            def flat_out() -> None:
                while time.monotonic() - t0 < duration:
                    publish()
                    time.sleep(0)  # let the services' thread have the GIL

            await asyncio.to_thread(flat_out)
        await asyncio.sleep(0.5)
        lat, when = [], []
        while (item := poses.get_nowait()) is not None:
            recv, p = item
            if p.seq in sent_at:
                lat.append((recv - sent_at[p.seq]) / 1e6)
                when.append((sent_at[p.seq] / 1e9) - (sent_at[0] / 1e9))
        if task:
            task.cancel()
            with contextlib.suppress(BaseException):
                await task
        bus.close()
    lat_a, when_a = np.array(lat or [float("nan")]), np.array(when or [0.0])
    first = float(np.median(lat_a[when_a < 1.0])) if np.any(when_a < 1.0) else float("nan")
    last = float(np.median(lat_a[when_a > duration - 1.0])) if np.any(
        when_a > duration - 1.0) else float("nan")
    return lat_a, seq, len(lat), first, last


# -- main -----------------------------------------------------------------------------------

SECTIONS: dict[str, Callable[[bool], None]] = {
    "bus": bench_bus, "vertices": bench_vertices, "pose": bench_pose,
    "calibration": bench_calibration, "e2e": bench_e2e,
}


def run_bench(only: list[str], quick: bool = False) -> int:
    unknown = [o for o in only if o not in SECTIONS]
    if unknown:
        print(f"shepherd: unknown bench section(s) {unknown}; expected {', '.join(SECTIONS)}",
              file=sys.stderr)
        return 2
    import platform
    print(f"# shepherd bench — {platform.processor() or platform.machine()}, "
          f"Python {platform.python_version()}, {'quick' if quick else 'full'} run")
    from services.cli import compile_kernels
    _progress("compiling the kernels (cached after the first run)")
    compile_kernels(sys.stderr)
    for name, fn in SECTIONS.items():
        if not only or name in only:
            fn(quick)
    return 0
