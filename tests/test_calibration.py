"""Calibration checked on real data with published results, and on simulated grids."""

import asyncio
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from schemas import CameraIntrinsics
from schemas.keys import INTRINSICS
from services.calibration.detect import DetectionError, detect_grid, detect_squares
from services.calibration.pattern import GridSheet, PatternSpec
from services.calibration.run import read_image
from services.calibration.synthetic import board_pose, render_plane
from services.calibration.zhang import CalibrationError, calibrate
from services.core.camera import CameraModel
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from tests.conftest import DATASETS, cli_here, run_cli, wait_alive_async

ZHANG = DATASETS / "zhang1998_calibration"
OPENCV = DATASETS / "opencv_left_chessboard"
# Zhang's published result (Calib.txt): alpha, gamma, beta, u0, v0; k1, k2
PUBLISHED = {"alpha": 832.5, "gamma": 0.204494, "beta": 832.53, "u0": 303.959, "v0": 206.585,
             "k1": -0.228601, "k2": 0.190353}


def _zhang_points():
    model = np.loadtxt(ZHANG / "Model.txt").reshape(-1, 2)
    return model, [np.loadtxt(ZHANG / f"data{i}.txt").reshape(-1, 2) for i in range(1, 6)]


def _params(K, dist):
    return {"alpha": K[0, 0], "beta": K[1, 1], "gamma": K[0, 1], "u0": K[0, 2], "v0": K[1, 2],
            "k1": dist[0], "k2": dist[1]}


def test_zhang_points_reproduce_his_published_calibration():
    model, data = _zhang_points()
    cal = calibrate([model] * 5, data)
    got = _params(cal.K, cal.dist)
    for k in ("alpha", "beta", "u0", "v0"):
        assert abs(got[k] - PUBLISHED[k]) / PUBLISHED[k] < 0.001, (k, got[k])
    assert abs(got["gamma"] - PUBLISHED["gamma"]) < 0.01
    assert abs(got["k1"] - PUBLISHED["k1"]) < 0.002 and abs(got["k2"] - PUBLISHED["k2"]) < 0.002
    assert cal.rms_px == pytest.approx(0.3364, abs=0.002)  # what his values give
    assert cal.per_view_rms_px == pytest.approx([0.347, 0.231, 0.540, 0.236, 0.211], abs=0.002)


def test_closed_form_alone_is_close_and_refinement_improves_it():
    model, data = _zhang_points()
    rough = calibrate([model] * 5, data, refine=False)
    fine = calibrate([model] * 5, data)
    assert abs(rough.K[0, 0] - 832.5) / 832.5 < 0.1  # distortion ignored: about 5% off
    assert fine.rms_px < rough.rms_px


def test_too_few_views_is_a_clear_error():
    model, data = _zhang_points()
    with pytest.raises(CalibrationError, match="at least 3"):
        calibrate([model] * 2, data[:2])


@pytest.mark.parametrize("i", range(1, 6))
def test_squares_detector_matches_zhangs_points(i):
    pts = detect_squares(read_image(ZHANG / f"CalibIm{i}.gif"))
    ref = np.loadtxt(ZHANG / f"data{i}.txt").reshape(-1, 2)
    assert pts.shape == (256, 2)
    assert np.median(np.linalg.norm(pts - ref, axis=1)) <= 0.3


def test_zhangs_images_calibrate_within_1_percent(tmp_path: Path):
    out = cli_here("calibrate", "intrinsics", *map(str, sorted(ZHANG.glob("CalibIm*.gif"))),
                   "--pattern", "squares:8x8:0.0127:0.0225778", "--out",
                   str(tmp_path / "cam.toml"), "--plots", str(tmp_path / "plots"))
    assert out.returncode == 0, out.stderr
    cam = CameraModel.load(tmp_path / "cam.toml")
    got = _params(cam.K, cam.dist)
    for k in ("alpha", "beta", "u0", "v0"):
        assert abs(got[k] - PUBLISHED[k]) / PUBLISHED[k] < 0.01, (k, got[k])
    assert abs(got["k1"] - PUBLISHED["k1"]) < 0.01
    assert len(list((tmp_path / "plots").glob("*.png"))) == 5
    fs = cv2.FileStorage(str(tmp_path / "cam.yaml"), cv2.FILE_STORAGE_READ)
    assert np.allclose(fs.getNode("camera_matrix").mat(), cam.K)
    fs.release()


def test_opencv_chessboards_within_1_percent_of_cv2_calibrate_camera(tmp_path: Path):
    paths = sorted(OPENCV.glob("left*.jpg"))
    out = cli_here("calibrate", "intrinsics", *map(str, paths), "--pattern",
                   "chessboard:9x6:1.0", "--out", str(tmp_path / "cam.toml"))
    assert out.returncode == 0, out.stderr
    ours = CameraModel.load(tmp_path / "cam.toml")
    obj = np.zeros((54, 3), np.float32)
    obj[:, :2] = np.indices((9, 6)).T.reshape(-1, 2)
    img_pts = []
    for p in paths:
        g = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        _, c = cv2.findChessboardCorners(g, (9, 6))
        img_pts.append(cv2.cornerSubPix(g, c, (5, 5), (-1, -1), (
            cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.1)))
    for flags in (0, cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3):
        _, K, *_ = cv2.calibrateCamera([obj] * len(paths), img_pts, (640, 480), None, None,
                                       flags=flags)
        for (i, j) in ((0, 0), (1, 1), (0, 2), (1, 2)):
            assert abs(ours.K[i, j] - K[i, j]) / K[i, j] < 0.01, (flags, i, j)
    # and OpenCV's own published reference
    assert ours.K[0, 0] == pytest.approx(532.80992189, rel=0.01)
    assert ours.K[1, 2] == pytest.approx(233.8879292, rel=0.01)


