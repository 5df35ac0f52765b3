import asyncio
import contextlib
import math
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from schemas import Command
from schemas.keys import FRAME
from services.core.camera import CameraModel
from services.core.mounts import Geometry
from services.core.world import CircleObstacle, PolygonObstacle, World
from services.runtime.config import parse_deployment
from services.runtime.launcher import run_deployment
from services.sim.camera_robot import CameraRobot, CameraRobotParams
from services.sim.humanoid import Humanoid, HumanoidParams
from services.sim.render import RenderStyle, coverage_mask, render_view
from services.sim.scenes import marker_pose, random_views
from services.sim.webcam import srgb_to_linear
from tests.conftest import cli_here, wait_for, wait_matched_key


def test_projection_matches_opencv_with_distortion_and_adds_skew():
    dist = np.array([-0.25, 0.12, 0.001, -0.002, 0.03])
    K = np.array([[800.0, 0.0, 320.0], [0, 790.0, 240.0], [0, 0, 1]])
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-0.3, 0.3, 200), rng.uniform(-0.2, 0.2, 200),
                           rng.uniform(0.2, 2.0, 200)])
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist)
    ref = ref.reshape(-1, 2)
    assert np.abs(CameraModel(K, dist).project(pts) - ref).max() < 1e-6
    # OpenCV's model has no skew; ours (Zhang's) does: u = fx x_d + skew y_d + cx
    skewed = CameraModel(K + np.array([[0, 2.06, 0], [0, 0, 0], [0, 0, 0]]), dist).project(pts)
    y_d = (ref[:, 1] - 240.0) / 790.0
    assert np.abs(skewed[:, 0] - (ref[:, 0] + 2.06 * y_d)).max() < 1e-6


def test_rendered_vertices_are_the_projected_marker_model():
    cam, g = CameraModel.paper(), Geometry()
    T = marker_pose(0.3, 300, 220, cam, math.radians(30), 0.2, math.radians(10))
    r = render_view(cam, T, marker_points_m=g.marker_points())
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    ref, _ = cv2.projectPoints(g.marker_points(), rvec, T[:3, 3], cam.K, cam.dist)
    ref = ref.reshape(-1, 2)
    ref[:, 0] += cam.K[0, 1] * (ref[:, 1] - cam.K[1, 2]) / cam.K[1, 1]  # OpenCV drops skew
    assert np.abs(r.vertices_px - ref).max() < 1e-6
    assert r.marker_visible


@pytest.mark.parametrize("distance", [0.15, 0.3, 0.8])
def test_rasterised_area_matches_polygon_area(distance):
    cam, g = CameraModel.paper(), Geometry()
    T = marker_pose(distance, 330, 250, cam, math.radians(35), 0.0, math.radians(12))
    style = RenderStyle(noise_sigma=0, clutter=False, distractors=False, background_level=0,
                        draw_body=False)
    r = render_view(cam, T, marker_points_m=g.marker_points(), style=style)
    x, y = r.vertices_px[:, 0], r.vertices_px[:, 1]
    polygon = 0.5 * abs(x @ np.roll(y, -1) - y @ np.roll(x, -1))
    # the image itself, in linear light: green is 0 everywhere, (R + B) / 2 is coverage
    img = srgb_to_linear(r.image / 255.0)
    measured = (img[..., 0] + img[..., 2]).sum() / 2
    assert abs(measured - polygon) / polygon < 0.005
    assert abs(r.coverage_area_px - polygon) / polygon < 0.005


def test_coverage_of_a_half_plane_is_exact_per_pixel():
    square = np.array([[0.25, -5], [10, -5], [10, 5], [0.25, 5]])
    cov = coverage_mask(square, 0, 0, 2, 1)
    # pixel 0 spans [-0.5, 0.5]: the polygon from x = 0.25 covers a quarter of it
    assert cov[0, 0] == pytest.approx(0.25, abs=1 / 32) and cov[0, 1] == 1.0


def test_same_seed_same_frames():
    a = [v.rendered.image for v in random_views(3, seed=5)]
    b = [v.rendered.image for v in random_views(3, seed=5)]
    c = [v.rendered.image for v in random_views(3, seed=6)]
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0], c[0])


def _run(h: Humanoid, seconds: float, dt: float = 0.01) -> None:
    for _ in range(round(seconds / dt)):
        h.step(dt)


EXACT = HumanoidParams(slip_fraction=0.0, heading_drift_deg=0.0, turn_noise_fraction=0.0,
                       reaction_delay_s=0.2)