@pytest.fixture(scope="module")
def simulated_grid_views():
    cam = CameraModel(np.array([[780.0, 0.0, 325.0], [0, 785.0, 238.0], [0, 0, 1]]),
                      np.array([-0.22, 0.09, 0.0, 0.0, 0.0]))
    sheet, ppm = GridSheet(), 10.0
    tex = sheet.raster(ppm, page=False)
    origin = ((sheet.overhang_mm + 5) * ppm,) * 2
    model = PatternSpec.parse("grid:9x9:0.02").model_points()
    rng = np.random.default_rng(5)
    views = []
    for i in range(7):
        T = board_pose(rng.uniform(0.4, 0.5), math.radians(rng.uniform(-35, 35)),
                       math.radians(rng.uniform(-35, 35)), math.radians(rng.uniform(-25, 25)),
                       (0.08, 0.08), (rng.uniform(-30, 30), rng.uniform(-20, 20)), cam)
        img = render_plane(cam, T, tex, ppm * 1000, origin, seed=i, noise_sigma=2.0,
                           blur_sigma=0.6)
        truth = cam.project(np.column_stack([model, np.zeros(len(model))]) @ T[:3, :3].T
                            + T[:3, 3])
        views.append((img, truth))
    return cam, model, views


def test_grid_detector_finds_81_ordered_points_sub_pixel(simulated_grid_views):
    _, _, views = simulated_grid_views
    for img, truth in views:
        pts = detect_grid(img)
        assert pts.shape == (81, 2)
        # a board rolled near 45 degrees may be labelled from another corner (still a proper
        # rotation, which is all calibration needs): compare with the nearest true point
        d = np.linalg.norm(pts[:, None] - truth[None], axis=2)
        assert len(set(d.argmin(1))) == 81
        err = d.min(1)
        assert np.median(err) < 0.05 and np.percentile(err, 95) < 0.3


def test_simulated_grid_calibration_recovers_the_camera(simulated_grid_views):
    cam, model, views = simulated_grid_views
    cal = calibrate([model] * len(views), [detect_grid(img) for img, _ in views])
    assert abs(cal.K[0, 0] - cam.K[0, 0]) / cam.K[0, 0] < 0.002
    assert abs(cal.K[1, 1] - cam.K[1, 1]) / cam.K[1, 1] < 0.002
    assert abs(cal.K[0, 2] - cam.K[0, 2]) < 1.0 and abs(cal.K[1, 2] - cam.K[1, 2]) < 1.0
    assert abs(cal.dist[0] - cam.dist[0]) < 0.01


def test_no_grid_is_a_clear_detection_error():
    with pytest.raises(DetectionError):
        detect_grid(np.full((480, 640), 200, np.uint8))


@pytest.mark.slow
def test_intrinsics_cli_skips_bad_views_and_needs_three(tmp_path: Path):
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 128, np.uint8))
    paths = sorted(ZHANG.glob("CalibIm*.gif"))
    out = run_cli("calibrate", "intrinsics", str(blank), *map(str, paths[:2]), "--pattern",
                  "squares:8x8:0.0127:0.0225778", "--out", str(tmp_path / "c.toml"))
    assert out.returncode == 2
    assert "blank.png: skipped" in out.stdout and "need at least 3" in out.stderr
    out = run_cli("calibrate", "intrinsics", str(blank), *map(str, paths), "--pattern",
                  "squares:8x8:0.0127:0.0225778", "--out", str(tmp_path / "c.toml"))
    assert out.returncode == 0 and "views_skipped = 1" in (tmp_path / "c.toml").read_text()
    assert run_cli("calibrate", "intrinsics", str(blank), "--pattern", "hex:3").returncode == 2


@pytest.mark.parametrize("suffix", ["pdf", "svg", "png"])
def test_pattern_is_drawn_at_exact_physical_size(tmp_path: Path, suffix):
    out = tmp_path / f"grid.{suffix}"
    res = cli_here("calibrate", "pattern", "--out", str(out), "--dpi", "200")
    assert res.returncode == 0, res.stderr
    data = out.read_bytes()
    if suffix == "pdf":
        assert data.startswith(b"%PDF") and b"/MediaBox [0 0 595.28 841.89]" in data
        assert data.count(b" re f") == 18 + 1 + 11  # 18 lines, the scale bar and its ticks
    elif suffix == "svg":
        assert b'width="210.0mm"' in data and data.count(b"<rect") == 1 + 18 + 12
    else:
        assert b"pHYs" in data[:100]
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
        assert img is not None and img.shape == (round(297 / 25.4 * 200), round(210 / 25.4 * 200))
        # the printed grid is itself detectable, with the right pitch
        pts = detect_grid(img).reshape(9, 9, 2)
        pitch_px = np.median(np.diff(pts[:, :, 0], axis=1))
        assert pitch_px == pytest.approx(20 / 25.4 * 200, rel=0.002)


def test_calibration_service_serves_the_file(tmp_path: Path, router, make_bus):
    (tmp_path / "cam.toml").write_text(CameraModel.paper().to_toml())
    dep = parse_deployment({"zenoh": {"connect": [router], "multicast_scouting": False},
                            "services": {"calibration": {"intrinsics": "cam.toml"}}},
                           tmp_path / "d.toml")
    bus = make_bus("asker")

    async def go():
        task = asyncio.create_task(run_deployment(dep, duration=10))
        await wait_alive_async(bus.session, "calibration")
        replies = await bus.get(INTRINSICS, CameraIntrinsics, timeout=2)
        task.cancel()
        return replies
    replies = asyncio.run(go())
    assert replies and replies[0].K[0][0] == pytest.approx(757.25)