def test_the_humanoid_walks_in_whole_steps_and_a_stop_finishes_the_step():
    p = EXACT
    h = Humanoid(0.0, 0.0, 0.0, p)
    h.receive(Command.WALK_FORWARD)
    _run(h, 0.19)
    assert h.x == 0.0 and not h.moving  # the reaction delay
    _run(h, 1.0)  # 1 s of walking: one whole step and part of the next
    assert p.step_length_m < h.x < 2 * p.step_length_m and h.moving
    h.receive(Command.STOP)
    _run(h, 1.0)
    assert h.x == pytest.approx(2 * p.step_length_m, abs=1e-9)  # the second step finished
    assert h.y == pytest.approx(0.0, abs=1e-9) and not h.moving
    h.receive(Command.WALK_BACKWARD)
    _run(h, 0.2 + p.step_period_s / 2)
    h.receive(Command.STOP)
    _run(h, 1.0)
    assert h.x == pytest.approx(2 * p.step_length_m - p.back_step_length_m, abs=1e-9)


def test_turns_are_whole_turning_steps():
    p = EXACT
    h = Humanoid(0.0, 0.0, 0.0, p)
    h.receive(Command.TURN_LEFT)
    _run(h, 0.2 + 2.5 * p.turn_period_s)
    h.receive(Command.STOP)
    _run(h, 1.0)
    assert h.yaw == pytest.approx(math.radians(3 * p.turn_step_deg), abs=1e-9)
    assert (h.x, h.y) == (0.0, 0.0)
    h.receive(Command.TURN_RIGHT)
    _run(h, 0.2 + 0.5 * p.turn_period_s)
    h.receive(Command.STOP)
    _run(h, 1.0)
    assert h.yaw == pytest.approx(math.radians(2 * p.turn_step_deg), abs=1e-9)


def test_the_body_sways_within_a_step_and_steps_drift_and_slip():
    p = HumanoidParams(slip_fraction=0.0, heading_drift_deg=0.0, reaction_delay_s=0.0,
                       sway_m=0.004)
    h = Humanoid(0.0, 0.0, 0.0, p)
    h.receive(Command.WALK_FORWARD)
    side = []
    for _ in range(round(2 * p.step_period_s / 0.01)):
        h.step(0.01)
        side.append(h.y)
    assert max(side) == pytest.approx(p.sway_m, rel=0.01)   # one step to the left,
    assert min(side) == pytest.approx(-p.sway_m, rel=0.01)  # the next to the right
    noisy = [Humanoid(0.0, 0.0, 0.0, HumanoidParams(reaction_delay_s=0.0), seed=s)
             for s in range(20)]
    for n in noisy:
        n.receive(Command.WALK_FORWARD)
        _run(n, 10 * n.params.step_period_s - 1e-6)
    q = noisy[0].params
    xs = np.array([n.x for n in noisy])
    yaws = np.degrees([n.yaw for n in noisy])
    assert 0.3 < xs.std() / (q.step_length_m * q.slip_fraction * math.sqrt(10)) < 3
    assert 0.3 < yaws.std() / (q.heading_drift_deg * math.sqrt(10)) < 3


def test_humanoid_walks_on_until_stopped_and_is_blocked_by_obstacles():
    world = World(obstacles=[CircleObstacle(x=0.5, y=0.0, radius=0.1)])
    h = Humanoid(0.0, 0.0, 0.0, HumanoidParams(slip_fraction=0, heading_drift_deg=0))
    h.receive(Command.WALK_FORWARD)
    for _ in range(2000):
        h.step(0.01, world)
    limit = 0.5 - 0.1 - h.params.radius_m  # touching the obstacle
    assert limit - h.params.step_length_m < h.x <= limit  # the last whole step that fits


def test_camera_robot_reaches_a_goal_within_limits():
    r = CameraRobot(0.0, 0.0, 0.0, CameraRobotParams(max_speed_mps=0.2))
    r.goal = (0.5, 0.3, math.pi / 2)
    speeds = []
    for _ in range(1500):
        r.step(0.01)
        speeds.append(abs(r.v))
    assert math.hypot(r.x - 0.5, r.y - 0.3) < 0.01
    assert abs(r.yaw - math.pi / 2) < 0.02
    assert max(speeds) <= 0.2 + 1e-9
    assert max(np.abs(np.diff(speeds))) <= 0.5 * 0.01 + 1e-9


def test_camera_robot_stops_short_of_an_obstacle():
    world = World(obstacles=[PolygonObstacle(points=[(0.4, -0.5), (0.5, -0.5), (0.5, 0.5),
                                                     (0.4, 0.5)])])
    r = CameraRobot(0.0, 0.0, 0.0)
    r.goal = (1.0, 0.0, 0.0)
    for _ in range(1500):
        r.step(0.01, world)
    assert r.blocked and r.x < 0.4 - r.params.radius_m + 1e-3
    assert world.clearance(r.x, r.y) >= r.params.radius_m


def test_sim_snapshot_of_a_fresh_scene(tmp_path: Path):
    out = cli_here("sim", "snapshot", "--fresh", "--out", str(tmp_path / "f.png"))
    assert out.returncode == 0, out.stderr
    img = cv2.imread(str(tmp_path / "f.png"))
    assert img is not None and img.shape == (480, 640, 3)
    magenta = (img[..., 0] > 200) & (img[..., 2] > 200) & (img[..., 1] < 60)
    assert magenta.sum() > 5000  # the rhombus fills about 5% of the image at 25 cm


@pytest.mark.slow
def test_frame_source_publishes_an_image_folder_and_survives_a_missing_device(
        tmp_path: Path, router, make_bus, sessions):
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i}.png"), np.full((24, 32, 3), 40 * i, np.uint8))
    looping = parse_deployment({
        "zenoh": {"connect": [router], "multicast_scouting": False},
        "services": {"frame_source": {"source": str(folder), "fps": 20, "loop": True}}})
    once = parse_deployment({
        "zenoh": {"connect": [router], "multicast_scouting": False},
        "services": {"frame_source": {"source": str(folder), "fps": 20, "loop": False}}})
    missing = parse_deployment({
        "zenoh": {"connect": [router], "multicast_scouting": False},
        "services": {"frame_source": {"source": "/dev/video99", "retry_s": 0.2}}})
    bus = make_bus("viewer")

    async def go():
        frames = bus.subscribe_frames(latest=False, queue=64)
        await wait_matched_key(sessions(), bus.keys.key(FRAME))  # the router has our subscriber
        await run_deployment(looping, duration=2.0)
        got: list = []

        def taken(n: int) -> bool:  # frames may still be on their way
            got.extend(iter(frames.get_nowait, None))
            return len(got) >= n
        with contextlib.suppress(pytest.fail.Exception):  # the assert below says how many
            await wait_for(lambda: taken(20), "20 frames", timeout=10)
        # (the very first frame may go out before the new session has seen our subscriber)
        seqs = [f.header.seq for f in got]
        levels = [int(f.image[0, 0, 0]) for f in got]
        assert len(got) >= 20 and seqs == list(range(seqs[0], seqs[0] + len(seqs)))
        assert levels == [[0, 40, 80][s % 3] for s in seqs]  # the folder, in name order, looped
        await asyncio.wait_for(run_deployment(once), 15)  # not looping: ends by itself
        got.clear()
        with contextlib.suppress(pytest.fail.Exception):
            await wait_for(lambda: taken(1) and got[-1].header.seq == 2, "the last image",
                           timeout=10)
        tail = [f.header.seq for f in got]
        assert tail and tail[-1] == 2 and tail == sorted(tail)
        # a device that is not there: the service keeps retrying, never crashes
        code = await run_deployment(missing, duration=1.5)
        assert code == 0
    asyncio.run(go())


def test_odometry_comes_at_its_own_rate_late_and_biased():
    from services.sim.service import OdometryFeed
    robot = CameraRobot(0.0, 0.0, 0.0, CameraRobotParams(odom_bias=(0.01, 0.0, 0.0),
                                                         odom_noise_m=0.0, odom_noise_rad=0.0))
    feed = OdometryFeed(hz=20.0, latency_s=0.02)
    released = []
    for k in range(30):  # one second of 30 fps frames
        now_ns = k * 33_333_333
        released += [(now_ns, s) for s in feed.tick(k / 30, now_ns, robot.odometry)]
    assert 18 <= len(released) <= 21  # about 20 a second, not 30
    assert all(now - s.stamp_ns >= 20_000_000 for now, s in released)  # never early
    assert all(s.x == pytest.approx(0.01) for _, s in released)


@pytest.mark.slow
def test_the_shipped_calibration_of_the_simulated_camera_is_ours_and_close_to_the_truth():
    from services.data import SIM_CAMERA
    from services.tools.sim_calibration import calibrate_simulated
    shipped = CameraModel.load(SIM_CAMERA)
    cal = calibrate_simulated(CameraModel.paper())
    assert np.allclose(shipped.K, cal.K, rtol=1e-8, atol=1e-6)  # regenerated: the same file
    assert not np.array_equal(shipped.K, CameraModel.paper().K)  # a measurement, not truth
    assert np.allclose(shipped.K, CameraModel.paper().K, rtol=2e-3, atol=0.5)


def test_without_scikit_image_a_procedural_room_stands_in(monkeypatch):
    from services.sim import textures
    monkeypatch.setattr(textures, "_skimage_data", lambda: None)
    textures.photo_srgb.cache_clear()
    textures.photo_scene.cache_clear()
    try:
        assert not textures.have_photos()
        room = textures.photo_scene(160, 120, 3)
        assert room.shape == (120, 160, 3) and 0.0 <= room.min() and room.max() <= 1.0
        assert room.std() > 0.01  # textured, not flat
        again = textures.photo_srgb(textures.WALL_PHOTOS[0])
        assert np.array_equal(again, textures._procedural(zlib.crc32(b"astronaut.png")))
    finally:
        textures.photo_srgb.cache_clear()
        textures.photo_scene.cache_clear()
